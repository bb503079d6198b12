/// @file anchor_model.h
/// @brief The Scaffold-GS anchor model as modified by HAC (method.md §1): anchors on a voxel grid
/// with a coded feature, 6 log-scales, K offsets and K offset-mask logits; three MLPs that turn
/// the visible anchors into neural Gaussians per view; anchor growing and pruning from training
/// statistics; Adam with per-group log-linear learning-rate schedules.
#pragma once

#include <array>
#include <map>
#include <memory>
#include <string>
#include <vector>

#include <torch/types.h>

#include "crpgs/camera.h"
#include "crpgs/feature_model.h"
#include "crpgs/rasterizer.h"
#include "crpgs/status.h"

namespace crpgs {

/// What a scene calls for (config section `scene`). An effect that is off is not computed: its
/// MLP input columns do not exist and no tensor is allocated for it.
struct SceneEffects {
  bool view_dependent = true;  ///< view direction (3) is an MLP input (HAC: on)
  bool distance_input = true;  ///< camera distance (1) is an MLP input (HAC: on)
  int appearance_dim = 0;      ///< per-training-image embedding fed to the colour MLP; 0 = off
  std::array<float, 3> background{0.f, 0.f, 0.f};
};

/// Learning rates (method.md §8). Decaying rates go log-linearly from *_init to *_final over
/// `max_steps` iterations; offset and mask rates are multiplied by the spatial lr scale.
struct LearningRates {
  double offset_init = 0.01, offset_final = 1e-4;
  double mask_init = 0.01, mask_final = 1e-4;
  double feature = 0.0075;
  double scaling = 0.007;
  double mlp_opacity_init = 2e-3, mlp_opacity_final = 2e-5;
  double mlp_cov_init = 4e-3, mlp_cov_final = 4e-3;
  double mlp_color_init = 8e-3, mlp_color_final = 5e-5;
  double appearance_init = 0.05, appearance_final = 5e-4;        ///< Scaffold-GS values
  double feature_model_init = 5e-3, feature_model_final = 1e-5;  ///< as HAC's encoding_xyz
  int max_steps = 30000;
};

struct AnchorModelOptions {
  int n_offsets = 10;        ///< K
  int hidden_dim = 50;       ///< width of the MLPs' hidden layer
  double voxel_size = 0.01;  ///< <= 0: the median squared 3-NN distance of the SfM points
  int update_init_factor = 16;
  int update_hierarchy_factor = 4;
  int update_depth = 3;
  double densify_grad_threshold = 2e-4;
  double min_opacity = 0.005;
  double success_threshold = 0.8;
  bool use_offset_mask = true;  ///< HAC: opacities multiplied by the binary offset mask
  double mask_threshold = 0.01;
  int random_init_points = 20000;  ///< used when the dataset has no SfM points
  SceneEffects effects;
  LearningRates lr;
};

/// The neural Gaussians generated for one view, plus what the statistics need.
struct NeuralGaussians {
  GaussianBatch batch;           ///< the kept Gaussians (opacity > 0)
  torch::Tensor visible;         ///< [N] bool: anchors passing the prefilter
  torch::Tensor neural_opacity;  ///< [M, K] opacities of the visible anchors (detached)
  torch::Tensor selection;       ///< [M*K] bool: which of the visible anchors' Gaussians were kept
  torch::Tensor source;          ///< [G] int64: anchor * K + k of each kept Gaussian
  torch::Tensor input;           ///< [M, C] the opacity/cov MLP input (for tests)
};

/// What one growing/pruning step did.
struct AdjustReport {
  int64_t grown = 0;
  int64_t pruned = 0;
};

/// Inputs of the initialisation.
struct AnchorInit {
  std::vector<std::array<float, 3>> points;  ///< SfM points; may be empty
  std::vector<Camera> train_cameras;         ///< for the lr scale, random init, appearance
};

class AnchorModel {
 public:
  /// Builds anchors from the points (or randomly inside the cameras' bounds when there are none),
  /// the MLPs (default Linear init drawn from `gen`) and the optimizer state. `features` decides
  /// the width of the stored (coded) feature and of the feature the MLPs see.
  static StatusOr<std::unique_ptr<AnchorModel>> create(const AnchorModelOptions& options,
                                                       std::shared_ptr<FeatureModel> features,
                                                       const AnchorInit& init,
                                                       torch::Generator gen);
  ~AnchorModel();
  AnchorModel(const AnchorModel&) = delete;
  AnchorModel& operator=(const AnchorModel&) = delete;

  int64_t num_anchors() const;
  int n_offsets() const;
  const AnchorModelOptions& options() const;
  double voxel_size() const;
  double spatial_lr_scale() const;
  /// Input widths of the opacity/cov MLPs and of the colour MLP.
  int64_t mlp_input_dim() const;
  int64_t color_input_dim() const;

  // Per-anchor tensors (views of the parameters; do not resize).
  torch::Tensor anchors() const;      ///< [N, 3]
  torch::Tensor features() const;     ///< [N, D_coded]
  torch::Tensor offsets() const;      ///< [N, K, 3]
  torch::Tensor scaling_raw() const;  ///< [N, 6]
  torch::Tensor mask_logits() const;  ///< [N, K]
  /// Anchor positions normalised to [0,1] by the bounds fixed at initialisation (HAC formula).
  torch::Tensor positions01() const;  ///< [N, 3]

  /// Generates the neural Gaussians of the anchors visible from `camera` (method.md §1.2).
  /// `camera_index` selects the appearance embedding (training image index; ignored when the
  /// appearance effect is off; a negative index uses the mean embedding). With `for_training`,
  /// the batch carries a screen-space gradient holder for the statistics.
  NeuralGaussians generate(const Camera& camera, int camera_index, Rasterizer& rasterizer,
                           const RenderSettings& settings, bool for_training);

  /// Accumulates the growing/pruning statistics after backward (method.md §1.4).
  void accumulate_statistics(const NeuralGaussians& g, const RenderOutput& out,
                             const Camera& camera);
  /// Grows and prunes anchors, resets the statistics, keeps the optimizer state consistent.
  /// `check_interval` is the schedule's update interval (the count thresholds scale with it).
  AdjustReport adjust_anchors(int check_interval, torch::Generator gen);
  /// Frees the statistics after densification ends (they are re-created if needed).
  void reset_statistics();

  /// Sets every group's learning rate for `iteration` (log-linear schedules).
  void update_learning_rates(int iteration);
  double learning_rate(const std::string& group) const;
  /// One Adam step (eps 1e-15) on every parameter that has a gradient, then zero the gradients.
  void optimizer_step();
  void zero_grad();

  /// Everything needed to continue training bit-identically: parameters, optimizer moments and
  /// steps, statistics, bounds and scales.
  std::map<std::string, torch::Tensor> state_dict() const;
  Status load_state_dict(const std::map<std::string, torch::Tensor>& state);

  /// All trainable tensors by group name (feature, offset, scaling, mask, mlp_*, appearance).
  std::vector<std::pair<std::string, torch::Tensor>> named_parameters() const;

  struct Impl;

 private:
  explicit AnchorModel(std::unique_ptr<Impl> impl);
  std::unique_ptr<Impl> impl_;
};

/// Mean squared distance of each point to its 3 nearest other points (grid-based, exact),
/// clamped to >= 1e-7. points: [N, 3] float. Returns [N].
torch::Tensor mean_sq_dist_3nn(const torch::Tensor& points);

}  // namespace crpgs
