# Sources of sdk/src/raster (paths relative to sdk/).
list(APPEND CRPGS_TORCH_SOURCES
  src/raster/stages.cpp          # project / intersect_tiles / rasterize_to_pixels, fwd + bwd
  src/raster/reference.cpp       # float64 plain-libtorch reference (tests, bench baseline)
  src/raster/cpu_rasterizer.cpp  # autograd wrapper, the `cpu` component and its descriptor
)
