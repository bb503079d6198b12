/// @file rasterizer.h
/// @brief The rasterizer component family (built-ins `cpu` and, with CUDA, `cuda`): renders
/// 3D Gaussians with precomputed colours, differentiably, through libtorch autograd.
#pragma once

#include <array>

#include <torch/types.h>

#include "crpgs/camera.h"
#include "crpgs/component.h"

namespace crpgs {

struct RenderSettings {
  std::array<float, 3> background{0.f, 0.f, 0.f};
  float near_plane = 0.01f;
  float far_plane = 100.f;
  bool render_depth = false;
};

/// Gaussians to render; all tensors float32 on the rasterizer's device.
struct GaussianBatch {
  torch::Tensor means;      ///< [N, 3] world positions
  torch::Tensor scales;     ///< [N, 3] activated (positive) scales
  torch::Tensor rotations;  ///< [N, 4] quaternions (w, x, y, z), need not be normalised
  torch::Tensor opacities;  ///< [N] in [0, 1]
  torch::Tensor colors;     ///< [N, 3] precomputed RGB
  /// Optional [N, 2] zeros with requires_grad: after backward its .grad holds the gradient of
  /// the loss w.r.t. the screen-space means (pixels), used for densification statistics.
  torch::Tensor means2d_grad_holder;
};

struct RenderOutput {
  torch::Tensor image;  ///< [H, W, 3]
  torch::Tensor alpha;  ///< [H, W, 1] accumulated opacity
  torch::Tensor depth;  ///< [H, W, 1] expected depth; undefined unless settings.render_depth
  torch::Tensor radii;  ///< [N] int32 pixel radius, 0 where culled
};

class Rasterizer : public Component {
 public:
  virtual torch::Device device() const = 0;
  virtual RenderOutput render(const GaussianBatch& gaussians, const Camera& camera,
                              const RenderSettings& settings) = 0;
  /// Anchor prefilter: which anchors (positions [N,3], extents [N,3] as axis scales with identity
  /// rotation) would be visible in `camera`, without building their Gaussians. Returns bool [N].
  virtual torch::Tensor visible_anchors(const torch::Tensor& positions,
                                        const torch::Tensor& extents, const Camera& camera,
                                        const RenderSettings& settings) = 0;
};

}  // namespace crpgs
