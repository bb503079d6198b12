# Test sources of tests/io (paths relative to tests/).
list(APPEND CRPGS_BASE_TEST_SOURCES
  io/test_image.cpp
  io/test_metrics.cpp
  io/test_colmap.cpp
  io/test_formats.cpp
  io/test_datasets.cpp
  io/test_ply.cpp)
# Baking anchor models into 3DGS Gaussians (needs libtorch).
list(APPEND CRPGS_TORCH_TEST_SOURCES io/test_gaussian_export.cpp)
