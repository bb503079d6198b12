/// @file bench_main.cpp
/// @brief main() of every bench program: restarts with the environment `crpgs` computes under
/// (OpenBLAS kernels as wide as the CPU, idle threads that sleep), so that a benchmark measures
/// what the tool runs, and records it in the output's context (`idle_compute_threads`,
/// `blas_kernels`). Set OPENBLAS_CORETYPE (e.g. Prescott), OMP_WAIT_POLICY or
/// OPENBLAS_THREAD_TIMEOUT to measure another environment.
#include <benchmark/benchmark.h>

#include "crpgs/runtime.h"

int main(int argc, char** argv) {
  crpgs::restart_with_compute_environment(argv);
  benchmark::AddCustomContext("idle_compute_threads", crpgs::idle_thread_settings());
  benchmark::AddCustomContext("blas_kernels", crpgs::blas_kernels_explained());
  benchmark::Initialize(&argc, argv);
  if (benchmark::ReportUnrecognizedArguments(argc, argv)) return 1;
  benchmark::RunSpecifiedBenchmarks();
  benchmark::Shutdown();
  return 0;
}
