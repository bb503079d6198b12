// BD-rate / BD-PSNR against hand-computed cases, and the PCHIP it rests on.
#include <gtest/gtest.h>

#include <cmath>

#include "crpgs/experiments/bd_rate.h"

namespace crpgs::experiments {
namespace {

// PSNR linear in ln(size): PCHIP reproduces a line exactly, so the answers are closed-form.
std::vector<RdPoint> linear_curve(double a, double b, std::vector<double> sizes) {
  std::vector<RdPoint> c;
  for (double s : sizes) c.push_back({s, a + b * std::log(s)});
  return c;
}

const std::vector<RdPoint> kCurve = {{1e6, 28.0}, {2e6, 30.1}, {4e6, 31.5}, {8e6, 32.2}};

TEST(BdRate, IdenticalCurvesGiveZero) {
  ASSERT_TRUE(bd_rate(kCurve, kCurve).has_value());
  EXPECT_NEAR(*bd_rate(kCurve, kCurve), 0.0, 1e-12);
  EXPECT_NEAR(*bd_psnr(kCurve, kCurve), 0.0, 1e-12);
}

TEST(BdRate, HalfTheSizeIsMinusFiftyPercent) {
  std::vector<RdPoint> half = kCurve, twice = kCurve;
  for (auto& p : half) p.size /= 2;
  for (auto& p : twice) p.size *= 2;
  EXPECT_NEAR(*bd_rate(kCurve, half), -50.0, 1e-9);
  EXPECT_NEAR(*bd_rate(kCurve, twice), 100.0, 1e-9);
  EXPECT_NEAR(*bd_rate(half, kCurve), 100.0, 1e-9);
}

TEST(BdRate, LinearCurvesMatchClosedForm) {
  const double b = 2.5;
  const auto a = linear_curve(10, b, {1e5, 3e5, 1e6, 3e6, 1e7});
  auto half = a;
  for (auto& p : half) p.size /= 2;
  // Same PSNR at half the size: at equal size the gain is b * ln 2.
  EXPECT_NEAR(*bd_psnr(a, half), b * std::log(2.0), 1e-9);
  // +0.5 dB everywhere: BD-PSNR 0.5; at equal PSNR ln(size) drops by 0.5 / b.
  auto up = a;
  for (auto& p : up) p.psnr += 0.5;
  EXPECT_NEAR(*bd_psnr(a, up), 0.5, 1e-9);
  EXPECT_NEAR(*bd_rate(a, up), (std::exp(-0.5 / b) - 1) * 100, 1e-9);
}

// A figure names what it integrates: the non-dominated points of each curve (a dominated point
// does not count) and the common interval, in dB for BD-rate and in bytes for BD-PSNR.
TEST(BdRate, FiguresSayTheirPointsAndInterval) {
  const std::vector<RdPoint> anchor = {{1e6, 28}, {2e6, 29}, {3e6, 30}, {4e6, 29.5}};
  const std::vector<RdPoint> test = {{1.5e6, 28.5}, {2.5e6, 30.5}};
  const auto rate = bd_rate_figure(anchor, test);
  ASSERT_TRUE(rate.has_value());
  EXPECT_EQ(rate->anchor_points, 3);
  EXPECT_EQ(rate->test_points, 2);
  EXPECT_DOUBLE_EQ(rate->lo, 28.5);
  EXPECT_DOUBLE_EQ(rate->hi, 30.0);
  EXPECT_DOUBLE_EQ(rate->value, *bd_rate(anchor, test));
  const auto psnr = bd_psnr_figure(anchor, test);
  ASSERT_TRUE(psnr.has_value());
  EXPECT_NEAR(psnr->lo, 1.5e6, 1e-3);
  EXPECT_NEAR(psnr->hi, 2.5e6, 1e-3);
  EXPECT_DOUBLE_EQ(psnr->value, *bd_psnr(anchor, test));
}

TEST(BdRate, NonOverlappingCurvesGiveNoResult) {
  const std::vector<RdPoint> low = {{1e6, 28}, {2e6, 29}, {3e6, 30}};
  const std::vector<RdPoint> high = {{1e7, 33}, {2e7, 34}, {3e7, 35}};
  EXPECT_FALSE(bd_rate(low, high).has_value());
  EXPECT_FALSE(bd_psnr(low, high).has_value());
  // Touching at one point is not an interval either.
  const std::vector<RdPoint> touch = {{3e6, 30}, {5e6, 31}};
  EXPECT_FALSE(bd_rate(low, touch).has_value());
  EXPECT_FALSE(bd_psnr(low, touch).has_value());
}

TEST(BdRate, FewerThanTwoPointsGiveNoResult) {
  EXPECT_FALSE(bd_rate(kCurve, {{2e6, 30}}).has_value());
  EXPECT_FALSE(bd_psnr({}, kCurve).has_value());
}

TEST(BdRate, DominatedPointsAreDropped) {
  std::vector<RdPoint> noisy = kCurve;
  noisy.push_back({3e6, 29.0});  // bigger than (2e6, 30.1) and worse
  noisy.push_back({8e6, 32.0});  // same size as (8e6, 32.2), worse
  noisy.push_back({1e6, 28.0});  // exact duplicate
  const auto front = pareto_front(noisy);
  ASSERT_EQ(front.size(), kCurve.size());
  for (size_t i = 0; i < front.size(); ++i) {
    EXPECT_EQ(front[i].size, kCurve[i].size);
    EXPECT_EQ(front[i].psnr, kCurve[i].psnr);
  }
  std::vector<RdPoint> half = kCurve;
  for (auto& p : half) p.size /= 2;
  EXPECT_NEAR(*bd_rate(noisy, half), -50.0, 1e-9);
  EXPECT_NEAR(*bd_rate(kCurve, noisy), 0.0, 1e-12);
  EXPECT_NEAR(*bd_psnr(noisy, kCurve), 0.0, 1e-12);
}

TEST(BdRate, OnlyTheCommonIntervalCounts) {
  // Both on lines (PCHIP is exact on them); the test curve reaches far beyond the anchor on
  // both sides, at half the size. Only the overlap is averaged, so the factor comes out exactly.
  const double a = 10, b = 2.0;
  const auto anchor = linear_curve(a, b, {1e5, 2e5, 5e5, 1e6});
  std::vector<RdPoint> test;
  for (double s : {1e3, 1e4, 5e4, 2e5, 1e6, 1e7, 1e8}) test.push_back({s, a + b * std::log(2 * s)});
  EXPECT_NEAR(*bd_rate(anchor, test), -50.0, 1e-9);
  EXPECT_NEAR(*bd_psnr(anchor, test), b * std::log(2.0), 1e-9);
  // A curve bent outside the common interval changes nothing inside it.
  auto bent = test;
  bent.front().psnr -= 3;
  bent.back().psnr += 4;
  EXPECT_NEAR(*bd_rate(anchor, bent), -50.0, 1e-9);
}

TEST(Pchip, InterpolatesKnotsAndLines) {
  const Pchip line({0, 1, 3, 4}, {1, 3, 7, 9});  // y = 2x + 1
  for (double x : {0.0, 0.3, 1.0, 2.2, 3.9, 4.0}) EXPECT_NEAR(line(x), 2 * x + 1, 1e-12);
  EXPECT_NEAR(line.integrate(0.5, 3.5), (3.5 * 3.5 + 3.5) - (0.25 + 0.5), 1e-12);
  const Pchip two({1, 2}, {5, 3});
  EXPECT_NEAR(two(1.5), 4.0, 1e-12);
}

TEST(Pchip, MonotoneDataGivesMonotoneInterpolantWithoutOvershoot) {
  // A step: a natural cubic spline overshoots around it; PCHIP must not.
  const std::vector<double> x = {0, 1, 2, 3, 4, 5, 6}, y = {0, 0, 0.1, 5, 5.05, 5.1, 9};
  const Pchip f(x, y);
  for (size_t k = 0; k < x.size(); ++k) EXPECT_NEAR(f(x[k]), y[k], 1e-12);
  double prev = f(0);
  for (int i = 1; i <= 6000; ++i) {
    const double xi = i * 1e-3, v = f(xi);
    EXPECT_GE(v, prev - 1e-12) << "not monotone at x=" << xi;
    const size_t k = std::min<size_t>(static_cast<size_t>(xi), x.size() - 2);
    EXPECT_GE(v, std::min(y[k], y[k + 1]) - 1e-12) << "undershoot at x=" << xi;
    EXPECT_LE(v, std::max(y[k], y[k + 1]) + 1e-12) << "overshoot at x=" << xi;
    prev = v;
  }
  // Flat segment stays flat.
  const Pchip flat({0, 1, 2, 3}, {1, 2, 2, 3});
  for (int i = 0; i <= 100; ++i) EXPECT_NEAR(flat(1 + i * 0.01), 2.0, 1e-12);
}

TEST(Pchip, DecreasingDataAndLocalExtremum) {
  const Pchip dec({0, 1, 2, 4}, {10, 4, 3.5, 0});
  double prev = dec(0);
  for (int i = 1; i <= 400; ++i) {
    const double v = dec(i * 0.01);
    EXPECT_LE(v, prev + 1e-12);
    prev = v;
  }
  const Pchip peak({0, 1, 2}, {0, 1, 0});
  EXPECT_EQ(peak.slopes()[1], 0.0);  // zero slope at a local maximum: no overshoot above 1
  for (int i = 0; i <= 200; ++i) EXPECT_LE(peak(i * 0.01), 1.0 + 1e-12);
}

TEST(Pchip, IntegralMatchesFineQuadrature) {
  const Pchip f({0, 0.5, 2, 2.5, 4}, {1, 3, 3.5, 7, 7.2});
  for (auto [a, b] : {std::pair{0.0, 4.0}, {0.2, 2.3}, {2.1, 2.4}}) {
    double sum = 0;
    const int n = 100000;
    for (int i = 0; i < n; ++i) sum += f(a + (i + 0.5) * (b - a) / n);
    EXPECT_NEAR(f.integrate(a, b), sum * (b - a) / n, 1e-8);
  }
}

}  // namespace
}  // namespace crpgs::experiments
