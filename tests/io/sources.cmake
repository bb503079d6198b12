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
# test_colmap runs the executable for the dataset warnings (it skips when the build has none).
if(TARGET crpgs_cli)
  set_property(SOURCE io/test_colmap.cpp APPEND PROPERTY COMPILE_DEFINITIONS
    CRPGS_CLI_PATH="$<TARGET_FILE:crpgs_cli>")
endif()
