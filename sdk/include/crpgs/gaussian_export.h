/// @file gaussian_export.h
/// @brief Baking an anchor model into standard 3DGS Gaussians (ply.h) and rendering such
/// Gaussians with our rasterizer.
///
/// The anchor model's MLPs take [feature, view direction, camera distance] (direction from the
/// camera to the anchor). A standard 3DGS scene has no such input, so baking fixes it:
///  - every active anchor is evaluated (a prefilter that keeps all anchors, not one camera's);
///  - scale and rotation are evaluated at each anchor's representative view: direction =
///    normalised mean of the unit directions from the given camera centres (the training
///    cameras) to the anchor, distance = mean distance to them; opacity (and so which Gaussians
///    exist: opacity > 0) is the mean over the cameras' own views (opacity_over_views) or the
///    representative view's;
///  - colour: SH coefficients of `sh_degree` are fitted per Gaussian by weighted least squares
///    to (colour - 0.5) (3DGS: colour = 0.5 + SH), on two sets of samples of the colour MLP:
///    each camera's own view (direction and distance from that camera centre to the anchor; the
///    SH basis at the direction from the centre to the Gaussian, as a renderer evaluates it),
///    which carries `view_weight` of the total weight, and `directions` unit directions of a
///    Fibonacci sphere at the anchor's representative distance, which carry the rest and keep the
///    SH bounded away from the cameras. view_weight = 0 fits the sphere alone: the DC term is then
///    the sphere-average colour, not the colour the cameras saw, which costs PSNR at low degrees.
///    With the appearance effect the mean embedding is used (as generate(camera_index = -1)).
#pragma once

#include <torch/types.h>

#include <Eigen/Core>
#include <array>
#include <cstdint>
#include <functional>
#include <vector>

#include "crpgs/anchor_model.h"
#include "crpgs/camera.h"
#include "crpgs/dataset.h"
#include "crpgs/ply.h"
#include "crpgs/rasterizer.h"

namespace crpgs {

/// Above this the sphere's share of the fit is too small to keep its normal equations
/// well-conditioned.
constexpr double kMaxViewWeight = 0.99;

struct BakeOptions {
  int sh_degree = 3;    ///< 0..3
  int directions = 96;  ///< sphere samples of the SH fit (>= sh_coeff_count(sh_degree))
  /// Opacity (and so which Gaussians exist): true: the mean over the cameras' views, each seeing
  /// 0 where the model gives a Gaussian none; false: the representative view's alone. On fern
  /// (export_fern.md) the mean gave +0.04 dB PSNR but -0.0006 SSIM and 3 % more Gaussians.
  bool opacity_over_views = false;
  double view_weight = 0.9;  ///< share of the fit on the cameras' own views, [0, kMaxViewWeight]
  std::vector<Eigen::Vector3d> camera_centers;  ///< representative views (>= 1)
};

/// [S, 3] unit directions of a Fibonacci sphere (deterministic).
torch::Tensor fibonacci_directions(int count);
/// [S, B] the 3DGS SH basis (sh_basis) at unit directions [S, 3], B = sh_coeff_count(degree).
torch::Tensor sh_basis_matrix(const torch::Tensor& dirs, int degree);
/// Samples of a weighted SH fit: colours [G, S, 3], the SH basis at their directions, shared
/// [S, B] or per Gaussian [G, S, B], and the weight of each sample.
struct ShSamples {
  torch::Tensor colors;
  torch::Tensor basis;
  double weight = 1;
};
/// SH coefficients [G, B, 3]: argmin Σ_parts weight Σ_s |0.5 + basis_s · c - colour_s|^2
/// (normal equations in float64; the parts together must determine all B coefficients).
torch::Tensor fit_sh(const std::vector<ShSamples>& parts);
/// The unweighted fit of colours [G, S, 3] sampled at shared dirs [S, 3].
torch::Tensor fit_sh(const torch::Tensor& colors, const torch::Tensor& dirs, int degree);

/// Bakes the Gaussians the model renders (its quantised/decoded rows when it has them; pass the
/// same `q` that was given to set_quantized so that positions and masks match; otherwise the
/// model's anchors()/offset_masks() are used).
StatusOr<PlyGaussians> bake_gaussians(AnchorModel& model, const BakeOptions& options,
                                      const QuantizedAttributes* q = nullptr);

/// The activated Gaussians of a .ply as seen from `camera` (colours from SH at the direction
/// from the camera centre to each Gaussian; opacity sigmoid, scales exp, rotation as stored).
GaussianBatch ply_to_batch(const PlyGaussians& g, const Camera& camera);

/// Fine-tuning of baked Gaussians on the training views (`crpgs export --refine`). The bake
/// fixes opacity, scale and rotation at one view per anchor, which a standard 3DGS file cannot
/// make depend on the view (export_fern.md); optimising the file's own parameters against the
/// photos, as 3DGS trains them, wins part of that back. No densification or pruning: the
/// Gaussians stay those the bake made.
struct RefineOptions {
  int iterations = 0;  ///< 0: nothing changes
  /// Loss (1 - lambda_dssim) L1 + lambda_dssim (1 - SSIM): the trainer's photometric loss
  /// (`train.lambda_dssim`), without its scale-volume term.
  double lambda_dssim = 0.2;
  /// 3DGS's learning rates (train.py defaults). The means' is multiplied by the cameras'
  /// extent (cameras_extent, as 3DGS and our trainer) and decays log-linearly from `means_lr` to
  /// `means_lr_final` over the iterations. A baked scene is converged, so it starts at a tenth
  /// of 3DGS's initial rate 1.6e-4 (where 3DGS's own schedule is halfway through).
  double means_lr = 1.6e-5, means_lr_final = 1.6e-6;
  double sh_dc_lr = 2.5e-3, sh_rest_lr = 2.5e-3 / 20;
  double opacity_lr = 0.05, scaling_lr = 5e-3, rotation_lr = 1e-3;
  uint64_t seed = 0;  ///< order of the views: a fresh seeded permutation per pass
};

struct RefineReport {
  int iterations = 0;
  int skipped = 0;  ///< iterations whose loss or gradients were not finite (no update)
  /// Complete passes over the views (each view once, in a shuffled order) that kept at least
  /// one iteration, and the mean loss of the first and the last of them (0 when none).
  int passes = 0;
  double first_pass_loss = 0, last_pass_loss = 0;
};

/// Optimises `g` in place on `views` (camera + photo each; at least one when iterations > 0).
/// The means get the rasterizer's gradient only, not the SH colour's through the view
/// direction. `on_iteration` (optional) is called after each iteration with its 1-based number
/// and loss.
StatusOr<RefineReport> refine_gaussians(
    PlyGaussians& g, Rasterizer& rasterizer, const std::vector<View>& views,
    const std::array<float, 3>& background, const RefineOptions& options,
    const std::function<void(int iteration, double loss)>& on_iteration = {});

}  // namespace crpgs
