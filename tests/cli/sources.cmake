# Test sources of tests/cli (paths relative to tests/): CLI pieces that need no torch, compiled in.
list(APPEND CRPGS_BASE_TEST_SOURCES cli/test_progress_bar.cpp ../apps/progress_bar.cpp
  cli/test_cli_errors.cpp)
# test_cli_errors runs the executable (it skips, saying why, when the build has none).
if(TARGET crpgs_cli)
  set_property(SOURCE cli/test_cli_errors.cpp APPEND PROPERTY COMPILE_DEFINITIONS
    CRPGS_CLI_PATH="$<TARGET_FILE:crpgs_cli>")
endif()
