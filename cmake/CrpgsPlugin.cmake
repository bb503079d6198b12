# crpgs_add_plugin(<kind> <type> SOURCES ...): a MODULE library named
# libcrpgs_<kind>_<type>.so, hidden visibility, placed where the host looks for plugins.
function(crpgs_add_plugin kind type)
  cmake_parse_arguments(ARG "NO_INSTALL" "OUTPUT_DIR" "SOURCES" ${ARGN})
  set(target crpgs_${kind}_${type})
  add_library(${target} MODULE ${ARG_SOURCES})
  if(TARGET crpgs::crpgs)
    target_link_libraries(${target} PRIVATE crpgs::crpgs)
  else()
    target_link_libraries(${target} PRIVATE crpgs)
  endif()
  # ATen's at::parallel_for is a header template: without -fopenmp in the plugin's own TUs it
  # runs serially there, whatever the thread count.
  if(NOT DEFINED OpenMP_CXX_FOUND)
    find_package(OpenMP QUIET)  # out-of-tree plugins
  endif()
  if(OpenMP_CXX_FOUND)
    target_link_libraries(${target} PRIVATE OpenMP::OpenMP_CXX)
  endif()
  if(COMMAND crpgs_set_warnings)
    crpgs_set_warnings(${target})
  endif()
  if(NOT ARG_OUTPUT_DIR AND DEFINED CRPGS_PLUGIN_BUILD_DIR)
    set(ARG_OUTPUT_DIR ${CRPGS_PLUGIN_BUILD_DIR})
  endif()
  set_target_properties(${target} PROPERTIES PREFIX "lib" CXX_VISIBILITY_PRESET hidden
    VISIBILITY_INLINES_HIDDEN ON)
  if(ARG_OUTPUT_DIR)
    set_target_properties(${target} PROPERTIES LIBRARY_OUTPUT_DIRECTORY ${ARG_OUTPUT_DIR})
  endif()
  if(NOT ARG_NO_INSTALL AND DEFINED CRPGS_PLUGIN_SUBDIR)
    install(TARGETS ${target} LIBRARY DESTINATION ${CRPGS_PLUGIN_SUBDIR})
  endif()
endfunction()
