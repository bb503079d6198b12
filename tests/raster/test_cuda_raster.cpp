/// @file test_cuda_raster.cpp
/// @brief The CUDA rasterizer against the CPU one: random and realistic scenes, every hard case
/// of test_raster.cpp, the stages on their own (identical tile lists) and the anchor prefilter.
/// Forward within 1e-4, gradients within 1e-3 of the largest CPU entry (relative). Runs where
/// libtorch sees a GPU; everywhere else each test prints why it skipped.
#include <gtest/gtest.h>

#include <cstdio>
#include <string>

#include "raster/raster_test_util.h"

#if CRPGS_BUILT_WITH_CUDA
#include <torch/cuda.h>

#include "raster/cuda/stages.h"
#include "raster/stages.h"
#endif

namespace crpgs::raster {
namespace {

using namespace crpgs::raster::test_util;

#if CRPGS_BUILT_WITH_CUDA

#define CRPGS_REQUIRE_GPU()                                                                     \
  if (!torch::cuda::is_available()) {                                                           \
    GTEST_SKIP() << "no CUDA device: libtorch sees none (CPU-only libtorch, no GPU or driver)"; \
  }

const torch::Device kGpu(torch::kCUDA, 0);

/// The largest |a - b| relative to the largest |b| (the form of expect_grad_close).
double rel_error(const at::Tensor& a, const at::Tensor& b) {
  return max_abs(a - b) / std::max(max_abs(b), 1e-8);
}

/// Renders on the GPU and on the CPU (all cores) and compares; prints the errors, which the
/// device run's record quotes.
void expect_gpu_matches_cpu(const Scene& s, const Camera& cam, const RenderSettings& st,
                            const std::string& what, bool gradients = true, uint32_t seed = 7) {
  const Weights w = random_weights(cam.width, cam.height, seed);
  const RenderRun cpu = run(s, cam, st, w, false, resolve_threads(0));
  const RenderRun gpu = run(s, cam, st, w, false, 1, kGpu);
  expect_finite(gpu, what + " (cuda)");
  expect_forward_close(gpu, cpu, what, 1e-4);
  double grad_err = 0;
  if (gradients) {
    expect_grads_close(gpu.grads, cpu.grads, 1e-3, what);
    for (const auto field : {&Grads::means, &Grads::scales, &Grads::rotations, &Grads::opacities,
                             &Grads::colors, &Grads::means2d}) {
      grad_err = std::max(grad_err, rel_error(gpu.grads.*field, cpu.grads.*field));
    }
  }
  std::printf(
      "[ parity ] %-28s N=%-7lld %4dx%-4d forward max|d| %.3g, image bit-equal %s, "
      "gradient max rel %.3g\n",
      what.c_str(), static_cast<long long>(s.size()), cam.width, cam.height,
      max_abs(gpu.out.image - cpu.out.image),
      at::equal(gpu.out.image, cpu.out.image) ? "yes" : "no", grad_err);
}

TEST(CudaRaster, RandomScenesMatchTheCpu) {
  CRPGS_REQUIRE_GPU();
  struct Case {
    int w, h, n;
    uint32_t seed;
    bool depth;
    double size_px;
  };
  for (const Case& c : {Case{48, 32, 40, 1, true, 3}, Case{37, 29, 60, 2, false, 3},
                        Case{70, 45, 120, 3, true, 3}, Case{16, 16, 25, 4, false, 3},
                        Case{256, 192, 5000, 5, true, 4}, Case{300, 200, 20000, 6, false, 8}}) {
    const Camera cam = make_camera(c.w, c.h);
    const Scene s = random_scene(c.n, c.seed, cam, c.size_px);
    expect_gpu_matches_cpu(s, cam, settings_with(c.depth), "random " + std::to_string(c.n), true,
                           c.seed + 1);
  }
}

// A realistic load: fern-sized image and Gaussian count, a few to tens of pixels each, many
// layers per pixel (the CPU benchmark's 100k-Gaussian scene gives ~2.4 entries per pixel).
TEST(CudaRaster, RealisticSceneMatchesTheCpu) {
  CRPGS_REQUIRE_GPU();
  const Camera cam = make_camera(504, 378);
  const Scene s = random_scene(150000, 17, cam, 6.0);
  expect_gpu_matches_cpu(s, cam, settings_with(true), "realistic 504x378");
}

TEST(CudaRaster, EveryHardCaseMatchesTheCpu) {
  CRPGS_REQUIRE_GPU();
  for (const HardCase& h : hard_cases())
    expect_gpu_matches_cpu(h.scene, h.cam, h.settings, h.name, h.gradients);
}

TEST(CudaRaster, StagesGiveTheCpuTileListsAndTermination) {
  CRPGS_REQUIRE_GPU();
  const RenderSettings st = settings_with(true);
  for (const HardCase& h : {termination_case(), tile_borders_case(), crowded_pixel_case(),
                            HardCase{"random", make_camera(100, 70),
                                     random_scene(300, 121, make_camera(100, 70)), st}}) {
    const Scene& s = h.scene;
    const Camera& cam = h.cam;
    const ProjectResult pc = project_forward(s.means, s.scales, s.rotations, cam, st, 1);
    const ProjectResult pg =
        cuda::project_forward(s.means.to(kGpu), s.scales.to(kGpu), s.rotations.to(kGpu), cam, st);
    EXPECT_TRUE(at::equal(pc.radii, pg.radii.cpu())) << h.name;
    EXPECT_LE(max_abs(pc.means2d - pg.means2d.cpu()), 1e-4) << h.name;
    EXPECT_LE(rel_error(pg.conics.cpu(), pc.conics), 1e-6) << h.name;
    // Tile lists from the GPU's own projection, with and without the alpha boxes.
    for (bool boxes : {false, true}) {
      const at::Tensor op = s.opacities;
      const TileIntersections ic =
          boxes ? intersect_tiles(pg.means2d.cpu(), pg.radii.cpu(), pg.depths.cpu(), cam.width,
                                  cam.height, 1, pg.conics.cpu(), op)
                : intersect_tiles(pg.means2d.cpu(), pg.radii.cpu(), pg.depths.cpu(), cam.width,
                                  cam.height, 1);
      const TileIntersections ig =
          boxes ? cuda::intersect_tiles(pg.means2d, pg.radii, pg.depths, cam.width, cam.height,
                                        pg.conics, op.to(kGpu))
                : cuda::intersect_tiles(pg.means2d, pg.radii, pg.depths, cam.width, cam.height);
      EXPECT_EQ(ic.tiles_x, ig.tiles_x);
      EXPECT_TRUE(at::equal(ic.tile_offsets, ig.tile_offsets.cpu())) << h.name << " " << boxes;
      EXPECT_TRUE(at::equal(ic.gaussian_ids, ig.gaussian_ids.cpu())) << h.name << " " << boxes;
    }
  }
  // The termination case through the GPU stages: the centre stops after three layers.
  const HardCase h = termination_case();
  const Scene& s = h.scene;
  const ProjectResult pr =
      cuda::project_forward(s.means.to(kGpu), s.scales.to(kGpu), s.rotations.to(kGpu), h.cam, st);
  const TileIntersections is = cuda::intersect_tiles(pr.means2d, pr.radii, pr.depths, 32, 32);
  const RasterizeResult rr =
      cuda::rasterize_forward(pr.means2d, pr.conics, s.opacities.to(kGpu), s.colors.to(kGpu),
                              pr.depths, is, 32, 32, st.background, true);
  EXPECT_EQ(rr.last_contrib[15][16].item<int>(), 3);
  const float T = rr.final_T[15][16].item<float>();
  EXPECT_GT(T, kMinTransmittance);
  EXPECT_LT(T, 1.3e-4f);
}

TEST(CudaRaster, VisibleAnchorsMatchTheCpu) {
  CRPGS_REQUIRE_GPU();
  const Camera cam = make_camera(64, 48);
  Scene s = random_scene(2000, 141, cam, 8.0);
  // Every third anchor behind the camera, every fifth far beside the image: both culled.
  for (int64_t i = 0; i < s.size(); i += 3) {
    const Eigen::Vector3d p = world_at_pixel(cam, 30, 20, -2.0);
    set_row(s.means, i, {p.x(), p.y(), p.z()});
  }
  for (int64_t i = 1; i < s.size(); i += 5) {
    const Eigen::Vector3d p = world_at_pixel(cam, 40 * cam.width, 20, 3.0);
    set_row(s.means, i, {p.x(), p.y(), p.z()});
  }
  const RenderSettings st;
  const at::Tensor vc = visible_anchors(s.means, s.scales, cam, st, 1);
  const at::Tensor vg = cuda::visible_anchors(s.means.to(kGpu), s.scales.to(kGpu), cam, st);
  EXPECT_TRUE(at::equal(vc, vg.cpu()));
  EXPECT_GT(vc.sum().item<int64_t>(), 500);  // at most 1,066 are left in the frustum
  EXPECT_LT(vc.sum().item<int64_t>(), 1500);
}

// A model kept on the CPU rendering on the GPU (what the `cuda` component does): outputs come
// back to the CPU, bit-equal to the CPU rasterizer's, and gradients reach the CPU leaves.
TEST(CudaRaster, BridgesGaussiansKeptOnTheCpu) {
  CRPGS_REQUIRE_GPU();
  const Camera cam = make_camera(120, 90);
  const Scene s = random_scene(800, 151, cam, 5.0);
  const RenderSettings st = settings_with(true);
  const Weights w = random_weights(cam.width, cam.height, 152);
  auto leaves = [&] {
    GaussianBatch g{s.means.clone(),     s.scales.clone(), s.rotations.clone(),
                    s.opacities.clone(), s.colors.clone(), at::zeros({s.size(), 2})};
    for (at::Tensor* t :
         {&g.means, &g.scales, &g.rotations, &g.opacities, &g.colors, &g.means2d_grad_holder})
      t->requires_grad_(true);
    return g;
  };
  const GaussianBatch on_cpu = leaves(), bridged = leaves();
  const RenderOutput a = render(on_cpu, cam, st, torch::kCPU, resolve_threads(0));
  const RenderOutput b = render_bridged(bridged, cam, st, kGpu, 1);
  ASSERT_TRUE(b.image.device().is_cpu());
  ASSERT_TRUE(b.radii.device().is_cpu());
  EXPECT_TRUE(at::equal(a.image, b.image));
  EXPECT_TRUE(at::equal(a.alpha, b.alpha));
  EXPECT_TRUE(at::equal(a.radii, b.radii));
  loss_of(a, w, true).backward();
  loss_of(b, w, true).backward();
  for (const auto field :
       {&GaussianBatch::means, &GaussianBatch::scales, &GaussianBatch::rotations,
        &GaussianBatch::opacities, &GaussianBatch::colors, &GaussianBatch::means2d_grad_holder}) {
    const at::Tensor& ga = (on_cpu.*field).grad();
    const at::Tensor& gb = (bridged.*field).grad();
    ASSERT_TRUE(gb.defined() && gb.device().is_cpu());
    EXPECT_GT(max_abs(ga), 0.0);
    EXPECT_LE(rel_error(gb, ga), 1e-3);
  }
}

TEST(CudaRaster, RejectsCpuTensors) {
  CRPGS_REQUIRE_GPU();
  const Camera cam = make_camera(16, 16);
  const Scene s = random_scene(4, 1, cam);
  GaussianBatch g{s.means, s.scales, s.rotations, s.opacities, s.colors, {}};
  try {
    render(g, cam, RenderSettings{}, kGpu, 1);
    ADD_FAILURE() << "CPU tensors were accepted";
  } catch (const c10::Error& e) {
    EXPECT_NE(std::string(e.what()).find("cuda rasterizer: means must be on cuda"),
              std::string::npos)
        << e.what();
  }
}

#else

TEST(CudaRaster, Skipped) {
  GTEST_SKIP() << "built without the CUDA rasterizer (CRPGS_CUDA_ENABLED is off: no nvcc or no "
                  "CUDA libtorch; docs/developing.md, 'CUDA')";
}

#endif

}  // namespace
}  // namespace crpgs::raster
