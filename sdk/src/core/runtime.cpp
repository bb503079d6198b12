/// @file runtime.cpp
/// @brief Thread pools (libtorch and OpenBLAS together) and allocator settings.
#include "crpgs/runtime.h"

#include <dlfcn.h>
#include <malloc.h>

#include <algorithm>
#include <string>
#include <thread>

#include <ATen/Parallel.h>

namespace crpgs {
namespace {

// OpenBLAS is found at run time: libtorch links the system BLAS, which may be another library.
struct OpenBlas {
  void (*set)(int) = nullptr;
  int (*get)() = nullptr;
  char* (*corename)() = nullptr;  // the kernels a DYNAMIC_ARCH build picked
  OpenBlas() {
    set = reinterpret_cast<void (*)(int)>(dlsym(RTLD_DEFAULT, "openblas_set_num_threads"));
    get = reinterpret_cast<int (*)()>(dlsym(RTLD_DEFAULT, "openblas_get_num_threads"));
    if (!set || !get) set = nullptr, get = nullptr;
    corename = reinterpret_cast<char* (*)()>(dlsym(RTLD_DEFAULT, "openblas_get_corename"));
  }
};

const OpenBlas& openblas() {
  static const OpenBlas blas;
  return blas;
}

void set_pools(int torch_threads, int blas_threads) {
  at::set_num_threads(torch_threads);
  if (openblas().set && blas_threads > 0) openblas().set(blas_threads);
}

}  // namespace

int resolve_threads(int requested) {
  return requested > 0 ? requested : std::max(1, int(std::thread::hardware_concurrency()));
}

void set_compute_threads(int requested) {
  const int n = resolve_threads(requested);
  set_pools(n, n);
}

ScopedComputeThreads::ScopedComputeThreads(int requested)
    : torch_threads_(at::get_num_threads()), blas_threads_(openblas().get ? openblas().get() : 0) {
  set_compute_threads(requested);
}

ScopedComputeThreads::~ScopedComputeThreads() {
  set_pools(torch_threads_, blas_threads_);
}

SingleThreadedBlas::SingleThreadedBlas() : blas_threads_(openblas().get ? openblas().get() : 0) {
  if (blas_threads_ > 1) openblas().set(1);
}

SingleThreadedBlas::~SingleThreadedBlas() {
  if (blas_threads_ > 1) openblas().set(blas_threads_);
}

std::string blas_kernels() {
  const OpenBlas& blas = openblas();
  return blas.corename ? std::string("OpenBLAS ") + blas.corename() : std::string("unknown");
}

void keep_freed_memory_in_heap() {
  // Blocks of any size come from the heap, and a free never trims it.
  mallopt(M_MMAP_THRESHOLD, 1 << 30);
  mallopt(M_TRIM_THRESHOLD, -1);
}

}  // namespace crpgs
