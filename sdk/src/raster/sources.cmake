# Sources of sdk/src/raster (paths relative to sdk/).
list(APPEND CRPGS_TORCH_SOURCES
  src/raster/stages.cpp          # project / intersect_tiles / rasterize_to_pixels, fwd + bwd
  src/raster/tile_kernels.cpp    # per-tile pixel loops (forward, backward), runtime ISA dispatch
  src/raster/reference.cpp       # float64 plain-libtorch reference (tests, bench baseline)
  src/raster/cpu_rasterizer.cpp  # autograd wrapper, the `cpu` component and its descriptor
)
# No FP traps lets the compiler if-convert the pixel loops; no contraction keeps the alpha that
# forward and backward recompute bitwise identical.
# -Wno-psabi: the kernels pass 32-byte vectors between inline helpers in the baseline clone.
set_source_files_properties(src/raster/stages.cpp PROPERTIES
  COMPILE_OPTIONS "-fno-trapping-math;-ffp-contract=off")
set_source_files_properties(src/raster/tile_kernels.cpp PROPERTIES
  COMPILE_OPTIONS "-fno-trapping-math;-ffp-contract=off;-Wno-psabi")
