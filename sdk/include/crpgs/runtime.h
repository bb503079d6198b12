/// @file runtime.h
/// @brief Process-wide settings for compute: the thread pools (libtorch's intra-op pool and
/// OpenBLAS's, set together: an OpenBLAS pool left at every core beside a 1-thread torch spins
/// its workers in sched_yield, and two such runs on two cores lose a fifth of their speed) and
/// the allocator.
#pragma once

#include <string>

namespace crpgs {

/// `requested` if > 0, else every core of the machine.
int resolve_threads(int requested);

/// Sets libtorch's intra-op threads and OpenBLAS's threads (when OpenBLAS is the BLAS) to
/// resolve_threads(requested).
void set_compute_threads(int requested);

/// The BLAS kernels in use, e.g. "OpenBLAS Cooperlake": OpenBLAS picks them for the CPU at
/// start-up unless OPENBLAS_CORETYPE names them (AVX-512 kernels run the MLPs' GEMMs ~1.5x
/// faster than the AVX2 "Haswell" ones on AMD Zen 4; bench BM_MlpGemm). "unknown" when the
/// BLAS is not OpenBLAS.
std::string blas_kernels();

/// Identifies the crpgs code in this process: a hash (16 hex digits) of the GNU build ids of
/// every loaded crpgs library and plugin (ELF objects named libcrpgs*), which change whenever
/// their code does. Checkpoints and shared prefixes record it, so a run can say when it continues
/// another build's state. "" when no such object carries a build id.
std::string code_build_id();

/// Sets both pools for a scope and restores what they were.
class ScopedComputeThreads {
 public:
  explicit ScopedComputeThreads(int requested);
  ~ScopedComputeThreads();
  ScopedComputeThreads(const ScopedComputeThreads&) = delete;
  ScopedComputeThreads& operator=(const ScopedComputeThreads&) = delete;

 private:
  int torch_threads_;
  int blas_threads_;
};

/// OpenBLAS on one thread for a scope, for code that runs independent GEMMs in parallel itself
/// (OpenBLAS runs a call with one thread in the calling thread). Restores the count. The setting
/// is process-wide: other threads' GEMMs in the scope also run on one thread.
class SingleThreadedBlas {
 public:
  SingleThreadedBlas();
  ~SingleThreadedBlas();
  SingleThreadedBlas(const SingleThreadedBlas&) = delete;
  SingleThreadedBlas& operator=(const SingleThreadedBlas&) = delete;

 private:
  int blas_threads_;
};

/// Keeps freed memory in the heap instead of returning it to the kernel: glibc otherwise maps
/// every block over 32 MiB anew and unmaps it on free, so each training iteration page-faults
/// its large tensors in again (~25k faults/s on fern, 14 % of the time in this VM). Memory
/// stays at the peak of one iteration. Idempotent; setup_training calls it.
void keep_freed_memory_in_heap();

}  // namespace crpgs
