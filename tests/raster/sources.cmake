# Test sources of tests/raster (paths relative to tests/).
list(APPEND CRPGS_TORCH_TEST_SOURCES raster/test_raster.cpp raster/test_cuda_raster.cpp)
