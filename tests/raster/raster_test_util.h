/// @file raster_test_util.h
/// @brief Scenes, cameras and comparison helpers shared by the rasterizer tests.
#pragma once

#include <gtest/gtest.h>

#include <cmath>
#include <random>
#include <string>
#include <vector>

#include <torch/torch.h>
#include <Eigen/Geometry>

#include "crpgs/rasterizer.h"
#include "raster/reference.h"
#include "raster/render.h"

namespace crpgs::raster::test_util {

/// A float32 scene (CPU, contiguous).
struct Scene {
  at::Tensor means, scales, rotations, opacities, colors;
  int64_t size() const { return means.size(0); }
};

/// A camera looking down +z with a small rotation and translation, so that R and t are exercised.
inline Camera make_camera(int width, int height) {
  Camera c;
  c.width = width;
  c.height = height;
  c.fx = 0.9 * std::max(width, height) + 3.0;
  c.fy = c.fx * 1.05;
  c.cx = 0.5 * width + 0.25;
  c.cy = 0.5 * height - 0.5;
  c.R = (Eigen::AngleAxisd(0.1, Eigen::Vector3d(0.3, 1.0, 0.2).normalized())).toRotationMatrix();
  c.t = Eigen::Vector3d(0.2, -0.1, 0.3);
  return c;
}

/// World point from camera-space coordinates.
inline Eigen::Vector3d to_world(const Camera& c, const Eigen::Vector3d& p_cam) {
  return c.R.transpose() * (p_cam - c.t);
}

/// World point that projects to pixel position (u, v) at depth z.
inline Eigen::Vector3d world_at_pixel(const Camera& c, double u, double v, double z) {
  return to_world(c, Eigen::Vector3d((u - c.cx) / c.fx * z, (v - c.cy) / c.fy * z, z));
}

inline Scene empty_scene(int64_t n) {
  Scene s;
  s.means = at::zeros({n, 3});
  s.scales = at::full({n, 3}, 0.1f);
  s.rotations = at::zeros({n, 4});
  if (n > 0) s.rotations.select(1, 0).fill_(1.f);
  s.opacities = at::full({n}, 0.5f);
  s.colors = at::full({n, 3}, 0.5f);
  return s;
}

inline void set_row(at::Tensor& t, int64_t i, std::initializer_list<double> v) {
  int k = 0;
  for (double x : v) t[i][k++] = x;
}

/// Random Gaussians in front of the camera; some partly off-screen (exercising the Jacobian
/// clamp), sizes of a few pixels, unnormalised random quaternions.
inline Scene random_scene(int64_t n, uint32_t seed, const Camera& cam, double size_px = 3.0) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> U(0.0, 1.0);
  std::normal_distribution<double> N(0.0, 1.0);
  Scene s = empty_scene(n);
  auto m = s.means.accessor<float, 2>();
  auto sc = s.scales.accessor<float, 2>();
  auto q = s.rotations.accessor<float, 2>();
  auto o = s.opacities.accessor<float, 1>();
  auto col = s.colors.accessor<float, 2>();
  for (int64_t i = 0; i < n; ++i) {
    const double z = 2.0 + 4.0 * U(rng);
    const double u = (-0.25 + 1.5 * U(rng)) * cam.width, v = (-0.25 + 1.5 * U(rng)) * cam.height;
    const Eigen::Vector3d w = world_at_pixel(cam, u, v, z);
    for (int k = 0; k < 3; ++k) {
      m[i][k] = float(w[k]);
      // Scale in world units giving roughly size_px pixels, anisotropic.
      sc[i][k] = float(size_px * z / cam.fx * std::exp(0.6 * N(rng)));
      col[i][k] = float(U(rng));
    }
    for (int k = 0; k < 4; ++k) q[i][k] = float(N(rng) * (0.5 + U(rng)));
    o[i] = float(0.05 + 0.9 * U(rng));
  }
  return s;
}

inline RenderSettings settings_with(bool depth, std::array<float, 3> bg = {0.1f, 0.3f, 0.7f}) {
  RenderSettings s;
  s.background = bg;
  s.render_depth = depth;
  return s;
}

// ---- The numerical hard cases (test_raster.cpp checks each against the reference and its own
// expectations; test_cuda_raster.cpp renders every one on the GPU against the CPU) ----------

struct HardCase {
  std::string name;
  Camera cam;
  Scene scene;
  RenderSettings settings;
  bool gradients = true;  // false: compare the forward only (test_raster.cpp says why)
};

/// 0: behind, 1: exactly at z = 0, 2: just in front of the near plane with a huge footprint,
/// 3: just behind the near plane, 4: in front but its 3D extent crosses z = 0.
inline HardCase near_plane_case() {
  HardCase h{"near plane", make_camera(48, 40), {}, settings_with(true)};
  h.scene = random_scene(12, 31, h.cam);
  const double zs[] = {-2.0, 0.0, 0.02, 0.009, 0.5};
  const double sc[] = {0.3, 0.3, 0.05, 0.05, 2.0};
  for (int i = 0; i < 5; ++i) {
    const Eigen::Vector3d w = world_at_pixel(h.cam, 20, 15, zs[i]);
    const Eigen::Vector3d wz = to_world(h.cam, Eigen::Vector3d(0.01, -0.02, zs[i]));
    const Eigen::Vector3d p = zs[i] == 0.0 ? wz : w;
    set_row(h.scene.means, i, {p.x(), p.y(), p.z()});
    set_row(h.scene.scales, i, {sc[i], sc[i] * 0.5, sc[i]});
  }
  h.scene.opacities[2] = 0.3f;
  return h;
}

inline HardCase extreme_scales_case() {
  HardCase h{"extreme scales", make_camera(40, 36), {}, settings_with(false)};
  Scene& s = h.scene = random_scene(20, 41, h.cam);
  set_row(s.scales, 0, {1e-9, 1e-9, 1e-9});
  set_row(s.scales, 1, {1e-12, 0.05, 1e-12});
  set_row(s.scales, 2, {50.0, 40.0, 60.0});  // covers the whole image
  set_row(s.scales, 3, {1e4, 1e-6, 1e3});
  s.opacities[2] = 0.2f;
  s.opacities[3] = 0.1f;
  return h;
}

/// Needles along the viewing ray and flat discs seen edge-on (identity rotation, camera R is
/// close to identity): before the 0.3 dilation their 2D covariances are (nearly) singular.
inline HardCase degenerate_covariances_case() {
  HardCase h{"degenerate covariances", make_camera(40, 32), {}, settings_with(true)};
  Scene& s = h.scene = random_scene(16, 51, h.cam);
  set_row(s.rotations, 0, {1, 0, 0, 0});
  set_row(s.scales, 0, {1e-7, 1e-7, 0.8});
  set_row(s.rotations, 1, {1, 0, 0, 0});
  set_row(s.scales, 1, {0.5, 1e-8, 0.5});
  set_row(s.rotations, 2, {0, 0, 0, 1});
  set_row(s.scales, 2, {0.0, 0.0, 0.0});  // a point: the dilation alone
  set_row(s.rotations, 3, {0.7071, 0.7071, 0, 0});
  set_row(s.scales, 3, {0.3, 1e-9, 1e-9});
  return h;
}

/// Lengths of the needles of huge_needles_case (σ from 1e5 to 1e9 px).
inline constexpr double kNeedleLengths[] = {1e4, 1e5, 1e6, 1e7, 1e8};

/// Needles in the image plane, diagonal to the pixel axes. Gradients through the conic cancel
/// terms of size σ², so they are compared only with every length capped at `max_length`.
inline HardCase huge_needles_case(double max_length) {
  HardCase h{"huge needles", make_camera(40, 32), {}, settings_with(false)};
  Scene& s = h.scene = random_scene(16, 53, h.cam);
  const double c8 = std::cos(M_PI / 8), s8 = std::sin(M_PI / 8);
  for (int i = 0; i < 5; ++i) {
    const Eigen::Vector3d w = world_at_pixel(h.cam, 12 + 4 * i, 10 + 3 * i, 3.0);
    set_row(s.means, i, {w.x(), w.y(), w.z()});
    set_row(s.rotations, i, {c8, 0, 0, i % 2 ? s8 : -s8});  // x axis to ±45° in the image
    set_row(s.scales, i, {std::min(kNeedleLengths[i], max_length), 1e-9, 1e-9});
    s.opacities[i] = 0.05f;
  }
  h.gradients = max_length <= kNeedleLengths[1];
  if (h.gradients) h.name = "long needles";
  return h;
}

inline HardCase quaternions_case() {
  HardCase h{"quaternions", make_camera(40, 32), {}, settings_with(false)};
  Scene& s = h.scene = random_scene(16, 61, h.cam, 4.0);
  set_row(s.rotations, 0, {0, 0, 0, 0});
  set_row(s.rotations, 1, {200.0, -150.0, 30.0, 80.0});
  set_row(s.rotations, 2, {1e-5, 2e-5, -1e-5, 3e-6});
  set_row(s.rotations, 3, {0, 0, 0, 3.0});
  return h;
}

inline HardCase opacity_case() {
  HardCase h{"opacity", make_camera(40, 32), {}, settings_with(true)};
  Scene& s = h.scene = random_scene(20, 71, h.cam, 4.0);
  s.opacities[0] = 0.f;
  s.opacities[1] = 0.9999f;
  s.opacities[2] = 1.f;
  s.opacities[3] = 1e-3f;  // below 1/255 everywhere
  return h;
}

/// Six large opaque layers over the image: alpha 0.95 each gives T = 0.05^3 = 1.25e-4 after
/// three, and the fourth would take it below 1e-4, so every pixel stops after three.
inline HardCase termination_case() {
  HardCase h{"termination", make_camera(32, 32), empty_scene(6), settings_with(true)};
  for (int i = 0; i < 6; ++i) {
    const Eigen::Vector3d p = world_at_pixel(h.cam, 16.3, 15.8, 2.0 + 0.5 * i);
    set_row(h.scene.means, i, {p.x(), p.y(), p.z()});
    set_row(h.scene.scales, i, {30.0, 30.0, 0.01});
    set_row(h.scene.colors, i, {0.2 * i, 1.0 - 0.15 * i, 0.5});
    h.scene.opacities[i] = 0.95f;
  }
  return h;
}

/// Means exactly on tile corners / edges in pixel coordinates.
inline HardCase tile_borders_case() {
  HardCase h{"tile borders", make_camera(64, 48), {}, settings_with(true)};
  h.scene = random_scene(12, 81, h.cam);
  const double px[][2] = {{16, 16}, {32, 16}, {48, 32}, {16, 40.5}, {0, 0}, {64, 48}};
  for (int i = 0; i < 6; ++i) {
    const Eigen::Vector3d p = world_at_pixel(h.cam, px[i][0], px[i][1], 3.0);
    set_row(h.scene.means, i, {p.x(), p.y(), p.z()});
  }
  return h;
}

inline std::vector<HardCase> odd_size_cases() {
  std::vector<HardCase> out;
  for (const auto& wh : {std::pair<int, int>{1, 1}, {17, 33}, {33, 17}, {15, 1}}) {
    HardCase h{std::to_string(wh.first) + "x" + std::to_string(wh.second),
               make_camera(wh.first, wh.second),
               {},
               settings_with(true)};
    h.scene = random_scene(20, 91, h.cam, 2.0);
    out.push_back(h);
  }
  return out;
}

inline HardCase empty_case() {
  return HardCase{"empty", make_camera(20, 12), empty_scene(0),
                  settings_with(true, {0.25f, 0.5f, 1.f})};
}

/// 3000 faint Gaussians around the same pixel: long per-pixel lists, late termination.
inline HardCase crowded_pixel_case() {
  HardCase h{"crowded pixel", make_camera(24, 20), {}, settings_with(true)};
  Scene& s = h.scene = random_scene(3000, 101, h.cam, 3.0);
  std::mt19937 rng(3);
  std::uniform_real_distribution<double> U(0, 1);
  auto o = s.opacities.accessor<float, 1>();
  for (int64_t i = 0; i < s.size(); ++i) {
    const Eigen::Vector3d p = world_at_pixel(h.cam, 11.5 + U(rng), 9.5 + U(rng), 2 + 3 * U(rng));
    set_row(s.means, i, {p.x(), p.y(), p.z()});
    o[i] = float(0.004 + 0.01 * U(rng));
  }
  return h;
}

/// Every hard case above.
inline std::vector<HardCase> hard_cases() {
  std::vector<HardCase> all = {near_plane_case(),
                               extreme_scales_case(),
                               degenerate_covariances_case(),
                               huge_needles_case(kNeedleLengths[4]),
                               huge_needles_case(kNeedleLengths[1]),
                               quaternions_case(),
                               opacity_case(),
                               termination_case(),
                               tile_borders_case(),
                               empty_case(),
                               crowded_pixel_case()};
  for (HardCase& h : odd_size_cases()) all.push_back(h);
  return all;
}

/// Random loss weights for image, alpha and depth.
struct Weights {
  at::Tensor image, alpha, depth;  // float64 [H,W,3], [H,W,1], [H,W,1]
};

inline Weights random_weights(int width, int height, uint32_t seed) {
  at::manual_seed(seed);
  Weights w;
  w.image = at::rand({height, width, 3}, at::kDouble) * 2 - 1;
  w.alpha = at::rand({height, width, 1}, at::kDouble) * 2 - 1;
  w.depth = (at::rand({height, width, 1}, at::kDouble) * 2 - 1) * 0.1;
  return w;
}

struct Grads {
  at::Tensor means, scales, rotations, opacities, colors, means2d;  // float64
};

struct RenderRun {
  RenderOutput out;  // float64
  Grads grads;
  double loss = 0;
};

inline at::Tensor loss_of(const RenderOutput& out, const Weights& w, bool depth) {
  const auto on = [&](const at::Tensor& t) { return t.to(out.image.device()); };  // CPU or CUDA
  at::Tensor l = (out.image.to(at::kDouble) * on(w.image)).sum() +
                 (out.alpha.to(at::kDouble) * on(w.alpha)).sum();
  if (depth) l = l + (out.depth.to(at::kDouble) * on(w.depth)).sum();
  return l;
}

/// Renders with the fast path (on `device`: the CPU stages with `threads`, or CUDA) or the
/// float64 reference and returns the outputs and the gradients of loss_of(), on the CPU.
inline RenderRun run(const Scene& s, const Camera& cam, const RenderSettings& st, const Weights& w,
                     bool reference, int threads = 1, torch::Device device = torch::kCPU) {
  const auto opt = at::TensorOptions(reference ? at::kDouble : at::kFloat).device(device);
  GaussianBatch g;
  g.means = s.means.to(opt).detach().requires_grad_(true);
  g.scales = s.scales.to(opt).detach().requires_grad_(true);
  g.rotations = s.rotations.to(opt).detach().requires_grad_(true);
  g.opacities = s.opacities.to(opt).detach().requires_grad_(true);
  g.colors = s.colors.to(opt).detach().requires_grad_(true);
  g.means2d_grad_holder = at::zeros({s.size(), 2}, opt).requires_grad_(true);
  RenderRun r;
  const RenderOutput out =
      reference ? reference::render(g, cam, st) : raster::render(g, cam, st, device, threads);
  const at::Tensor loss = loss_of(out, w, st.render_depth);
  r.loss = loss.item<double>();
  const std::vector<at::Tensor> leaves = {g.means,     g.scales, g.rotations,
                                          g.opacities, g.colors, g.means2d_grad_holder};
  std::vector<at::Tensor> gr = torch::autograd::grad({loss}, leaves, {}, false, false, true);
  for (size_t k = 0; k < gr.size(); ++k) {
    gr[k] = gr[k].defined() ? gr[k].to(at::kCPU, at::kDouble)
                            : at::zeros(leaves[k].sizes(), at::kDouble);
  }
  r.grads = {gr[0], gr[1], gr[2], gr[3], gr[4], gr[5]};
  r.out.image = out.image.detach().to(at::kCPU, at::kDouble);
  r.out.alpha = out.alpha.detach().to(at::kCPU, at::kDouble);
  if (st.render_depth) r.out.depth = out.depth.detach().to(at::kCPU, at::kDouble);
  r.out.radii = out.radii.cpu();
  return r;
}

inline bool all_finite(const at::Tensor& t) {
  return !t.defined() || t.numel() == 0 || at::isfinite(t).all().item<bool>();
}

inline double max_abs(const at::Tensor& t) {
  return t.numel() == 0 ? 0.0 : t.abs().max().item<double>();
}

inline void expect_finite(const RenderRun& r, const std::string& what) {
  EXPECT_TRUE(all_finite(r.out.image)) << what << ": image";
  EXPECT_TRUE(all_finite(r.out.alpha)) << what << ": alpha";
  EXPECT_TRUE(all_finite(r.out.depth)) << what << ": depth";
  for (const at::Tensor& g : {r.grads.means, r.grads.scales, r.grads.rotations, r.grads.opacities,
                              r.grads.colors, r.grads.means2d}) {
    EXPECT_TRUE(all_finite(g)) << what << ": gradient";
  }
}

/// Forward within 1e-5 (images in [0, 1]); depths compared as accumulated depth sum w_i z_i.
inline void expect_forward_close(const RenderRun& fast, const RenderRun& ref,
                                 const std::string& what, double tol = 1e-5) {
  ASSERT_EQ(fast.out.image.sizes(), ref.out.image.sizes()) << what;
  EXPECT_TRUE(at::equal(fast.out.radii, ref.out.radii)) << what << ": radii differ";
  EXPECT_LE(max_abs(fast.out.image - ref.out.image), tol) << what << ": image";
  EXPECT_LE(max_abs(fast.out.alpha - ref.out.alpha), tol) << what << ": alpha";
  if (ref.out.depth.defined()) {
    const double zmax = std::max(1.0, max_abs(ref.out.depth));
    EXPECT_LE(max_abs(fast.out.depth * fast.out.alpha - ref.out.depth * ref.out.alpha), tol * zmax)
        << what << ": depth";
  }
}

/// max |a - b| <= rel * max |b| (+ a floor for all-zero references).
inline void expect_grad_close(const at::Tensor& a, const at::Tensor& b, double rel,
                              const std::string& what) {
  const double scale = std::max(max_abs(b), 1e-8);
  EXPECT_LE(max_abs(a - b), rel * scale) << what << " (max |ref| = " << scale << ")";
}

inline void expect_grads_close(const Grads& a, const Grads& b, double rel,
                               const std::string& what) {
  expect_grad_close(a.means, b.means, rel, what + ": means");
  expect_grad_close(a.scales, b.scales, rel, what + ": scales");
  expect_grad_close(a.rotations, b.rotations, rel, what + ": rotations");
  expect_grad_close(a.opacities, b.opacities, rel, what + ": opacities");
  expect_grad_close(a.colors, b.colors, rel, what + ": colors");
  expect_grad_close(a.means2d, b.means2d, rel, what + ": means2d");
}

/// Renders both paths and checks finiteness, forward and all gradients.
inline void expect_matches_reference(const Scene& s, const Camera& cam, const RenderSettings& st,
                                     const std::string& what, uint32_t seed = 7) {
  const Weights w = random_weights(cam.width, cam.height, seed);
  const RenderRun fast = run(s, cam, st, w, false);
  const RenderRun ref = run(s, cam, st, w, true);
  expect_finite(fast, what + " (cpu)");
  expect_finite(ref, what + " (reference)");
  expect_forward_close(fast, ref, what);
  expect_grads_close(fast.grads, ref.grads, 1e-3, what);
}

}  // namespace crpgs::raster::test_util
