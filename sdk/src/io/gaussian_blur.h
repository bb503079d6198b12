/// @file gaussian_blur.h
/// @brief The SSIM window (docs/method.md §1.6, §4): 11 Gaussian taps, sigma 1.5, zero padding,
/// applied separably, along rows and then along columns. One definition for the evaluation
/// metric (double, one plane at a time) and the training loss (float, interleaved channels).
#pragma once

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>

namespace crpgs::ssim_window {

constexpr int kRadius = 5;
constexpr int kTaps = 2 * kRadius + 1;
constexpr double kSigma = 1.5;
constexpr double kC1 = 0.01 * 0.01, kC2 = 0.03 * 0.03;

template <typename T>
std::array<T, kTaps> taps() {
  std::array<double, kTaps> g{};
  double s = 0;
  for (int i = -kRadius; i <= kRadius; ++i)
    s += g[size_t(i + kRadius)] = std::exp(-(i * i) / (2 * kSigma * kSigma));
  std::array<T, kTaps> out{};
  for (int i = 0; i < kTaps; ++i) out[size_t(i)] = T(g[size_t(i)] / s);
  return out;
}

/// Along rows [y0, y1) of an image `width` pixels wide with `channels` interleaved values per
/// pixel: out[y][x, c] = sum over k of g[k] in[y][x + k - 5, c], taps outside the row skipped.
/// Every output sums its taps in ascending k, so the interior loop (which the compiler
/// vectorises) and the border loop give the same result.
template <typename T>
void blur_rows(const T* in, T* out, int64_t y0, int64_t y1, int64_t width, int64_t channels,
               const std::array<T, kTaps>& g) {
  const int64_t len = width * channels;
  const int64_t inner0 = std::min<int64_t>(kRadius, width) * channels;
  const int64_t inner1 = std::max<int64_t>(inner0, (width - kRadius) * channels);
  for (int64_t y = y0; y < y1; ++y) {
    const T* src = in + y * len;
    T* dst = out + y * len;
    auto border = [&](int64_t i) {
      const int64_t x = i / channels;
      const int64_t k0 = std::max<int64_t>(-kRadius, -x),
                    k1 = std::min<int64_t>(kRadius, width - 1 - x);
      T s = 0;
      for (int64_t k = k0; k <= k1; ++k) s += g[size_t(k + kRadius)] * src[i + k * channels];
      dst[i] = s;
    };
    for (int64_t i = 0; i < inner0; ++i) border(i);
    // Interior: one sweep of the row per tap, which vectorises across outputs (the taps of one
    // output are `channels` apart); each output still adds its taps in order, from 0.
    std::fill(dst + inner0, dst + inner1, T(0));
    for (int k = 0; k < kTaps; ++k) {
      const T gk = g[size_t(k)];
      const T* tap = src + (k - kRadius) * channels;
      for (int64_t i = inner0; i < inner1; ++i) dst[i] += gk * tap[i];
    }
    for (int64_t i = inner1; i < len; ++i) border(i);
  }
}

/// Along columns, for output rows [y0, y1) of a `height`-row image with rows of `len` values:
/// out[y] = sum over k of g[k] in[y + k - 5], rows outside the image skipped.
template <typename T>
void blur_columns(const T* in, T* out, int64_t y0, int64_t y1, int64_t height, int64_t len,
                  const std::array<T, kTaps>& g) {
  for (int64_t y = y0; y < y1; ++y) {
    T* dst = out + y * len;
    std::fill(dst, dst + len, T(0));
    const int64_t k0 = std::max<int64_t>(-kRadius, -y),
                  k1 = std::min<int64_t>(kRadius, height - 1 - y);
    for (int64_t k = k0; k <= k1; ++k) {
      const T wk = g[size_t(k + kRadius)];
      const T* src = in + (y + k) * len;
      for (int64_t i = 0; i < len; ++i) dst[i] += wk * src[i];
    }
  }
}

/// The two float passes with the window's taps, compiled for several instruction sets (the
/// training loss's hot loops; gaussian_blur.cpp). Same results as the templates above.
void blur_rows_f32(const float* in, float* out, int64_t y0, int64_t y1, int64_t width,
                   int64_t channels);
void blur_columns_f32(const float* in, float* out, int64_t y0, int64_t y1, int64_t height,
                      int64_t len);

}  // namespace crpgs::ssim_window
