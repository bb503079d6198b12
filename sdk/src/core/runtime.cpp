/// @file runtime.cpp
/// @brief Thread pools (libtorch and OpenBLAS together) and allocator settings.
#include "crpgs/runtime.h"

#include <dlfcn.h>
#include <malloc.h>

#include <algorithm>
#include <cstdlib>
#include <cstring>
#include <mutex>
#include <string>
#include <thread>

#include <ATen/Parallel.h>

namespace crpgs {
namespace {

// OpenBLAS is found at run time: libtorch links the system BLAS, which may be another library.
struct OpenBlas {
  void (*set)(int) = nullptr;
  int (*get)() = nullptr;
  // A DYNAMIC_ARCH build's kernel table (absent otherwise).
  char* (*corename)() = nullptr;
  void (*dynamic_init)() = nullptr;
  void (*dynamic_quit)() = nullptr;
  OpenBlas() {
    set = reinterpret_cast<void (*)(int)>(dlsym(RTLD_DEFAULT, "openblas_set_num_threads"));
    get = reinterpret_cast<int (*)()>(dlsym(RTLD_DEFAULT, "openblas_get_num_threads"));
    if (!set || !get) set = nullptr, get = nullptr;
    corename = reinterpret_cast<char* (*)()>(dlsym(RTLD_DEFAULT, "openblas_get_corename"));
    dynamic_init = reinterpret_cast<void (*)()>(dlsym(RTLD_DEFAULT, "gotoblas_dynamic_init"));
    dynamic_quit = reinterpret_cast<void (*)()>(dlsym(RTLD_DEFAULT, "gotoblas_dynamic_quit"));
    if (!corename || !dynamic_init || !dynamic_quit)
      corename = nullptr, dynamic_init = nullptr, dynamic_quit = nullptr;
  }
};

const OpenBlas& openblas() {
  static const OpenBlas blas;
  return blas;
}

bool has_avx512_for_openblas() {
#if defined(__x86_64__) && defined(__GNUC__)
  __builtin_cpu_init();
  return __builtin_cpu_supports("avx512f") && __builtin_cpu_supports("avx512bw") &&
         __builtin_cpu_supports("avx512dq") && __builtin_cpu_supports("avx512vl") &&
         __builtin_cpu_supports("avx512cd");
#else
  return false;
#endif
}

void use_avx512_blas_kernels_once() {
  static std::once_flag once;
  std::call_once(once, [] {
    const OpenBlas& blas = openblas();
    // The user's OPENBLAS_CORETYPE, if any, stands.
    if (!blas.corename || std::getenv("OPENBLAS_CORETYPE") || !has_avx512_for_openblas()) return;
    const std::string core = blas.corename();
    if (core != "Haswell" && core != "Zen") return;
    // Re-runs the library's own start-up choice with the variable set, as if the user had set it.
    setenv("OPENBLAS_CORETYPE", "SkylakeX", 0);
    blas.dynamic_quit();
    blas.dynamic_init();
    unsetenv("OPENBLAS_CORETYPE");
  });
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
  use_avx512_blas_kernels_once();
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
