/// @file test_portable_math.cpp
/// @brief The codec's portable arithmetic: exp and tanh against libm, the linear layer against
/// its fixed-order definition bit for bit and independent of the thread count.
#include <gtest/gtest.h>
#include <torch/torch.h>

#include <cmath>
#include <limits>

#include "crpgs/portable_math.h"
#include "crpgs/runtime.h"

namespace crpgs {
namespace {

TEST(PortableMath, ExpMatchesLibm) {
  for (double x = -700; x <= 700; x += 0.37)
    ASSERT_NEAR(portable_exp(x), std::exp(x), std::exp(x) * 1e-14) << x;
  EXPECT_EQ(portable_exp(-800), 0.0);
  EXPECT_EQ(portable_exp(0), 1.0);
  EXPECT_TRUE(std::isinf(portable_exp(800)));
  EXPECT_TRUE(std::isnan(portable_exp(std::nan(""))));
}

TEST(PortableMath, TanhMatchesLibmAndKeepsSpecialValues) {
  const float inf = std::numeric_limits<float>::infinity();
  auto x = torch::linspace(-30, 30, 6001);
  x = torch::cat({x, torch::tensor({0.f, -0.f, 1e-30f, -1e-30f, inf, -inf, std::nanf("")})});
  const auto y = portable_tanh(x);
  const float* xp = x.data_ptr<float>();
  const float* yp = y.data_ptr<float>();
  for (int64_t i = 0; i < x.numel(); ++i) {
    const float want = float(std::tanh(double(xp[i])));  // correctly rounded up to ~1 ulp
    if (std::isnan(xp[i])) {
      EXPECT_TRUE(std::isnan(yp[i]));
      continue;
    }
    EXPECT_LE(std::abs(yp[i] - want), std::abs(want) * 1.2e-7f + 1e-38f) << xp[i];
    EXPECT_EQ(std::signbit(yp[i]), std::signbit(xp[i])) << xp[i];
  }
  EXPECT_EQ(y[6001].item<float>(), 0.f);
  EXPECT_EQ(y[6005].item<float>(), 1.f);
  EXPECT_EQ(y[6006].item<float>(), -1.f);
}

// Output (n, o) = b[o] + x[n,0] w[o,0] + x[n,1] w[o,1] + ..., each step rounded to float.
torch::Tensor fixed_order_linear(const torch::Tensor& x, const torch::Tensor& w,
                                 const torch::Tensor& b) {
  auto y = torch::empty({x.size(0), w.size(0)});
  const auto xa = x.accessor<float, 2>(), wa = w.accessor<float, 2>();
  const auto ba = b.accessor<float, 1>();
  auto ya = y.accessor<float, 2>();
  for (int64_t n = 0; n < x.size(0); ++n)
    for (int64_t o = 0; o < w.size(0); ++o) {
      volatile float acc = ba[o];  // volatile: every step stored, as float
      for (int64_t i = 0; i < x.size(1); ++i) {
        const volatile float prod = xa[n][i] * wa[o][i];
        acc = acc + prod;
      }
      ya[n][o] = acc;
    }
  return y;
}

TEST(PortableMath, LinearIsTheFixedOrderSumOnAnyThreadCount) {
  torch::manual_seed(11);
  const auto x = torch::randn({333, 96}), w = torch::randn({175, 96}) * 0.1;
  const auto b = torch::randn({175});
  const auto want = fixed_order_linear(x, w, b);
  for (int threads : {1, 2, 3}) {
    ScopedComputeThreads scoped(threads);
    EXPECT_TRUE(torch::equal(portable_linear(x, w, b), want)) << threads << " threads";
  }
  // The same maths as torch::linear, up to rounding; no autograd.
  EXPECT_TRUE(torch::allclose(portable_linear(x, w, b), torch::linear(x, w, b), 1e-4, 1e-4));
  EXPECT_FALSE(portable_linear(x, w.requires_grad_(true), b).requires_grad());
  // Strided inputs are read as their values; empty inputs give empty outputs.
  EXPECT_TRUE(torch::equal(portable_linear(x.t().contiguous().t(), w.detach(), b), want));
  EXPECT_EQ(portable_linear(torch::zeros({0, 96}), w.detach(), b).sizes(),
            torch::IntArrayRef({0, 175}));
  EXPECT_THROW(portable_linear(x, torch::zeros({5, 4}), torch::zeros({5})), c10::Error);
  EXPECT_THROW(portable_linear(x, w.detach().to(torch::kDouble), b), c10::Error);
}

}  // namespace
}  // namespace crpgs
