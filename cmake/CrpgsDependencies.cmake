# Every third-party dependency, all from Debian 12 packages (scripts/setup installs them).
find_package(Torch REQUIRED)                   # libtorch-dev 1.13.1 (CPU)
crpgs_torch_headers_as_system()              # CrpgsWarnings.cmake
find_package(Eigen3 3.3 REQUIRED NO_MODULE)    # libeigen3-dev
find_package(yaml-cpp REQUIRED)                # libyaml-cpp-dev 0.7: target is `yaml-cpp`
find_package(draco REQUIRED)                   # libdraco-dev
find_package(ZLIB REQUIRED)                    # crc32 for bitstream sections
find_package(PkgConfig REQUIRED)
pkg_check_modules(STB REQUIRED IMPORTED_TARGET stb)   # libstb-dev: PNG/JPEG decode and encode
find_package(Threads REQUIRED)
# libgomp (gcc): ATen's at::parallel_for is a header template that runs serially in any TU
# compiled without -fopenmp, so every target with such kernels links OpenMP::OpenMP_CXX.
find_package(OpenMP)
if(CRPGS_BUILD_APPS)
  find_package(CLI11 REQUIRED)                 # libcli11-dev (header-only)
  pkg_check_modules(HTTPLIB REQUIRED IMPORTED_TARGET cpp-httplib)  # libcpp-httplib-dev: `crpgs view`
endif()
if(CRPGS_BUILD_TESTS)
  find_package(GTest REQUIRED)
endif()
if(CRPGS_BUILD_BENCH)
  find_package(benchmark REQUIRED)
endif()
