/// @file test_hash_grid_cuda.cpp
/// @brief The binary hash grid's CUDA kernels (grid_cuda.cu) against its CPU kernel: forward bit
/// for bit (float32 and float64, dense and hashed levels, binarised or not, points outside
/// [0, 1] and NaN), gradients within summation-order error, the straight-through mask. Runs where
/// the grid was built with its CUDA kernels and libtorch sees a GPU (scripts/cuda-check builds it
/// there); everywhere else each test prints why it skipped.
#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>
#include <functional>
#include <string>

#include <torch/torch.h>

#include "hash_grid/hash_grid_kernels.h"

#if CRPGS_GRID_CUDA
#include <torch/cuda.h>
#endif

namespace crpgs {
namespace {

using hash_grid::GridSpec;

#if CRPGS_GRID_CUDA
#define CRPGS_REQUIRE_GPU()                                                                     \
  if (!torch::cuda::is_available()) {                                                           \
    GTEST_SKIP() << "no CUDA device: libtorch sees none (CPU-only libtorch, no GPU or driver)"; \
  }

/// HAC's layout (12 3D levels, 3 x 4 planes) and a small one with dense and hashed levels of
/// both dimensions and 3 features.
const GridSpec& spec(bool hac) {
  static const GridSpec h = hash_grid::make_grid_spec(
      {18, 24, 33, 44, 59, 80, 108, 148, 201, 275, 376, 514}, 13, {130, 258, 514, 1026}, 15, 4);
  static const GridSpec s = hash_grid::make_grid_spec({6, 18, 40}, 12, {18, 70}, 10, 3);
  return hac ? h : s;
}

/// Random points in [0, 1]^3, a few just outside, on the border and NaN.
torch::Tensor positions(int64_t n, torch::ScalarType type, uint64_t seed) {
  torch::manual_seed(seed);
  auto p = torch::rand({n, 3}, torch::kDouble);
  p[0][0] = -1e-3;
  p[1][1] = 1.001;
  p[2] = torch::tensor({0.0, 1.0, 0.5}, torch::kDouble);
  p[3][2] = std::nan("");
  return p.to(type);
}

/// Every case: HAC's layout and the small one, float32 and float64, binarised or not; `name`
/// says which (for the parity lines the device run's record quotes).
void for_each_case(const std::function<void(const GridSpec&, torch::ScalarType, bool,
                                            const std::string& name)>& check) {
  for (bool hac : {true, false})
    for (auto type : {torch::kFloat, torch::kDouble})
      for (bool binarize : {true, false})
        check(spec(hac), type, binarize,
              std::string(hac ? "hac" : "small") + (type == torch::kFloat ? " f32" : " f64") +
                  " binarize " + (binarize ? "1" : "0"));
}
#else
#define CRPGS_REQUIRE_GPU()                                                              \
  GTEST_SKIP() << "the grid's CUDA kernels are not in this build (they need nvcc and a " \
                  "CUDA libtorch: scripts/cuda-check on a GPU machine)"
#endif

TEST(HashGridCuda, ForwardIsBitEqualToTheCpuKernel) {
  CRPGS_REQUIRE_GPU();
#if CRPGS_GRID_CUDA
  for_each_case([](const GridSpec& s, torch::ScalarType type, bool binarize,
                   const std::string& name) {
    const auto pos = positions(20000, type, 1);
    const auto table = (torch::randn({s.n_entries, s.n_features}, torch::kDouble) * 0.7).to(type);
    const auto cpu = hash_grid::grid_forward(s, pos, table, binarize);
    const auto gpu = hash_grid::grid_lookup_cuda(s, pos.cuda(), table.cuda(), binarize).cpu();
    ASSERT_EQ(gpu.sizes(), cpu.sizes());
    const double diff = (gpu - cpu).abs().max().item<double>();
    std::printf("[ parity ] grid forward %s: max|d| %.3g\n", name.c_str(), diff);
    EXPECT_TRUE(torch::equal(gpu, cpu)) << name << ": max difference " << diff;
    EXPECT_GT(cpu.abs().max().item<double>(), 0.1);
  });
#endif
}

TEST(HashGridCuda, GradientsMatchTheCpuKernel) {
  CRPGS_REQUIRE_GPU();
#if CRPGS_GRID_CUDA
  for_each_case([](const GridSpec& s, torch::ScalarType type, bool binarize,
                   const std::string& name) {
    const auto pos = positions(20000, type, 2);
    // Values beyond ±1 get no gradient through the straight-through estimator.
    const auto init = (torch::randn({s.n_entries, s.n_features}, torch::kDouble) * 1.5).to(type);
    const auto grad_out = torch::randn({pos.size(0), s.output_dim()}, torch::kDouble).to(type);
    const auto cpu = hash_grid::grid_backward(s, pos, init, grad_out, binarize);
    auto table = init.cuda().requires_grad_(true);
    hash_grid::grid_lookup_cuda(s, pos.cuda(), table, binarize).backward(grad_out.cuda());
    const auto gpu = table.grad().cpu();
    const double scale = cpu.abs().max().item<double>();
    const double rel = (gpu - cpu).abs().max().item<double>() / scale;
    std::printf("[ parity ] grid backward %s: max rel %.3g\n", name.c_str(), rel);
    EXPECT_GT(scale, 0.0);
    // Atomics sum in another order than the CPU's level loop: rounding only.
    EXPECT_LT(rel, type == torch::kFloat ? 1e-5 : 1e-12) << name;
    if (binarize) {
      const auto outside = init.abs().gt(1);
      ASSERT_GT(outside.sum().item<int64_t>(), 0);
      EXPECT_EQ(gpu.masked_select(outside).abs().max().item<double>(), 0.0) << name;
    }
  });
#endif
}

TEST(HashGridCuda, EmptyInputAndWrongShapes) {
  CRPGS_REQUIRE_GPU();
#if CRPGS_GRID_CUDA
  const GridSpec& s = spec(false);
  const auto table = torch::randn({s.n_entries, s.n_features}).cuda();
  const auto none = hash_grid::grid_lookup_cuda(s, torch::zeros({0, 3}).cuda(), table, true);
  EXPECT_EQ(none.size(0), 0);
  EXPECT_EQ(none.size(1), s.output_dim());
  EXPECT_THROW(hash_grid::grid_lookup_cuda(s, torch::zeros({4, 2}).cuda(), table, true),
               c10::Error);
  EXPECT_THROW(hash_grid::grid_lookup_cuda(s, torch::zeros({4, 3}), table, true), c10::Error);
#endif
}

}  // namespace
}  // namespace crpgs
