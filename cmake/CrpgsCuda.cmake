# Resolves CRPGS_WITH_CUDA (AUTO/ON/OFF):
#  - CRPGS_CUDA_KERNELS: nvcc was found (and CUDA is not OFF). The kernels and the glue are then
#    always compiled, so a broken kernel fails the build even where nothing CUDA can run.
#  - CRPGS_CUDA_ENABLED: the `cuda` rasterizer is linked into libcrpgs and registered. AUTO: when
#    libtorch itself was built with CUDA; ON: whenever nvcc is found.
set(CRPGS_CUDA_KERNELS OFF)
set(CRPGS_CUDA_ENABLED OFF)
set(_crpgs_torch_cuda OFF)
if(TARGET torch_cuda OR CUDA_FOUND OR TORCH_CUDA_LIBRARIES)
  set(_crpgs_torch_cuda ON)
endif()
if(NOT CRPGS_WITH_CUDA STREQUAL "OFF")
  include(CheckLanguage)
  check_language(CUDA)
  if(CRPGS_WITH_CUDA STREQUAL "ON" AND NOT CMAKE_CUDA_COMPILER)
    message(FATAL_ERROR "CRPGS_WITH_CUDA=ON but no CUDA compiler (nvcc) was found")
  endif()
  if(CMAKE_CUDA_COMPILER)
    # Hopper (H100/H200) and Ampere machine code, and PTX for later GPUs.
    if(NOT DEFINED CMAKE_CUDA_ARCHITECTURES)
      set(CMAKE_CUDA_ARCHITECTURES "80-real;90")
    endif()
    enable_language(CUDA)
    find_package(CUDAToolkit REQUIRED)
    set(CRPGS_CUDA_KERNELS ON)
    if(_crpgs_torch_cuda OR CRPGS_WITH_CUDA STREQUAL "ON")
      set(CRPGS_CUDA_ENABLED ON)
    endif()
  endif()
endif()
message(STATUS "crpgs: CRPGS_WITH_CUDA=${CRPGS_WITH_CUDA}; nvcc: ${CMAKE_CUDA_COMPILER}; "
               "CUDA libtorch: ${_crpgs_torch_cuda}; CUDA kernels compiled: ${CRPGS_CUDA_KERNELS}; "
               "CUDA rasterizer: ${CRPGS_CUDA_ENABLED}")
if(NOT CRPGS_CUDA_ENABLED)
  message(STATUS "crpgs: building without the CUDA rasterizer (available: cpu)")
endif()
