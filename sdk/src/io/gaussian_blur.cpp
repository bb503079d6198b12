/// @file gaussian_blur.cpp
/// @brief The SSIM window's float passes for the training loss, one clone per instruction set:
/// the loops vectorise across pixels and keep each output's tap order, so every clone gives the
/// same bits (no FMA contraction in this file).
#include "io/gaussian_blur.h"

#include "crpgs/target_clones.h"

namespace crpgs::ssim_window {
namespace {
const std::array<float, kTaps>& float_taps() {
  static const std::array<float, kTaps> g = taps<float>();
  return g;
}
}  // namespace

CRPGS_TARGET_CLONES __attribute__((flatten)) void blur_rows_f32(const float* in, float* out,
                                                                int64_t y0, int64_t y1,
                                                                int64_t width, int64_t channels) {
  blur_rows(in, out, y0, y1, width, channels, float_taps());
}

CRPGS_TARGET_CLONES __attribute__((flatten)) void blur_columns_f32(const float* in, float* out,
                                                                   int64_t y0, int64_t y1,
                                                                   int64_t height, int64_t len) {
  blur_columns(in, out, y0, y1, height, len, float_taps());
}

}  // namespace crpgs::ssim_window
