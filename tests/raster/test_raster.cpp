/// @file test_raster.cpp
/// @brief The CPU rasterizer against its float64 reference and finite differences: forward,
/// every gradient, the numerical edge cases, thread-count determinism, the stages on their own,
/// the anchor prefilter and the component's descriptor.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <limits>
#include <random>
#include <vector>

#include "crpgs/schema.h"
#include "raster/cpu_rasterizer.h"
#include "raster/raster_test_util.h"
#include "raster/stages.h"

namespace crpgs::raster {
namespace {

using namespace crpgs::raster::test_util;

// ---- Correctness on random scenes -------------------------------------------------------

struct SceneCase {
  int width, height, n;
  uint32_t seed;
  bool depth;
  friend std::ostream& operator<<(std::ostream& os, const SceneCase& c) {
    return os << c.width << "x" << c.height << "_n" << c.n << "_s" << c.seed
              << (c.depth ? "_depth" : "");
  }
};

class RandomScene : public ::testing::TestWithParam<SceneCase> {};

TEST_P(RandomScene, ForwardAndGradientsMatchReference) {
  const SceneCase c = GetParam();
  const Camera cam = make_camera(c.width, c.height);
  const Scene s = random_scene(c.n, c.seed, cam);
  const RenderSettings st = settings_with(c.depth);
  const Weights w = random_weights(c.width, c.height, c.seed + 1);
  const RenderRun fast = run(s, cam, st, w, false);
  const RenderRun ref = run(s, cam, st, w, true);
  expect_finite(fast, "cpu");
  expect_forward_close(fast, ref, "random scene");
  expect_grads_close(fast.grads, ref.grads, 1e-3, "random scene");
  // The scene must actually draw something and move every parameter.
  EXPECT_GT(max_abs(ref.out.alpha), 0.5);
  EXPECT_GT(ref.out.radii.gt(0).sum().item<int64_t>(), c.n / 3);
  for (const at::Tensor& g : {ref.grads.means, ref.grads.scales, ref.grads.rotations,
                              ref.grads.opacities, ref.grads.colors, ref.grads.means2d}) {
    EXPECT_GT(max_abs(g), 1e-6);
  }
}

INSTANTIATE_TEST_SUITE_P(Raster, RandomScene,
                         ::testing::Values(SceneCase{48, 32, 40, 1, true},
                                           SceneCase{37, 29, 60, 2, false},
                                           SceneCase{70, 45, 120, 3, true},
                                           SceneCase{16, 16, 25, 4, false}));

// Central differences of the float64 reference's loss: checks both the reference's autograd
// (tight) and the CPU rasterizer's analytic gradients (1e-3 of the tensor's largest entry).
TEST(RasterGradients, MatchCentralFiniteDifferences) {
  const Camera cam = make_camera(40, 30);
  const Scene s = random_scene(30, 11, cam, 4.0);
  const RenderSettings st = settings_with(true);
  const Weights w = random_weights(cam.width, cam.height, 12);
  const RenderRun fast = run(s, cam, st, w, false);
  const RenderRun ref = run(s, cam, st, w, true);
  auto loss_at = [&](const Scene& sc) {
    GaussianBatch g;
    g.means = sc.means.to(at::kDouble);
    g.scales = sc.scales.to(at::kDouble);
    g.rotations = sc.rotations.to(at::kDouble);
    g.opacities = sc.opacities.to(at::kDouble);
    g.colors = sc.colors.to(at::kDouble);
    return loss_of(reference::render(g, cam, st), w, true).item<double>();
  };
  // Perturb float64 copies of the parameters (the scene's tensors are float32).
  Scene sd;
  sd.means = s.means.to(at::kDouble);
  sd.scales = s.scales.to(at::kDouble);
  sd.rotations = s.rotations.to(at::kDouble);
  sd.opacities = s.opacities.to(at::kDouble);
  sd.colors = s.colors.to(at::kDouble);
  struct Param {
    const char* name;
    at::Tensor Scene::*field;
    at::Tensor Grads::*grad;
  };
  const Param params[] = {{"means", &Scene::means, &Grads::means},
                          {"scales", &Scene::scales, &Grads::scales},
                          {"rotations", &Scene::rotations, &Grads::rotations},
                          {"opacities", &Scene::opacities, &Grads::opacities},
                          {"colors", &Scene::colors, &Grads::colors}};
  const at::Tensor visible = ref.out.radii.gt(0).nonzero().flatten();
  ASSERT_GT(visible.numel(), 10);
  std::mt19937 rng(5);
  int checked = 0;
  for (const Param& p : params) {
    const at::Tensor g_ref = (ref.grads.*p.grad).reshape({-1});
    const at::Tensor g_fast = (fast.grads.*p.grad).reshape({-1});
    const int64_t per = (sd.*p.field).numel() / sd.size();
    const double scale = std::max(max_abs(g_ref), 1e-8);
    for (int trial = 0; trial < 8; ++trial) {
      const int64_t gi = visible[int64_t(rng() % visible.numel())].item<int64_t>();
      const int64_t flat = gi * per + int64_t(rng() % per);
      const double h = 1e-7;
      Scene plus = sd, minus = sd;
      plus.*p.field = (sd.*p.field).clone();
      minus.*p.field = (sd.*p.field).clone();
      (plus.*p.field).view({-1})[flat] += h;
      (minus.*p.field).view({-1})[flat] -= h;
      const double fd = (loss_at(plus) - loss_at(minus)) / (2 * h);
      const double gr = g_ref[flat].item<double>(), gf = g_fast[flat].item<double>();
      EXPECT_NEAR(gr, fd, 1e-5 * scale + 1e-6 * std::abs(fd)) << p.name << "[" << flat << "]";
      EXPECT_NEAR(gf, fd, 1e-3 * scale) << p.name << "[" << flat << "]";
      ++checked;
    }
  }
  EXPECT_EQ(checked, 40);
}

TEST(RasterThreads, OneAndTwoThreadsGiveIdenticalResults) {
  const Camera cam = make_camera(200, 150);
  const Scene s = random_scene(3000, 21, cam, 5.0);
  const RenderSettings st = settings_with(true);
  const Weights w = random_weights(cam.width, cam.height, 22);
  const RenderRun one = run(s, cam, st, w, false, 1);
  const RenderRun two = run(s, cam, st, w, false, 2);
  EXPECT_TRUE(at::equal(one.out.image, two.out.image));
  EXPECT_TRUE(at::equal(one.out.alpha, two.out.alpha));
  EXPECT_TRUE(at::equal(one.out.depth, two.out.depth));
  EXPECT_TRUE(at::equal(one.out.radii, two.out.radii));
  EXPECT_TRUE(at::equal(one.grads.means, two.grads.means));
  EXPECT_TRUE(at::equal(one.grads.scales, two.grads.scales));
  EXPECT_TRUE(at::equal(one.grads.rotations, two.grads.rotations));
  EXPECT_TRUE(at::equal(one.grads.opacities, two.grads.opacities));
  EXPECT_TRUE(at::equal(one.grads.colors, two.grads.colors));
  EXPECT_TRUE(at::equal(one.grads.means2d, two.grads.means2d));
  EXPECT_GT(max_abs(one.grads.means), 0.0);
}

// ---- Numerical edge cases (each also against the reference) ----------------------------

TEST(RasterStability, BehindCameraAndStraddlingNearPlane) {
  const HardCase h = near_plane_case();
  const Weights wt = random_weights(h.cam.width, h.cam.height, 3);
  const RenderRun fast = run(h.scene, h.cam, h.settings, wt, false);
  EXPECT_EQ(fast.out.radii[0].item<int>(), 0);
  EXPECT_EQ(fast.out.radii[1].item<int>(), 0);
  EXPECT_GT(fast.out.radii[2].item<int>(), 0);
  EXPECT_EQ(fast.out.radii[3].item<int>(), 0);
  EXPECT_GT(fast.out.radii[4].item<int>(), 0);
  EXPECT_EQ(max_abs(fast.grads.means[0]), 0.0);
  expect_matches_reference(h.scene, h.cam, h.settings, h.name);
}

TEST(RasterStability, ExtremelySmallAndLargeScales) {
  const HardCase h = extreme_scales_case();
  expect_matches_reference(h.scene, h.cam, h.settings, h.name);
}

TEST(RasterStability, NearSingularAndDegenerate2DCovariances) {
  const HardCase h = degenerate_covariances_case();
  expect_matches_reference(h.scene, h.cam, h.settings, h.name);
}

TEST(RasterStability, HugeNeedlesAcrossTheImageKeepAnAccurateConic) {
  // The 2D covariance is 0.3·I + σ²·w·wᵀ, so its inverse's largest eigenvalue is 1/0.3 whatever
  // σ (and never more for any Gaussian). c00·c11 − c01² loses that to cancellation from
  // σ² ≈ 1e14.
  const HardCase h = huge_needles_case(kNeedleLengths[4]);
  const Scene& s = h.scene;
  const ProjectResult pr = project_forward(s.means, s.scales, s.rotations, h.cam, h.settings, 2);
  auto con = pr.conics.accessor<float, 2>();
  auto rad = pr.radii.accessor<int32_t, 1>();
  const double bound = 1.0 / 0.3;
  for (int64_t i = 0; i < s.size(); ++i) {
    ASSERT_GT(rad[i], 0) << "gaussian " << i;
    const double a = con[i][0], b = con[i][1], c = con[i][2];
    const double lmax = 0.5 * (a + c) + std::hypot(0.5 * (a - c), b);
    EXPECT_GT(a, 0.0) << "gaussian " << i;
    EXPECT_GT(c, 0.0) << "gaussian " << i;
    if (i < 5) {
      EXPECT_NEAR(lmax / bound, 1.0, 1e-5) << "needle " << i << " of length " << kNeedleLengths[i];
    } else {
      EXPECT_LE(lmax, bound * (1 + 1e-5)) << "gaussian " << i;
    }
  }
  // The render matches the reference for every length. Gradients through the conic cancel
  // terms of size σ² in double, on both sides, so they are compared up to σ ≈ 1e6 px.
  const Weights wt = random_weights(h.cam.width, h.cam.height, 5);
  const RenderRun fast = run(s, h.cam, h.settings, wt, false);
  const RenderRun ref = run(s, h.cam, h.settings, wt, true);
  expect_finite(fast, h.name);
  expect_forward_close(fast, ref, h.name);
  const HardCase capped = huge_needles_case(kNeedleLengths[1]);
  expect_matches_reference(capped.scene, capped.cam, capped.settings, capped.name);
}

TEST(RasterStability, UnnormalisedAndZeroQuaternions) {
  const HardCase h = quaternions_case();
  expect_matches_reference(h.scene, h.cam, h.settings, h.name);
  const RenderRun fast = run(h.scene, h.cam, h.settings, random_weights(40, 32, 1), false);
  // The zero quaternion renders as the identity and gets no rotation gradient.
  EXPECT_GT(fast.out.radii[0].item<int>(), 0);
  EXPECT_EQ(max_abs(fast.grads.rotations[0]), 0.0);
}

TEST(RasterStability, OpacityZeroAndNearOne) {
  const HardCase h = opacity_case();
  expect_matches_reference(h.scene, h.cam, h.settings, h.name);
  const RenderRun fast = run(h.scene, h.cam, h.settings, random_weights(40, 32, 2), false);
  EXPECT_EQ(max_abs(fast.grads.colors[0]), 0.0);
  EXPECT_EQ(max_abs(fast.grads.colors[3]), 0.0);
}

TEST(RasterStability, TransmittanceReachesTerminationThreshold) {
  const HardCase h = termination_case();
  const Scene& s = h.scene;
  const RenderSettings& st = h.settings;
  expect_matches_reference(s, h.cam, st, h.name);
  // Through the stages: last contributor and final transmittance at the centre.
  const ProjectResult pr = project_forward(s.means, s.scales, s.rotations, h.cam, st, 1);
  const TileIntersections is = intersect_tiles(pr.means2d, pr.radii, pr.depths, 32, 32, 1);
  const RasterizeResult rr = rasterize_forward(pr.means2d, pr.conics, s.opacities, s.colors,
                                               pr.depths, is, 32, 32, st.background, true, 1);
  const int64_t tile = (15 / kTileSize) * is.tiles_x + 16 / kTileSize;
  EXPECT_EQ(is.tile_offsets[tile + 1].item<int>() - is.tile_offsets[tile].item<int>(), 6);
  EXPECT_EQ(rr.last_contrib[15][16].item<int>(), 3);
  const float T = rr.final_T[15][16].item<float>();
  EXPECT_GT(T, kMinTransmittance);
  EXPECT_LT(T, 1.3e-4f);
}

TEST(RasterStability, GaussiansExactlyOnTileBorders) {
  const HardCase h = tile_borders_case();
  expect_matches_reference(h.scene, h.cam, h.settings, h.name);
}

TEST(RasterStability, OnePixelAndOddImageSizes) {
  for (const HardCase& h : odd_size_cases())
    expect_matches_reference(h.scene, h.cam, h.settings, h.name);
}

TEST(RasterStability, EmptySetOfGaussians) {
  const HardCase h = empty_case();
  const RenderRun fast = run(h.scene, h.cam, h.settings, random_weights(20, 12, 4), false);
  EXPECT_EQ(fast.out.image.sizes(), (std::vector<int64_t>{12, 20, 3}));
  EXPECT_EQ(max_abs(fast.out.image.select(2, 0) - 0.25), 0.0);
  EXPECT_EQ(max_abs(fast.out.image.select(2, 2) - 1.0), 0.0);
  EXPECT_EQ(max_abs(fast.out.alpha), 0.0);
  EXPECT_EQ(max_abs(fast.out.depth), 0.0);
  EXPECT_EQ(fast.grads.means.sizes(), (std::vector<int64_t>{0, 3}));
  expect_finite(fast, h.name);
}

TEST(RasterStability, ThousandsOfGaussiansOnOnePixel) {
  const HardCase h = crowded_pixel_case();
  expect_matches_reference(h.scene, h.cam, h.settings, h.name);
}

// ---- Stages on their own --------------------------------------------------------------

TEST(RasterStages, ProjectMatchesReference) {
  const Camera cam = make_camera(64, 48);
  const Scene s = random_scene(200, 111, cam);
  const RenderSettings st = settings_with(false);
  const ProjectResult pr = project_forward(s.means, s.scales, s.rotations, cam, st, 2);
  const reference::Projection ref = reference::project(
      s.means.to(at::kDouble), s.scales.to(at::kDouble), s.rotations.to(at::kDouble), cam, st);
  EXPECT_TRUE(at::equal(pr.radii, ref.radii));
  const at::Tensor vis = pr.radii.gt(0).unsqueeze(1).to(at::kDouble);
  EXPECT_LE(max_abs((pr.means2d.to(at::kDouble) - ref.means2d) * vis), 1e-4);
  EXPECT_LE(max_abs((pr.conics.to(at::kDouble) - ref.conics) * vis) / max_abs(ref.conics), 1e-6);
  EXPECT_LE(max_abs((pr.depths.to(at::kDouble) - ref.depths) * vis.squeeze(1)), 1e-5);
}

TEST(RasterStages, IntersectListsEveryOverlapSortedByDepth) {
  const Camera cam = make_camera(100, 70);
  const Scene s = random_scene(300, 121, cam);
  const ProjectResult pr =
      project_forward(s.means, s.scales, s.rotations, cam, settings_with(false), 2);
  const TileIntersections is = intersect_tiles(pr.means2d, pr.radii, pr.depths, 100, 70, 2);
  ASSERT_EQ(is.tiles_x, 7);
  ASSERT_EQ(is.tiles_y, 5);
  auto off = is.tile_offsets.accessor<int32_t, 1>();
  auto ids = is.gaussian_ids.accessor<int32_t, 1>();
  auto dep = pr.depths.accessor<float, 1>();
  auto m2 = pr.means2d.accessor<float, 2>();
  auto rad = pr.radii.accessor<int32_t, 1>();
  int64_t expected_total = 0;
  for (int64_t i = 0; i < s.size(); ++i) {
    if (rad[i] <= 0) continue;
    const TileRect r = tile_rect(m2[i][0], m2[i][1], rad[i], is.tiles_x, is.tiles_y);
    expected_total += int64_t(r.x1 - r.x0) * (r.y1 - r.y0);
    for (int ty = r.y0; ty < r.y1; ++ty) {
      for (int tx = r.x0; tx < r.x1; ++tx) {
        const int t = ty * is.tiles_x + tx;
        bool found = false;
        for (int k = off[t]; k < off[t + 1]; ++k) found = found || ids[k] == i;
        EXPECT_TRUE(found) << "gaussian " << i << " missing from tile " << t;
      }
    }
  }
  EXPECT_EQ(is.gaussian_ids.numel(), expected_total);
  for (int t = 0; t < is.tiles_x * is.tiles_y; ++t) {
    for (int k = off[t] + 1; k < off[t + 1]; ++k) {
      const bool ordered =
          dep[ids[k - 1]] < dep[ids[k]] || (dep[ids[k - 1]] == dep[ids[k]] && ids[k - 1] < ids[k]);
      EXPECT_TRUE(ordered) << "tile " << t << " entry " << k;
    }
  }
}

TEST(RasterStages, TileRectIsTheClampedFloorOfTheBox) {
  // The tiles [floor((m - r) / 16), floor((m + r + 15) / 16)) clamped to the grid, for means on
  // and beside tile borders, off-image on either side, far away, and not finite.
  auto expect = [](double v, int hi) {
    return int(std::min<double>(hi, std::max(0.0, std::floor(v))));
  };
  const float inf = std::numeric_limits<float>::infinity();
  const std::vector<float> means{-1e30f, -100.f, -16.5f, -16.f,  -0.5f,        -0.f, 0.f,
                                 0.49f,  15.99f, 16.f,   16.01f, 47.5f,        63.f, 64.f,
                                 80.5f,  1e30f,  inf,    -inf,   std::nanf("")};
  for (float m : means) {
    for (int r : {0, 1, 3, 16, 17, 1000}) {
      const TileRect t = tile_rect(m, m * 0.5f, r, 4, 3);
      EXPECT_EQ(t.x0, expect((double(m) - r) / 16, 4)) << m << " r " << r;
      EXPECT_EQ(t.x1, expect((double(m) + r + 15) / 16, 4)) << m << " r " << r;
      EXPECT_EQ(t.y0, expect((double(m * 0.5f) - r) / 16, 3)) << m << " r " << r;
      EXPECT_EQ(t.y1, expect((double(m * 0.5f) + r + 15) / 16, 3)) << m << " r " << r;
    }
  }
}

// Enough Gaussians that the fill runs in two ranges, many equal depths (ties go by index),
// negative and zero depths, and culled ones: every tile's list equals a sort by (depth, index).
TEST(RasterStages, IntersectOrderHoldsForTiesNegativeDepthsAndTwoRanges) {
  constexpr int64_t n = 20000;
  constexpr int W = 96, H = 64;
  std::mt19937 rng(7);
  std::uniform_real_distribution<float> U(0.f, 1.f);
  at::Tensor m2 = at::empty({n, 2}), dep = at::empty({n});
  at::Tensor rad = at::empty({n}, at::kInt);
  auto m = m2.accessor<float, 2>();
  auto d = dep.accessor<float, 1>();
  auto r = rad.accessor<int32_t, 1>();
  for (int64_t i = 0; i < n; ++i) {
    m[i][0] = -10.f + (W + 20) * U(rng);
    m[i][1] = -10.f + (H + 20) * U(rng);
    d[i] = float(int(U(rng) * 40) - 5) * 0.25f;  // 40 values from -1.25 to 8.5, zero included
    r[i] = U(rng) < 0.1f ? 0 : 1 + int(U(rng) * 20);
  }
  auto off_of = [](const TileIntersections& is) {
    return std::vector<int32_t>(is.tile_offsets.data_ptr<int32_t>(),
                                is.tile_offsets.data_ptr<int32_t>() + is.tile_offsets.numel());
  };
  const TileIntersections one = intersect_tiles(m2, rad, dep, W, H, 1);
  const TileIntersections two = intersect_tiles(m2, rad, dep, W, H, 2);
  EXPECT_TRUE(at::equal(one.tile_offsets, two.tile_offsets));
  EXPECT_TRUE(at::equal(one.gaussian_ids, two.gaussian_ids));
  std::vector<std::vector<int32_t>> expected(size_t(one.tiles_x * one.tiles_y));
  for (int64_t i = 0; i < n; ++i) {
    if (r[i] <= 0) continue;
    const TileRect t = tile_rect(m[i][0], m[i][1], r[i], one.tiles_x, one.tiles_y);
    for (int ty = t.y0; ty < t.y1; ++ty)
      for (int tx = t.x0; tx < t.x1; ++tx)
        expected[size_t(ty * one.tiles_x + tx)].push_back(int32_t(i));
  }
  const std::vector<int32_t> off = off_of(two);
  const int32_t* ids = two.gaussian_ids.data_ptr<int32_t>();
  for (size_t t = 0; t < expected.size(); ++t) {
    std::vector<int32_t>& e = expected[t];
    std::stable_sort(e.begin(), e.end(), [&](int32_t a, int32_t b) { return d[a] < d[b]; });
    ASSERT_EQ(std::vector<int32_t>(ids + off[t], ids + off[t + 1]), e) << "tile " << t;
  }
}

// Tiles where a Gaussian's alpha cannot reach 1/255 are left out of its list: fewer entries,
// the same image, alpha, depth and gradients (the pixel loops skipped those entries anyway).
TEST(RasterStages, AlphaBoxesDropOnlyEntriesThatDrawNothing) {
  const Camera cam = make_camera(120, 90);
  Scene s = random_scene(600, 131, cam, 6.0);
  auto o = s.opacities.accessor<float, 1>();
  for (int64_t i = 0; i < s.size(); i += 3) o[i] = 0.005f + 0.02f * float(i % 7);  // faint ones
  const RenderSettings st = settings_with(true);
  const ProjectResult pr = project_forward(s.means, s.scales, s.rotations, cam, st, 2);
  const int W = cam.width, H = cam.height;
  const TileIntersections loose = intersect_tiles(pr.means2d, pr.radii, pr.depths, W, H, 2);
  const TileIntersections tight =
      intersect_tiles(pr.means2d, pr.radii, pr.depths, W, H, 2, pr.conics, s.opacities);
  EXPECT_LT(tight.gaussian_ids.numel(), loose.gaussian_ids.numel() * 9 / 10);
  // Each tight list is the loose one with some entries removed, order kept.
  for (int t = 0; t < loose.tiles_x * loose.tiles_y; ++t) {
    const auto a = loose.gaussian_ids.slice(0, loose.tile_offsets[t].item<int>(),
                                            loose.tile_offsets[t + 1].item<int>());
    const auto b = tight.gaussian_ids.slice(0, tight.tile_offsets[t].item<int>(),
                                            tight.tile_offsets[t + 1].item<int>());
    int64_t j = 0;
    for (int64_t k = 0; k < a.numel() && j < b.numel(); ++k)
      j += a[k].item<int>() == b[j].item<int>() ? 1 : 0;
    EXPECT_EQ(j, b.numel()) << "tile " << t;
  }
  auto render = [&](const TileIntersections& is) {
    RasterizeResult rr = rasterize_forward(pr.means2d, pr.conics, s.opacities, s.colors, pr.depths,
                                           is, W, H, st.background, true, 2);
    at::manual_seed(5);
    const at::Tensor vi = at::rand({H, W, 3}), va = at::rand({H, W, 1}), vd = at::rand({H, W, 1});
    RasterizeGrads g = rasterize_backward(pr.means2d, pr.conics, s.opacities, s.colors, pr.depths,
                                          is, rr, W, H, st.background, true, vi, va, vd, 2);
    return std::make_pair(rr, g);
  };
  const auto [r0, g0] = render(loose);
  const auto [r1, g1] = render(tight);
  EXPECT_TRUE(at::equal(r0.image, r1.image));
  EXPECT_TRUE(at::equal(r0.alpha, r1.alpha));
  EXPECT_TRUE(at::equal(r0.depth, r1.depth));
  EXPECT_TRUE(at::equal(r0.final_T, r1.final_T));
  EXPECT_TRUE(at::equal(g0.v_means2d, g1.v_means2d));
  EXPECT_TRUE(at::equal(g0.v_conics, g1.v_conics));
  EXPECT_TRUE(at::equal(g0.v_opacities, g1.v_opacities));
  EXPECT_TRUE(at::equal(g0.v_colors, g1.v_colors));
  EXPECT_TRUE(at::equal(g0.v_depths, g1.v_depths));
  EXPECT_GT(g0.v_opacities.abs().sum().item<float>(), 0.f);
}

// ---- Anchor prefilter and the component ------------------------------------------------

TEST(RasterAnchors, VisibleAnchorsFollowFrustumAndRadius) {
  const Camera cam = make_camera(64, 48);
  at::Tensor pos = at::zeros({6, 3});
  at::Tensor ext = at::full({6, 3}, 0.05f);
  auto put = [&](int i, const Eigen::Vector3d& p) { set_row(pos, i, {p.x(), p.y(), p.z()}); };
  put(0, world_at_pixel(cam, 32, 24, 3.0));   // centre: visible
  put(1, to_world(cam, {0, 0, -3.0}));        // behind
  put(2, world_at_pixel(cam, 400, 24, 3.0));  // far right of the frame
  put(3, world_at_pixel(cam, 70, 24, 3.0));   // just outside, but its radius reaches in
  set_row(ext, 3, {1.0, 1.0, 1.0});
  put(4, world_at_pixel(cam, 32, 24, 150.0));  // beyond the far plane
  put(5, world_at_pixel(cam, -3, -3, 2.0));    // corner, small but within one tile's reach
  CpuRasterizer rast(2);
  const at::Tensor vis = rast.visible_anchors(pos, ext, cam, RenderSettings{});
  ASSERT_EQ(vis.scalar_type(), at::kBool);
  const std::vector<bool> expected = {true, false, false, true, false, true};
  for (int i = 0; i < 6; ++i) EXPECT_EQ(vis[i].item<bool>(), expected[i]) << "anchor " << i;
}

TEST(RasterComponent, DescriptorSchemaAndHyperparams) {
  const crpgs_plugin_descriptor* d = cpu_rasterizer_descriptor();
  ASSERT_NE(d, nullptr);
  EXPECT_EQ(d->kind, uint32_t(CRPGS_KIND_RASTERIZER));
  EXPECT_STREQ(d->id, "org.crpgs.rasterizer.cpu");
  EXPECT_STREQ(d->type_name, "cpu");
  EXPECT_EQ(d->version_major, 1u);
  EXPECT_EQ(d->version_minor, 0u);
  const StatusOr<Schema> schema = Schema::parse(d->schema_yaml);
  ASSERT_TRUE(schema.ok());
  ASSERT_NE(schema->find("threads"), nullptr);
  EXPECT_EQ(schema->find("threads")->type, ParamType::kInt);

  crpgs_create_args args{};
  void* obj = nullptr;
  char err[256] = {0};
  ASSERT_EQ(d->create("{type: cpu, threads: 2}", &args, &obj, err, sizeof(err)), CRPGS_PLUGIN_OK)
      << err;
  auto* r = static_cast<Rasterizer*>(obj);
  EXPECT_EQ(r->type_name(), "cpu");
  EXPECT_EQ(r->hyperparams()["type"].as<std::string>(), "cpu");
  EXPECT_EQ(r->hyperparams()["threads"].as<int>(), 2);
  EXPECT_TRUE(r->device().is_cpu());
  d->destroy(obj);

  args.device_cuda = 1;
  EXPECT_EQ(d->create("{threads: 0}", &args, &obj, err, sizeof(err)), CRPGS_PLUGIN_ERROR);
  EXPECT_NE(std::string(err).find("CUDA"), std::string::npos) << err;
}

TEST(RasterComponent, RejectsWrongInputs) {
  CpuRasterizer rast;
  const Camera cam = make_camera(16, 16);
  GaussianBatch g;
  const Scene s = random_scene(4, 1, cam);
  g.means = s.means.to(at::kDouble);
  g.scales = s.scales;
  g.rotations = s.rotations;
  g.opacities = s.opacities;
  g.colors = s.colors;
  EXPECT_THROW(rast.render(g, cam, RenderSettings{}), c10::Error);
  g.means = s.means;
  g.colors = s.colors.narrow(1, 0, 2);
  EXPECT_THROW(rast.render(g, cam, RenderSettings{}), c10::Error);
}

}  // namespace
}  // namespace crpgs::raster
