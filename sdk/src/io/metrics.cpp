/// @file metrics.cpp
/// @brief PSNR / SSIM in double precision; SSIM via a separable Gaussian filter.
#include "crpgs/metrics.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <string>
#include <vector>

#include "io/gaussian_blur.h"

namespace crpgs {
namespace {

Status check_pair(const Image& a, const Image& b, const char* what) {
  if (a.width != b.width || a.height != b.height || a.channels != b.channels)
    return Status(StatusCode::kInvalidArgument,
                  std::string(what) + ": image sizes differ (" + std::to_string(a.width) + "x" +
                      std::to_string(a.height) + "x" + std::to_string(a.channels) + " vs " +
                      std::to_string(b.width) + "x" + std::to_string(b.height) + "x" +
                      std::to_string(b.channels) + ")");
  const size_t n = size_t(a.width) * a.height * a.channels;
  if (n == 0) return Status(StatusCode::kInvalidArgument, std::string(what) + ": empty image");
  if (a.pixels.size() != n || b.pixels.size() != n)
    return Status(StatusCode::kInvalidArgument, std::string(what) + ": pixel buffer size mismatch");
  return OkStatus();
}

using ssim_window::kC1;
using ssim_window::kC2;

// Zero-padded separable filtering of one plane [h, w] in place.
void blur(std::vector<double>& plane, int w, int h, const std::array<double, ssim_window::kTaps>& g,
          std::vector<double>& tmp) {
  tmp.resize(plane.size());
  ssim_window::blur_rows(plane.data(), tmp.data(), 0, h, w, 1, g);
  ssim_window::blur_columns(tmp.data(), plane.data(), 0, h, h, w, g);
}

}  // namespace

double psnr_from_mse(double m) {
  if (m <= 0) return std::numeric_limits<double>::infinity();
  return -10.0 * std::log10(m);
}

StatusOr<double> mse(const Image& a, const Image& b) {
  CRPGS_RETURN_IF_ERROR(check_pair(a, b, "mse"));
  double s = 0;
  for (size_t i = 0; i < a.pixels.size(); ++i) {
    const double d = double(a.pixels[i]) - double(b.pixels[i]);
    s += d * d;
  }
  return s / double(a.pixels.size());
}

StatusOr<double> psnr(const Image& a, const Image& b) {
  CRPGS_ASSIGN_OR_RETURN(const double m, mse(a, b));
  return psnr_from_mse(m);
}

StatusOr<double> ssim(const Image& a, const Image& b) {
  CRPGS_RETURN_IF_ERROR(check_pair(a, b, "ssim"));
  const int w = a.width, h = a.height, c = a.channels;
  const size_t n = size_t(w) * h;
  const auto g = ssim_window::taps<double>();
  std::vector<double> mu1(n), mu2(n), s11(n), s22(n), s12(n), tmp;
  double total = 0;
  for (int ch = 0; ch < c; ++ch) {
    for (size_t i = 0; i < n; ++i) {
      const double x = a.pixels[i * c + ch], y = b.pixels[i * c + ch];
      mu1[i] = x, mu2[i] = y, s11[i] = x * x, s22[i] = y * y, s12[i] = x * y;
    }
    for (auto* p : {&mu1, &mu2, &s11, &s22, &s12}) blur(*p, w, h, g, tmp);
    double sum = 0;
    for (size_t i = 0; i < n; ++i) {
      const double m1 = mu1[i], m2 = mu2[i];
      const double v1 = s11[i] - m1 * m1, v2 = s22[i] - m2 * m2, cov = s12[i] - m1 * m2;
      sum +=
          ((2 * m1 * m2 + kC1) * (2 * cov + kC2)) / ((m1 * m1 + m2 * m2 + kC1) * (v1 + v2 + kC2));
    }
    total += sum / double(n);
  }
  return total / c;
}

StatusOr<ImageMetrics> compare_images(const Image& a, const Image& b) {
  ImageMetrics m;
  CRPGS_ASSIGN_OR_RETURN(m.mse, mse(a, b));
  m.psnr = psnr_from_mse(m.mse);
  CRPGS_ASSIGN_OR_RETURN(m.ssim, ssim(a, b));
  return m;
}

}  // namespace crpgs
