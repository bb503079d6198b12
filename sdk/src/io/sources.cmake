# Sources of sdk/src/io (paths relative to sdk/).
list(APPEND CRPGS_BASE_SOURCES
  src/io/image.cpp
  src/io/metrics.cpp
  src/io/gaussian_blur.cpp  # the SSIM window's float passes, runtime ISA dispatch
  src/io/json.cpp
  src/io/npy.cpp
  src/io/colmap.cpp
  src/io/dataset.cpp
  src/io/ply.cpp)
# The clones must round alike: no FMA contraction.
set_source_files_properties(src/io/gaussian_blur.cpp PROPERTIES COMPILE_OPTIONS "-ffp-contract=off")
# Baking anchor models into 3DGS Gaussians (needs the anchor model, libtorch).
list(APPEND CRPGS_TORCH_SOURCES
  src/io/gaussian_export.cpp)
