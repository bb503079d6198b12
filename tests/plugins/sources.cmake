# Plugin tests: the maths through the plugins' internal kernels (compiled in here too), the
# components through the registry (CRPGS_PLUGIN_BUILD_DIR).
list(APPEND CRPGS_TORCH_TEST_SOURCES
  plugins/test_hash_grid.cpp
  plugins/test_hash_grid_cuda.cpp
  plugins/test_gaussian_coding.cpp
  plugins/test_sfa.cpp
  ../plugins/context/hash_grid/binary_grid.cpp
  ../plugins/context/hash_grid/hash_grid_kernels.cpp
  ../plugins/entropy/gaussian/gaussian_coding.cpp)
set_source_files_properties(../plugins/entropy/gaussian/gaussian_coding.cpp PROPERTIES
  COMPILE_OPTIONS "-ffp-contract=off")
# The grid kernels' ISA clones would take the precompiled header's options (contraction on).
include(${CMAKE_CURRENT_LIST_DIR}/../../plugins/context/hash_grid/kernel_options.cmake)
set_source_files_properties(../plugins/context/hash_grid/hash_grid_kernels.cpp PROPERTIES
  COMPILE_OPTIONS "${CRPGS_HASH_GRID_KERNEL_OPTIONS}" SKIP_PRECOMPILE_HEADERS ON)
