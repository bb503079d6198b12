# Plugin tests: the maths through the plugins' internal kernels (the hash grid's library,
# gaussian_coding compiled in here), the components through the registry (CRPGS_PLUGIN_BUILD_DIR).
list(APPEND CRPGS_TORCH_TEST_SOURCES
  plugins/test_hash_grid.cpp
  plugins/test_hash_grid_cuda.cpp
  plugins/test_gaussian_coding.cpp
  plugins/test_sfa.cpp
  ../plugins/entropy/gaussian/gaussian_coding.cpp)
set_source_files_properties(../plugins/entropy/gaussian/gaussian_coding.cpp PROPERTIES
  COMPILE_OPTIONS "-ffp-contract=off")
