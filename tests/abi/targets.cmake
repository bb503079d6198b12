# Deliberately broken plugins for the ABI tests, in their own directory (CRPGS_TEST_PLUGIN_DIR) so
# the real plugin dir stays clean. Torch-free: only torch/version.h for the build info.
set(_broken_dir ${PROJECT_BINARY_DIR}/test_plugins)
set(_broken_cases
  "not_a_plugin\;BROKEN_NOT_A_PLUGIN"
  "wrong_abi\;BROKEN_WRONG_ABI"
  "bad_build_info\;BROKEN_BUILD_INFO"
  "create_fails\;BROKEN_CREATE_FAILS"
  "bad_schema\;BROKEN_SCHEMA"
  "dup_a\;BROKEN_DUP"
  "dup_b\;BROKEN_DUP")
foreach(case ${_broken_cases})
  list(GET case 0 name)
  list(GET case 1 define)
  set(t crpgs_test_${name})
  add_library(${t} MODULE ${CMAKE_CURRENT_SOURCE_DIR}/abi/broken_plugin.cpp)
  target_include_directories(${t} PRIVATE ${PROJECT_SOURCE_DIR}/sdk/include)
  target_include_directories(${t} SYSTEM PRIVATE ${TORCH_INCLUDE_DIRS})
  target_link_libraries(${t} PRIVATE yaml-cpp)
  if(define STREQUAL "BROKEN_DUP")
    target_compile_definitions(${t} PRIVATE ${define} BROKEN_TYPE="duplicated")
  else()
    target_compile_definitions(${t} PRIVATE ${define} BROKEN_TYPE="${name}")
  endif()
  set_target_properties(${t} PROPERTIES LIBRARY_OUTPUT_DIRECTORY ${_broken_dir}
    CXX_VISIBILITY_PRESET hidden)
  crpgs_set_warnings(${t})
  add_dependencies(crpgs_base_tests ${t})
endforeach()
# A file that is not even a shared library.
file(MAKE_DIRECTORY ${_broken_dir})
file(WRITE ${_broken_dir}/libcrpgs_test_garbage.so "this is not an ELF file\n")

# The SDK as a third party sees it: install, build examples/ against the installed package,
# load its plugins with the installed crpgs. Needs every target built (ctest runs after the build).
add_test(NAME abi.out_of_tree_example_plugins
  COMMAND ${CMAKE_CURRENT_SOURCE_DIR}/abi/out_of_tree.sh ${PROJECT_BINARY_DIR} ${PROJECT_SOURCE_DIR})
set_tests_properties(abi.out_of_tree_example_plugins PROPERTIES TIMEOUT 600)
