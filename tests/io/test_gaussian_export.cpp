// Baking anchor models into 3DGS Gaussians: SH fit, export -> .ply -> import -> render.
#include <gtest/gtest.h>
#include <torch/torch.h>

#include <ATen/CPUGeneratorImpl.h>

#include <map>
#include <set>

#include "crpgs/anchor_model.h"
#include "crpgs/components.h"
#include "crpgs/gaussian_export.h"
#include "crpgs/scene_generator.h"
#include "crpgs/trainer.h"
#include "io/io_test_util.h"
#include "raster/cpu_rasterizer.h"

namespace crpgs {
namespace {

TEST(GaussianExport, ShFitIsExactOnAFieldOfTheSameDegree) {
  torch::manual_seed(7);
  auto dirs = fibonacci_directions(96);
  EXPECT_TRUE(torch::allclose(dirs.norm(2, 1), torch::ones({96}), 0, 1e-6));
  for (int d = 0; d <= 3; ++d) {
    const int nb = sh_coeff_count(d);
    auto coeffs = torch::randn({20, nb, 3}) * 0.3;     // [G, B, 3]
    auto basis = sh_basis_matrix(dirs, d);             // [S, B]
    auto colors = torch::matmul(basis, coeffs) + 0.5;  // [G, S, 3]
    auto fit = fit_sh(colors, dirs, d);
    EXPECT_LT((fit - coeffs).abs().max().item<float>(), 2e-5) << "degree " << d;
    // The fitted field evaluated through PlyGaussians (the importer's path) matches too.
    PlyGaussians g;
    g.sh_degree = d;
    auto dc = fit.select(1, 0).contiguous();
    auto rest = fit.narrow(1, 1, nb - 1).permute({0, 2, 1}).contiguous();
    g.sh_dc.assign(dc.data_ptr<float>(), dc.data_ptr<float>() + dc.numel());
    g.sh_rest.assign(rest.data_ptr<float>(), rest.data_ptr<float>() + rest.numel());
    g.opacity.assign(20, 0.f);
    const float* dp = dirs.data_ptr<float>();
    for (int s : {0, 31, 95}) {
      const auto c = g.color(5, dp[3 * s], dp[3 * s + 1], dp[3 * s + 2]);
      for (int ch = 0; ch < 3; ++ch)
        EXPECT_NEAR(c[size_t(ch)], std::max(0.f, colors[5][s][ch].item<float>()), 2e-5);
    }
  }
  // A lower degree than the field's is a least-squares fit, not exact.
  auto coeffs = torch::randn({4, 16, 3});
  auto colors = torch::matmul(sh_basis_matrix(dirs, 3), coeffs) + 0.5;
  EXPECT_GT((fit_sh(colors, dirs, 1) - coeffs.narrow(1, 0, 4)).abs().max().item<float>(), 1e-3);
}

TEST(GaussianExport, WeightedShFitSolvesTheWeightedNormalEquations) {
  torch::manual_seed(11);
  const int64_t G = 6, C = 5;
  auto dirs = fibonacci_directions(40);
  auto own = torch::randn({G, C, 3});
  own = own / own.norm(2, 2, true);  // each Gaussian its own directions
  for (int d : {1, 3}) {
    // A field of the fit's degree is recovered exactly whatever the weights.
    const int nb = sh_coeff_count(d);
    auto coeffs = torch::randn({G, nb, 3}) * 0.3;
    auto own_basis = sh_basis_matrix(own.reshape({G * C, 3}), d).reshape({G, C, nb});
    auto sphere_basis = sh_basis_matrix(dirs, d);
    auto fit = fit_sh({{torch::matmul(sphere_basis, coeffs) + 0.5, sphere_basis, 0.1 / 40},
                       {torch::matmul(own_basis, coeffs) + 0.5, own_basis, 0.9 / C}});
    EXPECT_LT((fit - coeffs).abs().max().item<float>(), 2e-5) << "degree " << d;
  }
  // Degree 0 is the weighted mean colour: 10% on the sphere's 40 samples, 90% on the own 5.
  auto on_sphere = torch::rand({G, 40, 3}), on_own = torch::rand({G, C, 3});
  auto fit =
      fit_sh({{on_sphere, sh_basis_matrix(dirs, 0), 0.1 / 40},
              {on_own, sh_basis_matrix(own.reshape({G * C, 3}), 0).reshape({G, C, 1}), 0.9 / C}});
  auto mean = 0.1 * on_sphere.mean(1) + 0.9 * on_own.mean(1);  // [G, 3]
  const float y00 = 0.28209479177387814f;
  EXPECT_LT((fit.select(1, 0) * y00 + 0.5 - mean).abs().max().item<float>(), 1e-5);
}

struct Scene {
  Dataset ds;
  std::shared_ptr<raster::CpuRasterizer> raster = std::make_shared<raster::CpuRasterizer>(1);
  Scene() {
    SyntheticSceneOptions o;
    o.width = 48;
    o.height = 36;
    o.views = 6;
    o.sfm_points = 800;
    auto s = generate_scene(o, *raster);
    if (!s.ok()) throw StatusError(s.status());
    ds = std::move(s).value();
  }
  std::unique_ptr<AnchorModel> model(const SceneEffects& fx) const {
    AnchorModelOptions o;
    o.voxel_size = 0.1;
    o.effects = fx;
    AnchorInit in;
    for (const auto& p : ds.points) in.points.push_back({p.x(), p.y(), p.z()});
    for (const auto& v : ds.train) in.train_cameras.push_back(v.camera);
    auto m = AnchorModel::create(o, identity_feature_model(50), in,
                                 at::make_generator<at::CPUGeneratorImpl>(5));
    if (!m.ok()) throw StatusError(m.status());
    return std::move(m).value();
  }
  BakeOptions bake(int degree, double view_weight = BakeOptions{}.view_weight) const {
    BakeOptions b;
    b.sh_degree = degree;
    b.view_weight = view_weight;
    for (const auto& v : ds.train) b.camera_centers.push_back(v.camera.center());
    return b;
  }
};

TEST(GaussianExport, ExportImportRenderEqualsTheBakedGaussians) {
  Scene s;
  auto m = s.model(SceneEffects{});
  torch::NoGradGuard ng;
  const auto dir = test::fresh_dir();
  for (int d : {0, 3}) {
    auto baked = bake_gaussians(*m, s.bake(d));
    ASSERT_TRUE(baked.ok()) << baked.status().message();
    ASSERT_GT(baked->size(), 100u);
    const std::string path = (dir / "scene.ply").string();
    ASSERT_TRUE(write_ply(path, *baked).ok());
    auto back = read_ply(path);
    ASSERT_TRUE(back.ok()) << back.status().message();
    for (const auto& v : s.ds.test) {
      RenderSettings rs;
      auto a = s.raster->render(ply_to_batch(*baked, v.camera), v.camera, rs).image;
      auto b = s.raster->render(ply_to_batch(*back, v.camera), v.camera, rs).image;
      EXPECT_TRUE(torch::equal(a, b)) << "degree " << d;
      EXPECT_GT(a.abs().sum().item<float>(), 0.f);  // something was rendered
    }
  }
}

TEST(GaussianExport, WithoutViewInputsTheBakeReproducesGenerate) {
  // No view direction and no distance input: every attribute is view-independent, so the baked
  // Gaussians (degree 0) must render like the anchor model itself.
  Scene s;
  SceneEffects fx;
  fx.view_dependent = false;
  fx.distance_input = false;
  auto m = s.model(fx);
  torch::NoGradGuard ng;
  auto baked = bake_gaussians(*m, s.bake(0));
  ASSERT_TRUE(baked.ok()) << baked.status().message();
  RenderSettings rs;
  for (const auto& v : s.ds.test) {
    auto gen = m->generate(v.camera, -1, *s.raster, rs, false);
    auto want = s.raster->render(gen.batch, v.camera, rs).image;
    auto got = s.raster->render(ply_to_batch(*baked, v.camera), v.camera, rs).image;
    EXPECT_LT((want - got).abs().max().item<float>(), 1e-4);
  }
}

TEST(GaussianExport, ViewDependentColourIsApproximatedBySh) {
  // With view inputs the bake is an approximation: degree 3 must be at least as close to the
  // anchor model's renders as degree 0 (same opacities and shapes, richer colour).
  Scene s;
  auto m = s.model(SceneEffects{});
  torch::NoGradGuard ng;
  auto b0 = bake_gaussians(*m, s.bake(0));
  auto b3 = bake_gaussians(*m, s.bake(3));
  ASSERT_TRUE(b0.ok() && b3.ok());
  ASSERT_EQ(b0->size(), b3->size());
  EXPECT_EQ(b0->means, b3->means);
  EXPECT_EQ(b3->sh_rest.size(), b3->size() * 45);
  RenderSettings rs;
  double e0 = 0, e3 = 0;
  for (const auto& v : s.ds.test) {
    auto want =
        s.raster->render(m->generate(v.camera, -1, *s.raster, rs, false).batch, v.camera, rs).image;
    e0 += (want - s.raster->render(ply_to_batch(*b0, v.camera), v.camera, rs).image)
              .pow(2)
              .mean()
              .item<double>();
    e3 += (want - s.raster->render(ply_to_batch(*b3, v.camera), v.camera, rs).image)
              .pow(2)
              .mean()
              .item<double>();
  }
  EXPECT_LE(e3, e0 * 1.05);
  EXPECT_LT(e3, 0.05);
}

TEST(GaussianExport, WeightingTheCamerasViewsFitsTheColoursTheySee) {
  // The sphere-only fit (view weight 0) spends the SH on directions no camera looks from; with
  // the cameras' own views weighted, the exported colours seen from those cameras come closer to
  // the model's. Gaussians are matched by their means, which bake and generate compute alike
  // (random offsets make them distinct: a fresh model's are all 0).
  Scene s;
  auto m = s.model(SceneEffects{});
  torch::NoGradGuard ng;
  torch::manual_seed(3);
  m->offsets().copy_(torch::randn(m->offsets().sizes()));
  RenderSettings rs;
  for (int degree : {0, 1, 3}) {
    double err[2] = {0, 0};
    for (int i = 0; i < 2; ++i) {
      auto b = bake_gaussians(*m, s.bake(degree, i == 0 ? 0.0 : 0.9));
      ASSERT_TRUE(b.ok()) << b.status().message();
      std::map<std::array<float, 3>, int64_t> row;
      for (size_t g = 0; g < b->size(); ++g)
        row[{b->means[3 * g], b->means[3 * g + 1], b->means[3 * g + 2]}] = int64_t(g);
      for (const auto& v : s.ds.train) {
        auto want = m->generate(v.camera, -1, *s.raster, rs, false).batch;
        auto got = ply_to_batch(*b, v.camera).colors;
        auto mu = want.means.contiguous();
        const float* p = mu.data_ptr<float>();
        std::vector<int64_t> model_rows, ply_rows;
        for (int64_t g = 0; g < mu.size(0); ++g) {
          auto it = row.find({p[3 * g], p[3 * g + 1], p[3 * g + 2]});
          if (it == row.end()) continue;
          model_rows.push_back(g);
          ply_rows.push_back(it->second);
        }
        ASSERT_GT(model_rows.size(), b->size() / 2);
        ASSERT_EQ(std::set<int64_t>(ply_rows.begin(), ply_rows.end()).size(), ply_rows.size());
        err[i] += (want.colors.index_select(0, torch::tensor(model_rows)) -
                   got.index_select(0, torch::tensor(ply_rows)))
                      .pow(2)
                      .sum()
                      .item<double>();
      }
    }
    EXPECT_LT(err[1], err[0]) << "degree " << degree;
  }
}

TEST(GaussianExport, OpacityOverViewsIsTheMeanOfWhatTheCamerasSee) {
  // Each exported Gaussian's opacity is the mean over the cameras of the model's opacity for it
  // (0 where the model gives it none), and a Gaussian no camera sees is not exported.
  Scene s;
  auto m = s.model(SceneEffects{});
  torch::NoGradGuard ng;
  torch::manual_seed(3);
  m->offsets().copy_(torch::randn(m->offsets().sizes()));  // distinct means, to match them
  auto opt = s.bake(0);
  opt.opacity_over_views = true;
  auto b = bake_gaussians(*m, opt);
  ASSERT_TRUE(b.ok()) << b.status().message();
  std::map<std::array<float, 3>, size_t> row;
  for (size_t g = 0; g < b->size(); ++g)
    row[{b->means[3 * g], b->means[3 * g + 1], b->means[3 * g + 2]}] = g;
  std::vector<double> sum(b->size(), 0.0);
  RenderSettings rs;
  for (const auto& v : s.ds.train) {
    auto gen = m->generate(v.camera, -1, *s.raster, rs, false).batch;
    auto mu = gen.means.contiguous();
    auto op = gen.opacities.contiguous();
    for (int64_t g = 0; g < mu.size(0); ++g) {
      const float* p = mu.data_ptr<float>() + 3 * g;
      auto it = row.find({p[0], p[1], p[2]});
      ASSERT_NE(it, row.end()) << "a Gaussian a camera sees was not exported";
      sum[it->second] += op.data_ptr<float>()[g];
    }
  }
  const double cameras = double(s.ds.train.size());
  for (size_t g = 0; g < b->size(); ++g) {
    ASSERT_GT(sum[g], 0.0) << "exported, but no camera sees it";
    EXPECT_NEAR(1.0 / (1.0 + std::exp(-double(b->opacity[g]))), sum[g] / cameras, 1e-5) << g;
  }
}

TEST(GaussianExport, RefusesBadOptions) {
  Scene s;
  auto m = s.model(SceneEffects{});
  auto b = s.bake(4);
  EXPECT_FALSE(bake_gaussians(*m, b).ok());
  b = s.bake(3);
  b.directions = 10;
  EXPECT_FALSE(bake_gaussians(*m, b).ok());
  b = s.bake(1);
  b.camera_centers.clear();
  EXPECT_FALSE(bake_gaussians(*m, b).ok());
  for (double w : {-0.1, 1.0, std::nan("")}) EXPECT_FALSE(bake_gaussians(*m, s.bake(1, w)).ok());
}

// Mean L1 of the .ply Gaussians' renders against the views' photos.
double mean_l1(const PlyGaussians& g, Rasterizer& r, const std::vector<View>& views) {
  torch::NoGradGuard ng;
  double sum = 0;
  for (const auto& v : views)
    sum += (r.render(ply_to_batch(g, v.camera), v.camera, RenderSettings{}).image -
            image_to_tensor(v.image))
               .abs()
               .mean()
               .item<double>();
  return sum / double(views.size());
}

StatusOr<PlyGaussians> baked_untrained(const Scene& s, int degree) {
  auto m = s.model(SceneEffects{});
  torch::NoGradGuard ng;
  return bake_gaussians(*m, s.bake(degree));
}

TEST(GaussianExport, RefineFitsTheTrainingViewsAndKeepsTheGaussians) {
  // An untrained model's bake is far from the photos: refining must bring the renders of the
  // training views, and of the held-out ones the scene shares, closer to them.
  Scene s;
  auto g = baked_untrained(s, 1);
  ASSERT_TRUE(g.ok()) << g.status().message();
  const PlyGaussians before = g.value();
  RefineOptions o;
  o.iterations = 100;
  int calls = 0;
  auto rep = refine_gaussians(*g, *s.raster, s.ds.train, {0, 0, 0}, o,
                              [&calls](int it, double) { EXPECT_EQ(it, ++calls); });
  ASSERT_TRUE(rep.ok()) << rep.status().message();
  EXPECT_EQ(rep->iterations, 100);
  EXPECT_EQ(calls, 100);
  EXPECT_EQ(rep->skipped, 0);
  EXPECT_EQ(rep->passes, 100 / int(s.ds.train.size()));
  EXPECT_LT(rep->last_pass_loss, 0.8 * rep->first_pass_loss);
  ASSERT_TRUE(g->check().ok());
  EXPECT_EQ(g->size(), before.size());
  EXPECT_EQ(g->sh_degree, 1);
  const double train_before = mean_l1(before, *s.raster, s.ds.train);
  const double train_after = mean_l1(*g, *s.raster, s.ds.train);
  EXPECT_LT(train_after, 0.75 * train_before);
  std::printf("training views' mean L1: %.4f -> %.4f\n", train_before, train_after);
  EXPECT_LT(mean_l1(*g, *s.raster, s.ds.test), mean_l1(before, *s.raster, s.ds.test));
  // Every parameter group moved.
  EXPECT_NE(g->means, before.means);
  EXPECT_NE(g->sh_dc, before.sh_dc);
  EXPECT_NE(g->sh_rest, before.sh_rest);
  EXPECT_NE(g->opacity, before.opacity);
  EXPECT_NE(g->log_scales, before.log_scales);
  EXPECT_NE(g->rotations, before.rotations);
}

TEST(GaussianExport, RefineIsDeterministicAndLeavesUnlearntParametersExact) {
  Scene s;
  auto g = baked_untrained(s, 3);
  ASSERT_TRUE(g.ok()) << g.status().message();
  RefineOptions o;
  o.iterations = 5;
  PlyGaussians a = g.value(), b = g.value();
  ASSERT_TRUE(refine_gaussians(a, *s.raster, s.ds.train, {0, 0, 0}, o).ok());
  ASSERT_TRUE(refine_gaussians(b, *s.raster, s.ds.train, {0, 0, 0}, o).ok());
  EXPECT_NE(a.sh_rest, g->sh_rest);  // degree 3's higher coefficients are learnt too
  EXPECT_EQ(a.means, b.means);
  EXPECT_EQ(a.sh_rest, b.sh_rest);
  EXPECT_EQ(a.opacity, b.opacity);
  // With every learning rate 0 the parameters come back bit-exact: reading the file's arrays
  // into the optimised tensors and writing them back undo each other.
  o.means_lr = o.means_lr_final = 0;
  o.sh_dc_lr = o.sh_rest_lr = o.opacity_lr = o.scaling_lr = o.rotation_lr = 0;
  PlyGaussians c = g.value();
  auto rep = refine_gaussians(c, *s.raster, s.ds.train, {0, 0, 0}, o);
  ASSERT_TRUE(rep.ok()) << rep.status().message();
  EXPECT_EQ(rep->iterations, 5);
  EXPECT_EQ(c.means, g->means);
  EXPECT_EQ(c.sh_dc, g->sh_dc);
  EXPECT_EQ(c.sh_rest, g->sh_rest);
  EXPECT_EQ(c.opacity, g->opacity);
  EXPECT_EQ(c.log_scales, g->log_scales);
  EXPECT_EQ(c.rotations, g->rotations);
}

TEST(GaussianExport, RefineRefusesWhatItCannotDo) {
  Scene s;
  auto g = baked_untrained(s, 0);
  ASSERT_TRUE(g.ok()) << g.status().message();
  const PlyGaussians before = g.value();
  RefineOptions o;
  o.iterations = 3;
  auto none = refine_gaussians(*g, *s.raster, {}, {0, 0, 0}, o);
  ASSERT_FALSE(none.ok());
  EXPECT_NE(none.status().message().find("no training views"), std::string::npos);
  o.iterations = -1;
  EXPECT_FALSE(refine_gaussians(*g, *s.raster, s.ds.train, {0, 0, 0}, o).ok());
  o.iterations = 3;
  o.opacity_lr = -1;
  EXPECT_FALSE(refine_gaussians(*g, *s.raster, s.ds.train, {0, 0, 0}, o).ok());
  o.opacity_lr = RefineOptions{}.opacity_lr;
  o.means_lr_final = 0;  // a log-linear decay to 0
  EXPECT_FALSE(refine_gaussians(*g, *s.raster, s.ds.train, {0, 0, 0}, o).ok());
  o.means_lr_final = RefineOptions{}.means_lr_final;
  o.lambda_dssim = 1.5;
  EXPECT_FALSE(refine_gaussians(*g, *s.raster, s.ds.train, {0, 0, 0}, o).ok());
  o.lambda_dssim = RefineOptions{}.lambda_dssim;
  auto cameras_only = s.ds.train;  // e.g. a dataset loaded without its images
  cameras_only[0].image = Image{};
  auto no_photo = refine_gaussians(*g, *s.raster, cameras_only, {0, 0, 0}, o);
  ASSERT_FALSE(no_photo.ok());
  EXPECT_NE(no_photo.status().message().find("no RGB photo"), std::string::npos);
  o.iterations = 0;  // nothing to do, nothing changes
  auto zero = refine_gaussians(*g, *s.raster, s.ds.train, {0, 0, 0}, o);
  ASSERT_TRUE(zero.ok());
  EXPECT_EQ(zero->iterations, 0);
  EXPECT_EQ(g->means, before.means);
  EXPECT_EQ(g->opacity, before.opacity);
  // Degree 0 has no f_rest to learn; the rest is refined as at any degree.
  o.iterations = 3;
  auto d0 = refine_gaussians(*g, *s.raster, s.ds.train, {0, 0, 0}, o);
  ASSERT_TRUE(d0.ok()) << d0.status().message();
  EXPECT_EQ(d0->skipped, 0);
  EXPECT_EQ(d0->passes, 0);  // fewer iterations than views: no complete pass
  EXPECT_TRUE(g->sh_rest.empty());
  EXPECT_NE(g->means, before.means);
  EXPECT_NE(g->sh_dc, before.sh_dc);
  EXPECT_NE(g->opacity, before.opacity);
}

}  // namespace
}  // namespace crpgs
