# Sources of sdk/src/raster (paths relative to sdk/).
list(APPEND CRPGS_TORCH_SOURCES
  src/raster/stages.cpp          # project / intersect_tiles / rasterize_to_pixels, fwd + bwd
  src/raster/reference.cpp       # float64 plain-libtorch reference (tests, bench baseline)
  src/raster/cpu_rasterizer.cpp  # autograd wrapper, the `cpu` component and its descriptor
)
# No FP traps lets the compiler if-convert the pixel loops; no contraction keeps the alpha that
# forward and backward recompute bitwise identical.
set_source_files_properties(src/raster/stages.cpp PROPERTIES
  COMPILE_OPTIONS "-fno-trapping-math;-ffp-contract=off")
