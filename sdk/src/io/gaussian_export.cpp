/// @file gaussian_export.cpp
/// @brief Anchor model -> 3DGS Gaussians with fitted SH, and .ply Gaussians -> GaussianBatch.
#include "crpgs/gaussian_export.h"

#include <algorithm>
#include <cmath>
#include <stdexcept>

#include <torch/nn/functional/normalization.h>

#include "core/shuffle.h"
#include "crpgs/chunked_mlp.h"
#include "crpgs/image_tensor.h"
#include "model/optimizer.h"

namespace crpgs {
namespace {

using torch::indexing::Slice;

/// A prefilter that keeps every anchor: baking is not about one camera's frustum.
class AllVisible final : public Rasterizer {
 public:
  std::string type_name() const override { return "all_visible"; }
  YAML::Node hyperparams() const override { return YAML::Node(); }
  torch::Device device() const override { return torch::kCPU; }
  RenderOutput render(const GaussianBatch&, const Camera&, const RenderSettings&) override {
    throw std::logic_error("AllVisible only answers visible_anchors");
  }
  torch::Tensor visible_anchors(const torch::Tensor& positions, const torch::Tensor&, const Camera&,
                                const RenderSettings&) override {
    return torch::ones({positions.size(0)}, torch::kBool);
  }
};

/// The generation MLPs as AnchorModel applies them: Linear, ReLU, Linear.
torch::Tensor mlp(const std::map<std::string, torch::Tensor>& t, const std::string& name,
                  const torch::Tensor& x) {
  return chunked_mlp(x, t.at(name + ".w1"), t.at(name + ".b1"), t.at(name + ".w2"),
                     t.at(name + ".b2"));
}

/// A .ply's Gaussians as tensors, before activation (what refine_gaussians optimises).
struct PlyTensors {
  torch::Tensor means;       ///< [N, 3]
  torch::Tensor log_scales;  ///< [N, 3]
  torch::Tensor rotations;   ///< [N, 4]
  torch::Tensor opacity;     ///< [N] logit
  torch::Tensor sh_dc;       ///< [N, 1, 3]
  torch::Tensor sh_rest;     ///< [N, B-1, 3]
};

PlyTensors ply_tensors(const PlyGaussians& g) {
  const int64_t n = int64_t(g.size());
  const int nb = sh_coeff_count(g.sh_degree);
  auto tensor = [](const std::vector<float>& v, std::vector<int64_t> shape) {
    return torch::from_blob(const_cast<float*>(v.data()), shape, torch::kFloat).clone();
  };
  PlyTensors t;
  t.means = tensor(g.means, {n, 3});
  t.log_scales = tensor(g.log_scales, {n, 3});
  t.rotations = tensor(g.rotations, {n, 4});
  t.opacity = tensor(g.opacity, {n});
  t.sh_dc = tensor(g.sh_dc, {n, 1, 3});
  t.sh_rest = tensor(g.sh_rest, {n, 3, nb - 1}).permute({0, 2, 1}).contiguous();
  return t;
}

PlyGaussians to_ply(const PlyTensors& t, int degree) {
  auto to_vec = [](const torch::Tensor& x) {
    auto c = x.detach().to(torch::kFloat).contiguous();
    return std::vector<float>(c.data_ptr<float>(), c.data_ptr<float>() + c.numel());
  };
  PlyGaussians out;
  out.sh_degree = degree;
  out.means = to_vec(t.means);
  out.sh_dc = to_vec(t.sh_dc);
  out.sh_rest = to_vec(t.sh_rest.permute({0, 2, 1}));  // channel-major: [N, 3, B-1]
  out.opacity = to_vec(t.opacity);
  out.log_scales = to_vec(t.log_scales);
  out.rotations = to_vec(t.rotations);
  return out;
}

/// The Gaussians as `camera` sees them: colour from the SH at the direction from its centre.
GaussianBatch activate(const PlyTensors& t, int degree, const Camera& camera) {
  GaussianBatch b;
  b.means = t.means;
  b.scales = torch::exp(t.log_scales);
  b.rotations = t.rotations;
  b.opacities = torch::sigmoid(t.opacity);
  const Eigen::Vector3d c = camera.center();
  auto d = t.means.detach() - torch::tensor({float(c[0]), float(c[1]), float(c[2])});
  d = d / d.norm(2, 1, true).clamp_min(1e-12);
  auto basis = sh_basis_matrix(d, degree);                                   // [N, B]
  auto coeffs = degree > 0 ? torch::cat({t.sh_dc, t.sh_rest}, 1) : t.sh_dc;  // [N, B, 3]
  b.colors = ((basis.unsqueeze(2) * coeffs).sum(1) + 0.5f).clamp_min(0);     // [N, 3]
  return b;
}

}  // namespace

torch::Tensor fibonacci_directions(int count) {
  auto d = torch::empty({count, 3});
  auto a = d.accessor<float, 2>();
  const double golden = M_PI * (3.0 - std::sqrt(5.0));
  for (int i = 0; i < count; ++i) {
    const double z = 1.0 - (2.0 * i + 1.0) / count;
    const double r = std::sqrt(std::max(0.0, 1.0 - z * z));
    a[i][0] = float(r * std::cos(golden * i));
    a[i][1] = float(r * std::sin(golden * i));
    a[i][2] = float(z);
  }
  return d;
}

torch::Tensor sh_basis_matrix(const torch::Tensor& dirs, int degree) {
  const auto d = dirs.to(torch::kFloat).contiguous();
  const int64_t s = d.size(0);
  const int nb = sh_coeff_count(degree);
  auto out = torch::empty({s, nb});
  const float* p = d.data_ptr<float>();
  float* o = out.data_ptr<float>();
  for (int64_t i = 0; i < s; ++i)
    sh_basis(degree, p[3 * i], p[3 * i + 1], p[3 * i + 2], o + nb * i);
  return out;
}

torch::Tensor fit_sh(const std::vector<ShSamples>& parts) {
  if (parts.empty()) throw std::invalid_argument("fit_sh: no samples");
  torch::Tensor normal, rhs;  // [1 or G, B, B], [G, B, 3]
  for (const auto& p : parts) {
    auto b = p.basis.to(torch::kDouble);
    if (b.dim() == 2) b = b.unsqueeze(0);
    auto bt = b.transpose(1, 2) * p.weight;
    auto n = torch::matmul(bt, b);
    auto r = torch::matmul(bt, p.colors.to(torch::kDouble) - 0.5);
    normal = normal.defined() ? normal + n : n;
    rhs = rhs.defined() ? rhs + r : r;
  }
  if (normal.size(0) == 1)  // one system for all Gaussians: invert it once
    return torch::matmul(torch::inverse(normal[0]), rhs).to(torch::kFloat);
  return torch::linalg_solve(normal, rhs).to(torch::kFloat);
}

torch::Tensor fit_sh(const torch::Tensor& colors, const torch::Tensor& dirs, int degree) {
  return fit_sh({ShSamples{colors, sh_basis_matrix(dirs, degree)}});
}

StatusOr<PlyGaussians> bake_gaussians(AnchorModel& model, const BakeOptions& options,
                                      const QuantizedAttributes* q) {
  const int degree = options.sh_degree;
  if (degree < 0 || degree > 3)
    return Status(StatusCode::kInvalidArgument, "export: SH degree must be 0..3");
  if (options.directions < sh_coeff_count(degree))
    return Status(StatusCode::kInvalidArgument,
                  "export: need at least " + std::to_string(sh_coeff_count(degree)) +
                      " directions for SH degree " + std::to_string(degree));
  if (options.camera_centers.empty())
    return Status(StatusCode::kInvalidArgument, "export: no camera centres for the view inputs");
  if (!(options.view_weight >= 0 && options.view_weight <= kMaxViewWeight))
    return Status(StatusCode::kInvalidArgument,
                  "export: the view weight must be in [0, " + std::to_string(kMaxViewWeight) + "]");
  torch::NoGradGuard no_grad;
  AllVisible all;
  Camera cam;
  cam.width = cam.height = 1;
  cam.fx = cam.fy = 1;
  RenderSettings settings;
  // Only the feature columns of the MLP input and the (de)quantised attributes are used.
  NeuralGaussians ng = model.generate(cam, -1, all, settings, false);
  const int64_t M = ng.input.size(0);
  const int64_t K = model.n_offsets();
  torch::Tensor pos = (q ? q->positions : model.anchors()).detach().to(torch::kFloat);  // [M, 3]
  torch::Tensor mask = (q ? q->offset_masks : model.offset_masks()).to(torch::kFloat);  // [M, K]
  if (pos.size(0) != M || mask.size(0) != M)
    return Status(
        StatusCode::kInvalidArgument,
        "export: the model renders " + std::to_string(M) + " anchors but " +
            std::to_string(pos.size(0)) +
            " positions were given (pass the QuantizedAttributes given to set_quantized)");
  const SceneEffects& fx = model.options().effects;
  const int64_t F = ng.input.size(1) - (fx.view_dependent ? 3 : 0) - (fx.distance_input ? 1 : 0);
  auto feat = ng.input.narrow(1, 0, F);  // [M, F]
  auto scal = ng.used_scaling;           // [M, 6]
  auto offs = ng.used_offsets;           // [M, K, 3]

  // Representative view per anchor: mean unit direction and mean distance from the cameras.
  auto sum_u = torch::zeros({M, 3}, torch::kDouble), sum_d = torch::zeros({M, 1}, torch::kDouble);
  auto pos_d = pos.to(torch::kDouble);
  Eigen::Vector3d mean_c = Eigen::Vector3d::Zero();
  for (const auto& c : options.camera_centers) {
    auto d = pos_d - torch::tensor({c[0], c[1], c[2]}, torch::kDouble);  // [M, 3]
    auto n = d.norm(2, 1, true).clamp_min(1e-12);
    sum_u += d / n;
    sum_d += n;
    mean_c += c;
  }
  mean_c /= double(options.camera_centers.size());
  auto u_norm = sum_u.norm(2, 1, true);
  auto fallback = pos_d - torch::tensor({mean_c[0], mean_c[1], mean_c[2]}, torch::kDouble);
  fallback = fallback / fallback.norm(2, 1, true).clamp_min(1e-12);
  auto rep_dir = torch::where(u_norm > 1e-6, sum_u / u_norm.clamp_min(1e-12), fallback)
                     .to(torch::kFloat);                                              // [M, 3]
  auto rep_dist = (sum_d / double(options.camera_centers.size())).to(torch::kFloat);  // [M, 1]

  auto view_input = [&](const torch::Tensor& f, const torch::Tensor& dir,
                        const torch::Tensor& dist) {
    std::vector<torch::Tensor> parts{f};
    if (fx.view_dependent) parts.push_back(dir);
    if (fx.distance_input) parts.push_back(dist);
    return parts.size() == 1 ? f : torch::cat(parts, 1);
  };
  const auto mlps = model.mlp_tensors();
  auto in_rep = view_input(feat, rep_dir, rep_dist);  // [M, C]
  const int64_t n_cameras = int64_t(options.camera_centers.size());
  auto centers = torch::empty({n_cameras, 3});
  auto centers_acc = centers.accessor<float, 2>();
  for (int64_t c = 0; c < n_cameras; ++c)
    for (int i = 0; i < 3; ++i) centers_acc[c][i] = float(options.camera_centers[size_t(c)][i]);
  auto unit = [](const torch::Tensor& v) { return v / v.norm(2, -1, true).clamp_min(1e-12); };
  // Opacity: the mean over the cameras' own views of what each would see (where the model gives
  // a Gaussian no opacity it does not exist for that camera: 0), or the representative view's.
  torch::Tensor opacity;  // [M, K]
  if (options.opacity_over_views) {
    opacity = torch::zeros({M, K});
    for (int64_t c = 0; c < n_cameras; ++c) {
      auto d = pos - centers[c];  // [M, 3]
      opacity +=
          torch::tanh(mlp(mlps, "mlp_opacity", view_input(feat, unit(d), d.norm(2, 1, true))))
              .clamp_min(0);
    }
    opacity = opacity / double(n_cameras) * mask;
  } else {
    opacity = torch::tanh(mlp(mlps, "mlp_opacity", in_rep)) * mask;
  }
  auto cov = mlp(mlps, "mlp_cov", in_rep).reshape({M * K, 7});
  auto keep = (opacity.reshape({M * K}) > 0).nonzero().squeeze(1);  // [G]
  const int64_t G = keep.size(0);
  auto anchor_of = keep.div(K, "floor");
  auto sc = scal.index_select(0, anchor_of);  // [G, 6]
  auto means = pos.index_select(0, anchor_of) +
               offs.reshape({M * K, 3}).index_select(0, keep) * sc.index({Slice(), Slice(0, 3)});
  auto cv = cov.index_select(0, keep);
  auto scales = sc.index({Slice(), Slice(3, 6)}) * torch::sigmoid(cv.index({Slice(), Slice(0, 3)}));
  auto rot = torch::nn::functional::normalize(cv.index({Slice(), Slice(3, 7)}),
                                              torch::nn::functional::NormalizeFuncOptions().dim(1));
  auto op =
      opacity.reshape({M * K}).index_select(0, keep).to(torch::kDouble).clamp(1e-12, 1 - 1e-12);

  // Colours in chunks of anchors, at the sphere's directions and at each camera's own view;
  // SH fitted per Gaussian.
  const int S = options.directions;
  const double w = options.view_weight;
  const int64_t C = w > 0 ? n_cameras : 0;            // cameras in the colour fit
  auto dirs = fibonacci_directions(S);                // [S, 3]
  auto sphere_basis = sh_basis_matrix(dirs, degree);  // [S, B]
  torch::Tensor app;
  if (fx.appearance_dim > 0) app = mlps.at("appearance").mean(0);  // as camera_index = -1
  const int nb = sh_coeff_count(degree);
  auto coeffs = torch::empty({G, nb, 3});
  // Anchors per chunk: ~1M MLP rows and per-camera bases of bounded size, whatever the cameras.
  const int64_t chunk = std::max<int64_t>(16, (int64_t(1024) * S) / (S + C));
  auto keep_acc = keep.accessor<int64_t, 1>();
  int64_t g0 = 0;
  for (int64_t a0 = 0; a0 < M && g0 < G; a0 += chunk) {
    const int64_t mc = std::min(chunk, M - a0);
    int64_t g1 = g0;
    while (g1 < G && keep_acc[g1] < (a0 + mc) * K) ++g1;
    if (g1 == g0) continue;
    const int64_t T = S + C;
    auto dd = dirs.unsqueeze(1).expand({S, mc, 3});                          // [T, mc, 3]
    auto dist = rep_dist.narrow(0, a0, mc).unsqueeze(0).expand({S, mc, 1});  // [T, mc, 1]
    if (C > 0) {
      auto v = pos.narrow(0, a0, mc).unsqueeze(0) - centers.unsqueeze(1);  // [C, mc, 3]
      dd = torch::cat({dd, unit(v)}, 0);
      dist = torch::cat({dist, v.norm(2, 2, true)}, 0);
    }
    auto f = feat.narrow(0, a0, mc).unsqueeze(0).expand({T, mc, F}).reshape({T * mc, F});
    auto in = view_input(f, dd.reshape({T * mc, 3}), dist.reshape({T * mc, 1}));
    if (app.defined()) in = torch::cat({in, app.unsqueeze(0).expand({T * mc, app.size(0)})}, 1);
    auto col = torch::sigmoid(mlp(mlps, "mlp_color", in))
                   .reshape({T, mc * K, 3})
                   .permute({1, 0, 2});  // [mc*K, T, 3]
    const int64_t g = g1 - g0;
    auto c = col.index_select(0, keep.narrow(0, g0, g) - a0 * K);  // [g, T, 3]
    std::vector<ShSamples> parts{{c.narrow(1, 0, S), sphere_basis, (1 - w) / S}};
    if (C > 0) {
      // The basis where a renderer evaluates it: from the camera centre to the Gaussian.
      auto v = unit(means.narrow(0, g0, g).unsqueeze(1) - centers.unsqueeze(0));  // [g, C, 3]
      auto basis = sh_basis_matrix(v.reshape({g * C, 3}), degree).reshape({g, C, nb});
      parts.push_back({c.narrow(1, S, C), basis, w / double(C)});
    }
    coeffs.narrow(0, g0, g).copy_(fit_sh(parts));
    g0 = g1;
  }

  PlyTensors t;
  t.means = means;
  t.log_scales = torch::log(scales.clamp_min(1e-30));
  t.rotations = rot;
  t.opacity = torch::log(op / (1 - op));
  t.sh_dc = coeffs.narrow(1, 0, 1);
  t.sh_rest = coeffs.narrow(1, 1, nb - 1);
  return to_ply(t, degree);
}

GaussianBatch ply_to_batch(const PlyGaussians& g, const Camera& camera) {
  return activate(ply_tensors(g), g.sh_degree, camera);
}

StatusOr<RefineReport> refine_gaussians(PlyGaussians& g, Rasterizer& rasterizer,
                                        const std::vector<View>& views,
                                        const std::array<float, 3>& background,
                                        const RefineOptions& o,
                                        const std::function<void(int, double)>& on_iteration) {
  RefineReport report;
  if (o.iterations < 0)
    return Status(StatusCode::kInvalidArgument, "refine: the iterations must be >= 0");
  if (o.iterations == 0 || g.size() == 0) return report;
  if (views.empty())
    return Status(StatusCode::kInvalidArgument,
                  "refine: no training views (the dataset has only test views)");
  for (double lr : {o.means_lr, o.means_lr_final, o.sh_dc_lr, o.sh_rest_lr, o.opacity_lr,
                    o.scaling_lr, o.rotation_lr})
    if (!(lr >= 0 && std::isfinite(lr)))
      return Status(StatusCode::kInvalidArgument, "refine: learning rates must be finite and >= 0");
  if ((o.means_lr > 0) != (o.means_lr_final > 0))
    return Status(StatusCode::kInvalidArgument,
                  "refine: the means' learning rate decays log-linearly: its start and end must "
                  "both be 0 or both be > 0");
  if (!(o.lambda_dssim >= 0 && o.lambda_dssim <= 1))
    return Status(StatusCode::kInvalidArgument, "refine: lambda_dssim must be in [0, 1]");
  for (const auto& v : views)
    if (v.image.width != v.camera.width || v.image.height != v.camera.height ||
        v.image.channels != 3)
      return Status(StatusCode::kInvalidArgument,
                    "refine: view '" + v.camera.name + "' has no RGB photo of its camera's size");
  CRPGS_RETURN_IF_ERROR(g.check());
  PlyTensors t = ply_tensors(g);
  std::vector<Eigen::Vector3d> centers;
  for (const auto& v : views) centers.push_back(v.camera.center());
  const double extent = cameras_extent(centers);

  struct Group {
    torch::Tensor* param;
    double lr;
    torch::Tensor m = torch::zeros_like(*param), v = torch::zeros_like(*param);
    int64_t step = 0;
  };
  std::vector<Group> groups;  // the means' lr is set per iteration
  for (auto [param, lr] : {std::pair{&t.means, 0.0},
                           {&t.sh_dc, o.sh_dc_lr},
                           {&t.sh_rest, o.sh_rest_lr},
                           {&t.opacity, o.opacity_lr},
                           {&t.log_scales, o.scaling_lr},
                           {&t.rotations, o.rotation_lr}}) {
    param->requires_grad_(true);
    groups.push_back(Group{param, lr});
  }
  std::vector<torch::Tensor> photos;
  for (const auto& v : views) photos.push_back(image_to_tensor(v.image));
  RenderSettings settings;
  settings.background = background;
  const int n_views = int(views.size());
  std::vector<int> order;
  double pass_loss = 0;  // sum over this pass's kept iterations
  int pass_kept = 0;
  std::vector<double> pass_means;  // one per complete pass with a kept iteration
  for (int it = 1; it <= o.iterations; ++it) {
    const int pass = (it - 1) / n_views, pos = (it - 1) % n_views;
    if (pos == 0) order = seeded_permutation(n_views, o.seed * 0x9E3779B97F4A7C15ull + pass);
    const View& view = views[size_t(order[size_t(pos)])];
    const torch::Tensor& photo = photos[size_t(order[size_t(pos)])];
    groups[0].lr = extent * log_lerp(o.means_lr, o.means_lr_final, it - 1, o.iterations - 1);
    auto image =
        rasterizer.render(activate(t, g.sh_degree, view.camera), view.camera, settings).image;
    auto loss = (1.0 - o.lambda_dssim) * (image - photo).abs().mean() +
                o.lambda_dssim * (1.0 - tensor_ssim(image, photo));
    const double value = loss.item<double>();
    bool finite = std::isfinite(value);
    if (finite) {
      loss.backward();
      for (auto& gr : groups)
        if (gr.param->grad().defined() && !torch::isfinite(gr.param->grad()).all().item<bool>())
          finite = false;
    }
    if (finite) {
      torch::NoGradGuard no_grad;
      for (auto& gr : groups) {
        if (!gr.param->grad().defined()) continue;
        adam_update(*gr.param, gr.param->grad(), gr.m, gr.v, gr.lr, ++gr.step);
      }
      pass_loss += value;
      ++pass_kept;
    } else {
      ++report.skipped;  // a non-finite update would poison the Adam moments for good
    }
    for (auto& gr : groups)
      if (gr.param->grad().defined()) gr.param->mutable_grad().reset();
    if (pos == n_views - 1) {
      if (pass_kept > 0) pass_means.push_back(pass_loss / pass_kept);
      pass_loss = 0;
      pass_kept = 0;
    }
    report.iterations = it;
    if (on_iteration) on_iteration(it, value);
  }
  report.passes = int(pass_means.size());
  if (!pass_means.empty()) {
    report.first_pass_loss = pass_means.front();
    report.last_pass_loss = pass_means.back();
  }
  torch::NoGradGuard no_grad;
  for (auto& gr : groups) gr.param->requires_grad_(false);
  PlyGaussians refined = to_ply(t, g.sh_degree);
  refined.dropped_non_finite = g.dropped_non_finite;
  g = std::move(refined);
  return report;
}

}  // namespace crpgs
