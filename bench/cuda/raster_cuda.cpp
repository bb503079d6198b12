// The CUDA rasterizer's speed against the CPU one on the same machine and scene (bench_raster's
// fern layout, fern_scene.h): forward and forward+backward at 504x378 and 1008x756 for 10k,
// 100k and 300k Gaussians. GPU times: median of --reps runs after warm-up, each synchronised
// (torch::cuda::synchronize) before the clock is read; CPU times: median of --cpu-reps runs on
// all cores. Then the GPU stages one by one (100k Gaussians), each synchronised. Prints two
// Markdown tables; results go by hand to bench/results/raster_cuda.md.
// Usage: bench_raster_cuda [--reps N] [--cpu-reps N] [--quick]
#include <algorithm>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <functional>
#include <vector>

#include <torch/cuda.h>
#include <torch/torch.h>

#include "fern_scene.h"
#include "raster/cuda/stages.h"
#include "raster/render.h"
#include "raster/stages.h"

namespace {

using crpgs::Camera;
using crpgs::GaussianBatch;
using crpgs::RenderOutput;
using crpgs::RenderSettings;
using clock_type = std::chrono::steady_clock;

// Median milliseconds of `reps` calls of f (after `warm` untimed ones).
double median_ms(int warm, int reps, bool cuda, const std::function<void()>& f) {
  for (int i = 0; i < warm; ++i) f();
  if (cuda) torch::cuda::synchronize();
  std::vector<double> t;
  for (int i = 0; i < reps; ++i) {
    const auto a = clock_type::now();
    f();
    if (cuda) torch::cuda::synchronize();
    t.push_back(std::chrono::duration<double, std::milli>(clock_type::now() - a).count());
  }
  std::sort(t.begin(), t.end());
  return t[t.size() / 2];
}

struct Times {
  double fwd, fwdbwd;
};

Times time_path(const GaussianBatch& scene, const Camera& cam, torch::Device d, int threads,
                int reps) {
  const bool cuda = d.is_cuda();
  const GaussianBatch plain = crpgs::bench::copy_to(scene, d, false);
  const GaussianBatch g = crpgs::bench::copy_to(scene, d, true);
  const at::Tensor target = at::rand({cam.height, cam.width, 3}).to(d);
  const RenderSettings st;
  const int warm = cuda ? 3 : 1;
  Times t{};
  t.fwd = median_ms(warm, reps, cuda, [&] {
    at::NoGradGuard no_grad;
    const RenderOutput out = crpgs::raster::render(plain, cam, st, d, threads);
    (void)out;
  });
  t.fwdbwd = median_ms(warm, reps, cuda, [&] {
    const RenderOutput out = crpgs::raster::render(g, cam, st, d, threads);
    (out.image - target).abs().mean().backward();
    for (const at::Tensor& p :
         {g.means, g.scales, g.rotations, g.opacities, g.colors, g.means2d_grad_holder}) {
      p.mutable_grad().reset();
    }
  });
  return t;
}

// Median ms of each GPU stage (forward, then the backward of an image gradient).
void print_stages(const GaussianBatch& scene, const Camera& cam, int reps) {
  namespace rc = crpgs::raster::cuda;
  const GaussianBatch g = crpgs::bench::copy_to(scene, torch::Device(torch::kCUDA, 0), false);
  const RenderSettings st;
  const at::Tensor v_img = at::rand({cam.height, cam.width, 3}).to(g.means.device());
  crpgs::raster::ProjectResult pr;
  crpgs::raster::TileIntersections is;
  crpgs::raster::RasterizeResult rr;
  crpgs::raster::RasterizeGrads rg;
  const double proj = median_ms(
      3, reps, true, [&] { pr = rc::project_forward(g.means, g.scales, g.rotations, cam, st); });
  const double isect = median_ms(3, reps, true, [&] {
    is = rc::intersect_tiles(pr.means2d, pr.radii, pr.depths, cam.width, cam.height, pr.conics,
                             g.opacities);
  });
  const double fwd = median_ms(3, reps, true, [&] {
    rr = rc::rasterize_forward(pr.means2d, pr.conics, g.opacities, g.colors, pr.depths, is,
                               cam.width, cam.height, st.background, false);
  });
  const double bwd = median_ms(3, reps, true, [&] {
    rg = rc::rasterize_backward(pr.means2d, pr.conics, g.opacities, g.colors, pr.depths, is, rr,
                                cam.width, cam.height, st.background, false, v_img, at::Tensor(),
                                at::Tensor());
  });
  const double pbwd = median_ms(3, reps, true, [&] {
    rc::project_backward(g.means, g.scales, g.rotations, cam, pr, rg.v_means2d, rg.v_conics,
                         rg.v_depths);
  });
  std::printf("| %dx%d | %lld | %.3f | %.3f | %.3f | %.3f | %.3f | %lld |\n", cam.width, cam.height,
              static_cast<long long>(scene.means.size(0)), proj, isect, fwd, bwd, pbwd,
              static_cast<long long>(is.gaussian_ids.numel()));
}

}  // namespace

int main(int argc, char** argv) {
  int reps = 50, cpu_reps = 5;
  bool quick = false;
  for (int i = 1; i < argc; ++i) {
    if (!std::strcmp(argv[i], "--reps") && i + 1 < argc)
      reps = std::atoi(argv[++i]);
    else if (!std::strcmp(argv[i], "--cpu-reps") && i + 1 < argc)
      cpu_reps = std::atoi(argv[++i]);
    else if (!std::strcmp(argv[i], "--quick"))
      quick = true;
  }
  if (!torch::cuda::is_available()) {
    std::printf("SKIPPED: libtorch sees no CUDA device\n");
    return 0;
  }
  const crpgs::bench::SfmModel& fern = crpgs::bench::fern_model();
  if (!fern.ok) {
    std::printf("SKIPPED: %s\n", fern.error.c_str());
    return 0;
  }
  const int threads = crpgs::raster::resolve_threads(0);
  at::set_num_threads(threads);
  std::printf(
      "| size | Gaussians | GPU fwd (ms) | GPU fwd+bwd (ms) | CPU fwd (ms, %d threads) | "
      "CPU fwd+bwd (ms) | speed-up fwd | speed-up fwd+bwd |\n|---|---:|---:|---:|---:|---:|"
      "---:|---:|\n",
      threads);
  for (int w : {504, 1008}) {
    for (int64_t n : {int64_t(10000), int64_t(100000), int64_t(300000)}) {
      if (quick && (w != 504 || n != 100000)) continue;
      const Camera cam = crpgs::bench::fern_camera(fern, w);
      const GaussianBatch scene = crpgs::bench::make_fern_scene(fern, n);
      const Times gpu = time_path(scene, cam, torch::Device(torch::kCUDA, 0), threads, reps);
      const Times cpu = time_path(scene, cam, torch::kCPU, threads, cpu_reps);
      std::printf("| %dx%d | %lld | %.3f | %.3f | %.1f | %.1f | %.0fx | %.0fx |\n", cam.width,
                  cam.height, static_cast<long long>(n), gpu.fwd, gpu.fwdbwd, cpu.fwd, cpu.fwdbwd,
                  cpu.fwd / gpu.fwd, cpu.fwdbwd / gpu.fwdbwd);
      std::fflush(stdout);
    }
  }
  std::printf(
      "\n| size | Gaussians | project (ms) | intersect (ms) | raster fwd (ms) | raster bwd "
      "(ms) | project bwd (ms) | tile entries |\n|---|---:|---:|---:|---:|---:|---:|---:|\n");
  for (int w : {504, 1008}) {
    if (quick && w != 504) continue;
    print_stages(crpgs::bench::make_fern_scene(fern, 100000), crpgs::bench::fern_camera(fern, w),
                 reps);
  }
  return 0;
}
