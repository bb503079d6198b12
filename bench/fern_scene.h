/// @file fern_scene.h
/// @brief The rasterizer benchmarks' scene (bench_raster, bench/cuda/raster_cuda.cpp): Gaussians
/// scattered around fern's SfM points (a real scene's layout), seen from its first camera.
/// Reads ../shared/data/fern (CRPGS_SHARED_DATA_DIR); SfmModel::ok is false when it is absent.
#pragma once

#include <cmath>
#include <cstdint>
#include <fstream>
#include <map>
#include <random>
#include <string>
#include <vector>

#include <torch/torch.h>
#include <Eigen/Geometry>

#include "crpgs/rasterizer.h"

namespace crpgs::bench {

struct SfmModel {
  std::vector<Eigen::Vector3d> points, colors;
  Camera camera;  // the first image's camera at the dataset's full resolution
  bool ok = false;
  std::string error;
};

template <typename T>
inline T read_pod(std::ifstream& f) {
  T v{};
  f.read(reinterpret_cast<char*>(&v), sizeof(T));
  return v;
}

// Minimal COLMAP binary reader (cameras, the first image, points) for the benchmark scene.
inline SfmModel load_fern() {
  SfmModel m;
  const std::string dir = std::string(CRPGS_SHARED_DATA_DIR) + "/fern/sparse/0/";
  std::ifstream cams(dir + "cameras.bin", std::ios::binary);
  std::ifstream imgs(dir + "images.bin", std::ios::binary);
  std::ifstream pts(dir + "points3D.bin", std::ios::binary);
  if (!cams || !imgs || !pts) {
    m.error = "fern's COLMAP model is not under " + dir;
    return m;
  }
  read_pod<uint64_t>(cams);
  read_pod<int32_t>(cams);
  const int32_t model = read_pod<int32_t>(cams);
  const uint64_t w = read_pod<uint64_t>(cams), h = read_pod<uint64_t>(cams);
  const double f = read_pod<double>(cams);
  double fy = f, cx, cy;
  if (model == 1 || model == 4) {  // PINHOLE / OPENCV: fx fy cx cy
    fy = read_pod<double>(cams);
  }
  cx = read_pod<double>(cams);
  cy = read_pod<double>(cams);
  m.camera.width = int(w);
  m.camera.height = int(h);
  m.camera.fx = f;
  m.camera.fy = fy;
  m.camera.cx = cx;
  m.camera.cy = cy;
  read_pod<uint64_t>(imgs);
  read_pod<uint32_t>(imgs);
  double q[4], t[3];
  for (double& v : q) v = read_pod<double>(imgs);
  for (double& v : t) v = read_pod<double>(imgs);
  m.camera.R = Eigen::Quaterniond(q[0], q[1], q[2], q[3]).normalized().toRotationMatrix();
  m.camera.t = Eigen::Vector3d(t[0], t[1], t[2]);
  const uint64_t n = read_pod<uint64_t>(pts);
  for (uint64_t i = 0; i < n && pts; ++i) {
    read_pod<uint64_t>(pts);
    Eigen::Vector3d p;
    for (int k = 0; k < 3; ++k) p[k] = read_pod<double>(pts);
    Eigen::Vector3d c;
    for (int k = 0; k < 3; ++k) c[k] = read_pod<uint8_t>(pts) / 255.0;
    read_pod<double>(pts);
    const uint64_t track = read_pod<uint64_t>(pts);
    pts.seekg(std::streamoff(track * 8), std::ios::cur);
    m.points.push_back(p);
    m.colors.push_back(c);
  }
  m.ok = pts.good() && m.points.size() == n && n > 100;
  if (!m.ok) m.error = "could not parse " + dir + "points3D.bin";
  return m;
}

/// fern's model, loaded once.
inline const SfmModel& fern_model() {
  static const SfmModel m = load_fern();
  return m;
}

// Mean distance of each SfM point to its 3 nearest neighbours (brute force, once).
inline std::vector<double> point_spacing(const SfmModel& m) {
  const size_t np = m.points.size();
  std::vector<double> spacing(np);
  for (size_t i = 0; i < np; ++i) {
    double best[3] = {1e30, 1e30, 1e30};
    for (size_t j = 0; j < np; ++j) {
      if (j == i) continue;
      const double d = (m.points[i] - m.points[j]).squaredNorm();
      if (d < best[2]) {
        best[2] = d;
        if (best[2] < best[1]) std::swap(best[1], best[2]);
        if (best[1] < best[0]) std::swap(best[0], best[1]);
      }
    }
    spacing[i] = (std::sqrt(best[0]) + std::sqrt(best[1]) + std::sqrt(best[2])) / 3;
  }
  return spacing;
}

// Gaussians scattered around the SfM points: spread and size follow the local point spacing
// (mean distance to the 3 nearest points), shrinking as more Gaussians share the same surface.
inline GaussianBatch make_fern_scene(const SfmModel& m, int64_t n) {
  static std::map<int64_t, GaussianBatch> cache;
  auto it = cache.find(n);
  if (it != cache.end()) return it->second;
  const size_t np = m.points.size();
  static std::vector<double> spacing;
  if (spacing.size() != np) spacing = point_spacing(m);
  std::mt19937 rng(1234);

  std::uniform_real_distribution<double> U(0, 1);
  std::normal_distribution<double> N(0, 1);
  const double shrink = std::cbrt(double(np) / double(n));
  GaussianBatch g;
  g.means = at::empty({n, 3});
  g.scales = at::empty({n, 3});
  g.rotations = at::empty({n, 4});
  g.opacities = at::empty({n});
  g.colors = at::empty({n, 3});
  auto me = g.means.accessor<float, 2>();
  auto sc = g.scales.accessor<float, 2>();
  auto ro = g.rotations.accessor<float, 2>();
  auto op = g.opacities.accessor<float, 1>();
  auto co = g.colors.accessor<float, 2>();
  for (int64_t i = 0; i < n; ++i) {
    const size_t j = size_t(rng() % np);
    const double s = spacing[j];
    for (int k = 0; k < 3; ++k) {
      me[i][k] = float(m.points[j][k] + N(rng) * s);
      sc[i][k] = float(0.5 * s * shrink * std::exp(0.5 * N(rng)));
      co[i][k] = float(std::min(1.0, std::max(0.0, m.colors[j][k] + 0.1 * N(rng))));
    }
    for (int k = 0; k < 4; ++k) ro[i][k] = float(N(rng));
    op[i] = float(0.1 + 0.85 * U(rng));
  }
  cache[n] = g;
  return g;
}

/// fern's first camera at `width` pixels (height to scale).
inline Camera fern_camera(const SfmModel& m, int width) {
  const Camera& c = m.camera;
  return c.resized(width, int(std::lround(double(c.height) * width / c.width)));
}

/// Copies on `device` (leaves that require a gradient when `grad`), and a means2d gradient
/// holder.
inline GaussianBatch copy_to(const GaussianBatch& s, torch::Device device, bool grad) {
  auto leaf = [&](const at::Tensor& t) {
    return t.to(device).detach().clone().requires_grad_(grad);
  };
  return GaussianBatch{leaf(s.means),     leaf(s.scales), leaf(s.rotations),
                       leaf(s.opacities), leaf(s.colors), leaf(at::zeros({s.means.size(0), 2}))};
}

inline GaussianBatch with_grad(const GaussianBatch& s) {
  return copy_to(s, torch::kCPU, true);
}

}  // namespace crpgs::bench
