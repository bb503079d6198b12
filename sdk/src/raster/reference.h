/// @file reference.h
/// @brief A plain-libtorch float64 version of the rasterizer maths (slow; for tests and the
/// benchmark's baseline). Differentiable through libtorch autograd; it follows the same
/// conventions as stages.h, including the tile assignment from the 3-sigma radius.
#pragma once

#include <array>

#include <ATen/ATen.h>

#include "crpgs/camera.h"
#include "crpgs/rasterizer.h"

namespace crpgs::raster::reference {

struct Projection {
  at::Tensor means2d;  // [N, 2] float64
  at::Tensor conics;   // [N, 3] float64
  at::Tensor depths;   // [N] float64
  at::Tensor radii;    // [N] int32 (no gradient), 0 where culled
};

/// means [N,3], scales [N,3], rotations [N,4]: float64.
Projection project(const at::Tensor& means, const at::Tensor& scales, const at::Tensor& rotations,
                   const Camera& camera, const RenderSettings& settings);

struct Image {
  at::Tensor image;  // [H, W, 3] float64
  at::Tensor alpha;  // [H, W, 1]
  at::Tensor depth;  // [H, W, 1] sum of w_i z_i (not normalised); undefined unless asked
};

/// opacities [N], colors [N,3]: float64; the projection's tensors as returned by project().
Image rasterize(const Projection& proj, const at::Tensor& opacities, const at::Tensor& colors,
                int width, int height, const std::array<float, 3>& background, bool render_depth);

/// The whole pipeline with RenderOutput's meaning (depth = expected depth, normalised).
RenderOutput render(const GaussianBatch& gaussians, const Camera& camera,
                    const RenderSettings& settings);

}  // namespace crpgs::raster::reference
