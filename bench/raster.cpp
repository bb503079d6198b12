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
#include "fern_scene.h"
#include "raster/cpu_rasterizer.h"
#include "raster/reference.h"
#include "raster/stages.h"

namespace {

using crpgs::Camera;
using crpgs::GaussianBatch;
using namespace crpgs::bench;

const SfmModel& fern() {
  static const SfmModel& m = [] {
    // As training sets it (setup_training): otherwise glibc maps and unmaps every large block
    // on each call, and the stage times measure this VM's page faults (raster.md, session 11).
    crpgs::keep_freed_memory_in_heap();
    return std::cref(fern_model());
  }();
  return m;
}

GaussianBatch make_scene(int64_t n) {
  return make_fern_scene(fern(), n);
}

Camera bench_camera(int width) {
  return fern_camera(fern(), width);
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
