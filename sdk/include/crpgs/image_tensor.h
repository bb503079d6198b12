/// @file image_tensor.h
/// @brief Images as tensors, and their quality measures on tensors: the differentiable SSIM of
/// the training loss and the export's refinement, and PSNR.
#pragma once

#include <torch/types.h>

#include "crpgs/image.h"

namespace crpgs {

/// An image as a [H, W, C] float tensor (a copy), and back (values clamped to [0, 1]).
torch::Tensor image_to_tensor(const Image& im);
Image tensor_to_image(const torch::Tensor& t);

/// Differentiable SSIM (11x11 Gaussian window, sigma 1.5, C1 = 0.01^2, C2 = 0.03^2, zero
/// padding, mean over the map). a, b: non-empty float [H, W, C] on one device; the gradient
/// flows to `a` only (`b`, the reference, must not require one). On the CPU a hand-written
/// kernel and backward; elsewhere tensor_ssim_reference.
torch::Tensor tensor_ssim(const torch::Tensor& a, const torch::Tensor& b);
/// The same SSIM from libtorch operations (depthwise convolutions, autograd), on any device.
torch::Tensor tensor_ssim_reference(const torch::Tensor& a, const torch::Tensor& b);
/// PSNR in dB of [H, W, C] images in [0, 1] (b is moved to a's device).
double tensor_psnr(const torch::Tensor& a, const torch::Tensor& b);

}  // namespace crpgs
