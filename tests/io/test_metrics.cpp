/// @file test_metrics.cpp
/// @brief PSNR / SSIM (metrics.h) against closed forms and a naive 2D reference.
#include <gtest/gtest.h>

#include <cmath>
#include <limits>
#include <random>

#include "crpgs/metrics.h"
#include "io_test_util.h"

namespace crpgs {
namespace {

Image constant(int w, int h, int c, float v) {
  Image im = Image::zeros(w, h, c);
  std::fill(im.pixels.begin(), im.pixels.end(), v);
  return im;
}

Image add_noise(const Image& im, float sigma, unsigned seed) {
  Image out = im;
  std::mt19937 rng(seed);
  std::normal_distribution<float> n(0.f, sigma);
  for (float& v : out.pixels) v = std::clamp(v + n(rng), 0.f, 1.f);
  return out;
}

std::vector<double> window_1d() {
  std::vector<double> g(11);
  double s = 0;
  for (int i = 0; i < 11; ++i)
    s += g[size_t(i)] = std::exp(-double((i - 5) * (i - 5)) / (2 * 1.5 * 1.5));
  for (double& v : g) v /= s;
  return g;
}

// Direct (non-separable) 11x11 zero-padded SSIM, one channel, straight from the definition.
double naive_ssim(const Image& a, const Image& b) {
  const std::vector<double> g = window_1d();
  const double C1 = 1e-4, C2 = 9e-4;
  double total = 0;
  for (int c = 0; c < a.channels; ++c) {
    double sum = 0;
    for (int y = 0; y < a.height; ++y)
      for (int x = 0; x < a.width; ++x) {
        double m1 = 0, m2 = 0, s11 = 0, s22 = 0, s12 = 0;
        for (int dy = -5; dy <= 5; ++dy)
          for (int dx = -5; dx <= 5; ++dx) {
            const int yy = y + dy, xx = x + dx;
            if (yy < 0 || xx < 0 || yy >= a.height || xx >= a.width) continue;
            const double w = g[size_t(dy + 5)] * g[size_t(dx + 5)];
            const double p = a.at(yy, xx, c), q = b.at(yy, xx, c);
            m1 += w * p, m2 += w * q, s11 += w * p * p, s22 += w * q * q, s12 += w * p * q;
          }
        const double v1 = s11 - m1 * m1, v2 = s22 - m2 * m2, cv = s12 - m1 * m2;
        sum += (2 * m1 * m2 + C1) * (2 * cv + C2) / ((m1 * m1 + m2 * m2 + C1) * (v1 + v2 + C2));
      }
    total += sum / (a.width * a.height);
  }
  return total / a.channels;
}

TEST(Metrics, PsnrOfIdenticalImagesIsInfinite) {
  const Image a = test::random_image(16, 9, 3, 1);
  auto p = psnr(a, a);
  ASSERT_TRUE(p.ok());
  EXPECT_TRUE(std::isinf(*p) && *p > 0);
  EXPECT_EQ(*mse(a, a), 0.0);
  EXPECT_TRUE(std::isinf(psnr_from_mse(0.0)));
}

TEST(Metrics, PsnrKnownMse) {
  // Constant difference 0.25 (exact in float): MSE = 1/16, PSNR = 10·log10(16).
  auto p = psnr(constant(7, 5, 3, 0.5f), constant(7, 5, 3, 0.25f));
  ASSERT_TRUE(p.ok());
  EXPECT_NEAR(*p, 10.0 * std::log10(16.0), 1e-12);
  // Half of the values differ by 0.5: MSE = 0.125.
  Image a = constant(4, 2, 1, 0.f), b = a;
  for (int x = 0; x < 4; ++x) b.at(0, x, 0) = 0.5f;
  EXPECT_DOUBLE_EQ(*mse(a, b), 0.125);
  EXPECT_NEAR(*psnr(a, b), -10.0 * std::log10(0.125), 1e-12);
  EXPECT_NEAR(psnr_from_mse(0.01), 20.0, 1e-12);
}

TEST(Metrics, SizeMismatchIsAnError) {
  EXPECT_EQ(psnr(constant(4, 4, 3, 0), constant(4, 5, 3, 0)).status().code(),
            StatusCode::kInvalidArgument);
  EXPECT_FALSE(ssim(constant(4, 4, 3, 0), constant(4, 4, 1, 0)).ok());
  EXPECT_FALSE(ssim(Image(), Image()).ok());
}

TEST(Metrics, SsimOfIdenticalImagesIsOne) {
  const Image a = test::random_image(40, 23, 3, 2);
  EXPECT_NEAR(*ssim(a, a), 1.0, 1e-12);
}

TEST(Metrics, SsimOnePixelHandComputed) {
  // 1x1 image: with zero padding only the centre tap w = g0² of the window sees data, so
  // mu = w·x, sigma² = w·x² − w²·x², cov = w·x·y − w²·x·y.
  const std::vector<double> g = window_1d();
  const double w = g[5] * g[5], x = 0.5, y = 0.25, C1 = 1e-4, C2 = 9e-4;
  const double mx = w * x, my = w * y;
  const double vx = w * x * x - mx * mx, vy = w * y * y - my * my, cxy = w * x * y - mx * my;
  const double expected =
      (2 * mx * my + C1) * (2 * cxy + C2) / ((mx * mx + my * my + C1) * (vx + vy + C2));
  EXPECT_NEAR(*ssim(constant(1, 1, 1, 0.5f), constant(1, 1, 1, 0.25f)), expected, 1e-12);
  EXPECT_LT(expected, 0.99);  // the case is not trivially 1
}

TEST(Metrics, SsimMatchesNaiveReference) {
  const Image a = test::random_image(13, 17, 3, 4);
  const Image b = add_noise(a, 0.1f, 5);
  EXPECT_NEAR(*ssim(a, b), naive_ssim(a, b), 1e-10);
  const Image c = test::random_image(3, 2, 1, 6),
              d = test::random_image(3, 2, 1, 7);  // smaller than the window
  EXPECT_NEAR(*ssim(c, d), naive_ssim(c, d), 1e-10);
}

TEST(Metrics, SsimIsSymmetricAndDropsWithNoise) {
  const Image a = resize_area(test::random_image(128, 96, 3, 8), 64, 48);  // some spatial structure
  const Image light = add_noise(a, 0.02f, 9), heavy = add_noise(a, 0.1f, 10);
  const double s_ab = *ssim(a, light), s_ba = *ssim(light, a);
  EXPECT_NEAR(s_ab, s_ba, 1e-12);
  const double s_heavy = *ssim(a, heavy);
  EXPECT_LT(s_ab, 1.0);
  EXPECT_LT(s_heavy, s_ab);
  EXPECT_GT(*psnr(a, light), *psnr(a, heavy));
  auto all = compare_images(a, heavy);
  ASSERT_TRUE(all.ok());
  EXPECT_DOUBLE_EQ(all->ssim, s_heavy);
  EXPECT_DOUBLE_EQ(all->psnr, *psnr(a, heavy));
}

}  // namespace
}  // namespace crpgs
