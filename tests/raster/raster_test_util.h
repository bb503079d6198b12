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
#include "raster/cpu_rasterizer.h"
#include "raster/reference.h"

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
  at::Tensor l =
      (out.image.to(at::kDouble) * w.image).sum() + (out.alpha.to(at::kDouble) * w.alpha).sum();
  if (depth) l = l + (out.depth.to(at::kDouble) * w.depth).sum();
  return l;
}

/// Renders with the fast path (threads as given) or the float64 reference and returns the
/// outputs and the gradients of loss_of().
inline RenderRun run(const Scene& s, const Camera& cam, const RenderSettings& st, const Weights& w,
                     bool reference, int threads = 1) {
  const auto dt = reference ? at::kDouble : at::kFloat;
  GaussianBatch g;
  g.means = s.means.to(dt).detach().requires_grad_(true);
  g.scales = s.scales.to(dt).detach().requires_grad_(true);
  g.rotations = s.rotations.to(dt).detach().requires_grad_(true);
  g.opacities = s.opacities.to(dt).detach().requires_grad_(true);
  g.colors = s.colors.to(dt).detach().requires_grad_(true);
  g.means2d_grad_holder = at::zeros({s.size(), 2}, dt).requires_grad_(true);
  RenderRun r;
  RenderOutput out;
  if (reference) {
    out = reference::render(g, cam, st);
  } else {
    CpuRasterizer rast(threads);
    out = rast.render(g, cam, st);
  }
  const at::Tensor loss = loss_of(out, w, st.render_depth);
  r.loss = loss.item<double>();
  const std::vector<at::Tensor> leaves = {g.means,     g.scales, g.rotations,
                                          g.opacities, g.colors, g.means2d_grad_holder};
  std::vector<at::Tensor> gr = torch::autograd::grad({loss}, leaves, {}, false, false, true);
  for (size_t k = 0; k < gr.size(); ++k) {
    gr[k] = gr[k].defined() ? gr[k].to(at::kDouble) : at::zeros_like(leaves[k], at::kDouble);
  }
  r.grads = {gr[0], gr[1], gr[2], gr[3], gr[4], gr[5]};
  r.out.image = out.image.detach().to(at::kDouble);
  r.out.alpha = out.alpha.detach().to(at::kDouble);
  if (st.render_depth) r.out.depth = out.depth.detach().to(at::kDouble);
  r.out.radii = out.radii;
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
