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

/// The core type OpenBLAS runs ("Haswell", "SkylakeX", ...), "" when the BLAS is not OpenBLAS.
std::string openblas_core();

/// How wide the vectors are that an OpenBLAS core type's kernels use: 0 SSE, 1 AVX, 2 AVX2 + FMA,
/// 3 AVX-512; -1 for a name not known here.
int openblas_core_vector_level(const std::string& core);

/// The same scale for this CPU (AVX-512 counts with F, CD, BW, DQ and VL, as OpenBLAS's SkylakeX
/// kernels need them), as the CPU and the OS support it.
int cpu_vector_level();

/// The OPENBLAS_CORETYPE to restart with when OpenBLAS picked kernels narrower than the CPU runs
/// ("SkylakeX", "Haswell" or "Sandybridge"), else "". OpenBLAS falls back to SSE3 "Prescott" on
/// CPUs newer than itself: Debian 12's 0.3.21 on an Intel Xeon of model 207 (Emerald Rapids) ran
/// the MLPs' GEMMs 3.1-3.5x slower than with SkylakeX (bench/results/train_fern.md).
std::string wider_openblas_core(const std::string& picked, int cpu_level);

/// Set by `crpgs` with OPENBLAS_CORETYPE when it restarted itself for wider kernels: the core
/// type OpenBLAS had picked, so that the log can tell this from a user's own OPENBLAS_CORETYPE.
inline constexpr char kOpenBlasPickedVariable[] = "CRPGS_OPENBLAS_PICKED";

/// "OMP_WAIT_POLICY=PASSIVE, OPENBLAS_THREAD_TIMEOUT=4": how idle compute threads wait, as the
/// environment sets it ("(unset)" for a variable it lacks).
std::string idle_thread_settings();

/// Restarts this process once (execv of /proc/self/exe with `argv`) with the environment compute
/// runs best under, where the user set none of it: idle threads that sleep (OMP_WAIT_POLICY,
/// OPENBLAS_THREAD_TIMEOUT: libgomp's and OpenBLAS's spinning pools steal each other's cores) and
/// OPENBLAS_CORETYPE when OpenBLAS picked kernels narrower than the CPU runs. Both libraries read
/// these when they load, before main(), so only a restart applies them. Returns when nothing
/// needed setting, under valgrind (whose child would escape the measurement) or when the restart
/// failed; call it first in main(), before any thread starts.
void restart_with_compute_environment(char** argv);

/// "OpenBLAS SkylakeX (...)": blas_kernels() and why they are those kernels when
/// OPENBLAS_CORETYPE chose them.
std::string blas_kernels_explained();

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
