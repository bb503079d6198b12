// Training with the rate path (docs/method.md §2.3-§2.6): phase switching, the rate and mask terms
// acting on a tiny generated scene, quantised evaluation, config wiring.
#include <gtest/gtest.h>
#include <torch/torch.h>

#include <cmath>
#include <filesystem>
#include <iostream>
#include <map>
#include <set>

#include "crpgs/atomic_file.h"
#include "crpgs/codec.h"
#include "crpgs/components.h"
#include "crpgs/experiments/sweep.h"
#include "crpgs/runtime.h"
#include "crpgs/scene_generator.h"
#include "crpgs/trainer.h"
#include "experiments/exp_test_util.h"
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

// train.device: the model stays on the CPU by default; `cuda` without a GPU (or with a CPU-only
// libtorch, as on CI) is refused at set-up, saying why.
TEST(RateTraining, TrainingDeviceIsTheCpuUnlessCudaIsAvailable) {
  const std::string base =
      "dataset: {format: synthetic, synthetic_width: 32, synthetic_height: 24, "
      "synthetic_views: 6}\n";
  auto plain_cfg = Config::from_string(base + "train: {threads: 1}\n", "cpu.yaml");
  ASSERT_TRUE(plain_cfg.ok());
  auto plain = setup_training(plain_cfg->resolve(test::rate_registry()).value(),
                              test::rate_registry(), SetupOptions());
  ASSERT_TRUE(plain.ok()) << plain.status().to_string();
  EXPECT_TRUE((*plain)->model().device().is_cpu());
  (*plain)->model().to(torch::kCPU);  // already there: nothing changes
  EXPECT_TRUE((*plain)->model().features().requires_grad());
  if (torch::cuda::is_available()) {
    GTEST_SKIP() << "a CUDA device is visible: the refusal without one is not testable here "
                    "(scripts/cuda-check E2E=1 trains on it)";
  }
  auto cfg = Config::from_string(
      base + "train: {threads: 1, device: cuda}\nrasterizer: {type: cpu, threads: 1}\n",
      "gpu.yaml");
  ASSERT_TRUE(cfg.ok());
  auto resolved = cfg->resolve(test::rate_registry());
  ASSERT_TRUE(resolved.ok()) << resolved.status().to_string();
  auto t = setup_training(resolved.value(), test::rate_registry(), SetupOptions());
  ASSERT_FALSE(t.ok());
  EXPECT_NE(t.status().message().find("train.device: cuda"), std::string::npos)
      << t.status().to_string();
  EXPECT_NE(t.status().message().find("no CUDA device"), std::string::npos)
      << t.status().to_string();
  // Commands that read a trained model (eval, encode, render, export) keep it on the CPU: a run
  // trained on a GPU is read on a machine without one.
  SetupOptions reading;
  reading.model_on_cpu = true;
  auto read = setup_training(resolved.value(), test::rate_registry(), reading);
  ASSERT_TRUE(read.ok()) << read.status().to_string();
  EXPECT_TRUE((*read)->model().device().is_cpu());
  // A device that does not exist is the schema's error, naming the choices.
  auto bad = Config::from_string(base + "train: {device: tpu}\n", "tpu.yaml");
  ASSERT_TRUE(bad.ok());
  auto bad_resolved = bad->resolve(test::rate_registry());
  ASSERT_FALSE(bad_resolved.ok());
  EXPECT_NE(bad_resolved.status().message().find("cuda"), std::string::npos)
      << bad_resolved.status().to_string();
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
  // Grid contexts and link strategies are one plugin kind: each in the other's section is
  // refused, not trained with no links (or failing later without a word of the config).
  if (test::rate_registry().find(CRPGS_KIND_CONTEXT, "link_random")) {
    const std::string base =
        "dataset: {format: synthetic, synthetic_width: 32, synthetic_height: 24, "
        "synthetic_views: 6}\ntrain: {threads: 1}\nentropy: {type: gaussian}\n";
    for (const auto& [text, want] : std::vector<std::pair<std::string, std::string>>{
             {"context: {type: link_random}\n",
              "swapped.yaml: context.type: 'link_random' is a link strategy; it belongs under "
              "`links:`"},
             {"context: {type: hash_grid, log2_hashmap_size: 10, log2_hashmap_size_2d: 10}\n"
              "links: {type: hash_grid}\n",
              "swapped.yaml: links.type: 'hash_grid' is a grid context; it belongs under "
              "`context:`"}}) {
      auto c = Config::from_string(base + text, "swapped.yaml");
      auto swapped = setup_training(c->resolve(test::rate_registry()).value(),
                                    test::rate_registry(), SetupOptions());
      ASSERT_FALSE(swapped.ok()) << text;
      EXPECT_EQ(swapped.status().message(), want);
    }
  } else {
    std::cout << "[ SKIPPED  ] the swapped-sections check: link_random plugin not built\n";
  }
}

// The components' random initial values (hash table, mlp_grid) follow train.seed: the same seed
// gives the same ones whatever the global generator held before, another seed others.
TEST(RateTraining, TrainSeedSeedsTheComponentsInitialValues) {
  SKIP_WITHOUT_PLUGINS();
  auto context_params = [](int seed, uint64_t disturb) {
    torch::manual_seed(disturb);
    auto cfg = Config::from_string(
        "dataset: {format: synthetic, synthetic_width: 32, synthetic_height: 24, "
        "synthetic_views: 6}\n"
        "train: {threads: 1, seed: " +
            std::to_string(seed) +
            "}\n"
            "context: {type: hash_grid, log2_hashmap_size: 10, log2_hashmap_size_2d: 10}\n"
            "entropy: {type: gaussian}\n",
        "seed.yaml");
    auto t = setup_training(cfg->resolve(test::rate_registry()).value(), test::rate_registry(),
                            SetupOptions());
    if (!t.ok()) throw StatusError(t.status());
    std::vector<torch::Tensor> out;
    for (const auto& p : (*t)->model().context()->parameters()) out.push_back(p.detach().clone());
    return out;
  };
  const auto a = context_params(3, 11), b = context_params(3, 12), c = context_params(4, 11);
  ASSERT_EQ(a.size(), b.size());
  for (size_t i = 0; i < a.size(); ++i) {
    EXPECT_TRUE(torch::equal(a[i], b[i])) << "parameter " << i;
    EXPECT_FALSE(torch::equal(a[i], c[i])) << "parameter " << i;
  }
}

// A tiny rate-path config (rate_start 10 of 30 iterations) with the given weight and seed.
Config prefix_test_config(double lambda, int seed, int threads = 1) {
  const std::string t = std::to_string(threads);
  auto cfg = Config::from_string(
      "dataset: {format: synthetic, synthetic_width: 32, synthetic_height: 24, "
      "synthetic_views: 6}\n"
      "train: {schedule: fast, fast_factor: 0.001, threads: " +
          t + ", eval_interval: 0, seed: " + std::to_string(seed) +
          "}\n"
          "rasterizer: {type: cpu, threads: " +
          t +
          "}\n"
          "context: {type: hash_grid, log2_hashmap_size: 10, log2_hashmap_size_2d: 10}\n"
          "entropy: {type: gaussian}\n"
          "rate: {lambda: " +
          std::to_string(lambda) + ", subset: 0.5, recompute_bounds: true}\n",
      "prefix.yaml");
  if (!cfg.ok()) throw StatusError(cfg.status());
  auto resolved = cfg->resolve(test::rate_registry());
  if (!resolved.ok()) throw StatusError(resolved.status());
  return resolved.value();
}

std::unique_ptr<Trainer> prefix_test_trainer(const Config& cfg, const std::string& prefix_dir) {
  auto t = setup_training(cfg, test::rate_registry(), SetupOptions{"", false, prefix_dir});
  if (!t.ok()) throw StatusError(t.status());
  return std::move(t).value();
}

bool same_state(Trainer& a, Trainer& b) {
  auto x = a.model().state_dict(), y = b.model().state_dict();
  if (x.size() != y.size()) return false;
  for (const auto& kv : x)
    if (!y.count(kv.first) || !torch::equal(kv.second, y.at(kv.first))) return false;
  return true;
}

// train.device joined the config after fern's sweeps had published prefixes: its default leaves
// a CPU run's key as the builds before it computed it (their prefixes and running sweeps go on),
// a GPU run gets its own.
TEST(RateTraining, PrefixKeyLeavesTheDefaultDeviceOut) {
  SKIP_WITHOUT_PLUGINS();
  const Config cpu = prefix_test_config(0.004, 3);
  YAML::Node tree = YAML::Load(cpu.dump());
  ASSERT_EQ(tree["train"]["device"].as<std::string>(), "cpu");
  tree["train"].remove("device");
  // feature_model_hold_lr_scale came later still; at its default it is left out too.
  ASSERT_EQ(tree["train"]["feature_model_hold_lr_scale"].as<double>(), 0.0);
  tree["train"].remove("feature_model_hold_lr_scale");
  YAML::Emitter older_text;
  older_text << tree;
  const auto older = Config::from_string(older_text.c_str(), "older.yaml");
  ASSERT_TRUE(older.ok()) << older.status().to_string();
  EXPECT_NE(older->hash(), cpu.hash());
  EXPECT_EQ(shared_prefix_key(older.value()), shared_prefix_key(cpu));
  auto gpu = Config::from_string(cpu.dump(), "gpu.yaml");  // a copy: Config shares its nodes
  ASSERT_TRUE(gpu.ok() && gpu->apply_override("train.device=cuda").ok());
  EXPECT_NE(shared_prefix_key(gpu.value()), shared_prefix_key(cpu));
  auto soft = Config::from_string(cpu.dump(), "soft.yaml");
  ASSERT_TRUE(soft.ok() && soft->apply_override("train.feature_model_hold_lr_scale=0.1").ok());
  EXPECT_NE(shared_prefix_key(soft.value()), shared_prefix_key(cpu));
}

// Nothing reads the rate weights up to rate_start, so a run that starts from another run's
// published state there ends bit-identical to the same run trained from the start.
TEST(RateTraining, SharedPrefixContinuesExactlyLikeTrainingFromTheStart) {
  SKIP_WITHOUT_PLUGINS();
  const std::string dir = std::string(CRPGS_TEST_TMP_DIR) + "/shared_prefix";
  std::filesystem::remove_all(dir);
  const Config low = prefix_test_config(0.004, 3), high = prefix_test_config(0.02, 3);
  const Config other_seed = prefix_test_config(0.02, 4);
  const std::string key = shared_prefix_key(low);
  ASSERT_EQ(key.size(), 16u);
  EXPECT_EQ(shared_prefix_key(high), key);
  EXPECT_NE(shared_prefix_key(other_seed), key);
  EXPECT_EQ(shared_prefix_key(Config::from_string("train: {seed: 1}\n", "plain.yaml").value()),
            "");  // no rate path, nothing to share

  auto first = prefix_test_trainer(low, dir);
  EXPECT_EQ(first->iteration(), 0);
  EXPECT_EQ(first->prefix_status(), "");
  ASSERT_TRUE(first->train().ok());
  const std::string prefix = dir + "/" + key + ".pt";
  ASSERT_TRUE(std::filesystem::exists(prefix));

  auto shared = prefix_test_trainer(high, dir);
  const int rate_start = shared->options().schedule.rate_start;
  ASSERT_EQ(rate_start, 10);
  EXPECT_EQ(shared->iteration(), rate_start);
  EXPECT_NE(shared->prefix_status().find("started at iteration 10"), std::string::npos)
      << shared->prefix_status();
  // Published by this build on the same threads: no note that it comes from elsewhere.
  EXPECT_EQ(shared->state_build_id(), code_build_id());
  EXPECT_EQ(shared->state_execution(), shared->execution());
  EXPECT_EQ(shared->prefix_status().find("not bit-identical"), std::string::npos)
      << shared->prefix_status();
  // Other thread counts share the prefix (they change only the last bits), and the run says so.
  // Its setup set the process's threads to 2: `shared` still trains on its own 1.
  const Config two_threads = prefix_test_config(0.02, 3, 2);
  EXPECT_NE(two_threads.hash(), high.hash());
  EXPECT_EQ(shared_prefix_key(two_threads), key);
  auto other_threads = prefix_test_trainer(two_threads, dir);
  EXPECT_EQ(other_threads->iteration(), rate_start);
  const std::string& note = other_threads->prefix_status();
  EXPECT_NE(note.find("trained with train.threads 1, rasterizer.threads 1, "), std::string::npos)
      << note;
  EXPECT_NE(note.find("continued with train.threads 2, rasterizer.threads 2, "), std::string::npos)
      << note;
  EXPECT_NE(note.find("not bit-identical"), std::string::npos) << note;
  EXPECT_EQ(note.find("another build"), std::string::npos) << note;
  struct ThreadsSeen : ProgressCallback {
    int threads = -1;
    void on_iteration(const TrainingProgress&) override { threads = at::get_num_threads(); }
  } seen;
  ASSERT_EQ(at::get_num_threads(), 2);
  ASSERT_TRUE(shared->train(&seen).ok());
  EXPECT_EQ(seen.threads, 1);
  EXPECT_EQ(at::get_num_threads(), 2);  // the process's count is back
  auto alone = prefix_test_trainer(high, "");
  ASSERT_TRUE(alone->train().ok());
  EXPECT_TRUE(same_state(*shared, *alone));
  EXPECT_FALSE(same_state(*shared, *first));  // the weight acts after rate_start

  // Another seed is another training: it does not start from this prefix.
  EXPECT_EQ(prefix_test_trainer(other_seed, dir)->iteration(), 0);

  // A prefix that is unreadable or not at rate_start is not used, and leaves the trainer as a
  // fresh one: it still trains to the same state.
  const std::string bad_dir = dir + "/bad";
  std::filesystem::create_directories(bad_dir);
  ASSERT_TRUE(write_file_atomic(bad_dir + "/" + key + ".pt", "not a checkpoint").ok());
  auto junk = prefix_test_trainer(high, bad_dir);
  EXPECT_EQ(junk->iteration(), 0);
  EXPECT_NE(junk->prefix_status().find("not used"), std::string::npos) << junk->prefix_status();
  // Moved aside, so that this run publishes a good one for the others.
  EXPECT_TRUE(std::filesystem::exists(bad_dir + "/" + key + ".pt.unusable"));
  EXPECT_FALSE(std::filesystem::exists(bad_dir + "/" + key + ".pt"));
  ASSERT_TRUE(junk->train().ok());
  EXPECT_TRUE(same_state(*junk, *alone));
  EXPECT_TRUE(std::filesystem::exists(bad_dir + "/" + key + ".pt"));
  ASSERT_TRUE(first->save_checkpoint(bad_dir + "/" + key + ".pt").ok());  // iteration 30
  auto late = prefix_test_trainer(high, bad_dir);
  EXPECT_EQ(late->iteration(), 0);
  EXPECT_NE(late->prefix_status().find("not rate_start"), std::string::npos)
      << late->prefix_status();
  ASSERT_TRUE(late->train().ok());
  EXPECT_TRUE(same_state(*late, *alone));
}

// The sweep groups runs by the key of the config it resolves; the trainer computes it from the
// config.yaml the sweep wrote. Both must agree, or no run would find its group's prefix.
TEST(RateTraining, SweepAndTrainerAgreeOnTheSharedPrefixKey) {
  SKIP_WITHOUT_PLUGINS();
  const std::string root = CRPGS_SOURCE_DIR;
  auto spec = experiments::load_sweep(root + "/configs/sweeps/fern_rd.yaml");
  ASSERT_TRUE(spec.ok()) << spec.status().to_string();
  EXPECT_TRUE(spec->share_prefix);
  const auto runs =
      experiments::expand_sweep(spec.value(), std::string(CRPGS_TEST_TMP_DIR) + "/prefix_sweep");
  ASSERT_EQ(runs.size(), 8u);
  std::set<std::string> keys;
  for (auto run : runs) {
    run.config_path = root + "/" + run.config_path;  // the sweep names them from the repository
    auto cfg = experiments::build_run_config(run, &test::rate_registry());
    ASSERT_TRUE(cfg.ok()) << cfg.status().to_string();
    ASSERT_TRUE(experiments::prepare_run(run, &test::rate_registry()).ok());
    auto saved = Config::load_file(run.dir + "/config.yaml");
    ASSERT_TRUE(saved.ok());
    auto resolved = saved->resolve(test::rate_registry());
    ASSERT_TRUE(resolved.ok());
    EXPECT_EQ(shared_prefix_key(resolved.value()), shared_prefix_key(cfg.value())) << run.id;
    keys.insert(shared_prefix_key(cfg.value()));
  }
  EXPECT_EQ(keys.size(), 2u);  // HAC's four weights share one prefix, CRP-GS's another
}

// A run finished on a GPU machine (`crpgs sweep --set train.device=cuda --set
// rasterizer.type=cuda`) counts as done here, even where this build has no CUDA rasterizer to
// resolve its config with; resuming it here would change where it computes, and says so.
TEST(RateTraining, ARunFinishedOnAGpuCountsAsDoneOnACpuBuild) {
  SKIP_WITHOUT_PLUGINS();
  const std::string root = CRPGS_SOURCE_DIR;
  auto spec = experiments::load_sweep(root + "/configs/sweeps/benchmark_fast.yaml");
  ASSERT_TRUE(spec.ok()) << spec.status().message();
  const std::string out = std::string(CRPGS_TEST_TMP_DIR) + "/gpu_sweep";
  std::filesystem::remove_all(out);
  auto runs = experiments::select_runs(experiments::expand_sweep(spec.value(), out),
                                       {"fern/crpgs/lambda-4.0e-3_*"});
  ASSERT_EQ(runs.size(), 1u);
  runs[0].config_path = root + "/" + runs[0].config_path;
  runs[0].scene = root + "/" + runs[0].scene;
  const experiments::SweepRun here = runs[0];
  ASSERT_TRUE(experiments::add_overrides(runs, {"train.device=cuda", "rasterizer.type=cuda"}).ok());
  // Unresolved: as a CUDA build wrote it (a CPU build cannot resolve the CUDA rasterizer).
  ASSERT_TRUE(experiments::prepare_run(runs[0], nullptr).ok());
  EXPECT_EQ(experiments::config_change(here, &test::rate_registry(), true), "");
  EXPECT_NE(experiments::config_change(here, &test::rate_registry()), "");
}

// fern_rd_sequential.yaml continues fern_rd.yaml's runs: the same ids and directories, and
// configs that differ only in thread counts (which a finished run's config may).
TEST(RateTraining, TheSequentialFernSweepHasFernRdsRunsAndPrefixes) {
  SKIP_WITHOUT_PLUGINS();
  const std::string root = CRPGS_SOURCE_DIR;
  auto rd = experiments::load_sweep(root + "/configs/sweeps/fern_rd.yaml");
  auto seq = experiments::load_sweep(root + "/configs/sweeps/fern_rd_sequential.yaml");
  ASSERT_TRUE(rd.ok() && seq.ok());
  const std::string out = std::string(CRPGS_TEST_TMP_DIR) + "/sequential_sweep";
  std::filesystem::remove_all(out);
  const auto a = experiments::expand_sweep(rd.value(), out);
  const auto b = experiments::expand_sweep(seq.value(), out);
  ASSERT_EQ(a.size(), b.size());
  for (size_t i = 0; i < a.size(); ++i) {
    auto run = a[i], other = b[i];
    run.config_path = root + "/" + run.config_path;
    other.config_path = root + "/" + other.config_path;
    EXPECT_EQ(run.id, other.id);
    EXPECT_EQ(run.dir, other.dir);
    EXPECT_EQ(run.method, other.method);
    ASSERT_TRUE(experiments::prepare_run(run, &test::rate_registry()).ok());
    EXPECT_EQ(experiments::config_change(other, &test::rate_registry(), true), "") << run.id;
    EXPECT_EQ(experiments::config_change(other, &test::rate_registry()),
              "rasterizer.threads: 1 -> 2, train.threads: 1 -> 2")
        << run.id;
    // ...and the same shared prefixes: either sweep continues the other's.
    EXPECT_EQ(
        shared_prefix_key(experiments::build_run_config(run, &test::rate_registry()).value()),
        shared_prefix_key(experiments::build_run_config(other, &test::rate_registry()).value()))
        << run.id;
  }
}

// fern_rd_low_rate.yaml adds rate weights to fern_rd.yaml's runs directory: new ids, and each
// method starts from the prefix fern_rd's runs of that method publish.
TEST(RateTraining, TheLowRateFernSweepAddsRunsThatShareFernRdsPrefixes) {
  SKIP_WITHOUT_PLUGINS();
  const std::string root = CRPGS_SOURCE_DIR;
  auto rd = experiments::load_sweep(root + "/configs/sweeps/fern_rd.yaml");
  auto low = experiments::load_sweep(root + "/configs/sweeps/fern_rd_low_rate.yaml");
  ASSERT_TRUE(rd.ok() && low.ok());
  EXPECT_EQ(rd->output, low->output);
  const std::string out = std::string(CRPGS_TEST_TMP_DIR) + "/low_rate_sweep";
  std::filesystem::remove_all(out);
  std::map<std::string, std::string> prefix_of_method;
  std::set<std::string> ids;
  auto key_of = [&](experiments::SweepRun run) {
    run.config_path = root + "/" + run.config_path;
    EXPECT_TRUE(experiments::prepare_run(run, &test::rate_registry()).ok()) << run.id;
    return shared_prefix_key(experiments::build_run_config(run, &test::rate_registry()).value());
  };
  for (const auto& run : experiments::expand_sweep(rd.value(), out)) {
    prefix_of_method[run.method] = key_of(run);
    ids.insert(run.id);
  }
  const auto added = experiments::expand_sweep(low.value(), out);
  ASSERT_EQ(added.size(), 4u);
  for (const auto& run : added) {
    EXPECT_EQ(ids.count(run.id), 0u) << run.id << " is one of fern_rd's runs";
    ASSERT_EQ(prefix_of_method.count(run.method), 1u) << run.method;
    EXPECT_EQ(key_of(run), prefix_of_method[run.method]) << run.id;
  }
}

// With real keys the sweep starts the first run of a group without a prefix before the runs of
// a group whose prefix is published (they can start any time from it).
TEST(RateTraining, SweepStartsTheRunsThatComputeAPrefixFirst) {
  SKIP_WITHOUT_PLUGINS();
  const std::string dir = std::string(CRPGS_TEST_TMP_DIR) + "/prefix_order";
  std::filesystem::remove_all(dir);
  std::filesystem::create_directories(dir);
  auto write = [](const std::string& path, const std::string& text) {
    ASSERT_TRUE(write_file_atomic(path, text).ok());
  };
  for (const char* name : {"a", "b"})
    write(dir + "/" + name + ".yaml",
          std::string("dataset: {format: synthetic}\ncontext: {type: hash_grid}\n"
                      "entropy: {type: gaussian}\ntrain: {seed: ") +
              (name[0] == 'a' ? "1" : "2") + "}\n");
  const std::string yaml = "output: " + dir + "/runs\nconfigs: [" + dir + "/a.yaml, " + dir +
                           "/b.yaml]\noverrides: {rate.lambda: [1.0e-4, 1.0e-3]}\n";
  const auto runs = experiments::expand_sweep(experiments::parse_sweep(yaml, "s.yaml").value());
  ASSERT_EQ(runs.size(), 4u);  // a/1e-4, a/1e-3, b/1e-4, b/1e-3
  experiments::ExecOptions opt;
  opt.runner = experiments::test::write_fake_runner(dir);
  opt.registry = &test::rate_registry();
  opt.prefix_dir = dir + "/runs/prefixes";
  opt.workers = 1;
  std::vector<std::string> started;
  opt.log = [&](const std::string& line) {
    if (line.find(": started") != std::string::npos) started.push_back(line);
  };
  // a's prefix is published; b's is not: both b runs go first (the fake runner publishes none).
  std::filesystem::create_directories(opt.prefix_dir);
  const std::string key_a =
      shared_prefix_key(experiments::build_run_config(runs[0], opt.registry).value());
  write(opt.prefix_dir + "/" + key_a + ".pt", "x");
  ASSERT_TRUE(experiments::run_sweep_local(runs, opt).ok());
  ASSERT_EQ(started.size(), 4u);
  const char* order[] = {"b/lambda-1.0e-4", "b/lambda-1.0e-3", "a/lambda-1.0e-4",
                         "a/lambda-1.0e-3"};
  for (size_t i = 0; i < 4; ++i)
    EXPECT_NE(started[i].find(order[i]), std::string::npos) << i << ": " << started[i];
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
  EXPECT_GE(sweeps, 5);  // fern_rd, fern_rd_fast, benchmark, ablation, ablation_fast
}

}  // namespace
}  // namespace crpgs

namespace crpgs {
namespace {

// A model left on its training device is refused before anything reads it through a host
// pointer (the symbols' own check is Codec.RefusesSymbolsOffTheCpu, which runs everywhere).
TEST(RateTraining, EncodeRefusesAModelOffTheCpu) {
  SKIP_WITHOUT_PLUGINS();
  if (!torch::cuda::is_available()) GTEST_SKIP() << "needs a CUDA device (AnchorModel::to)";
  Dataset ds = test::tiny_scene();
  auto t = rate_trainer(ds, rate_schedule(2), RateOptions());
  t->model().to(torch::kCUDA);
  QuantizedAttributes q;
  auto coded = coded_model_from(t->model(), &q);
  ASSERT_FALSE(coded.ok());
  EXPECT_NE(coded.status().message().find("the model is on cuda"), std::string::npos)
      << coded.status().message();
}

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
