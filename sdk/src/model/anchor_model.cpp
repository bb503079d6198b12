/// @file anchor_model.cpp
/// @brief Anchor model: initialisation, neural Gaussian generation, statistics, growing and
/// pruning, and a small Adam whose per-row state is grown and pruned with the anchors.
#include "crpgs/anchor_model.h"

#include "crpgs/chunked_mlp.h"
#include "crpgs/links.h"
#include "model/adam_kernel.h"
#include "model/optimizer.h"
#include "model/sorted_gather.h"

#include <torch/torch.h>

#include <ATen/CPUGeneratorImpl.h>
#include <ATen/Parallel.h>
#include <ATen/core/PhiloxRNGEngine.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <limits>
#include <mutex>
#include <optional>

namespace crpgs {

using torch::indexing::Slice;

namespace {

constexpr double kAdamBeta1 = 0.9, kAdamBeta2 = 0.999, kAdamEps = 1e-15;

struct Mlp {
  torch::Tensor w1, b1, w2, b2;
  torch::Tensor forward(const torch::Tensor& x) const { return chunked_mlp(x, w1, b1, w2, b2); }
};

// torch.nn.Linear's default init: kaiming_uniform(a=sqrt(5)) = U(-1/sqrt(in), 1/sqrt(in)) for
// the weight and the bias; drawn from our generator so that runs are reproducible.
void init_linear(torch::Tensor& w, torch::Tensor& b, int64_t in, int64_t out,
                 torch::Generator& gen) {
  const double bound = 1.0 / std::sqrt(double(in));
  w = torch::empty({out, in}).uniform_(-bound, bound, gen);
  b = torch::empty({out}).uniform_(-bound, bound, gen);
}

// Uniform [0, 1) floats on the CPU: one 64-bit draw from `g` (the global generator when empty)
// keys a Philox stream, cut into fixed chunks filled in parallel. torch::rand's Mersenne twister
// makes one value at a time on one thread (~12 ms of a rate-phase iteration on fern, 2M values;
// bench/results/train_fern.md); these values depend on the key and their index only, not on the
// thread count, and the run's generator advances by one draw per call.
torch::Tensor uniform_floats(at::IntArrayRef sizes, const c10::optional<at::Generator>& g) {
  uint64_t key = 0;
  {
    auto* gen =
        at::get_generator_or_default<at::CPUGeneratorImpl>(g, at::detail::getDefaultCPUGenerator());
    std::lock_guard<std::mutex> lock(gen->mutex_);
    key = gen->random64();
  }
  auto out = torch::empty(sizes, torch::kFloat);
  float* p = out.data_ptr<float>();
  const int64_t n = out.numel();
  constexpr int64_t kChunk = 1 << 14;
  at::parallel_for(0, (n + kChunk - 1) / kChunk, 1, [&](int64_t begin, int64_t end) {
    for (int64_t c = begin; c < end; ++c) {
      at::philox_engine engine(key, uint64_t(c));
      const int64_t last = std::min(n, (c + 1) * kChunk);
      for (int64_t i = c * kChunk; i < last; ++i)
        p[i] = float(engine() >> 8) * (1.0f / 16777216.0f);  // 24 bits: exact in a float
    }
  });
  return out;
}

Mlp make_mlp(int64_t in, int64_t hidden, int64_t out, torch::Generator& gen) {
  Mlp m;
  init_linear(m.w1, m.b1, in, hidden, gen);
  init_linear(m.w2, m.b2, hidden, out, gen);
  return m;
}

// Straight-through binary mask: forward (sigmoid(l) > t), gradient of sigmoid (HAC get_mask).
torch::Tensor ste_mask(const torch::Tensor& logits, double threshold) {
  auto s = torch::sigmoid(logits);
  return ((s > threshold).to(s.dtype()) - s).detach() + s;
}

// HAC update_anchor_bound: per-axis min/max expanded multiplicatively about the origin.
torch::Tensor hac_bounds(const torch::Tensor& anchor) {  // [N, 3] -> [2, 3]
  if (anchor.size(0) == 0)
    return torch::stack({torch::zeros({3}, anchor.options()), torch::ones({3}, anchor.options())});
  auto mn = std::get<0>(anchor.min(0)), mx = std::get<0>(anchor.max(0));
  mn = torch::where(mn < 0, mn * 1.2, mn * 0.8);
  mx = torch::where(mx > 0, mx * 1.2, mx * 0.8);
  // A scene flat on an axis through 0 (all anchors at 0 there) would get lo = hi = 0: an empty
  // interval that no bitstream may carry. One unit either side (HAC's bounds are in world units).
  const auto flat = mx <= mn;
  return torch::stack({torch::where(flat, mn - 1, mn), torch::where(flat, mx + 1, mx)});
}

torch::Tensor normalise(const torch::Tensor& pos, const torch::Tensor& bounds) {
  auto lo = bounds[0], hi = bounds[1];
  return (pos - lo) / (hi - lo).clamp_min(1e-9);
}

// Mean of all elements in double, in a fixed order (identical for any thread count): eight
// interleaved partial sums, so the loop is not one chain of dependent additions (training calls
// this on every anchor's features each iteration). Off the CPU a double mean on the device.
float serial_mean(const torch::Tensor& t) {
  if (!t.device().is_cpu()) return t.detach().to(torch::kDouble).mean().item<float>();
  auto c = t.detach().to(torch::kFloat).contiguous();
  const float* d = c.data_ptr<float>();
  const int64_t n = c.numel();
  constexpr int64_t kLanes = 8;
  double lane[kLanes] = {};
  int64_t i = 0;
  for (; i + kLanes <= n; i += kLanes)
    for (int64_t l = 0; l < kLanes; ++l) lane[l] += d[i + l];
  for (; i < n; ++i) lane[i % kLanes] += d[i];
  double s = 0;
  for (double v : lane) s += v;
  return n ? float(s / double(n)) : 0.f;
}

// x clamped to mean +- 15000 q (q broadcasts; docs/method.md §2.2).
torch::Tensor clamp_about(const torch::Tensor& x, float mean, const torch::Tensor& q) {
  auto r = q * 15000.0;
  return torch::min(torch::max(x, mean - r), mean + r);
}

// The codec's symbols of x with steps q about `mean` (float, no gradient): round(x/q) within
// mean ± 15000 q, and 0 where q = 0 (a saturated step) instead of inf or NaN.
torch::Tensor code_symbols(const torch::Tensor& x, float mean, const torch::Tensor& q) {
  auto k = torch::round(clamp_about(x.detach(), mean, q) / q);
  return torch::nan_to_num(k, 0.0, 0.0, 0.0).clamp(-double(1 << 30), double(1 << 30));
}

// Voxel keys for set membership; coordinates are far inside +-2^20 for any sane voxel size.
torch::Tensor cell_keys(const torch::Tensor& cells) {  // [N, 3] int64 -> [N]
  auto c = cells.clamp(-(int64_t(1) << 20) + 1, (int64_t(1) << 20) - 1) + (int64_t(1) << 20);
  return c.select(1, 0) * (int64_t(1) << 42) + c.select(1, 1) * (int64_t(1) << 21) + c.select(1, 2);
}

}  // namespace

/// One optimised tensor with its schedule and Adam moments.
struct ParamGroup {
  std::string name;
  std::string schedule;  // which lr schedule
  torch::Tensor param;
  torch::Tensor m, v;
  int64_t step = 0;
  double lr = 0;
  bool per_anchor = false;  // rows follow the anchors (grown/pruned with them)
  bool external = false;    // owned by a component (updated in place, loaded with copy_)
};

/// What generate() renders instead of the parameters (quantised or decoded attributes).
struct RenderValues {
  torch::Tensor positions;    // [A, 3]
  torch::Tensor positions01;  // [A, 3]
  torch::Tensor features;     // [A, Dc]
  torch::Tensor scaling;      // [A, 6] activated
  torch::Tensor offsets;      // [A, K, 3]
  torch::Tensor mask;         // [A, K] float 0/1
  // [A, F] the feature model's output, computed once: SFA's shared feature is per anchor, not
  // per rendered view (docs/method.md §7.15).
  torch::Tensor mlp_features;
};

struct AnchorModel::Impl {
  AnchorModelOptions opt;
  std::shared_ptr<FeatureModel> features_model;
  int K = 10;
  double voxel = 0.01;
  double spatial_lr_scale = 1.0;
  torch::Tensor anchor;            // [N, 3]
  torch::Tensor bounds;            // [2, 3] min, max (HAC update_anchor_bound)
  std::vector<ParamGroup> groups;  // feature, offset, scaling, mask, mlp_*, appearance, fm.*
  int i_feat = -1, i_offset = -1, i_scaling = -1, i_mask = -1, i_app = -1;
  Mlp mlp_opacity, mlp_color, mlp_cov;
  int mlp_first = -1;  // index of the first MLP group (12 tensors follow)
  // Rate path (docs/method.md §2).
  std::shared_ptr<ContextModel> context;
  std::shared_ptr<EntropyModel> entropy;
  RateOptions rate;
  QuantPhase phase = QuantPhase::kRaw;
  torch::Generator gen;
  // Anchor links (CRP-GS, docs/method.md §6.2-§6.3).
  std::shared_ptr<ContextModel> link_strategy;
  LinkOptions link_opt;
  torch::Tensor links;                  // [N] int64 root model index or -1; undefined until built
  int i_leaf = -1;                      // first of the 4 leaf-MLP groups
  std::optional<RenderValues> over;     // set_quantized
  std::optional<RenderValues> decoded;  // from_decoded: always rendered
  // Statistics (docs/method.md §1.4).
  torch::Tensor opacity_accum, anchor_demon;      // [N]
  torch::Tensor offset_grad_accum, offset_denom;  // [N*K]

  torch::Tensor& p(int i) { return groups[size_t(i)].param; }
  const torch::Tensor& p(int i) const { return groups[size_t(i)].param; }

  void add_group(const std::string& name, const std::string& schedule, torch::Tensor t,
                 bool per_anchor) {
    ParamGroup g;
    g.name = name;
    g.schedule = schedule;
    g.param = t.detach().contiguous().requires_grad_(true);
    g.m = torch::zeros_like(g.param);
    g.v = torch::zeros_like(g.param);
    g.per_anchor = per_anchor;
    groups.push_back(std::move(g));
  }
  void bind_mlps() {
    auto at = [&](int k) { return groups[size_t(mlp_first + k)].param; };
    mlp_opacity = {at(0), at(1), at(2), at(3)};
    mlp_cov = {at(4), at(5), at(6), at(7)};
    mlp_color = {at(8), at(9), at(10), at(11)};
  }
  void reset_stats() {
    const int64_t n = anchor.size(0);
    opacity_accum = torch::zeros({n}, anchor.options());
    anchor_demon = torch::zeros({n}, anchor.options());
    offset_grad_accum = torch::zeros({n * K}, anchor.options());
    offset_denom = torch::zeros({n * K}, anchor.options());
  }
  // Uniform [0, 1) floats drawn on the CPU from `g` (the global generator when empty) and moved
  // to the model's device: the draws, and so a run's randomness, are the same on every device.
  torch::Tensor rand(at::IntArrayRef sizes, const c10::optional<at::Generator>& g) const {
    return uniform_floats(sizes, g).to(anchor.device());
  }
  void lr_for(ParamGroup& g, int it) const;
  c10::optional<at::Generator> gen_opt() const {
    return gen.defined() ? c10::optional<at::Generator>(gen) : c10::nullopt;
  }
  const RenderValues* render_values() const {
    return over ? &*over : decoded ? &*decoded : nullptr;
  }
  void add_external(const std::string& name, const std::string& schedule, const torch::Tensor& t) {
    ParamGroup g;
    g.name = name;
    g.schedule = schedule;
    g.param = t;  // owned by the component; updated in place
    g.m = torch::zeros_like(t);
    g.v = torch::zeros_like(t);
    g.external = true;
    groups.push_back(std::move(g));
  }
  void append_rows(ParamGroup& g, const torch::Tensor& rows) {
    g.param = torch::cat({g.param.detach(), rows.to(g.param.dtype())}, 0).requires_grad_(true);
    g.m = torch::cat({g.m, torch::zeros_like(rows)}, 0);
    g.v = torch::cat({g.v, torch::zeros_like(rows)}, 0);
  }
  void keep_rows(ParamGroup& g, const torch::Tensor& idx) {
    g.param = g.param.detach().index_select(0, idx).requires_grad_(true);
    g.m = g.m.index_select(0, idx);
    g.v = g.v.index_select(0, idx);
  }
  int64_t grow(const torch::Tensor& grads, const torch::Tensor& offset_mask, torch::Generator& gen);
  torch::Tensor leaf_means(const torch::Tensor& rows, const torch::Tensor& base_mu,
                           float feature_mean) const;
};

// μ_f of the anchors `rows` [S] with the leaf model where the anchor is a leaf of an active root
// (docs/method.md §7.9-§7.10): f̂_root = the codec's value of f (code_symbols·Q) through a
// straight-through estimator with Q detached; the root's Q and position are computed on demand
// (it need not be visible). feature_mean: serial_mean of every anchor's features, the centre of
// the codec's clamp.
torch::Tensor AnchorModel::Impl::leaf_means(const torch::Tensor& rows, const torch::Tensor& base_mu,
                                            float feature_mean) const {
  auto root = links.index_select(0, rows);  // [S]
  auto is_leaf = root >= 0;
  if (opt.use_offset_mask) {  // only the roots' masks: this runs every rate-phase iteration
    auto logits = p(i_mask).detach().index_select(0, root.clamp_min(0));
    is_leaf = is_leaf & (torch::sigmoid(logits) > opt.mask_threshold).any(1);
  }
  auto leaf_rows = is_leaf.nonzero().squeeze(1);  // [L]
  if (leaf_rows.size(0) == 0) return base_mu;
  auto roots = root.index_select(0, leaf_rows);
  auto root_pos01 = normalise(anchor.index_select(0, roots), bounds);
  auto leaf_pos01 = normalise(anchor.index_select(0, rows.index_select(0, leaf_rows)), bounds);
  const EntropyParamLayout layout{features_model->coded_dim(), K};
  torch::Tensor q_root;
  {
    torch::NoGradGuard ng;
    q_root = split_entropy_params(context->forward(root_pos01), layout, rate.q0).q_f;
  }
  auto f_root = p(i_feat).index_select(0, roots);
  // The root's feature as the decoder will have it (quantize()): clamped about the features'
  // mean, 0 where the step is saturated.
  const auto decoded = code_symbols(f_root, feature_mean, q_root) * q_root;
  auto f_hat = decoded + (f_root - f_root.detach());  // exactly `decoded`, gradient 1
  const LeafMlp mlp{p(i_leaf), p(i_leaf + 1), p(i_leaf + 2), p(i_leaf + 3), link_opt.residual};
  auto mu_leaf =
      leaf_feature_mean(mlp, f_hat, root_pos01, leaf_pos01, base_mu.index_select(0, leaf_rows));
  return base_mu.index_put({leaf_rows}, mu_leaf);
}

double log_lerp(double a, double b, int it, int max_steps) {
  if (a == b || a <= 0 || b <= 0) return a;
  const double s = std::clamp(double(it) / std::max(1, max_steps), 0.0, 1.0);
  return std::exp((1 - s) * std::log(a) + s * std::log(b));
}

double cameras_extent(const std::vector<Eigen::Vector3d>& centers) {
  if (centers.empty()) return 1.0;
  Eigen::Vector3d mean = Eigen::Vector3d::Zero();
  for (const auto& c : centers) mean += c;
  mean /= double(centers.size());
  double radius = 0;
  for (const auto& c : centers) radius = std::max(radius, (c - mean).norm());
  radius *= 1.1;
  return radius > 1e-6 ? radius : 1.0;
}

void AnchorModel::Impl::lr_for(ParamGroup& g, int it) const {
  const LearningRates& lr = opt.lr;
  const int T = lr.max_steps;
  if (g.schedule == "feature")
    g.lr = lr.feature;
  else if (g.schedule == "scaling")
    g.lr = lr.scaling;
  else if (g.schedule == "offset")
    g.lr = log_lerp(lr.offset_init * spatial_lr_scale, lr.offset_final * spatial_lr_scale, it, T);
  else if (g.schedule == "mask")
    g.lr = log_lerp(lr.mask_init * spatial_lr_scale, lr.mask_final * spatial_lr_scale, it, T);
  else if (g.schedule == "mlp_opacity")
    g.lr = log_lerp(lr.mlp_opacity_init, lr.mlp_opacity_final, it, T);
  else if (g.schedule == "mlp_cov")
    g.lr = log_lerp(lr.mlp_cov_init, lr.mlp_cov_final, it, T);
  else if (g.schedule == "mlp_color")
    g.lr = log_lerp(lr.mlp_color_init, lr.mlp_color_final, it, T);
  else if (g.schedule == "appearance")
    g.lr = log_lerp(lr.appearance_init, lr.appearance_final, it, T);
  else if (g.schedule == "context")
    g.lr = log_lerp(rate.lr_context_init, rate.lr_context_final, it, T);
  else if (g.schedule == "context_mlp")
    g.lr = log_lerp(rate.lr_context_mlp_init, rate.lr_context_mlp_final, it, T);
  else if (g.schedule == "leaf_mlp")  // its own window (docs/method.md §7.7)
    g.lr = log_lerp(link_opt.lr_leaf_init, link_opt.lr_leaf_final, it - link_opt.lr_start,
                    link_opt.lr_end - link_opt.lr_start);
  else  // the feature model (e.g. SFA's shared grid)
    g.lr = log_lerp(lr.feature_model_init, lr.feature_model_final, it, T) *
           (it < lr.feature_model_start ? lr.feature_model_hold_scale : 1.0);
}

torch::Tensor mean_sq_dist_3nn(const torch::Tensor& points) {
  // The exact kNN of the link strategies; fewer than 3 other points count as distance 0.
  auto nn = nearest_neighbors(points.to(torch::kFloat), torch::Tensor(), 3, false);
  TORCH_CHECK(nn.ok(), nn.status().to_string());
  auto d2 = nn->sq_dist.masked_fill(torch::isinf(nn->sq_dist), 0.0);  // [N, 3]
  return (d2.sum(1) / 3).clamp_min(1e-7).to(torch::kFloat);
}

namespace {
/// [N] bool: points that project inside at least one camera's image, in front of it.
torch::Tensor seen_by_any(const torch::Tensor& pts, const std::vector<Camera>& cameras) {
  auto seen = torch::zeros({pts.size(0)}, torch::kBool);
  for (const Camera& c : cameras) {
    auto R = torch::empty({3, 3});
    auto t = torch::empty({3});
    for (int i = 0; i < 3; ++i) {
      t[i] = float(c.t[i]);
      for (int j = 0; j < 3; ++j) R[i][j] = float(c.R(i, j));
    }
    auto cam = pts.matmul(R.t()) + t;  // [N, 3]
    auto z = cam.select(1, 2);
    auto u = cam.select(1, 0) / z * float(c.fx) + float(c.cx);
    auto v = cam.select(1, 1) / z * float(c.fy) + float(c.cy);
    seen |= (z > RenderSettings().near_plane) & (u >= 0) & (u < float(c.width)) & (v >= 0) &
            (v < float(c.height));
  }
  return seen;
}

/// `n` random points in the cube of half-size `half` about `center`, kept only where a training
/// view sees them: an anchor no training view sees is never trained, and its Gaussians show up as
/// haze in the test views that do see it (lego, full schedule: 8,171 of 16,911 anchors unseen;
/// masking them took one val view from 15.6 to 32.9 dB). Falls back to the unfiltered draw if
/// the cameras see none of it.
torch::Tensor random_points_seen(int64_t n, double half, const torch::Tensor& center,
                                 const std::vector<Camera>& cameras, torch::Generator& gen) {
  auto draw = [&] { return (torch::rand({n, 3}, gen) * 2 - 1) * half + center; };
  std::vector<torch::Tensor> kept;
  int64_t count = 0;
  torch::Tensor first;
  for (int round = 0; round < 16 && count < n; ++round) {
    auto pts = draw();
    if (!first.defined()) first = pts;
    auto k = pts.index({seen_by_any(pts, cameras)});
    count += k.size(0);
    kept.push_back(k);
  }
  if (count == 0) return first;
  return torch::cat(kept).slice(0, 0, n);
}
}  // namespace

AnchorModel::AnchorModel(std::unique_ptr<Impl> impl) : impl_(std::move(impl)) {}
AnchorModel::~AnchorModel() = default;

StatusOr<std::unique_ptr<AnchorModel>> AnchorModel::create(const AnchorModelOptions& options,
                                                           std::shared_ptr<FeatureModel> features,
                                                           const AnchorInit& init,
                                                           torch::Generator gen) {
  if (!features) return Status(StatusCode::kInvalidArgument, "anchor model: no feature model");
  if (options.n_offsets < 1 || options.hidden_dim < 1)
    return Status(StatusCode::kInvalidArgument,
                  "anchor model: n_offsets and hidden_dim must be >= 1");
  if (options.effects.appearance_dim < 0)
    return Status(StatusCode::kInvalidArgument, "scene.appearance_dim must be >= 0");
  if (init.train_cameras.empty())
    return Status(StatusCode::kInvalidArgument, "anchor model: no training cameras");
  torch::NoGradGuard no_grad;
  auto impl = std::make_unique<Impl>();
  impl->opt = options;
  impl->features_model = std::move(features);
  impl->K = options.n_offsets;
  const int K = impl->K;

  // 1. Camera extent -> spatial lr scale.
  std::vector<Eigen::Vector3d> centers;
  for (const auto& c : init.train_cameras) centers.push_back(c.center());
  impl->spatial_lr_scale = cameras_extent(centers);

  // 2. Points: SfM, or random inside the cameras' bounds.
  torch::Tensor pts;
  if (!init.points.empty()) {
    pts = torch::empty({int64_t(init.points.size()), 3});
    auto acc = pts.accessor<float, 2>();
    for (size_t i = 0; i < init.points.size(); ++i)
      for (int a = 0; a < 3; ++a) acc[int64_t(i)][a] = init.points[i][size_t(a)];
  } else {
    const int64_t n = std::max(1, options.random_init_points);
    Eigen::Vector3d mean_c = Eigen::Vector3d::Zero();
    for (const auto& c : centers) mean_c += c;
    mean_c /= double(centers.size());
    pts =
        random_points_seen(n, impl->spatial_lr_scale / 1.1,
                           torch::tensor({float(mean_c.x()), float(mean_c.y()), float(mean_c.z())}),
                           init.train_cameras, gen);
  }

  // 3. Voxelise: unique(round(p / v)) * v (v automatic when voxel_size <= 0).
  double v = options.voxel_size;
  if (v <= 0) v = mean_sq_dist_3nn(pts).median().item<double>();
  if (!(v > 0)) v = 1e-3;
  impl->voxel = v;
  auto cells = torch::round(pts / v).to(torch::kLong);
  auto uniq = std::get<0>(at::unique_dim(cells, 0, /*sorted=*/true, false, false));
  impl->anchor = uniq.to(torch::kFloat) * float(v);
  const int64_t N = impl->anchor.size(0);

  // 4. Bounds (HAC update_anchor_bound); the rate path may recompute them at rate_start.
  impl->bounds = hac_bounds(impl->anchor);

  // 5. Per-anchor parameters.
  auto d2 = mean_sq_dist_3nn(impl->anchor).clamp_min(1e-7);
  auto scaling = torch::log(torch::sqrt(d2)).unsqueeze(1).repeat({1, 6});
  const int64_t dc = impl->features_model->coded_dim();
  impl->add_group("feature", "feature", torch::zeros({N, dc}), true);
  impl->i_feat = 0;
  impl->add_group("offset", "offset", torch::zeros({N, K, 3}), true);
  impl->i_offset = 1;
  impl->add_group("scaling", "scaling", scaling, true);
  impl->i_scaling = 2;
  impl->add_group("mask", "mask", torch::ones({N, K}), true);
  impl->i_mask = 3;

  // 6. MLPs; the input width depends on which effects are on.
  const SceneEffects& fx = options.effects;
  const int64_t in = impl->features_model->feature_dim() + (fx.view_dependent ? 3 : 0) +
                     (fx.distance_input ? 1 : 0);
  const int64_t in_color = in + fx.appearance_dim;
  const int64_t H = options.hidden_dim;
  impl->mlp_first = int(impl->groups.size());
  auto add_mlp = [&](const std::string& name, int64_t in_dim, int64_t out_dim) {
    Mlp m = make_mlp(in_dim, H, out_dim, gen);
    impl->add_group(name + ".w1", name, m.w1, false);
    impl->add_group(name + ".b1", name, m.b1, false);
    impl->add_group(name + ".w2", name, m.w2, false);
    impl->add_group(name + ".b2", name, m.b2, false);
  };
  add_mlp("mlp_opacity", in, K);
  add_mlp("mlp_cov", in, 7 * K);
  add_mlp("mlp_color", in_color, 3 * K);
  impl->bind_mlps();
  if (fx.appearance_dim > 0) {
    impl->i_app = int(impl->groups.size());
    impl->add_group("appearance", "appearance",
                    torch::randn({int64_t(centers.size()), int64_t(fx.appearance_dim)}, gen),
                    false);
  }
  // 7. The feature model's own parameters (e.g. SFA's hash grid) share the optimizer.
  int fm_index = 0;
  for (auto& t : impl->features_model->parameters())
    impl->add_external("feature_model." + std::to_string(fm_index++), "feature_model", t);
  impl->reset_stats();
  auto model = std::unique_ptr<AnchorModel>(new AnchorModel(std::move(impl)));
  model->update_learning_rates(0);
  return model;
}

int64_t AnchorModel::num_anchors() const {
  return impl_->anchor.size(0);
}
int AnchorModel::n_offsets() const {
  return impl_->K;
}
const AnchorModelOptions& AnchorModel::options() const {
  return impl_->opt;
}
double AnchorModel::voxel_size() const {
  return impl_->voxel;
}
double AnchorModel::spatial_lr_scale() const {
  return impl_->spatial_lr_scale;
}
int64_t AnchorModel::mlp_input_dim() const {
  return impl_->mlp_opacity.w1.size(1);
}
int64_t AnchorModel::color_input_dim() const {
  return impl_->mlp_color.w1.size(1);
}
torch::Tensor AnchorModel::anchors() const {
  return impl_->anchor;
}
torch::Tensor AnchorModel::features() const {
  return impl_->p(impl_->i_feat);
}
torch::Tensor AnchorModel::offsets() const {
  return impl_->p(impl_->i_offset);
}
torch::Tensor AnchorModel::scaling_raw() const {
  return impl_->p(impl_->i_scaling);
}
torch::Tensor AnchorModel::mask_logits() const {
  return impl_->p(impl_->i_mask);
}
torch::Tensor AnchorModel::positions01() const {
  return normalise(impl_->anchor, impl_->bounds);
}
torch::Tensor AnchorModel::bounds() const {
  return impl_->bounds;
}
void AnchorModel::recompute_bounds() {
  impl_->bounds = hac_bounds(impl_->anchor);
}
torch::Tensor AnchorModel::offset_masks() const {
  const Impl& m = *impl_;
  if (!m.opt.use_offset_mask)
    return torch::ones({m.anchor.size(0), m.K}, m.anchor.options().dtype(torch::kBool));
  return torch::sigmoid(m.p(m.i_mask).detach()) > m.opt.mask_threshold;
}
torch::Tensor AnchorModel::active_anchors() const {
  return offset_masks().any(1);
}
torch::Tensor AnchorModel::mask_loss() const {
  return torch::sigmoid(impl_->p(impl_->i_mask)).mean();
}
std::map<std::string, torch::Tensor> AnchorModel::mlp_tensors() const {
  std::map<std::string, torch::Tensor> out;
  for (int k = 0; k < 12; ++k) {
    const auto& g = impl_->groups[size_t(impl_->mlp_first + k)];
    out[g.name] = g.param.detach();
  }
  if (impl_->i_app >= 0) out["appearance"] = impl_->p(impl_->i_app).detach();
  if (impl_->i_leaf >= 0)
    for (int k = 0; k < 4; ++k) out[kLeafMlpNames[k]] = impl_->p(impl_->i_leaf + k).detach();
  return out;
}

Status AnchorModel::attach_rate(std::shared_ptr<ContextModel> context,
                                std::shared_ptr<EntropyModel> entropy, const RateOptions& options) {
  Impl& m = *impl_;
  if (!context || !entropy)
    return Status(StatusCode::kInvalidArgument, "rate path: needs a context and an entropy model");
  if (m.context) return Status(StatusCode::kInvalidArgument, "rate path: already attached");
  const EntropyParamLayout layout{m.features_model->coded_dim(), m.K};
  if (context->output_dim() != layout.width())
    return Status(StatusCode::kInvalidArgument,
                  "rate path: context '" + context->type_name() + "' outputs " +
                      std::to_string(context->output_dim()) +
                      " values per anchor, the entropy "
                      "parameters need " +
                      std::to_string(layout.width()) + " (2*(Dc + 6 + 3K) + 3)");
  if (!(options.subset > 0 && options.subset <= 1))
    return Status(StatusCode::kInvalidArgument, "rate.subset must be in (0, 1]");
  m.context = std::move(context);
  m.entropy = std::move(entropy);
  m.rate = options;
  auto params = m.context->parameters();
  for (size_t i = 0; i < params.size(); ++i) {
    if (i == 0)
      m.add_external("context.grid.0", "context", params[i]);
    else
      m.add_external("context.mlp." + std::to_string(i - 1), "context_mlp", params[i]);
  }
  update_learning_rates(0);
  return OkStatus();
}
Status AnchorModel::attach_links(std::shared_ptr<ContextModel> links, const LinkOptions& options,
                                 torch::Generator gen) {
  Impl& m = *impl_;
  if (!links) return Status(StatusCode::kInvalidArgument, "links: no link strategy");
  if (!m.context) return Status(StatusCode::kInvalidArgument, "links: need the rate path first");
  if (m.link_strategy) return Status(StatusCode::kInvalidArgument, "links: already attached");
  if (options.leaf_hidden < 1 || options.lr_end <= options.lr_start)
    return Status(StatusCode::kInvalidArgument,
                  "links: leaf_hidden must be >= 1 and the lr window non-empty");
  torch::NoGradGuard no_grad;
  m.link_strategy = std::move(links);
  m.link_opt = options;
  const int64_t dc = m.features_model->coded_dim();
  Mlp leaf = make_mlp(dc + 6, options.leaf_hidden, dc, gen);
  if (options.residual) {  // starts as the base model: no rate spike when links appear
    leaf.w2.zero_();
    leaf.b2.zero_();
  }
  m.i_leaf = int(m.groups.size());
  const torch::Tensor parts[4] = {leaf.w1, leaf.b1, leaf.w2, leaf.b2};
  for (int k = 0; k < 4; ++k) m.add_group(kLeafMlpNames[k], "leaf_mlp", parts[k], false);
  update_learning_rates(0);
  return OkStatus();
}
bool AnchorModel::has_links() const {
  return impl_->link_strategy != nullptr;
}
ContextModel* AnchorModel::link_strategy() const {
  return impl_->link_strategy.get();
}
StatusOr<int64_t> AnchorModel::rebuild_links(uint64_t seed) {
  Impl& m = *impl_;
  if (!m.link_strategy) return Status(StatusCode::kInvalidArgument, "links: none attached");
  torch::NoGradGuard no_grad;
  // The link strategies' searches run on the CPU (crpgs/links.h); the result follows the model.
  const auto cpu = [](const torch::Tensor& t) { return t.detach().to(torch::kCPU); };
  LinkInputs in;
  in.features = cpu(m.p(m.i_feat));  // raw f_i (docs/method.md §7.5)
  in.positions = cpu(m.anchor);
  in.active = cpu(active_anchors());
  in.seed = seed;
  auto links = m.link_strategy->build_links(in).to(torch::kCPU, torch::kLong).contiguous();
  const int64_t n = m.anchor.size(0);
  if (links.dim() != 1 || links.size(0) != n)
    return Status(StatusCode::kInternal,
                  "links: '" + m.link_strategy->type_name() + "' returned the wrong shape");
  // One hop, roots and leaves active and distinct: anything else would break the decode order.
  auto is_leaf = links >= 0;
  auto roots = links.masked_select(is_leaf);
  if (roots.numel() > 0 &&
      (roots.max().item<int64_t>() >= n || is_leaf.index_select(0, roots).any().item<bool>() ||
       !in.active.index_select(0, roots).all().item<bool>() ||
       !in.active.masked_select(is_leaf).all().item<bool>() ||
       torch::bincount(roots).max().item<int64_t>() > 1))
    return Status(StatusCode::kInternal, "links: '" + m.link_strategy->type_name() +
                                             "' returned links that are not a one-hop one-to-one "
                                             "matching of active anchors");
  m.links = links.to(m.anchor.device());
  return roots.numel();
}
torch::Tensor AnchorModel::links() const {
  return impl_->links;
}
torch::Tensor AnchorModel::feature_means(const torch::Tensor& rows,
                                         const torch::Tensor& base_mu) const {
  const Impl& m = *impl_;
  return m.links.defined() ? m.leaf_means(rows, base_mu, serial_mean(m.p(m.i_feat))) : base_mu;
}
LeafMlp AnchorModel::leaf_mlp() const {
  const Impl& m = *impl_;
  if (m.i_leaf < 0) return {};
  return {m.p(m.i_leaf), m.p(m.i_leaf + 1), m.p(m.i_leaf + 2), m.p(m.i_leaf + 3),
          m.link_opt.residual};
}
bool AnchorModel::has_rate() const {
  return impl_->context != nullptr;
}
ContextModel* AnchorModel::context() const {
  return impl_->context.get();
}
EntropyModel* AnchorModel::entropy() const {
  return impl_->entropy.get();
}
const RateOptions& AnchorModel::rate_options() const {
  return impl_->rate;
}
void AnchorModel::set_quant_phase(QuantPhase phase) {
  impl_->phase = phase;
}
QuantPhase AnchorModel::quant_phase() const {
  return impl_->phase;
}
void AnchorModel::set_generator(torch::Generator gen) {
  impl_->gen = std::move(gen);
}

QuantizedAttributes AnchorModel::quantize(const torch::Tensor& index) const {
  TORCH_CHECK(impl_->context, "quantize: no rate path attached");
  return quantize(*impl_->context, impl_->rate.q0, index);
}

QuantizedAttributes AnchorModel::quantize(ContextModel& context, const QuantSteps& q0,
                                          const torch::Tensor& index) const {
  torch::NoGradGuard ng;
  const Impl& m = *impl_;
  const int64_t K = m.K;
  QuantizedAttributes q;
  // On the CPU whatever the model's device: the codec's arithmetic (kPortable) is the CPU's, and
  // the encoder reads these tensors. set_quantized moves what it renders to the model's device.
  const auto cpu = [](const torch::Tensor& t) { return t.detach().to(torch::kCPU); };
  const auto masks = cpu(offset_masks());  // [N, K]
  q.active = masks.any(1);
  q.index = index.defined() ? cpu(index).to(torch::kLong) : q.active.nonzero().squeeze(1);
  const float v = float(m.voxel);
  const auto vt = torch::tensor(v);
  q.positions = torch::round(cpu(m.anchor).index_select(0, q.index) / vt) * vt;  // [A, 3]
  q.bounds = cpu(m.bounds).clone();
  q.positions01 = normalise(q.positions, q.bounds);
  const EntropyParamLayout layout{m.features_model->coded_dim(), K};
  q.params = predict_entropy_params(context, q.positions01, layout, q0, 3000,
                                    Arithmetic::kPortable);  // as the codec
  for (auto* t : {&q.params.mu_f, &q.params.sigma_f, &q.params.mu_s, &q.params.sigma_s,
                  &q.params.mu_o, &q.params.sigma_o, &q.params.q_f, &q.params.q_s, &q.params.q_o})
    *t = t->detach().contiguous();
  auto quant = [](const torch::Tensor& x, float mean, const torch::Tensor& step, torch::Tensor* sym,
                  torch::Tensor* val) {
    *sym = code_symbols(x, mean, step).to(torch::kInt);
    *val = sym->to(torch::kFloat) * step;
  };
  const auto feat = cpu(m.p(m.i_feat));
  const auto scal = torch::exp(cpu(m.p(m.i_scaling)));
  const auto offs = cpu(m.p(m.i_offset));
  quant(feat.index_select(0, q.index), serial_mean(feat), q.params.q_f, &q.feature_symbols,
        &q.features);
  quant(scal.index_select(0, q.index), serial_mean(scal), q.params.q_s, &q.scaling_symbols,
        &q.scaling);
  quant(offs.index_select(0, q.index), serial_mean(offs), q.params.q_o.unsqueeze(2),
        &q.offset_symbols, &q.offsets);
  q.offset_masks = masks.index_select(0, q.index);
  const auto keep = q.offset_masks.unsqueeze(2);  // [A, K, 1]
  q.offset_symbols = q.offset_symbols.masked_fill(~keep, 0);
  q.offsets = q.offsets.masked_fill(~keep, 0.f);
  return q;
}

void AnchorModel::set_quantized(const QuantizedAttributes& q) {
  const auto dev = impl_->anchor.device();
  RenderValues r;
  r.positions = q.positions.to(dev);
  r.positions01 = q.positions01.to(dev);
  r.features = q.features.to(dev);
  r.scaling = q.scaling.to(dev);
  r.offsets = q.offsets.to(dev);
  r.mask = q.offset_masks.to(dev, torch::kFloat);
  {
    torch::NoGradGuard ng;
    r.mlp_features = impl_->features_model->forward(r.features, r.positions01).contiguous();
  }
  impl_->over = std::move(r);
}
void AnchorModel::clear_quantized() {
  impl_->over.reset();
}
bool AnchorModel::is_quantized() const {
  return impl_->render_values() != nullptr;
}

StatusOr<std::unique_ptr<AnchorModel>> AnchorModel::from_decoded(
    const AnchorModelOptions& options, std::shared_ptr<FeatureModel> features,
    const torch::Tensor& positions, const torch::Tensor& features_values,
    const torch::Tensor& scaling_activated, const torch::Tensor& offsets,
    const torch::Tensor& offset_masks, const std::map<std::string, torch::Tensor>& mlps,
    const torch::Tensor& bounds, double voxel_size) {
  auto bad = [](const std::string& msg) {
    return Status(StatusCode::kInvalidArgument, "decoded anchor model: " + msg);
  };
  if (!features) return bad("no feature model");
  const int64_t K = options.n_offsets, A = positions.defined() ? positions.size(0) : -1;
  const int64_t dc = features->coded_dim();
  auto shape_is = [](const torch::Tensor& t, std::vector<int64_t> s) {
    return t.defined() && t.sizes() == c10::IntArrayRef(s);
  };
  if (!shape_is(positions, {A, 3})) return bad("positions must be [A, 3]");
  if (!shape_is(features_values, {A, dc}))
    return bad("features must be [A, " + std::to_string(dc) + "]");
  if (!shape_is(scaling_activated, {A, 6})) return bad("scaling must be [A, 6]");
  if (!shape_is(offsets, {A, K, 3})) return bad("offsets must be [A, K, 3]");
  if (!shape_is(offset_masks, {A, K})) return bad("offset masks must be [A, K]");
  if (!shape_is(bounds, {2, 3})) return bad("bounds must be [2, 3]");
  const SceneEffects& fx = options.effects;
  const int64_t in =
      features->feature_dim() + (fx.view_dependent ? 3 : 0) + (fx.distance_input ? 1 : 0);
  const int64_t H = options.hidden_dim;
  const std::vector<std::pair<std::string, int64_t>> mlp_in = {
      {"mlp_opacity", in}, {"mlp_cov", in}, {"mlp_color", in + fx.appearance_dim}};
  const std::map<std::string, int64_t> mlp_out = {
      {"mlp_opacity", K}, {"mlp_cov", 7 * K}, {"mlp_color", 3 * K}};
  auto impl = std::make_unique<Impl>();
  impl->opt = options;
  impl->features_model = std::move(features);
  impl->K = int(K);
  impl->voxel = voxel_size;
  auto f32 = [](const torch::Tensor& t) { return t.detach().to(torch::kFloat).contiguous(); };
  impl->anchor = f32(positions);
  impl->bounds = f32(bounds);
  impl->add_group("feature", "feature", f32(features_values), true);
  impl->i_feat = 0;
  impl->add_group("offset", "offset", f32(offsets), true);
  impl->i_offset = 1;
  impl->add_group("scaling", "scaling", torch::log(f32(scaling_activated)), true);
  impl->i_scaling = 2;
  // Logits whose sigmoid is clearly on either side of any threshold in (0.0001, 0.9999).
  impl->add_group("mask", "mask", offset_masks.to(torch::kBool).to(torch::kFloat) * 20 - 10, true);
  impl->i_mask = 3;
  impl->mlp_first = int(impl->groups.size());
  for (const auto& [name, in_dim] : mlp_in) {
    const int64_t out = mlp_out.at(name);
    const std::vector<std::pair<std::string, std::vector<int64_t>>> parts = {
        {".w1", {H, in_dim}}, {".b1", {H}}, {".w2", {out, H}}, {".b2", {out}}};
    for (const auto& [suffix, shape] : parts) {
      auto it = mlps.find(name + suffix);
      if (it == mlps.end()) return bad("missing MLP tensor '" + name + suffix + "'");
      if (!shape_is(it->second, shape))
        return bad("MLP tensor '" + name + suffix + "' has the wrong shape");
      impl->add_group(name + suffix, name, f32(it->second), false);
    }
  }
  impl->bind_mlps();
  if (fx.appearance_dim > 0) {
    auto it = mlps.find("appearance");
    if (it == mlps.end() || it->second.dim() != 2 || it->second.size(1) != fx.appearance_dim)
      return bad("missing or malformed 'appearance' embedding");
    impl->i_app = int(impl->groups.size());
    impl->add_group("appearance", "appearance", f32(it->second), false);
  }
  RenderValues r;
  r.positions = impl->anchor;
  r.positions01 = normalise(impl->anchor, impl->bounds);
  r.features = impl->p(impl->i_feat).detach();
  r.scaling = f32(scaling_activated);
  r.offsets = impl->p(impl->i_offset).detach();
  r.mask = offset_masks.to(torch::kFloat);
  {
    torch::NoGradGuard ng;
    r.mlp_features = impl->features_model->forward(r.features, r.positions01).contiguous();
  }
  impl->decoded = std::move(r);
  impl->reset_stats();
  return std::unique_ptr<AnchorModel>(new AnchorModel(std::move(impl)));
}

NeuralGaussians AnchorModel::generate(const Camera& camera, int camera_index,
                                      Rasterizer& rasterizer, const RenderSettings& settings,
                                      bool for_training) {
  Impl& m = *impl_;
  const int64_t K = m.K;
  NeuralGaussians out;
  const RenderValues* rv = m.render_values();
  const auto& anchor = rv ? rv->positions : m.anchor;
  auto scaling = rv ? rv->scaling : torch::exp(m.p(m.i_scaling));  // [N, 6]
  {
    torch::NoGradGuard ng;
    out.visible =
        rasterizer.visible_anchors(anchor, scaling.index({Slice(), Slice(0, 3)}), camera, settings);
  }
  auto idx = out.visible.nonzero().squeeze(1);  // [M]
  const int64_t M = idx.size(0);
  // Every gather index here is non-decreasing, as gather_sorted_rows needs: idx, keep and live
  // come from nonzero() and anchor_of = keep / K (so sparse_mlp's rows, the live anchors of the
  // Gaussians, do not decrease either).
  auto anchor_v = gather_sorted_rows(anchor, idx);                               // [M, 3]
  auto pos01_v = gather_sorted_rows(rv ? rv->positions01 : positions01(), idx);  // [M, 3]
  auto feat_c = gather_sorted_rows(rv ? rv->features : m.p(m.i_feat), idx);      // [M, Dc]
  auto scal_v = gather_sorted_rows(scaling, idx);                                // [M, 6]
  auto offs_v = gather_sorted_rows(rv ? rv->offsets : m.p(m.i_offset), idx);     // [M, K, 3]
  torch::Tensor mask_v;                                                          // [M, K]
  if (rv)
    mask_v = rv->mask.index_select(0, idx);
  else if (m.opt.use_offset_mask)
    mask_v = ste_mask(gather_sorted_rows(m.p(m.i_mask), idx), m.opt.mask_threshold);
  // Training-time quantisation (docs/method.md §2.3): uniform noise of one step.
  if (for_training && !rv && m.context && m.phase != QuantPhase::kRaw) {
    const EntropyParamLayout layout{m.features_model->coded_dim(), K};
    ContextModel::PartialOutput ctx;
    if (m.phase == QuantPhase::kFixedNoise) {
      out.q_f = torch::full({M, 1}, m.rate.q0.feature, anchor_v.options());
      out.q_s = torch::full({M, 1}, m.rate.q0.scaling, anchor_v.options());
      out.q_o = torch::full({M, 1}, m.rate.q0.offset, anchor_v.options());
    } else {
      ctx = m.context->forward_partial(pos01_v, EntropyParamLayout::kStepColumns);
      EntropyParams steps;
      set_quant_steps(ctx.tail, m.rate.q0, &steps);
      out.q_f = steps.q_f;
      out.q_s = steps.q_s;
      out.q_o = steps.q_o;
    }
    auto noise = [&](const torch::Tensor& x) { return m.rand(x.sizes(), m.gen_opt()) - 0.5; };
    feat_c = feat_c + noise(feat_c) * out.q_f;
    scal_v = scal_v + noise(scal_v) * out.q_s;
    offs_v = offs_v + noise(offs_v) * out.q_o.unsqueeze(2);
    if (m.phase == QuantPhase::kAdaptiveNoise) {
      // Rate on a random subset of the visible active anchors (docs/method.md §2.5).
      auto mask_r = mask_v.defined() ? mask_v : torch::ones({M, K}, anchor_v.options());
      auto active_v = (mask_r.detach() > 0.5).any(1);  // [M]
      auto chosen =
          ((m.rand({M}, m.gen_opt()) <= m.rate.subset) & active_v).nonzero().squeeze(1);  // [S]
      const int64_t S = chosen.size(0);
      out.rate_subset = S;
      const double active_fraction = M > 0 ? active_v.sum().item<double>() / double(M) : 0.0;
      if (S > 0) {
        auto sel = [&](const torch::Tensor& t) { return t.index_select(0, chosen); };
        auto bits = [&](const torch::Tensor& x, float mean, const torch::Tensor& mu,
                        const torch::Tensor& sigma, const torch::Tensor& q) {
          return m.entropy->bits(clamp_about(x, mean, q), mu, sigma, q);
        };
        // Means and scales of the subset only; its steps are those its noise used.
        const EntropyParams ep = split_entropy_params(ctx.rows(chosen), layout, m.rate.q0);
        auto q_f = sel(out.q_f), q_s = sel(out.q_s), q_o = sel(out.q_o);
        // One pass over every anchor's features: the leaf model's clamp and the rate share it.
        const float feat_mean = serial_mean(m.p(m.i_feat));
        auto mu_f = m.links.defined()
                        ? m.leaf_means(idx.index_select(0, chosen), ep.mu_f, feat_mean)
                        : ep.mu_f;
        auto b_f = bits(sel(feat_c), feat_mean, mu_f, ep.sigma_f, q_f);
        auto b_s = bits(sel(scal_v), serial_mean(torch::exp(m.p(m.i_scaling).detach())), ep.mu_s,
                        ep.sigma_s, q_s);
        auto b_o = bits(sel(offs_v).reshape({S, 3 * K}), serial_mean(m.p(m.i_offset)), ep.mu_o,
                        ep.sigma_o, q_o);
        b_o = b_o * sel(mask_r).unsqueeze(2).expand({S, K, 3}).reshape({S, 3 * K});
        const double n_elem = double(S * (feat_c.size(1) + 6 + 3 * K));
        out.bits_per_param = (b_f.sum() + b_s.sum() + b_o.sum()) / n_elem * active_fraction;
      } else {
        out.bits_per_param = torch::zeros({}, anchor_v.options());
      }
    }
  }
  out.used_features = feat_c;
  out.used_scaling = scal_v;
  out.used_offsets = offs_v;
  auto feat = rv ? rv->mlp_features.index_select(0, idx)
                 : m.features_model->forward(feat_c, pos01_v);  // [M, F]
  std::vector<torch::Tensor> parts{feat};
  const SceneEffects& fx = m.opt.effects;
  if (fx.view_dependent || fx.distance_input) {
    const Eigen::Vector3d c = camera.center();
    auto cam = torch::tensor({float(c[0]), float(c[1]), float(c[2])}).to(anchor_v.device());
    auto d = anchor_v - cam;         // [M, 3]
    auto dist = d.norm(2, 1, true);  // [M, 1]
    if (fx.view_dependent) parts.push_back(d / dist);
    if (fx.distance_input) parts.push_back(dist);
  }
  auto input = parts.size() == 1 ? feat : torch::cat(parts, 1);  // [M, C]
  out.input = input;
  auto opacity = torch::tanh(m.mlp_opacity.forward(input));  // [M, K]
  if (mask_v.defined()) opacity = opacity * mask_v;
  out.neural_opacity = opacity.detach();
  auto flat_op = opacity.reshape({M * K});
  out.selection = flat_op > 0;                     // [M*K]
  auto keep = out.selection.nonzero().squeeze(1);  // [G]
  out.source = (idx.unsqueeze(1) * K + torch::arange(K, idx.options()))
                   .reshape({M * K})
                   .index_select(0, keep);
  auto anchor_of = keep.div(K, "floor");  // row in the visible set
  // Colour and covariance only for the anchors with a Gaussian left: the other rows would be
  // discarded (and get no gradient).
  auto live = opacity.detach().gt(0).any(1).nonzero().squeeze(1);  // [L]
  const int64_t L = live.size(0);
  auto live_row =
      torch::full({M}, -1, idx.options()).index_put_({live}, torch::arange(L, idx.options()));
  auto row_of = live_row.index_select(0, anchor_of);  // [G], into [L], non-decreasing
  auto slot_of = keep.remainder(K);                   // [G]
  auto input_l = gather_sorted_rows(input, live);
  auto color_in = input_l;
  if (fx.appearance_dim > 0) {
    auto& emb = m.p(m.i_app);
    auto e = camera_index >= 0 && camera_index < emb.size(0) ? emb[camera_index] : emb.mean(0);
    color_in = torch::cat({input_l, e.unsqueeze(0).expand({L, e.size(0)})}, 1);
  }
  // Only the kept Gaussians' outputs of the last layer.
  auto sparse = [&](const Mlp& mlp, const torch::Tensor& x, int64_t outputs) {
    return sparse_mlp(x, mlp.w1, mlp.b1, mlp.w2, mlp.b2, row_of, slot_of, outputs);
  };
  auto sc = gather_sorted_rows(scal_v, anchor_of);  // [G, 6]
  auto offs = gather_sorted_rows(offs_v.reshape({M * K, 3}), keep);
  auto cv = sparse(m.mlp_cov, input_l, 7);  // [G, 7]
  GaussianBatch& b = out.batch;
  b.means = gather_sorted_rows(anchor_v, anchor_of) + offs * sc.index({Slice(), Slice(0, 3)});
  b.scales = sc.index({Slice(), Slice(3, 6)}) * torch::sigmoid(cv.index({Slice(), Slice(0, 3)}));
  b.rotations = torch::nn::functional::normalize(
      cv.index({Slice(), Slice(3, 7)}), torch::nn::functional::NormalizeFuncOptions().dim(1));
  b.opacities = gather_sorted_rows(flat_op, keep);
  b.colors = torch::sigmoid(sparse(m.mlp_color, color_in, 3));
  if (for_training)
    b.means2d_grad_holder =
        torch::zeros({keep.size(0), 2}, anchor_v.options()).requires_grad_(true);
  return out;
}

void AnchorModel::accumulate_statistics(const NeuralGaussians& g, const RenderOutput& out,
                                        const Camera& camera) {
  torch::NoGradGuard ng;
  Impl& m = *impl_;
  auto idx = g.visible.nonzero().squeeze(1);
  m.opacity_accum.index_add_(0, idx, g.neural_opacity.clamp_min(0).sum(1));
  m.anchor_demon.index_add_(0, idx, torch::ones({idx.size(0)}, m.anchor.options()));
  if (!g.batch.means2d_grad_holder.defined() || !g.batch.means2d_grad_holder.grad().defined())
    return;
  auto rendered = (out.radii > 0).nonzero().squeeze(1);  // [R]
  // The thresholds (2e-4) are for gradients w.r.t. NDC as in 3DGS; our holder is in pixels.
  auto grad = g.batch.means2d_grad_holder.grad().index_select(0, rendered);  // [R, 2]
  auto to_ndc = torch::tensor({0.5f * float(camera.width), 0.5f * float(camera.height)})
                    .to(m.anchor.device());
  auto norm = (grad * to_ndc).norm(2, 1);
  auto src = g.source.index_select(0, rendered);
  m.offset_grad_accum.index_add_(0, src, norm);
  m.offset_denom.index_add_(0, src, torch::ones({src.size(0)}, m.anchor.options()));
}

int64_t AnchorModel::Impl::grow(const torch::Tensor& grads, const torch::Tensor& offset_mask,
                                torch::Generator& gen) {
  const int64_t init_length = anchor.size(0) * K;
  int64_t grown = 0;
  for (int i = 0; i < opt.update_depth; ++i) {
    const double threshold =
        opt.densify_grad_threshold * std::pow(double(opt.update_hierarchy_factor / 2), i);
    auto cand = (grads >= threshold) & offset_mask;
    auto rnd = rand({cand.size(0)}, gen) > std::pow(0.5, i + 1);
    cand = cand & rnd;
    const int64_t inc = anchor.size(0) * K - init_length;
    if (inc == 0) {
      if (i > 0) continue;  // Scaffold-GS: deeper levels only after a level added anchors
    } else {
      cand = torch::cat({cand, torch::zeros({inc}, cand.options())});
    }
    auto scaling = torch::exp(p(i_scaling));
    auto all_xyz = anchor.unsqueeze(1) +
                   p(i_offset) * scaling.index({Slice(), Slice(0, 3)}).unsqueeze(1);  // [N,K,3]
    int64_t size_factor = opt.update_init_factor;
    for (int l = 0; l < i; ++l) size_factor /= opt.update_hierarchy_factor;
    const double cur = voxel * double(size_factor);
    auto grid = torch::round(anchor / cur).to(torch::kLong);  // [N, 3]
    auto sel = cand.nonzero().squeeze(1);
    if (sel.size(0) == 0) continue;
    auto sel_grid =
        torch::round(all_xyz.reshape({-1, 3}).index_select(0, sel) / cur).to(torch::kLong);
    auto u = at::unique_dim(sel_grid, 0, true, true, false);
    auto uniq = std::get<0>(u), inverse = std::get<1>(u);
    auto fresh = ~torch::isin(cell_keys(uniq), cell_keys(grid));  // [U]
    auto fresh_idx = fresh.nonzero().squeeze(1);
    const int64_t n_new = fresh_idx.size(0);
    if (n_new == 0) continue;
    auto new_anchor = uniq.index_select(0, fresh_idx).to(torch::kFloat) * float(cur);
    // Feature of a new anchor: channel-wise max over the parents whose Gaussians fell into it.
    auto& feat = p(i_feat);
    auto parent_feat = feat.detach().index_select(0, sel.div(K, "floor"));  // [S, D]
    auto pooled = max_rows_into(parent_feat, inverse, uniq.size(0));
    const auto o = anchor.options();
    append_rows(groups[size_t(i_feat)], pooled.index_select(0, fresh_idx));
    append_rows(groups[size_t(i_offset)], torch::zeros({n_new, K, 3}, o));
    append_rows(groups[size_t(i_scaling)], torch::full({n_new, 6}, std::log(cur), o));
    append_rows(groups[size_t(i_mask)], torch::ones({n_new, K}, o));
    anchor = torch::cat({anchor, new_anchor}, 0);
    opacity_accum = torch::cat({opacity_accum, torch::zeros({n_new}, o)});
    anchor_demon = torch::cat({anchor_demon, torch::zeros({n_new}, o)});
    grown += n_new;
  }
  return grown;
}

AdjustReport AnchorModel::adjust_anchors(int check_interval, torch::Generator gen) {
  torch::NoGradGuard ng;
  Impl& m = *impl_;
  m.over.reset();
  const int64_t K = m.K;
  AdjustReport rep;
  // 1. Grow from the average screen-space gradients of Gaussians seen often enough.
  auto grads = (m.offset_grad_accum / m.offset_denom).nan_to_num(0.0, 0.0, 0.0);  // [N*K]
  auto offset_mask = m.offset_denom > check_interval * m.opt.success_threshold * 0.5;
  const int64_t n_before = m.anchor.size(0);
  rep.grown = m.grow(grads, offset_mask, gen);
  // 2. Reset the offset statistics that were used; pad for the new anchors.
  m.offset_denom.masked_fill_(offset_mask, 0);
  m.offset_grad_accum.masked_fill_(offset_mask, 0);
  const int64_t pad = (m.anchor.size(0) - n_before) * K;
  m.offset_denom = torch::cat({m.offset_denom, torch::zeros({pad}, m.anchor.options())});
  m.offset_grad_accum = torch::cat({m.offset_grad_accum, torch::zeros({pad}, m.anchor.options())});
  // 3. Prune anchors seen often whose Gaussians stayed (nearly) transparent.
  auto seen = m.anchor_demon > check_interval * m.opt.success_threshold;
  auto prune = (m.opacity_accum < m.opt.min_opacity * m.anchor_demon) & seen;
  m.opacity_accum.masked_fill_(seen, 0);
  m.anchor_demon.masked_fill_(seen, 0);
  auto keep = (~prune).nonzero().squeeze(1);
  rep.pruned = m.anchor.size(0) - keep.size(0);
  if (rep.pruned > 0) {
    m.offset_denom = m.offset_denom.view({-1, K}).index_select(0, keep).reshape({-1});
    m.offset_grad_accum = m.offset_grad_accum.view({-1, K}).index_select(0, keep).reshape({-1});
    m.opacity_accum = m.opacity_accum.index_select(0, keep);
    m.anchor_demon = m.anchor_demon.index_select(0, keep);
    m.anchor = m.anchor.index_select(0, keep);
  }
  // Scaffold-GS replaces the per-anchor parameters on every adjustment, which drops their
  // gradients for this iteration's step; do the same so results match the reference.
  for (auto& g : m.groups)
    if (g.per_anchor) m.keep_rows(g, keep);
  if (rep.grown > 0 || rep.pruned > 0) m.links = torch::Tensor();  // indices changed: rebuild
  // 4. HAC quirk: after each prune step the base scales are clamped (log space, <= 0.05).
  m.p(m.i_scaling).index({Slice(), Slice(3, 6)}).clamp_max_(0.05);
  return rep;
}

void AnchorModel::reset_statistics() {
  impl_->reset_stats();
}

void AnchorModel::update_learning_rates(int iteration) {
  for (auto& g : impl_->groups) impl_->lr_for(g, iteration);
}

double AnchorModel::learning_rate(const std::string& group) const {
  for (const auto& g : impl_->groups)
    if (g.name == group || g.schedule == group) return g.lr;
  return 0;
}

// One parallel pass over the elements: the unfused form made seven passes over every moment and
// parameter tensor.
void adam_update(torch::Tensor& param, const torch::Tensor& grad, torch::Tensor& m,
                 torch::Tensor& v, double lr, int64_t step) {
  TORCH_CHECK(
      grad.numel() == param.numel() && m.numel() == param.numel() && v.numel() == param.numel(),
      "Adam: gradient or moments do not match the parameter's ", param.numel(), " elements");
  const double bc1 = 1 - std::pow(kAdamBeta1, double(step));
  const double bc2 = 1 - std::pow(kAdamBeta2, double(step));
  const bool flat = param.device().is_cpu() && param.scalar_type() == at::kFloat &&
                    param.is_contiguous() && grad.scalar_type() == at::kFloat &&
                    grad.is_contiguous() && m.scalar_type() == at::kFloat && m.is_contiguous() &&
                    v.scalar_type() == at::kFloat && v.is_contiguous();
  if (!flat) {
    m.mul_(kAdamBeta1).add_(grad, 1 - kAdamBeta1);
    v.mul_(kAdamBeta2).addcmul_(grad, grad, 1 - kAdamBeta2);
    param.addcdiv_(m, (v.sqrt() / std::sqrt(bc2)).add_(kAdamEps), -lr / bc1);
    return;
  }
  const AdamScalars s{float(kAdamBeta1),     float(kAdamBeta2),         float(1 - kAdamBeta1),
                      float(1 - kAdamBeta2), float(1 / std::sqrt(bc2)), float(kAdamEps),
                      float(lr / bc1)};
  float* p = param.data_ptr<float>();
  float* mp = m.data_ptr<float>();
  float* vp = v.data_ptr<float>();
  const float* gp = grad.data_ptr<float>();
  at::parallel_for(0, param.numel(), 1 << 15,
                   [&](int64_t b, int64_t e) { adam_kernel(p, mp, vp, gp, b, e, s); });
}

void AnchorModel::optimizer_step() {
  torch::NoGradGuard ng;
  for (auto& g : impl_->groups) {
    if (!g.param.grad().defined()) continue;
    g.step += 1;
    adam_update(g.param, g.param.grad(), g.m, g.v, g.lr, g.step);
  }
  zero_grad();
}

void AnchorModel::zero_grad() {
  for (auto& g : impl_->groups)
    if (g.param.grad().defined()) g.param.mutable_grad().reset();
}

std::vector<std::pair<std::string, torch::Tensor>> AnchorModel::named_parameters() const {
  std::vector<std::pair<std::string, torch::Tensor>> out;
  for (const auto& g : impl_->groups) out.emplace_back(g.name, g.param);
  return out;
}

std::map<std::string, torch::Tensor> AnchorModel::state_dict() const {
  const Impl& m = *impl_;
  std::map<std::string, torch::Tensor> s;
  s["anchor"] = m.anchor;
  s["bounds"] = m.bounds;
  s["voxel_size"] = torch::tensor(m.voxel, torch::kDouble);
  s["spatial_lr_scale"] = torch::tensor(m.spatial_lr_scale, torch::kDouble);
  s["stat.opacity_accum"] = m.opacity_accum;
  s["stat.anchor_demon"] = m.anchor_demon;
  s["stat.offset_grad_accum"] = m.offset_grad_accum;
  s["stat.offset_denom"] = m.offset_denom;
  if (m.links.defined()) s["links"] = m.links;
  for (const auto& g : m.groups) {
    s["param." + g.name] = g.param.detach();
    s["adam_m." + g.name] = g.m;
    s["adam_v." + g.name] = g.v;
    s["adam_step." + g.name] = torch::tensor(g.step, torch::kLong);
  }
  return s;
}

const std::vector<std::string>& AnchorModel::optional_state_keys() {
  static const std::vector<std::string> keys = {"links"};
  return keys;
}

Status AnchorModel::load_state_dict(const std::map<std::string, torch::Tensor>& s) {
  Impl& m = *impl_;
  // Everything is read and checked into copies first: on any error the model is unchanged.
  auto bad = [](const std::string& msg) { return Status(StatusCode::kInvalidArgument, msg); };
  auto get = [&](const std::string& k, std::vector<int64_t> shape,
                 c10::ScalarType dtype) -> StatusOr<torch::Tensor> {
    auto it = s.find(k);
    if (it == s.end()) return Status(StatusCode::kCorruptBitstream, "checkpoint lacks '" + k + "'");
    const torch::Tensor& t = it->second;
    if (!t.defined() || t.sizes() != c10::IntArrayRef(shape) || t.scalar_type() != dtype)
      return bad("checkpoint tensor '" + k + "' is " +
                 (t.defined()
                      ? std::string(c10::toString(t.scalar_type())) + " " + c10::str(t.sizes())
                      : std::string("undefined")) +
                 ", expected " + c10::toString(dtype) + " " + c10::str(c10::IntArrayRef(shape)) +
                 " (was it trained with another scene/model config?)");
    return t.detach().clone();
  };
  torch::NoGradGuard ng;
  auto it_anchor = s.find("anchor");
  if (it_anchor == s.end() || !it_anchor->second.defined() || it_anchor->second.dim() != 2)
    return Status(StatusCode::kCorruptBitstream, "checkpoint lacks a [N, 3] 'anchor'");
  const int64_t n = it_anchor->second.size(0), nk = n * m.K;
  CRPGS_ASSIGN_OR_RETURN(torch::Tensor anchor, get("anchor", {n, 3}, torch::kFloat));
  CRPGS_ASSIGN_OR_RETURN(torch::Tensor bounds, get("bounds", {2, 3}, torch::kFloat));
  CRPGS_ASSIGN_OR_RETURN(torch::Tensor voxel, get("voxel_size", {}, torch::kDouble));
  CRPGS_ASSIGN_OR_RETURN(torch::Tensor lr_scale, get("spatial_lr_scale", {}, torch::kDouble));
  std::array<torch::Tensor, 4> stats;
  const std::array<std::pair<const char*, int64_t>, 4> stat_rows = {{{"stat.opacity_accum", n},
                                                                     {"stat.anchor_demon", n},
                                                                     {"stat.offset_grad_accum", nk},
                                                                     {"stat.offset_denom", nk}}};
  for (size_t i = 0; i < stats.size(); ++i) {
    CRPGS_ASSIGN_OR_RETURN(stats[i], get(stat_rows[i].first, {stat_rows[i].second}, torch::kFloat));
  }
  torch::Tensor links;
  if (s.count("links")) {
    if (!m.link_strategy)  // its leaves would need the leaf model this model does not have
      return bad(
          "the checkpoint holds anchor links but this model has none (no links section in the "
          "config): resume it with the config it was trained with");
    CRPGS_ASSIGN_OR_RETURN(links, get("links", {n}, torch::kLong));
    if (Status st = check_links(links, {}); !st.ok()) return bad("checkpoint " + st.message());
  }
  struct Staged {
    torch::Tensor param, m, v;
    int64_t step;
  };
  std::vector<Staged> staged;
  for (const auto& g : m.groups) {
    std::vector<int64_t> shape = g.param.sizes().vec();
    if (g.per_anchor) shape[0] = n;
    const auto dtype = g.param.scalar_type();
    Staged st;
    CRPGS_ASSIGN_OR_RETURN(st.param, get("param." + g.name, shape, dtype));
    CRPGS_ASSIGN_OR_RETURN(st.m, get("adam_m." + g.name, shape, dtype));
    CRPGS_ASSIGN_OR_RETURN(st.v, get("adam_v." + g.name, shape, dtype));
    CRPGS_ASSIGN_OR_RETURN(torch::Tensor step, get("adam_step." + g.name, {}, torch::kLong));
    st.step = step.item<int64_t>();
    if (st.step < 0) return bad("checkpoint 'adam_step." + g.name + "' is negative");
    staged.push_back(std::move(st));
  }
  const double voxel_size = voxel.item<double>(), spatial = lr_scale.item<double>();
  if (!(voxel_size > 0) || !std::isfinite(voxel_size) || !(spatial > 0) || !std::isfinite(spatial))
    return bad("checkpoint voxel_size / spatial_lr_scale must be finite and > 0");

  // Commit, on the model's device: nothing below can fail.
  const auto dev = m.anchor.device();
  const auto on = [&](const torch::Tensor& t) { return t.defined() ? t.to(dev) : t; };
  m.anchor = on(anchor);
  m.bounds = on(bounds);
  m.voxel = voxel_size;
  m.spatial_lr_scale = spatial;
  m.opacity_accum = on(stats[0]);
  m.anchor_demon = on(stats[1]);
  m.offset_grad_accum = on(stats[2]);
  m.offset_denom = on(stats[3]);
  m.links = on(links);
  for (size_t i = 0; i < m.groups.size(); ++i) {
    ParamGroup& g = m.groups[i];
    if (g.external)
      g.param.copy_(staged[i].param);  // the component owns the tensor; same shape and dtype
    else
      g.param = on(staged[i].param).requires_grad_(true);
    g.m = on(staged[i].m);
    g.v = on(staged[i].v);
    g.step = staged[i].step;
  }
  m.bind_mlps();
  return OkStatus();
}

std::shared_ptr<FeatureModel> AnchorModel::feature_model() const {
  return impl_->features_model;
}

torch::Device AnchorModel::device() const {
  return impl_->anchor.device();
}

void AnchorModel::to(const torch::Device& device) {
  Impl& m = *impl_;
  if (m.anchor.device() == device) return;
  torch::NoGradGuard ng;
  auto move = [&](torch::Tensor& t) {
    if (t.defined()) t = t.to(device);
  };
  for (auto* t : {&m.anchor, &m.bounds, &m.links, &m.opacity_accum, &m.anchor_demon,
                  &m.offset_grad_accum, &m.offset_denom})
    move(*t);
  for (auto& g : m.groups) {
    if (g.external) {
      // The component holds this tensor: swap its storage in place so that the component sees it.
      g.param.set_data(g.param.detach().to(device));
    } else {
      g.param = g.param.detach().to(device).requires_grad_(true);
    }
    g.param.mutable_grad().reset();
    move(g.m);
    move(g.v);
  }
  m.bind_mlps();
  for (auto* rv : {&m.over, &m.decoded})
    if (*rv)
      for (auto* t : {&(*rv)->positions, &(*rv)->positions01, &(*rv)->features, &(*rv)->scaling,
                      &(*rv)->offsets, &(*rv)->mask, &(*rv)->mlp_features})
        move(*t);
}

}  // namespace crpgs
