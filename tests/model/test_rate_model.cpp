// Rate path of the anchor model (docs/method.md §2): training-time noise per phase, the rate term,
// the mask loss, test-time quantisation (quantize) and the decoder-side model (from_decoded).
#include <gtest/gtest.h>
#include <torch/torch.h>

#include <ATen/CPUGeneratorImpl.h>

#include "crpgs/anchor_model.h"
#include "crpgs/components.h"
#include "crpgs/scene_generator.h"
#include "raster/cpu_rasterizer.h"
#include "train/rate_test_util.h"

namespace crpgs {
namespace {

using torch::indexing::Slice;

struct RateScene {
  Dataset ds;
  std::shared_ptr<Rasterizer> raster = std::make_shared<raster::CpuRasterizer>(1);
  RateScene() {
    at::set_num_threads(1);
    SyntheticSceneOptions o;
    o.width = 40;
    o.height = 30;
    o.views = 6;
    o.sfm_points = 1500;
    auto s = generate_scene(o, *raster);
    if (!s.ok()) throw StatusError(s.status());
    ds = std::move(s).value();
  }
  // A model with the rate path and non-trivial attributes (some anchors fully masked).
  std::unique_ptr<AnchorModel> model(const RateOptions& ro = RateOptions()) const {
    AnchorInit in;
    for (const auto& p : ds.points) in.points.push_back({p.x(), p.y(), p.z()});
    for (const auto& v : ds.train) in.train_cameras.push_back(v.camera);
    AnchorModelOptions o;
    o.voxel_size = 0.1;
    auto gen = at::make_generator<at::CPUGeneratorImpl>(5);
    auto m = AnchorModel::create(o, identity_feature_model(50), in, gen);
    if (!m.ok()) throw StatusError(m.status());
    RateSetup rs = test::make_rate_setup(50, 10, ro);
    Status st = (*m)->attach_rate(rs.context, rs.entropy, rs.options);
    if (!st.ok()) throw StatusError(st);
    torch::NoGradGuard ng;
    auto& model = **m;
    const int64_t N = model.num_anchors();
    model.features().copy_(torch::randn({N, 50}, gen) * 3);
    model.offsets().copy_(torch::randn({N, 10, 3}, gen) * 0.5);
    model.scaling_raw().add_(torch::randn({N, 6}, gen) * 0.3);
    auto logits = torch::randn({N, 10}, gen) * 4;
    logits.index_put_({Slice(0, N / 5)}, -10.0);  // first fifth: inactive anchors
    model.mask_logits().copy_(logits);
    return std::move(m).value();
  }
  RenderSettings settings() const { return RenderSettings(); }
};

#define SKIP_WITHOUT_PLUGINS()                            \
  do {                                                    \
    const std::string why = test::rate_plugins_missing(); \
    if (!why.empty()) GTEST_SKIP() << why;                \
  } while (0)

TEST(RateModel, NoiseIsBoundedByHalfAStepAndOnlyInNoisePhases) {
  SKIP_WITHOUT_PLUGINS();
  RateScene s;
  RateOptions ro;
  ro.subset = 1.0;  // every visible active anchor: the subset is never empty
  auto m = s.model(ro);
  m->set_generator(at::make_generator<at::CPUGeneratorImpl>(11));
  const auto& cam = s.ds.train[0].camera;
  auto raw_of = [&](const NeuralGaussians& g) {
    auto idx = g.visible.nonzero().squeeze(1);
    return std::make_tuple(m->features().detach().index_select(0, idx),
                           torch::exp(m->scaling_raw().detach()).index_select(0, idx),
                           m->offsets().detach().index_select(0, idx));
  };
  auto check_within = [](const torch::Tensor& used, const torch::Tensor& raw,
                         const torch::Tensor& q, const char* what) {
    auto d = (used.detach() - raw).abs();
    auto half = (q.detach() * 0.5).expand_as(d);
    EXPECT_TRUE((d <= half * (1 + 1e-5) + 1e-7).all().item<bool>()) << what;
    EXPECT_GT(d.max().item<double>(), 0.0) << what << ": no noise added";
    EXPECT_GT(d.max().item<double>(), 0.25 * half.max().item<double>()) << what;
  };
  // Raw phase: attributes as stored, no steps, no rate.
  m->set_quant_phase(QuantPhase::kRaw);
  auto g0 = m->generate(cam, 0, *s.raster, s.settings(), true);
  ASSERT_GT(g0.visible.sum().item<int64_t>(), 10);
  auto [f0, s0, o0] = raw_of(g0);
  EXPECT_TRUE(torch::equal(g0.used_features.detach(), f0));
  EXPECT_FALSE(g0.q_f.defined());
  EXPECT_FALSE(g0.bits_per_param.defined());
  // Fixed steps Q0.
  m->set_quant_phase(QuantPhase::kFixedNoise);
  auto g1 = m->generate(cam, 0, *s.raster, s.settings(), true);
  auto [f1, s1, o1] = raw_of(g1);
  EXPECT_NEAR(g1.q_f.max().item<double>(), 1.0, 1e-9);
  EXPECT_NEAR(g1.q_s.min().item<double>(), 0.001, 1e-9);
  check_within(g1.used_features, f1, g1.q_f, "features");
  check_within(g1.used_scaling, s1, g1.q_s, "scaling");
  check_within(g1.used_offsets, o1, g1.q_o.unsqueeze(2), "offsets");
  EXPECT_FALSE(g1.bits_per_param.defined());
  // Adaptive steps from the context, rate term with gradients to the context and the masks.
  m->set_quant_phase(QuantPhase::kAdaptiveNoise);
  auto g2 = m->generate(cam, 0, *s.raster, s.settings(), true);
  auto [f2, s2, o2] = raw_of(g2);
  EXPECT_TRUE((g2.q_f > 0).all().item<bool>());
  EXPECT_TRUE((g2.q_f < 2.0).all().item<bool>());
  EXPECT_TRUE((g2.q_o < 0.4).all().item<bool>());
  check_within(g2.used_features, f2, g2.q_f, "features (adaptive)");
  check_within(g2.used_offsets, o2, g2.q_o.unsqueeze(2), "offsets (adaptive)");
  ASSERT_TRUE(g2.bits_per_param.defined());
  EXPECT_GT(g2.rate_subset, 0);
  const double bpp = g2.bits_per_param.item<double>();
  EXPECT_TRUE(std::isfinite(bpp));
  EXPECT_GT(bpp, 0.0);
  g2.bits_per_param.backward();
  auto params = m->context()->parameters();
  ASSERT_GE(params.size(), 2u);
  EXPECT_TRUE(params[0].grad().defined());                        // grid (straight-through)
  ASSERT_TRUE(params.back().grad().defined());                    // context MLP
  EXPECT_GT(params.back().grad().abs().sum().item<double>(), 0);  // Q and mu/sigma
  ASSERT_TRUE(m->mask_logits().grad().defined());                 // offset bits x STE mask
  EXPECT_GT(m->mask_logits().grad().abs().sum().item<double>(), 0);
  m->zero_grad();
  // Rendering (not training) never adds noise.
  auto g3 = m->generate(cam, 0, *s.raster, s.settings(), false);
  auto [f3, s3, o3] = raw_of(g3);
  EXPECT_TRUE(torch::equal(g3.used_features.detach(), f3));
}

TEST(RateModel, MaskLossIsTheMeanSigmoidAndReachesTheLogits) {
  SKIP_WITHOUT_PLUGINS();
  RateScene s;
  auto m = s.model();
  auto loss = m->mask_loss();
  EXPECT_NEAR(loss.item<double>(), torch::sigmoid(m->mask_logits().detach()).mean().item<double>(),
              1e-7);
  loss.backward();
  ASSERT_TRUE(m->mask_logits().grad().defined());
  EXPECT_TRUE((m->mask_logits().grad() >= 0).all().item<bool>());  // lowering logits lowers it
  EXPECT_GT(m->mask_logits().grad().sum().item<double>(), 0);
  // Activity = any offset mask on; the first fifth was switched off.
  auto active = m->active_anchors();
  EXPECT_FALSE(active.index({Slice(0, m->num_anchors() / 5)}).any().item<bool>());
  EXPECT_TRUE(active.any().item<bool>());
}

TEST(RateModel, QuantizeIsDeterministicAndWithinHalfAStep) {
  SKIP_WITHOUT_PLUGINS();
  RateScene s;
  auto m = s.model();
  {  // one value far outside mean +- 15000 Q: clamped, not wrapped
    torch::NoGradGuard ng;
    const int64_t i = m->active_anchors().nonzero()[0][0].item<int64_t>();
    m->features()[i][0] = 1e5f;  // small enough not to move the mean far
  }
  at::set_num_threads(1);
  const QuantizedAttributes a = m->quantize();
  at::set_num_threads(2);
  const QuantizedAttributes b = m->quantize();
  at::set_num_threads(1);
  for (auto [x, y, name] : {std::make_tuple(a.feature_symbols, b.feature_symbols, "features"),
                            std::make_tuple(a.scaling_symbols, b.scaling_symbols, "scaling"),
                            std::make_tuple(a.offset_symbols, b.offset_symbols, "offsets"),
                            std::make_tuple(a.params.mu_f, b.params.mu_f, "mu_f"),
                            std::make_tuple(a.params.sigma_o, b.params.sigma_o, "sigma_o"),
                            std::make_tuple(a.params.q_s, b.params.q_s, "q_s"),
                            std::make_tuple(a.features, b.features, "dequantised features")})
    EXPECT_TRUE(torch::equal(x, y)) << name << " differ between 1 and 2 threads";
  // Rows: exactly the active anchors, in index order.
  const auto active = m->active_anchors();
  EXPECT_TRUE(torch::equal(a.index, active.nonzero().squeeze(1)));
  EXPECT_TRUE(torch::equal(a.active, active));
  const int64_t A = a.index.size(0);
  ASSERT_GT(A, 10);
  ASSERT_LT(A, m->num_anchors());
  EXPECT_EQ(a.feature_symbols.scalar_type(), torch::kInt);
  EXPECT_EQ(a.offset_symbols.sizes(), (std::vector<int64_t>{A, 10, 3}));
  // Positions on the voxel grid, normalised by the bounds.
  const float v = float(m->voxel_size());
  auto pos = m->anchors().index_select(0, a.index);
  EXPECT_TRUE(torch::allclose(a.positions, pos, 0, 1e-4));
  EXPECT_TRUE(torch::equal(a.positions, torch::round(a.positions / v) * v));
  // Dequantised = symbol * Q, within Q/2 of the raw value except where clamped.
  auto check = [&](const torch::Tensor& raw, const torch::Tensor& deq, const torch::Tensor& sym,
                   const torch::Tensor& q, int64_t expected_clamped, const char* name) {
    EXPECT_TRUE(torch::equal(deq, sym.to(torch::kFloat) * q)) << name;
    auto d = (deq - raw).abs();
    auto far = d > (q * 0.5).expand_as(d) * (1 + 1e-5) + 1e-6;
    EXPECT_EQ(far.sum().item<int64_t>(), expected_clamped) << name;
  };
  torch::NoGradGuard ng;
  const auto feat = m->features().index_select(0, a.index);
  check(feat, a.features, a.feature_symbols, a.params.q_f, 1, "features");
  check(torch::exp(m->scaling_raw()).index_select(0, a.index), a.scaling, a.scaling_symbols,
        a.params.q_s, 0, "scaling");
  auto keep = a.offset_masks.unsqueeze(2).expand({A, 10, 3});
  auto offs = m->offsets().index_select(0, a.index);
  auto q_o = a.params.q_o.unsqueeze(2).expand({A, 10, 3});
  check(offs.masked_select(keep), a.offsets.masked_select(keep),
        a.offset_symbols.masked_select(keep), q_o.masked_select(keep), 0, "offsets");
  EXPECT_EQ(a.offset_symbols.masked_select(~keep).abs().sum().item<int64_t>(), 0);
  // The clamped value sits at mean + 15000 Q (to one step).
  const int64_t row = (feat.select(1, 0) > 1e4).nonzero()[0][0].item<int64_t>();
  const double mean = m->features().mean().item<double>(), q = a.params.q_f[row][0].item<double>();
  EXPECT_NEAR(a.features[row][0].item<double>(), mean + 15000 * q, q);
  // An explicit row order gives the same symbols per anchor (chunks of 3000 > A here).
  auto rev = a.index.flip(0);
  const QuantizedAttributes r = m->quantize(rev);
  EXPECT_TRUE(torch::equal(r.feature_symbols.flip(0), a.feature_symbols));
}

TEST(RateModel, FromDecodedRendersExactlyLikeTheQuantisedModel) {
  SKIP_WITHOUT_PLUGINS();
  RateScene s;
  auto m = s.model();
  const QuantizedAttributes q = m->quantize();
  const auto& cam = s.ds.test.empty() ? s.ds.train[1].camera : s.ds.test[0].camera;
  torch::NoGradGuard ng;
  auto render = [&](AnchorModel& model) {
    auto g = model.generate(cam, -1, *s.raster, s.settings(), false);
    return s.raster->render(g.batch, cam, s.settings()).image;
  };
  auto raw = render(*m);
  m->set_quantized(q);
  EXPECT_TRUE(m->is_quantized());
  auto quantised = render(*m);
  m->clear_quantized();
  EXPECT_FALSE(m->is_quantized());
  EXPECT_GT(quantised.sum().item<double>(), 0.0);
  EXPECT_FALSE(torch::equal(raw, quantised));  // quantisation changes something
  EXPECT_TRUE(torch::equal(render(*m), raw));  // and clearing restores the raw model

  auto d = AnchorModel::from_decoded(m->options(), identity_feature_model(50), q.positions,
                                     q.features, q.scaling, q.offsets, q.offset_masks,
                                     m->mlp_tensors(), m->bounds(), m->voxel_size());
  ASSERT_TRUE(d.ok()) << d.status().to_string();
  EXPECT_EQ((*d)->num_anchors(), q.index.size(0));
  EXPECT_TRUE(torch::equal((*d)->bounds(), m->bounds()));
  EXPECT_TRUE((*d)->is_quantized());
  EXPECT_FALSE((*d)->has_rate());
  EXPECT_TRUE(torch::equal(render(**d), quantised));
  for (const auto& [name, t] : m->mlp_tensors())
    EXPECT_TRUE(torch::equal((*d)->mlp_tensors().at(name), t)) << name;
  // Malformed inputs are refused with a message.
  auto bad =
      AnchorModel::from_decoded(m->options(), identity_feature_model(50), q.positions,
                                q.features.index({Slice(), Slice(0, 10)}), q.scaling, q.offsets,
                                q.offset_masks, m->mlp_tensors(), m->bounds(), m->voxel_size());
  EXPECT_FALSE(bad.ok());
  auto mlps = m->mlp_tensors();
  mlps.erase("mlp_cov.b2");
  auto missing = AnchorModel::from_decoded(m->options(), identity_feature_model(50), q.positions,
                                           q.features, q.scaling, q.offsets, q.offset_masks, mlps,
                                           m->bounds(), m->voxel_size());
  ASSERT_FALSE(missing.ok());
  EXPECT_NE(missing.status().message().find("mlp_cov.b2"), std::string::npos);
}

// A scene flat on an axis through 0 still gets a non-empty interval there (the codec refuses an
// empty one), and nothing non-finite comes out of normalising its positions.
TEST(RateModel, AFlatSceneGetsBoundsACodecCanCarry) {
  RateScene s;
  AnchorInit in;
  for (const auto& p : s.ds.points) in.points.push_back({p.x(), p.y(), 0.0f});
  for (const auto& v : s.ds.train) in.train_cameras.push_back(v.camera);
  AnchorModelOptions o;
  o.voxel_size = 0.1;
  auto m = AnchorModel::create(o, identity_feature_model(50), in,
                               at::make_generator<at::CPUGeneratorImpl>(5));
  ASSERT_TRUE(m.ok()) << m.status().message();
  ASSERT_TRUE(torch::equal((*m)->anchors().select(1, 2), torch::zeros({(*m)->num_anchors()})));
  const auto b = (*m)->bounds();
  EXPECT_TRUE((b[1] > b[0]).all().item<bool>()) << b;
  EXPECT_EQ(b[0][2].item<float>(), -1.0f);
  EXPECT_EQ(b[1][2].item<float>(), 1.0f);
  EXPECT_TRUE(torch::isfinite((*m)->positions01()).all().item<bool>());
}

TEST(RateModel, AttachRejectsAContextOfTheWrongWidth) {
  SKIP_WITHOUT_PLUGINS();
  RateScene s;
  RateSetup rs = test::make_rate_setup(30, 10, RateOptions());  // 135 wide, the model needs 175
  AnchorInit in;
  for (const auto& v : s.ds.train) in.train_cameras.push_back(v.camera);
  for (const auto& p : s.ds.points) in.points.push_back({p.x(), p.y(), p.z()});
  AnchorModelOptions o;
  o.voxel_size = 0.1;
  auto plain = AnchorModel::create(o, identity_feature_model(50), in,
                                   at::make_generator<at::CPUGeneratorImpl>(1));
  ASSERT_TRUE(plain.ok());
  Status st = (*plain)->attach_rate(rs.context, rs.entropy, rs.options);
  EXPECT_FALSE(st.ok());
  EXPECT_FALSE((*plain)->has_rate());
}

}  // namespace
}  // namespace crpgs
