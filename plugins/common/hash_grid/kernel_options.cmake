# Compile options of hash_grid_kernels.cpp (the crpgs_hash_grid library, CMakeLists.txt here).
# No contraction: kernel, reference and every ISA clone round identically. No FP
# traps: the per-lane selects of the corner blocks if-convert, so they vectorise.
set(CRPGS_HASH_GRID_KERNEL_OPTIONS "-ffp-contract=off;-fno-trapping-math")

# crpgs_hash_grid_cuda(<target>): the grid's CUDA kernels (grid_cuda.cu, nvcc alone, no
# contraction) and their glue. Linked into <target> (the crpgs_hash_grid library, which passes
# them and CRPGS_GRID_CUDA=1 on to what links it) where the CUDA rasterizer is
# (cmake/CrpgsCuda.cmake: a CUDA libtorch and nvcc); where only nvcc is, compiled
# on their own, so that a machine without a GPU still catches a broken kernel or glue.
set(_crpgs_hash_grid_dir ${CMAKE_CURRENT_LIST_DIR})
function(crpgs_hash_grid_cuda target)
  if(NOT CRPGS_CUDA_KERNELS)
    return()
  endif()
  set(_dir ${_crpgs_hash_grid_dir})
  if(NOT TARGET crpgs_hash_grid_cuda_kernels)
    add_library(crpgs_hash_grid_cuda_kernels STATIC ${_dir}/grid_cuda.cu)
    target_compile_options(crpgs_hash_grid_cuda_kernels PRIVATE --fmad=false
      --Werror all-warnings -Xcompiler=-Wall,-Wextra,-Werror)
    set_target_properties(crpgs_hash_grid_cuda_kernels PROPERTIES POSITION_INDEPENDENT_CODE ON
      CUDA_STANDARD 17)
    target_link_libraries(crpgs_hash_grid_cuda_kernels PUBLIC CUDA::cudart_static)
    if(NOT CRPGS_CUDA_ENABLED)
      add_library(crpgs_hash_grid_cuda_glue OBJECT ${_dir}/grid_cuda_glue.cpp)
      target_link_libraries(crpgs_hash_grid_cuda_glue PRIVATE crpgs)
      crpgs_set_warnings(crpgs_hash_grid_cuda_glue)
    endif()
  endif()
  if(CRPGS_CUDA_ENABLED)
    target_sources(${target} PRIVATE ${_dir}/grid_cuda_glue.cpp)
    target_link_libraries(${target} PUBLIC crpgs_hash_grid_cuda_kernels)
    target_compile_definitions(${target} PUBLIC CRPGS_GRID_CUDA=1)
  endif()
endfunction()
