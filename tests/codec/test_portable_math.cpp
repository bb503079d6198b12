/// @file test_portable_math.cpp
/// @brief The codec's portable arithmetic: exp, tanh and 1 + tanh against libm, the linear layer
/// against its fixed-order definition bit for bit and independent of the thread count; the
/// adaptive steps' two forms.
#include <gtest/gtest.h>
#include <torch/torch.h>

#include <cmath>
#include <limits>

#include "crpgs/entropy_params.h"
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

TEST(PortableMath, OnePlusTanhIsAccurateWhereTheSumCancels) {
  const float inf = std::numeric_limits<float>::infinity();
  auto x = torch::linspace(-40, 40, 8001);
  x = torch::cat({x, torch::tensor({inf, -inf, std::nanf("")})});
  const auto y = portable_one_plus_tanh(x);
  const float* xp = x.data_ptr<float>();
  const float* yp = y.data_ptr<float>();
  for (int64_t i = 0; i < 8001; ++i) {
    // 1 + tanh(x) = 2 / (1 + e^(−2x)), in long double: no cancellation for x << 0.
    const float want = float(2.0L / (1.0L + std::exp(-2.0L * xp[i])));
    ASSERT_GT(yp[i], 0.f) << xp[i];
    EXPECT_LE(std::abs(yp[i] - want), want * 1.2e-7f) << xp[i];
  }
  EXPECT_EQ(y[8001].item<float>(), 2.f);
  EXPECT_EQ(y[8002].item<float>(), 0.f);
  EXPECT_TRUE(std::isnan(y[8003].item<float>()));
  // Where 1 + tanh in float has already cancelled to 0 (format 1.1's steps).
  const auto a = torch::tensor({-9.5f});
  EXPECT_EQ((portable_tanh(a) + 1).item<float>(), 0.f);
  EXPECT_NEAR(portable_one_plus_tanh(a).item<float>(), 2 * std::exp(-19.0), 1e-15);
}

TEST(QuantSteps, TwoSigmoidStepsStayPositiveWithAGradientOnBothArithmetics) {
  const QuantSteps q0{1.0, 0.001, 0.2};
  auto a = torch::linspace(-40, 40, 801).unsqueeze(1).repeat({1, 3}).requires_grad_(true);
  EntropyParams fast, portable;
  set_quant_steps(a, q0, &fast, Arithmetic::kFast, StepForm::kTwoSigmoid);
  set_quant_steps(a, q0, &portable, Arithmetic::kPortable, StepForm::kTwoSigmoid);
  for (const auto& [f, p] : {std::pair{fast.q_f, portable.q_f}, std::pair{fast.q_s, portable.q_s},
                             std::pair{fast.q_o, portable.q_o}}) {
    EXPECT_TRUE(p.gt(0).all().item<bool>());
    // Training's steps (ATen's sigmoid) and the codec's agree to a few ulp.
    EXPECT_LE(((f.detach() - p) / p).abs().max().item<double>(), 6e-7);
  }
  // The rate can pull a saturated step back: d q / d a > 0 down to a = −40 (above a ≈ 9 it is
  // below float's resolution, as it always was: q is 2·Q0 there).
  fast.q_f.sum().backward();
  const auto g = a.grad().select(1, 0).slice(0, 0, 401);  // a in [−40, 0]
  EXPECT_TRUE(g.gt(0).all().item<bool>()) << g.min().item<float>();
  // Format 1.1's form: q = 0 and no gradient from a ≈ −9 on.
  auto b = torch::tensor({{-9.5f, -9.5f, -9.5f}}).requires_grad_(true);
  EntropyParams old;
  set_quant_steps(b, q0, &old, Arithmetic::kFast, StepForm::kOnePlusTanh);
  old.q_f.sum().backward();
  EXPECT_EQ(old.q_f.item<float>(), 0.f);
  EXPECT_EQ(b.grad()[0][0].item<float>(), 0.f);
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
