# Script mode, run at every build (sdk/CMakeLists.txt):
#   cmake -DSOURCE_DIR=<repo> -DOUTPUT=<header> -P CrpgsGitCommit.cmake
# Writes OUTPUT (#define CRPGS_GIT_COMMIT "<commit>[-dirty]") when it changed, so that
# `crpgs --version` and metrics.json name the commit a binary was built from ("unknown" outside a
# git checkout).
execute_process(COMMAND git -C "${SOURCE_DIR}" describe --always --dirty --abbrev=12
  OUTPUT_VARIABLE commit OUTPUT_STRIP_TRAILING_WHITESPACE ERROR_QUIET RESULT_VARIABLE rc)
if(NOT rc EQUAL 0 OR commit STREQUAL "")
  set(commit "unknown")
endif()
set(text "#define CRPGS_GIT_COMMIT \"${commit}\"\n")
set(old "")
if(EXISTS "${OUTPUT}")
  file(READ "${OUTPUT}" old)
endif()
if(NOT old STREQUAL text)
  file(WRITE "${OUTPUT}" "${text}")
endif()
