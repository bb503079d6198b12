/// @file gaussian_export.h
/// @brief Baking an anchor model into standard 3DGS Gaussians (ply.h) and rendering such
/// Gaussians with our rasterizer.
///
/// The anchor model's MLPs take [feature, view direction, camera distance] (direction from the
/// camera to the anchor). A standard 3DGS scene has no such input, so baking fixes it:
///  - every active anchor is evaluated (a prefilter that keeps all anchors, not one camera's);
///  - opacity, scale, rotation (and so which Gaussians exist: opacity > 0) are evaluated at each
///    anchor's representative view: direction = normalised mean of the unit directions from the
///    given camera centres (the training cameras) to the anchor, distance = mean distance to them;
///  - colour: per Gaussian, the colour MLP is evaluated at `directions` unit directions of a
///    Fibonacci sphere with the anchor's representative distance, and SH coefficients of
///    `sh_degree` are fitted by least squares to (colour - 0.5) (3DGS: colour = 0.5 + SH).
///    With the appearance effect the mean embedding is used (as generate(camera_index = -1)).
#pragma once

#include <torch/types.h>

#include <Eigen/Core>
#include <vector>

#include "crpgs/anchor_model.h"
#include "crpgs/camera.h"
#include "crpgs/ply.h"
#include "crpgs/rasterizer.h"

namespace crpgs {

struct BakeOptions {
  int sh_degree = 3;    ///< 0..3
  int directions = 96;  ///< samples of the SH fit (>= sh_coeff_count(sh_degree))
  std::vector<Eigen::Vector3d> camera_centers;  ///< representative views (>= 1)
};

/// [S, 3] unit directions of a Fibonacci sphere (deterministic).
torch::Tensor fibonacci_directions(int count);
/// [S, B] the 3DGS SH basis (sh_basis) at unit directions [S, 3], B = sh_coeff_count(degree).
torch::Tensor sh_basis_matrix(const torch::Tensor& dirs, int degree);
/// Least-squares SH coefficients [G, B, 3] of colours [G, S, 3] sampled at dirs [S, 3]:
/// argmin Σ_s |0.5 + basis(d_s) · c - colour_s|^2 (solved in float64).
torch::Tensor fit_sh(const torch::Tensor& colors, const torch::Tensor& dirs, int degree);

/// Bakes the Gaussians the model renders (its quantised/decoded rows when it has them; pass the
/// same `q` that was given to set_quantized so that positions and masks match; otherwise the
/// model's anchors()/offset_masks() are used).
StatusOr<PlyGaussians> bake_gaussians(AnchorModel& model, const BakeOptions& options,
                                      const QuantizedAttributes* q = nullptr);

/// The activated Gaussians of a .ply as seen from `camera` (colours from SH at the direction
/// from the camera centre to each Gaussian; opacity sigmoid, scales exp, rotation as stored).
GaussianBatch ply_to_batch(const PlyGaussians& g, const Camera& camera);

}  // namespace crpgs
