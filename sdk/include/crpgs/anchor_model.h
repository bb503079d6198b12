/// @file anchor_model.h
/// @brief The Scaffold-GS anchor model as modified by HAC (docs/method.md §1): anchors on a voxel
/// grid with a coded feature, 6 log-scales, K offsets and K offset-mask logits; three MLPs that
/// turn the visible anchors into neural Gaussians per view; anchor growing and pruning from
/// training statistics; Adam with per-group log-linear learning-rate schedules.
#pragma once

#include <array>
#include <map>
#include <memory>
#include <string>
#include <vector>

#include <torch/types.h>

#include "crpgs/camera.h"
#include "crpgs/context_model.h"
#include "crpgs/entropy_model.h"
#include "crpgs/entropy_params.h"
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

/// Learning rates (docs/method.md §8). Decaying rates go log-linearly from *_init to *_final over
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
  /// Before this iteration the feature model learns at feature_model_hold_scale times its lr
  /// (0: its parameters stay as initialised).
  int feature_model_start = 0;
  double feature_model_hold_scale = 0.0;
  /// train.feature_model_start: auto. The hold above applies where the anchors start from random
  /// points (no SfM points: growing and pruning must first find the surfaces, and shared features
  /// learnt meanwhile switch whole regions off); from SfM points the feature model learns from
  /// the start. make_trainer decides, from the dataset.
  bool feature_model_start_auto = false;
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

/// HAC's rate path (config section `rate`, docs/method.md §2.2-§2.6). Used only when a context and
/// an entropy model are attached (AnchorModel::attach_rate).
struct RateOptions {
  double lambda = 0.001;         ///< weight of the rate term (bits per parameter)
  double mask_lambda = 5e-4;     ///< weight of mean(sigmoid(mask logits))
  double subset = 0.05;          ///< fraction of the visible active anchors the rate is measured on
  QuantSteps q0;                 ///< Q0 of features, (activated) scaling, offsets
  bool recompute_bounds = true;  ///< HAC: bounds recomputed at rate_start; false: frozen (SFA)
  std::string geometry = "draco";       ///< how the bitstream codes anchor positions: draco or raw
  std::string link_coding = "compact";  ///< how the bitstream codes COHS links: compact or paper
  bool prune_links = true;  ///< compact coding: drop links that cost more bits than they save
  double lr_context_init = 5e-3, lr_context_final = 1e-5;          ///< grid (HAC encoding_xyz)
  double lr_context_mlp_init = 5e-3, lr_context_mlp_final = 1e-5;  ///< HAC mlp_grid
};

/// CRP-GS's anchor links (docs/method.md §6.2-§6.3, §7.6-§7.10; config `rate.leaf_*`): a link
/// strategy (a ContextModel's build_links) pairs leaves with roots; the leaf-feature mean comes
/// from a leaf MLP conditioned on the root's quantised feature (LeafMlp).
struct LinkOptions {
  int leaf_hidden = 60;                              ///< hidden width of the leaf MLP
  double lr_leaf_init = 5e-3, lr_leaf_final = 5e-5;  ///< log-linear over [lr_start, lr_end]
  int lr_start = 30000, lr_end = 40000;
  bool residual = false;  ///< μ_l = μ_base + MLP(·), last layer zero-initialised
};

/// What generate(..., for_training = true) does to the attributes (docs/method.md §2.3). Only used
/// when the rate path is attached; without it training always renders raw attributes.
enum class QuantPhase {
  kRaw,            ///< it <= quant_start
  kFixedNoise,     ///< quant_start < it <= rate_start: + U(-1/2, 1/2) * Q0
  kAdaptiveNoise,  ///< it > rate_start: + U(-1/2, 1/2) * Q (context, not detached) + rate term
};

/// The quantised attributes of a set of anchors (AnchorModel::quantize), row r = model anchor
/// index[r]. Everything is float32 / int32 / bool on the CPU, detached.
struct QuantizedAttributes {
  torch::Tensor index;            ///< [A] int64: model anchor of each row (the evaluation order)
  torch::Tensor active;           ///< [N] bool over all model anchors: any offset mask on
  torch::Tensor positions;        ///< [A, 3] round(anchor / v) * v, float32 (v = float(voxel_size))
  torch::Tensor positions01;      ///< [A, 3] (positions - min) / (max - min).clamp_min(1e-9)
  torch::Tensor bounds;           ///< [2, 3] min, max (the model's bounds())
  EntropyParams params;           ///< [A, ...] mu/sigma/q from predict_entropy_params(chunk 3000)
  torch::Tensor feature_symbols;  ///< [A, Dc] int32
  torch::Tensor scaling_symbols;  ///< [A, 6] int32 (of the activated scaling exp(scaling_raw))
  torch::Tensor offset_symbols;   ///< [A, K, 3] int32 (zero where the offset mask is off)
  torch::Tensor features;         ///< [A, Dc] dequantised: float(symbol) * q_f
  torch::Tensor scaling;          ///< [A, 6] dequantised activated scaling: float(symbol) * q_s
  torch::Tensor offsets;          ///< [A, K, 3] dequantised: float(symbol) * q_o (0 if masked)
  torch::Tensor offset_masks;     ///< [A, K] bool
};

/// The neural Gaussians generated for one view, plus what the statistics need.
struct NeuralGaussians {
  GaussianBatch batch;           ///< the kept Gaussians (opacity > 0)
  torch::Tensor visible;         ///< [N] bool: anchors passing the prefilter
  torch::Tensor neural_opacity;  ///< [M, K] opacities of the visible anchors (detached)
  torch::Tensor selection;       ///< [M*K] bool: which of the visible anchors' Gaussians were kept
  torch::Tensor source;          ///< [G] int64: anchor * K + k of each kept Gaussian
  torch::Tensor input;           ///< [M, C] the opacity/cov MLP input (for tests)
  /// The attributes of the visible anchors as used for this view (noised in the noise phases):
  torch::Tensor used_features;  ///< [M, Dc] coded features
  torch::Tensor used_scaling;   ///< [M, 6] activated scaling
  torch::Tensor used_offsets;   ///< [M, K, 3]
  torch::Tensor q_f, q_s, q_o;  ///< [M, 1] the noise steps; undefined when no noise was added
  /// Rate phase only (kAdaptiveNoise, training): bits per coded parameter of the random subset
  /// of visible active anchors x the active fraction of the visible anchors (docs/method.md §2.5),
  /// differentiable; undefined otherwise. rate_subset: anchors in the subset.
  torch::Tensor bits_per_param;
  int64_t rate_subset = 0;
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
  /// Builds anchors from the points (or, when there are none, from random points inside the
  /// cameras' bounds that at least one training view sees),
  /// the MLPs (default Linear init drawn from `gen`) and the optimizer state. `features` decides
  /// the width of the stored (coded) feature and of the feature the MLPs see.
  static StatusOr<std::unique_ptr<AnchorModel>> create(const AnchorModelOptions& options,
                                                       std::shared_ptr<FeatureModel> features,
                                                       const AnchorInit& init,
                                                       torch::Generator gen);
  ~AnchorModel();
  AnchorModel(const AnchorModel&) = delete;
  AnchorModel& operator=(const AnchorModel&) = delete;

  /// Where the model's tensors live (the CPU unless moved).
  torch::Device device() const;
  /// Moves every tensor of the model to `device`: parameters, optimiser moments, statistics,
  /// links, and the parameters of the components it optimises (feature model, context), which
  /// move in place so that the components see them. Gradients are dropped. Random draws stay on
  /// the CPU (the training generator is a CPU one) and are moved, so a run draws the same numbers
  /// on every device; quantize() and the link searches also run on CPU copies.
  void to(const torch::Device& device);

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
  /// Anchor positions normalised to [0,1] by bounds() (values outside are possible for anchors
  /// grown outside them).
  torch::Tensor positions01() const;  ///< [N, 3]
  /// [2, 3] float32 min, max (HAC update_anchor_bound: min x1.2 if < 0 else x0.8, max x1.2 if
  /// > 0 else x0.8), computed at initialisation and by recompute_bounds().
  torch::Tensor bounds() const;
  void recompute_bounds();
  /// Current binary offset masks (sigmoid(logit) > mask_threshold; all on without
  /// use_offset_mask) [N, K] bool, and anchor activity (any mask on) [N] bool.
  torch::Tensor offset_masks() const;
  torch::Tensor active_anchors() const;
  /// mean(sigmoid(mask logits)) over all N x K logits, differentiable (HAC mask loss, unweighted).
  torch::Tensor mask_loss() const;
  /// The Gaussian-generation MLPs by name (mlp_opacity.w1, .b1, .w2, .b2, mlp_cov.*, mlp_color.*,
  /// and `appearance` when the effect is on), detached.
  std::map<std::string, torch::Tensor> mlp_tensors() const;
  /// The feature model the MLPs' input comes from (shared with whoever created the model).
  std::shared_ptr<FeatureModel> feature_model() const;

  // ---- Rate path (HAC, docs/method.md §2) ----
  /// Attaches a grid context (output width EntropyParamLayout{coded_dim, K}.width()) and an
  /// entropy model. The context's parameters join the optimizer: the first tensor of
  /// context->parameters() is the grid (schedule `context`, HAC encoding_xyz), the rest the
  /// context MLP (schedule `context_mlp`, mlp_grid) - the hash_grid plugin's documented order.
  /// Call before training and before loading a checkpoint.
  Status attach_rate(std::shared_ptr<ContextModel> context, std::shared_ptr<EntropyModel> entropy,
                     const RateOptions& options);
  bool has_rate() const;
  ContextModel* context() const;  ///< null without the rate path
  EntropyModel* entropy() const;  ///< null without the rate path
  const RateOptions& rate_options() const;
  /// Attaches a link strategy and creates the leaf MLP (drawn from `gen`; its tensors join
  /// mlp_tensors() as kLeafMlpNames and the optimizer with schedule `leaf_mlp`). Requires the
  /// rate path; call before loading a checkpoint.
  Status attach_links(std::shared_ptr<ContextModel> links, const LinkOptions& options,
                      torch::Generator gen);
  bool has_links() const;
  ContextModel* link_strategy() const;  ///< null without links
  /// (Re)builds the links from scratch from the current raw features, positions and activity
  /// (docs/method.md §7.6). Returns the number of leaves.
  StatusOr<int64_t> rebuild_links(uint64_t seed);
  /// [N] int64: the model index of each anchor's root, or -1; undefined before the first build
  /// (and after growing/pruning, which invalidates them). During training, a leaf whose root is
  /// inactive uses the base model (docs/method.md §7.10).
  torch::Tensor links() const;
  /// The leaf MLP (undefined without links).
  LeafMlp leaf_mlp() const;
  /// μ_f the rate term uses for the anchors `rows` [S] (model indices) given their base-model
  /// means [S, Dc]: the leaf model (on the root's straight-through-quantised feature) for leaves
  /// of an active root, the base means otherwise. Differentiable.
  torch::Tensor feature_means(const torch::Tensor& rows, const torch::Tensor& base_mu) const;
  /// Phase of the training-time quantisation (set by the trainer every iteration).
  void set_quant_phase(QuantPhase phase);
  QuantPhase quant_phase() const;
  /// The generator the noise and the rate subset are drawn from (the trainer's, so resuming is
  /// bit-identical). Without one, the global generator is used.
  void set_generator(torch::Generator gen);

  /// Test-time quantisation (docs/method.md §2.2-§2.3), the canonical recipe the codec reproduces:
  ///  1. rows: `index` (int64 model anchor indices, in evaluation order) or, when undefined, the
  ///     active anchors (any offset mask on) in increasing index order;
  ///  2. positions = round(anchor / v) * v in float32 with v = float(voxel_size());
  ///     positions01 = (positions - bounds[0]) / (bounds[1] - bounds[0]).clamp_min(1e-9);
  ///  3. params = predict_entropy_params(context, positions01, {coded_dim, K}, q0, 3000) - the
  ///     context evaluated on these rows only, in chunks of 3000 in row order;
  ///  4. x in {features [A, Dc], exp(scaling_raw) [A, 6], offsets [A, K, 3]} with its step q
  ///     ([A, 1], broadcast) and m = float32 mean of that attribute over ALL N model anchors:
  ///     xc = min(max(x, m - 15000 q), m + 15000 q); k = round(xc / q) (half to even), non-finite
  ///     k -> 0, clamped to +-2^30; symbol = int32(k); value = float(symbol) * q;
  ///     offsets whose mask is off get symbol 0 and value 0.
  /// Deterministic for any thread count. Does not change the model. CPU tensors, whatever the
  /// model's device.
  QuantizedAttributes quantize(ContextModel& context, const QuantSteps& q0,
                               const torch::Tensor& index = {}) const;
  /// The same with the attached context and rate_options().q0 (requires has_rate()).
  QuantizedAttributes quantize(const torch::Tensor& index = {}) const;
  /// Makes generate() render exactly the rows of `q` (their snapped positions, dequantised
  /// values and masks; other anchors are not rendered; NeuralGaussians::visible/source then
  /// index q's rows) until clear_quantized(). For rendering only (not for training); growing or
  /// pruning clears it. A model from from_decoded() always renders its decoded values.
  void set_quantized(const QuantizedAttributes& q);
  void clear_quantized();
  bool is_quantized() const;

  /// A render-only model from decoded attributes (no cameras, no optimizer state, no rate path):
  /// positions [A, 3] float32 (as QuantizedAttributes::positions), features [A, Dc],
  /// scaling_activated [A, 6], offsets [A, K, 3], offset_masks [A, K] bool, mlps by name as
  /// mlp_tensors() returns them, bounds [2, 3], voxel_size. It renders exactly like the source
  /// model after set_quantized() with the same rows.
  static StatusOr<std::unique_ptr<AnchorModel>> from_decoded(
      const AnchorModelOptions& options, std::shared_ptr<FeatureModel> features,
      const torch::Tensor& positions, const torch::Tensor& features_values,
      const torch::Tensor& scaling_activated, const torch::Tensor& offsets,
      const torch::Tensor& offset_masks, const std::map<std::string, torch::Tensor>& mlps,
      const torch::Tensor& bounds, double voxel_size);

  /// Generates the neural Gaussians of the anchors visible from `camera` (docs/method.md §1.2).
  /// `camera_index` selects the appearance embedding (training image index; ignored when the
  /// appearance effect is off; a negative index uses the mean embedding). With `for_training`,
  /// the batch carries a screen-space gradient holder for the statistics.
  NeuralGaussians generate(const Camera& camera, int camera_index, Rasterizer& rasterizer,
                           const RenderSettings& settings, bool for_training);

  /// Accumulates the growing/pruning statistics after backward (docs/method.md §1.4).
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
  /// Keys state_dict() holds only when set (the links once built); a reader of a saved state
  /// must look for these beyond the keys of a fresh model's state_dict().
  static const std::vector<std::string>& optional_state_keys();

  /// All trainable tensors by group name (feature, offset, scaling, mask, mlp_*, appearance,
  /// feature_model.i, context.grid.i, context.mlp.i).
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
