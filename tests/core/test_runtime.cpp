// The compute runtime: OpenBLAS's kernel choice on AVX-512 CPUs, and GEMMs after the switch.
#include <gtest/gtest.h>
#include <torch/torch.h>

#include <cstdlib>
#include <string>

#include "crpgs/runtime.h"

namespace crpgs {
namespace {

bool cpu_has_avx512() {
#if defined(__x86_64__) && defined(__GNUC__)
  __builtin_cpu_init();
  return __builtin_cpu_supports("avx512f") && __builtin_cpu_supports("avx512bw") &&
         __builtin_cpu_supports("avx512dq") && __builtin_cpu_supports("avx512vl") &&
         __builtin_cpu_supports("avx512cd");
#else
  return false;
#endif
}

TEST(Runtime, AvxTwoFallbackBecomesAvx512KernelsAndGemmsStayRight) {
  const std::string before = blas_kernels();
  set_compute_threads(2);
  const std::string after = blas_kernels();
  const bool fallback = before == "OpenBLAS Haswell" || before == "OpenBLAS Zen";
  if (fallback && cpu_has_avx512() && !std::getenv("OPENBLAS_CORETYPE")) {
    EXPECT_EQ(after, "OpenBLAS SkylakeX");
  } else {
    std::cout << "[ NOTE     ] no switch applies here (" << before << ", AVX-512 "
              << (cpu_has_avx512() ? "yes" : "no") << "); checking the kernels stay\n";
    EXPECT_EQ(after, before);
  }
  // The swapped table computes GEMMs of the MLPs' shapes, on one and on two threads.
  torch::manual_seed(3);
  const auto x = torch::randn({1024, 54}), w = torch::randn({50, 54});
  const auto want = torch::mm(x.to(torch::kDouble), w.to(torch::kDouble).t());
  for (int threads : {1, 2}) {
    ScopedComputeThreads scoped(threads);
    const auto got = torch::mm(x, w.t()).to(torch::kDouble);
    EXPECT_LT((got - want).abs().max().item<double>(), 1e-4) << threads << " threads";
  }
}

}  // namespace
}  // namespace crpgs
