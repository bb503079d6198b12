// Benchmarks of the CPU rasterizer: forward and forward+backward at 504x378 and 1008x756 for
// 10k / 100k / 300k Gaussians laid out around fern's SfM points (a real scene's layout, seen
// from one of its training cameras), 1 vs 2 threads, and the float64 reference for the speed-up.
// glibc's allocator is set as training sets it (keep_freed_memory_in_heap). Results are recorded
// by hand in bench/results/raster.md.
#include <benchmark/benchmark.h>

#include <chrono>
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
#include "crpgs/runtime.h"
#include "raster/cpu_rasterizer.h"
#include "raster/reference.h"
#include "raster/stages.h"

namespace {

using crpgs::Camera;
using crpgs::GaussianBatch;

struct SfmModel {
  std::vector<Eigen::Vector3d> points, colors;
  Camera camera;  // the first image's camera at the dataset's full resolution
  bool ok = false;
  std::string error;
};

template <typename T>
T read_pod(std::ifstream& f) {
  T v{};
  f.read(reinterpret_cast<char*>(&v), sizeof(T));
  return v;
}

// Minimal COLMAP binary reader (cameras, the first image, points) for the benchmark scene.
SfmModel load_fern() {
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

const SfmModel& fern() {
  static const SfmModel m = [] {
    // As training sets it (setup_training): otherwise glibc maps and unmaps every large block
    // on each call, and the stage times measure this VM's page faults (raster.md, session 11).
    crpgs::keep_freed_memory_in_heap();
    return load_fern();
  }();
  return m;
}

// Mean distance of each SfM point to its 3 nearest neighbours (brute force, once).
std::vector<double> point_spacing(const SfmModel& m) {
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
GaussianBatch make_scene(int64_t n) {
  static std::map<int64_t, GaussianBatch> cache;
  auto it = cache.find(n);
  if (it != cache.end()) return it->second;
  const SfmModel& m = fern();
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

Camera bench_camera(int width) {
  const Camera& c = fern().camera;
  return c.resized(width, int(std::lround(double(c.height) * width / c.width)));
}

GaussianBatch with_grad(const GaussianBatch& s) {
  GaussianBatch g;
  g.means = s.means.clone().requires_grad_(true);
  g.scales = s.scales.clone().requires_grad_(true);
  g.rotations = s.rotations.clone().requires_grad_(true);
  g.opacities = s.opacities.clone().requires_grad_(true);
  g.colors = s.colors.clone().requires_grad_(true);
  g.means2d_grad_holder = at::zeros({s.means.size(0), 2}).requires_grad_(true);
  return g;
}

// Args: width, Gaussians, threads.
void BM_Forward(benchmark::State& state) {
  if (!fern().ok) {
    state.SkipWithError(fern().error.c_str());
    return;
  }
  const int threads = int(state.range(2));
  at::set_num_threads(threads);
  const Camera cam = bench_camera(int(state.range(0)));
  const GaussianBatch g = make_scene(state.range(1));
  crpgs::raster::CpuRasterizer rast(threads);
  int64_t visible = 0;
  for (auto _ : state) {
    at::NoGradGuard no_grad;
    const crpgs::RenderOutput out = rast.render(g, cam, crpgs::RenderSettings{});
    benchmark::DoNotOptimize(out.image.data_ptr<float>());
    visible = out.radii.gt(0).sum().item<int64_t>();
  }
  state.counters["visible"] = double(visible);
}

void BM_ForwardBackward(benchmark::State& state) {
  if (!fern().ok) {
    state.SkipWithError(fern().error.c_str());
    return;
  }
  const int threads = int(state.range(2));
  at::set_num_threads(threads);
  const Camera cam = bench_camera(int(state.range(0)));
  const GaussianBatch g = with_grad(make_scene(state.range(1)));
  crpgs::raster::CpuRasterizer rast(threads);
  const at::Tensor target = at::rand({cam.height, cam.width, 3});
  for (auto _ : state) {
    const crpgs::RenderOutput out = rast.render(g, cam, crpgs::RenderSettings{});
    const at::Tensor loss = (out.image - target).abs().mean();
    loss.backward();
    benchmark::DoNotOptimize(g.means.grad().data_ptr<float>());
    for (const at::Tensor& t :
         {g.means, g.scales, g.rotations, g.opacities, g.colors, g.means2d_grad_holder}) {
      t.mutable_grad().reset();
    }
  }
}

// The float64 reference, forward + backward, for the speed-up ratio (10k Gaussians only).
void BM_ReferenceForwardBackward(benchmark::State& state) {
  if (!fern().ok) {
    state.SkipWithError(fern().error.c_str());
    return;
  }
  at::set_num_threads(int(state.range(2)));
  const Camera cam = bench_camera(int(state.range(0)));
  const GaussianBatch g = with_grad(make_scene(state.range(1)));
  const at::Tensor target = at::rand({cam.height, cam.width, 3}, at::kDouble);
  for (auto _ : state) {
    const crpgs::RenderOutput out =
        crpgs::raster::reference::render(g, cam, crpgs::RenderSettings{});
    const at::Tensor loss = (out.image - target).abs().mean();
    loss.backward();
    for (const at::Tensor& t :
         {g.means, g.scales, g.rotations, g.opacities, g.colors, g.means2d_grad_holder}) {
      t.mutable_grad().reset();
    }
  }
}

// Forward stages timed one by one (ms per stage as counters), plus the tile-list length.
void BM_Stages(benchmark::State& state) {
  if (!fern().ok) {
    state.SkipWithError(fern().error.c_str());
    return;
  }
  namespace r = crpgs::raster;
  const int threads = int(state.range(2));
  at::set_num_threads(threads);
  const Camera cam = bench_camera(int(state.range(0)));
  const GaussianBatch g = make_scene(state.range(1));
  const crpgs::RenderSettings st;
  double t_proj = 0, t_isect = 0, t_fwd = 0, t_bwd = 0, t_pbwd = 0;
  int64_t entries = 0;
  using clock = std::chrono::steady_clock;
  auto ms = [](clock::time_point a, clock::time_point b) {
    return std::chrono::duration<double, std::milli>(b - a).count();
  };
  const at::Tensor v_img = at::rand({cam.height, cam.width, 3});
  for (auto _ : state) {
    const auto t0 = clock::now();
    const r::ProjectResult pr =
        r::project_forward(g.means, g.scales, g.rotations, cam, st, threads);
    const auto t1 = clock::now();
    const r::TileIntersections is = r::intersect_tiles(pr.means2d, pr.radii, pr.depths, cam.width,
                                                       cam.height, threads, pr.conics, g.opacities);
    const auto t2 = clock::now();
    const r::RasterizeResult rr =
        r::rasterize_forward(pr.means2d, pr.conics, g.opacities, g.colors, pr.depths, is, cam.width,
                             cam.height, st.background, false, threads);
    const auto t3 = clock::now();
    const r::RasterizeGrads rg = r::rasterize_backward(
        pr.means2d, pr.conics, g.opacities, g.colors, pr.depths, is, rr, cam.width, cam.height,
        st.background, false, v_img, at::Tensor(), at::Tensor(), threads);
    const auto t4 = clock::now();
    const r::ProjectGrads pg = r::project_backward(g.means, g.scales, g.rotations, cam, pr,
                                                   rg.v_means2d, rg.v_conics, rg.v_depths, threads);
    const auto t5 = clock::now();
    benchmark::DoNotOptimize(pg.v_means.data_ptr<float>());
    t_proj += ms(t0, t1);
    t_isect += ms(t1, t2);
    t_fwd += ms(t2, t3);
    t_bwd += ms(t3, t4);
    t_pbwd += ms(t4, t5);
    entries = is.gaussian_ids.numel();
  }
  const double n = double(state.iterations());
  state.counters["project_ms"] = t_proj / n;
  state.counters["isect_ms"] = t_isect / n;
  state.counters["raster_fwd_ms"] = t_fwd / n;
  state.counters["raster_bwd_ms"] = t_bwd / n;
  state.counters["project_bwd_ms"] = t_pbwd / n;
  state.counters["tile_entries"] = double(entries);
}

void sizes(benchmark::internal::Benchmark* b) {
  for (int64_t w : {504, 1008})
    for (int64_t n : {10000, 100000, 300000})
      for (int64_t t : {1, 2}) b->Args({w, n, t});
}

BENCHMARK(BM_Forward)->Apply(sizes)->Unit(benchmark::kMillisecond)->UseRealTime();
BENCHMARK(BM_ForwardBackward)->Apply(sizes)->Unit(benchmark::kMillisecond)->UseRealTime();
BENCHMARK(BM_Stages)->Apply(sizes)->Unit(benchmark::kMillisecond)->UseRealTime();
BENCHMARK(BM_ReferenceForwardBackward)
    ->Args({504, 10000, 2})
    ->Unit(benchmark::kMillisecond)
    ->UseRealTime()
    ->Iterations(1);

}  // namespace

// main(): bench/main/bench_main.cpp
