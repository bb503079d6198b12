# Formatting: every tracked C++/CUDA source follows .clang-format (skips, exit 77, without
# clang-format).
add_test(NAME style.clang_format
  COMMAND ${CMAKE_CURRENT_SOURCE_DIR}/style/clang_format_check.sh ${PROJECT_SOURCE_DIR})
set_tests_properties(style.clang_format PROPERTIES SKIP_RETURN_CODE 77 TIMEOUT 300)
