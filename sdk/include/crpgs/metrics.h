/// @file metrics.h
/// @brief Image quality metrics of the evaluation protocol (docs/method.md §1.6, §4), without
/// libtorch. Inputs are HWC float images in [0, 1] of equal size and channel count; accumulation is
/// in double precision.
#pragma once

#include "crpgs/image.h"
#include "crpgs/status.h"

namespace crpgs {

/// Mean squared error over all pixels and channels.
StatusOr<double> mse(const Image& a, const Image& b);

/// PSNR = 20·log10(1/√MSE) = −10·log10(MSE), peak 1. Identical images give +infinity
/// (std::numeric_limits<double>::infinity()), never a cap: a caller averaging over views sees inf
/// and can report "lossless" instead of a made-up number.
StatusOr<double> psnr(const Image& a, const Image& b);
/// PSNR from an MSE (+infinity for mse == 0).
double psnr_from_mse(double mse);

/// SSIM with an 11×11 Gaussian window (σ = 1.5, normalised), C1 = 0.01², C2 = 0.03², zero padding
/// (the window is not renormalised at borders, as in conv2d with padding 5), mean over the map,
/// averaged over channels. Symmetric in a and b; 1 for identical images.
StatusOr<double> ssim(const Image& a, const Image& b);

struct ImageMetrics {
  double mse = 0, psnr = 0, ssim = 0;
};
/// All metrics at once.
StatusOr<ImageMetrics> compare_images(const Image& a, const Image& b);

}  // namespace crpgs
