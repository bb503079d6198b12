# Sources of sdk/src/raster (paths relative to sdk/). Also included by tools/cuda-check, so the
# per-file options name absolute paths.
list(APPEND CRPGS_TORCH_SOURCES
  src/raster/stages.cpp          # project / intersect_tiles / rasterize_to_pixels, fwd + bwd
  src/raster/tile_kernels.cpp    # per-tile pixel loops (forward, backward), runtime ISA dispatch
  src/raster/project_kernels.cpp # projection forward + backward, 4 Gaussians per step, dispatch
  src/raster/reference.cpp       # float64 plain-libtorch reference (tests, bench baseline)
  src/raster/render.cpp          # the autograd function of both rasterizers, device dispatch
  src/raster/cpu_rasterizer.cpp  # the `cpu` component and its descriptor
)
set(_raster ${CMAKE_CURRENT_LIST_DIR})
# No FP traps lets the compiler if-convert the pixel loops; no contraction keeps the alpha that
# forward and backward recompute bitwise identical.
set_source_files_properties(${_raster}/stages.cpp PROPERTIES
  COMPILE_OPTIONS "-fno-trapping-math;-ffp-contract=off")
# The kernels include no libtorch header and skip the precompiled one: its saved options would
# turn FMA contraction back on in the target_clones clones. -Wno-psabi: 32-byte vectors pass
# between inline helpers in the baseline clone.
set_source_files_properties(${_raster}/tile_kernels.cpp PROPERTIES
  COMPILE_OPTIONS "-fno-trapping-math;-ffp-contract=off;-Wno-psabi"
  SKIP_PRECOMPILE_HEADERS ON)
# The same, and errno-free sqrt so that the projection's lane-wise square roots vectorise.
set_source_files_properties(${_raster}/project_kernels.cpp PROPERTIES
  COMPILE_OPTIONS "-fno-trapping-math;-ffp-contract=off;-fno-math-errno;-Wno-psabi"
  SKIP_PRECOMPILE_HEADERS ON)
# The CUDA rasterizer (cmake/CrpgsCuda.cmake): the kernels, compiled by nvcc without libtorch
# and without contraction (they round as the CPU kernels above), and the glue + component,
# linked into libcrpgs when CRPGS_CUDA_ENABLED and otherwise compiled on their own so that a
# machine without a GPU still catches a broken kernel or glue.
set(CRPGS_CUDA_KERNEL_SOURCES ${_raster}/cuda/kernels.cu)
set(CRPGS_CUDA_KERNEL_OPTIONS --fmad=false)
set(CRPGS_CUDA_KERNEL_WARNINGS --Werror all-warnings -Xcompiler=-Wall,-Wextra,-Werror)
set(CRPGS_CUDA_GLUE_SOURCES ${_raster}/cuda/stages.cpp ${_raster}/cuda_rasterizer.cpp)
