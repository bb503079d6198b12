// Training with the rate path (method.md §2.3-§2.6): phase switching, the rate and mask terms
// acting on a tiny generated scene, quantised evaluation, config wiring.
#include <gtest/gtest.h>
#include <torch/torch.h>

#include <cmath>
#include <filesystem>
#include <iostream>

#include "crpgs/codec.h"
#include "crpgs/components.h"
#include "crpgs/experiments/sweep.h"
#include "crpgs/scene_generator.h"
#include "crpgs/trainer.h"
#include "raster/cpu_rasterizer.h"
#include "train/rate_test_util.h"

namespace crpgs {
namespace {

#define SKIP_WITHOUT_PLUGINS()                            \
  do {                                                    \
    const std::string why = test::rate_plugins_missing(); \
    if (!why.empty()) GTEST_SKIP() << why;                \
  } while (0)

// quant_start 10, rate_start 22; growing from 15 every 5 (on both sides of the boundaries, but
// not at rate_start itself, so the recomputed bounds can be checked after that step).
TrainOptions rate_schedule(int iterations) {
  TrainOptions to;
  to.schedule = Schedule::scaled(0.01);
  to.schedule.iterations = iterations;
  to.schedule.update_interval = 5;
  to.schedule.quant_start = 10;
  to.schedule.rate_start = 22;
  to.eval_interval = 0;
  to.seed = 3;
  return to;
}

std::unique_ptr<Trainer> rate_trainer(const Dataset& ds, const TrainOptions& to,
                                      const RateOptions& ro) {
  at::set_num_threads(1);
  torch::manual_seed(1);  // the context's init draws from the global generator
  AnchorModelOptions mo;
  mo.voxel_size = 0.08;
  mo.lr.max_steps = to.schedule.iterations;
  auto t = make_trainer(to, mo, ds, std::make_shared<raster::CpuRasterizer>(1),
                        identity_feature_model(50), test::make_rate_setup(50, 10, ro));
  if (!t.ok()) throw StatusError(t.status());
  return std::move(t).value();
}

TEST(RateTraining, PhasesSwitchAtQuantStartAndRateStart) {
  SKIP_WITHOUT_PLUGINS();
  Dataset ds = test::tiny_scene();
  auto t = rate_trainer(ds, rate_schedule(28), RateOptions());
  auto context_mlp = [&] { return t->model().context()->parameters().back().detach().clone(); };
  const auto ctx0 = context_mlp();
  for (int it = 1; it <= 28; ++it) {
    auto loss = t->step();
    ASSERT_TRUE(loss.ok());
    ASSERT_TRUE(std::isfinite(loss.value())) << "iteration " << it;
    const RateReport& r = t->last_rate();
    const QuantPhase expected = it <= 10   ? QuantPhase::kRaw
                                : it <= 22 ? QuantPhase::kFixedNoise
                                           : QuantPhase::kAdaptiveNoise;
    EXPECT_EQ(t->model().quant_phase(), expected) << "iteration " << it;
    if (it <= 22) {
      EXPECT_FALSE(r.on) << "rate term before rate_start, iteration " << it;
    } else {
      EXPECT_TRUE(r.on) << "no rate term after rate_start, iteration " << it;
      EXPECT_TRUE(std::isfinite(r.rate));
      EXPECT_GT(r.rate, 0.0);
      EXPECT_GT(r.hash_bits, 0.0);
      EXPECT_GE(r.rate, r.bits_per_param);
      EXPECT_GT(r.mask_loss, 0.0);
    }
    if (it == 22) {  // the context has not moved yet; bounds recomputed at rate_start
      EXPECT_TRUE(torch::equal(ctx0, context_mlp()));
      auto before = t->model().bounds().clone();
      t->model().recompute_bounds();
      EXPECT_TRUE(torch::equal(before, t->model().bounds()));
    }
  }
  // The context learned in the rate phase, and evaluation runs on quantised attributes.
  EXPECT_FALSE(torch::equal(ctx0, context_mlp()));
  EXPECT_GT(t->model().learning_rate("context"), 0.0);
  EXPECT_GT(t->model().learning_rate("context_mlp"), 0.0);
  auto ev = t->evaluate();
  ASSERT_TRUE(ev.ok()) << ev.status().to_string();
  EXPECT_TRUE(std::isfinite(ev->mean_psnr));
  EXPECT_FALSE(t->model().is_quantized());  // evaluation leaves the model as it was
}

// Checkpoints carry the context, its optimizer state, the bounds and the noise generator.
TEST(RateTraining, ResumeInTheRatePhaseEqualsUninterrupted) {
  SKIP_WITHOUT_PLUGINS();
  Dataset ds = test::tiny_scene();
  TrainOptions to = rate_schedule(30);
  auto full = rate_trainer(ds, to, RateOptions());
  ASSERT_TRUE(full->train().ok());
  to.output_dir = std::string(CRPGS_TEST_TMP_DIR) + "/rate_resume";
  auto first = rate_trainer(ds, to, RateOptions());
  for (int i = 0; i < 26; ++i) ASSERT_TRUE(first->step().ok());
  ASSERT_TRUE(first->save_checkpoint(first->checkpoint_path()).ok());
  auto resumed = rate_trainer(ds, to, RateOptions());
  ASSERT_TRUE(resumed->load_checkpoint(first->checkpoint_path()).ok());
  ASSERT_TRUE(resumed->train().ok());
  auto a = full->model().state_dict(), b = resumed->model().state_dict();
  ASSERT_EQ(a.size(), b.size());
  EXPECT_TRUE(a.count("param.context.grid.0"));
  for (const auto& kv : a) EXPECT_TRUE(torch::equal(kv.second, b.at(kv.first))) << kv.first;
}

TEST(RateTraining, FrozenBoundsStayAtTheirInitialValue) {
  SKIP_WITHOUT_PLUGINS();
  Dataset ds = test::tiny_scene();
  RateOptions ro;
  ro.recompute_bounds = false;
  auto t = rate_trainer(ds, rate_schedule(25), ro);
  const auto initial = t->model().bounds().clone();
  ASSERT_TRUE(t->train().ok());
  EXPECT_TRUE(torch::equal(initial, t->model().bounds()));
}

// lambda and mask_lambda act: a large weight ends with fewer bits per parameter, a large mask
// weight with fewer offsets switched on, than the same run without them.
TEST(RateTraining, LargeWeightsLowerTheRateAndTheMasks) {
  SKIP_WITHOUT_PLUGINS();
  Dataset ds = test::tiny_scene();
  const TrainOptions to = rate_schedule(60);
  auto run = [&](double lambda, double mask_lambda) {
    RateOptions ro;
    ro.lambda = lambda;
    ro.mask_lambda = mask_lambda;
    ro.subset = 0.5;  // a tiny scene has few anchors
    auto t = rate_trainer(ds, to, ro);
    EXPECT_TRUE(t->train().ok());
    const double bits = test::quantized_bits_per_param(t->model());
    const double mask = torch::sigmoid(t->model().mask_logits().detach()).mean().item<double>();
    return std::make_pair(bits, mask);
  };
  const auto base = run(0.0, 0.0);
  const auto rate = run(0.2, 0.0);
  const auto masks = run(0.0, 1.0);
  std::cout << "bits/param: lambda 0 " << base.first << ", lambda 0.2 " << rate.first
            << "; mean mask sigmoid: " << base.second << " vs mask_lambda 1 " << masks.second
            << "\n";
  EXPECT_LT(rate.first, 0.9 * base.first);
  EXPECT_LT(masks.second, base.second - 0.01);
}

TEST(RateTraining, SetupFromConfigAttachesTheRatePath) {
  SKIP_WITHOUT_PLUGINS();
  auto cfg = Config::from_string(
      "dataset: {format: synthetic, synthetic_width: 32, synthetic_height: 24, "
      "synthetic_views: 6}\n"
      "train: {schedule: fast, fast_factor: 0.001, threads: 1}\n"
      "rasterizer: {type: cpu, threads: 1}\n"
      "context: {type: hash_grid, log2_hashmap_size: 10, log2_hashmap_size_2d: 10}\n"
      "entropy: {type: gaussian}\n"
      "rate: {lambda: 0.004, recompute_bounds: false}\n",
      "test.yaml");
  ASSERT_TRUE(cfg.ok()) << cfg.status().to_string();
  auto resolved = cfg->resolve(test::rate_registry());
  ASSERT_TRUE(resolved.ok()) << resolved.status().to_string();
  auto t = setup_training(resolved.value(), test::rate_registry(), SetupOptions());
  ASSERT_TRUE(t.ok()) << t.status().to_string();
  EXPECT_TRUE((*t)->model().has_rate());
  EXPECT_DOUBLE_EQ((*t)->model().rate_options().lambda, 0.004);
  EXPECT_FALSE((*t)->model().rate_options().recompute_bounds);
  EXPECT_DOUBLE_EQ((*t)->model().rate_options().subset, 0.05);
  // Without the sections: the plain model. With only one of them: an error.
  auto plain_cfg = Config::from_string(
      "dataset: {format: synthetic, synthetic_width: 32, synthetic_height: 24, "
      "synthetic_views: 6}\ntrain: {threads: 1}\n",
      "plain.yaml");
  auto plain = setup_training(plain_cfg->resolve(test::rate_registry()).value(),
                              test::rate_registry(), SetupOptions());
  ASSERT_TRUE(plain.ok());
  EXPECT_FALSE((*plain)->model().has_rate());
  auto half_cfg = Config::from_string("entropy: {type: gaussian}\n", "half.yaml");
  auto half = setup_training(half_cfg->resolve(test::rate_registry()).value(),
                             test::rate_registry(), SetupOptions());
  ASSERT_FALSE(half.ok());
  EXPECT_NE(half.status().message().find("context"), std::string::npos);
}

TEST(RateTraining, HacConfigAndSweepsUseTheRateSection) {
  SKIP_WITHOUT_PLUGINS();
  const std::string root = CRPGS_SOURCE_DIR;
  auto cfg = Config::load_file(root + "/configs/hac.yaml");
  ASSERT_TRUE(cfg.ok()) << cfg.status().to_string();
  auto r = cfg->resolve(test::rate_registry());
  ASSERT_TRUE(r.ok()) << r.status().to_string();
  EXPECT_EQ(r->section("context")["type"].as<std::string>(), "hash_grid");
  EXPECT_EQ(r->section("entropy")["type"].as<std::string>(), "gaussian");
  auto ro = rate_options_from_config(r.value());
  ASSERT_TRUE(ro.ok());
  EXPECT_DOUBLE_EQ(ro->lambda, 0.001);
  EXPECT_TRUE(ro->recompute_bounds);
  EXPECT_DOUBLE_EQ(ro->q0.offset, 0.2);
  // An out-of-range weight is refused by the schema.
  auto bad = Config::from_string("rate: {lambda: 2}\n", "bad.yaml");
  ASSERT_TRUE(bad.ok());
  EXPECT_FALSE(bad->resolve(test::rate_registry()).ok());
  int sweeps = 0;
  for (const auto& entry : std::filesystem::directory_iterator(root + "/configs/sweeps")) {
    const std::string sweep = entry.path().string();
    auto spec = experiments::load_sweep(sweep);
    ASSERT_TRUE(spec.ok()) << sweep << ": " << spec.status().to_string();
    EXPECT_EQ(spec->rate_key, "rate.lambda") << sweep;
    ++sweeps;
  }
  EXPECT_GE(sweeps, 5);  // fern_rd, fern_rd_fast, lego_rd, ablation, ablation_fast
}

}  // namespace
}  // namespace crpgs

namespace crpgs {
namespace {

// The whole HAC path: train -> bitstream -> decode in the same way a fresh decoder would (from the
// bytes and the config inside them) -> the decoded model renders exactly like the training-side
// quantised model.
TEST(RateTraining, BitstreamDecodesToTheQuantisedModel) {
  SKIP_WITHOUT_PLUGINS();
  Dataset ds = test::tiny_scene();
  auto t = rate_trainer(ds, rate_schedule(26), RateOptions());
  for (int it = 0; it < 26; ++it) ASSERT_TRUE(t->step().ok());

  QuantizedAttributes q;
  auto coded = coded_model_from(t->model(), &q);
  ASSERT_TRUE(coded.ok()) << coded.status().to_string();
  // The config the decoder rebuilds the components from (as make_rate_setup built them).
  auto cfg = Config::from_string(
      "context: {type: hash_grid, log2_hashmap_size: 10, log2_hashmap_size_2d: 10}\n"
      "entropy: {type: gaussian}\nmodel: {feature_dim: 50, n_offsets: 10}\n",
      "bitstream_test.yaml");
  ASSERT_TRUE(cfg.ok());
  auto resolved = cfg->resolve(test::rate_registry());
  ASSERT_TRUE(resolved.ok()) << resolved.status().to_string();
  auto enc = encode_model(coded.value(), resolved.value(), codec_components_of(t->model()));
  ASSERT_TRUE(enc.ok()) << enc.status().to_string();

  at::set_num_threads(2);  // a different thread count than the encoder's
  auto dec = decode_model(enc->bytes, test::rate_registry());
  at::set_num_threads(1);
  ASSERT_TRUE(dec.ok()) << dec.status().to_string();
  EXPECT_TRUE(torch::equal(dec->model.feature_sym, coded->feature_sym));
  EXPECT_TRUE(torch::equal(dec->model.scaling_sym, coded->scaling_sym));
  EXPECT_TRUE(torch::equal(dec->model.offset_sym, coded->offset_sym));
  EXPECT_TRUE(torch::equal(dec->model.offset_masks, coded->offset_masks));
  EXPECT_TRUE(torch::equal(dec->params.q_f, q.params.q_f));
  auto decoded = model_from_decoded(dec.value(), t->model().options());
  ASSERT_TRUE(decoded.ok()) << decoded.status().to_string();
  const auto img =
      test::render_quantised_and_decoded(t->model(), q, *decoded.value(), ds.test.at(0).camera);
  EXPECT_GT(img.gaussians, 0);
  EXPECT_TRUE(torch::equal(img.quantised, img.decoded))
      << "max diff " << (img.quantised - img.decoded).abs().max().item<float>();
}

}  // namespace
}  // namespace crpgs
