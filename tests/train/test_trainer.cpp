// Trainer: learning works, resume is bit-identical, stop/save flags, evaluation, config wiring.
#include <gtest/gtest.h>
#include <torch/script.h>
#include <torch/torch.h>

#include <cmath>
#include <filesystem>
#include <fstream>
#include <functional>
#include <iostream>
#include <memory>

#include "crpgs/components.h"
#include "crpgs/lpips.h"
#include "crpgs/metrics.h"
#include "crpgs/scene_generator.h"
#include "crpgs/trainer.h"
#include "raster/cpu_rasterizer.h"

namespace crpgs {
namespace {

namespace fs = std::filesystem;

Dataset scene(int w, int h, int views) {
  raster::CpuRasterizer r(1);
  SyntheticSceneOptions o;
  o.width = w;
  o.height = h;
  o.views = views;
  o.sfm_points = 2000;
  auto s = generate_scene(o, r);
  if (!s.ok()) throw StatusError(s.status());
  return std::move(s).value();
}

// One thread: on a shared 2-core machine, parallel regions stall on descheduled threads.
std::unique_ptr<Trainer> trainer(const Dataset& ds, const TrainOptions& to) {
  at::set_num_threads(1);
  AnchorModelOptions mo;
  mo.voxel_size = 0.08;
  mo.lr.max_steps = to.schedule.iterations;
  auto t = make_trainer(to, mo, ds, std::make_shared<raster::CpuRasterizer>(1),
                        identity_feature_model(50));
  if (!t.ok()) throw StatusError(t.status());
  return std::move(t).value();
}

std::string tmp_dir(const std::string& name) {
  auto d = fs::path(CRPGS_TEST_TMP_DIR) / ("train_" + name);
  fs::remove_all(d);
  fs::create_directories(d);
  return d.string();
}

// A short schedule with growing and pruning inside it.
Schedule tiny_schedule(int iterations) {
  Schedule s = Schedule::scaled(0.01);  // 300 its: stats after 5, adjust every 1 from 15
  s.iterations = iterations;
  s.update_interval = 10;
  return s;
}

/// Every tensor of the two trainers' models is equal.
void expect_equal_states(Trainer& a, Trainer& b) {
  const auto sa = a.model().state_dict(), sb = b.model().state_dict();
  ASSERT_EQ(sa.size(), sb.size());
  for (const auto& kv : sa) EXPECT_TRUE(torch::equal(kv.second, sb.at(kv.first))) << kv.first;
}

TEST(Schedule, FastScalesEveryBoundary) {
  Schedule f = Schedule::scaled(0.1);
  EXPECT_EQ(f.iterations, 3000);
  EXPECT_EQ(f.start_stat, 50);
  EXPECT_EQ(f.update_from, 150);
  EXPECT_EQ(f.update_interval, 10);
  EXPECT_EQ(f.update_until, 1500);
  EXPECT_EQ(f.pause_from, 300);
  EXPECT_EQ(f.pause_until, 400);
  EXPECT_EQ(f.rate_start, 1000);
  EXPECT_EQ(Schedule::full().iterations, 30000);
}

TEST(Schedule, AnchorsAdjustEveryIntervalFromUpdateFromToUpdateUntilOutsideThePause) {
  const Schedule f = Schedule::full();  // HAC: every 100 from 1500 to 15000, paused 3000..3999
  std::vector<int> at;
  for (int it = 1; it <= f.iterations; ++it)
    if (f.adjusts_at(it)) at.push_back(it);
  EXPECT_EQ(at.front(), 1600);
  EXPECT_EQ(at.back(), 14900);
  EXPECT_EQ(std::count(at.begin(), at.end(), 3000) + std::count(at.begin(), at.end(), 3900), 0);
  EXPECT_EQ(std::count(at.begin(), at.end(), 4000), 1);
  EXPECT_EQ(at.size(), size_t(134 - 10));  // 1600..14900 in steps of 100, less 3000..3900
}

TEST(Ssim, MatchesTheMetricsLibraryAndIsOneForEqualImages) {
  auto a = torch::rand({40, 50, 3});
  auto b = (a + 0.1 * torch::randn({40, 50, 3})).clamp(0, 1);
  EXPECT_NEAR(tensor_ssim(a, a).item<double>(), 1.0, 1e-5);
  auto to_image = [](const torch::Tensor& t) {
    Image im = Image::zeros(int(t.size(1)), int(t.size(0)), 3);
    auto c = t.contiguous();
    std::copy(c.data_ptr<float>(), c.data_ptr<float>() + c.numel(), im.pixels.begin());
    return im;
  };
  auto ref = ssim(to_image(a), to_image(b));
  ASSERT_TRUE(ref.ok());
  EXPECT_NEAR(tensor_ssim(a, b).item<double>(), ref.value(), 1e-4);
}

// The training loss's SSIM and its hand-written gradient against libtorch's autograd of the
// convolution form (tensor_ssim_reference, what other devices run), in double.
torch::Tensor autograd_ssim(const torch::Tensor& a, const torch::Tensor& b) {
  return tensor_ssim_reference(a.to(torch::kDouble), b.to(torch::kDouble));
}

// Sizes with and without an interior (the window is 11 wide), one and three channels.
TEST(Ssim, ValueAndGradientMatchAutogradOfTheConvolutionForm) {
  torch::manual_seed(3);
  for (auto shape : std::vector<std::vector<int64_t>>{
           {37, 52, 3}, {12, 9, 3}, {4, 3, 1}, {11, 23, 1}, {64, 10, 3}}) {
    auto gt = torch::rand(shape);
    auto base = (gt + 0.2 * torch::randn(shape)).clamp(0, 1);
    auto x = base.clone().requires_grad_(true);
    auto s = tensor_ssim(x, gt);
    (-0.7 * s).backward();  // a loss weight, as in training
    auto xr = base.to(torch::kDouble).requires_grad_(true);
    auto sr = autograd_ssim(xr, gt);
    (-0.7 * sr).backward();
    EXPECT_NEAR(s.item<double>(), sr.item<double>(), 2e-6) << c10::IntArrayRef(shape);
    const double scale = xr.grad().abs().max().item<double>();
    EXPECT_GT(scale, 0.0);
    EXPECT_LT((x.grad().to(torch::kDouble) - xr.grad()).abs().max().item<double>(), 2e-4 * scale)
        << c10::IntArrayRef(shape);
  }
}

// In float, as a GPU runs it: the convolution form against the CPU kernel.
TEST(Ssim, FloatReferenceMatchesTheCpuKernel) {
  torch::manual_seed(4);
  auto gt = torch::rand({45, 61, 3});
  auto base = (gt + 0.15 * torch::randn({45, 61, 3})).clamp(0, 1);
  auto x = base.clone().requires_grad_(true), xr = base.clone().requires_grad_(true);
  auto s = tensor_ssim(x, gt), sr = tensor_ssim_reference(xr, gt);
  s.backward();
  sr.backward();
  EXPECT_NEAR(s.item<double>(), sr.item<double>(), 1e-5);
  const double scale = xr.grad().abs().max().item<double>();
  EXPECT_GT(scale, 0.0);
  EXPECT_LT((x.grad() - xr.grad()).abs().max().item<double>(), 1e-3 * scale);
  EXPECT_THROW(tensor_ssim_reference(x, gt.clone().requires_grad_(true)), c10::Error);
}

// A view (not contiguous) gives the same; a reference that takes a gradient is refused.
TEST(Ssim, AcceptsViewsAndRefusesAGradientOnTheReference) {
  auto gt = torch::rand({3, 20, 30}).permute({1, 2, 0});
  auto x = torch::rand({3, 20, 30}).permute({1, 2, 0});
  ASSERT_FALSE(x.is_contiguous());
  EXPECT_EQ(tensor_ssim(x, gt).item<float>(),
            tensor_ssim(x.contiguous(), gt.contiguous()).item<float>());
  EXPECT_THROW(tensor_ssim(x, gt.clone().requires_grad_(true)), c10::Error);
}

TEST(Ssim, SameResultWithOneAndTwoThreads) {
  auto gt = torch::rand({50, 60, 3});
  auto base = (gt + 0.1 * torch::randn({50, 60, 3})).clamp(0, 1);
  std::vector<torch::Tensor> values, grads;
  const int threads_before = at::get_num_threads();
  for (int threads : {1, 2}) {
    at::set_num_threads(threads);
    auto x = base.clone().requires_grad_(true);
    auto s = tensor_ssim(x, gt);
    s.backward();
    values.push_back(s.detach());
    grads.push_back(x.grad());
  }
  at::set_num_threads(threads_before);
  EXPECT_TRUE(torch::equal(values[0], values[1]));
  EXPECT_TRUE(torch::equal(grads[0], grads[1]));
}

// A broken gradient (or a loop that does not learn) stays near the initial PSNR.
TEST(Trainer, ShortTrainingRaisesTestPsnr) {
  Dataset ds = scene(48, 36, 16);
  TrainOptions to;
  to.schedule = Schedule::scaled(0.01);  // growing from 15 to 150
  to.schedule.iterations = 200;          // measured: 14.4 -> 29.0 dB after 300
  to.schedule.update_interval = 10;
  auto t = trainer(ds, to);
  auto before = t->evaluate();
  ASSERT_TRUE(before.ok()) << before.status().to_string();
  ASSERT_TRUE(t->train().ok());
  auto after = t->evaluate();
  ASSERT_TRUE(after.ok());
  const StepTimes& tm = t->times();
  std::cout << "test PSNR " << before->mean_psnr << " -> " << after->mean_psnr << " dB, SSIM "
            << before->mean_ssim << " -> " << after->mean_ssim << "; anchors "
            << t->model().num_anchors() << "; seconds: generate " << tm.generate << " render "
            << tm.render << " loss " << tm.loss << " backward " << tm.backward << " optimizer "
            << tm.optimizer << "\n";
  EXPECT_GT(after->mean_psnr, before->mean_psnr + 8.0);
  EXPECT_GT(after->mean_psnr, 20.0);
  EXPECT_GT(after->mean_ssim, before->mean_ssim);
}

TEST(Trainer, ResumeEqualsUninterrupted) {
  Dataset ds = scene(40, 30, 10);
  TrainOptions to;
  to.schedule = tiny_schedule(40);
  to.seed = 7;
  auto full = trainer(ds, to);
  ASSERT_TRUE(full->train().ok());

  to.output_dir = tmp_dir("resume");
  auto first = trainer(ds, to);
  to.schedule.iterations = 40;
  for (int i = 0; i < 23; ++i) ASSERT_TRUE(first->step().ok());  // stop mid-interval
  ASSERT_TRUE(first->save_checkpoint(first->checkpoint_path()).ok());
  auto resumed = trainer(ds, to);
  ASSERT_TRUE(resumed->load_checkpoint(first->checkpoint_path()).ok());
  EXPECT_EQ(resumed->iteration(), 23);
  ASSERT_TRUE(resumed->train().ok());

  EXPECT_EQ(resumed->model().num_anchors(), full->model().num_anchors());
  EXPECT_TRUE(torch::equal(resumed->model().anchors(), full->model().anchors()));
  expect_equal_states(*full, *resumed);
}

TEST(Trainer, RefusedCheckpointLeavesTheTrainerUnchanged) {
  Dataset ds = scene(32, 24, 6);
  TrainOptions to;
  to.schedule = tiny_schedule(20);
  to.seed = 3;
  to.output_dir = tmp_dir("refused");
  auto source = trainer(ds, to);
  for (int i = 0; i < 12; ++i) ASSERT_TRUE(source->step().ok());
  ASSERT_TRUE(source->save_checkpoint(source->checkpoint_path()).ok());
  auto target = trainer(ds, to);
  for (int i = 0; i < 5; ++i) ASSERT_TRUE(target->step().ok());
  auto before = target->model().state_dict();  // copies: a load into the live tensors shows too
  for (auto& kv : before) kv.second = kv.second.clone();
  // Rewrite the checkpoint with one entry replaced (or dropped when `value` is undefined).
  auto rewritten = [&](const std::string& key, const torch::Tensor& value) {
    torch::serialize::InputArchive in;
    in.load_from(source->checkpoint_path());
    torch::serialize::OutputArchive out;
    for (const auto& k : in.keys()) {
      torch::Tensor t;
      in.read(k, t);
      if (k != key) out.write(k, t);
    }
    if (value.defined()) out.write(key, value);
    const std::string path = to.output_dir + "/rewritten.pt";
    out.save_to(path);
    return path;
  };
  const std::vector<std::pair<std::string, torch::Tensor>> broken = {
      {"iteration", torch::Tensor()},
      {"iteration", torch::tensor(int64_t(-3))},
      {"rng", torch::zeros({3}, torch::kUInt8)},
      {"model__stat__offset_denom", torch::zeros({1})},
  };
  for (const auto& [key, value] : broken) {
    const std::string path = rewritten(key, value);
    Status st = target->load_checkpoint(path);
    EXPECT_FALSE(st.ok()) << key;
    EXPECT_EQ(target->iteration(), 5) << key;
    const auto after = target->model().state_dict();
    for (const auto& kv : before)
      EXPECT_TRUE(torch::equal(kv.second, after.at(kv.first))) << key << ": " << kv.first;
  }
}

TEST(Trainer, AStateTrainedPartlyUnderAnotherPrefixKeyIsNotPublishedAsPrefix) {
  Dataset ds = scene(32, 24, 6);
  struct Notes : ProgressCallback {
    bool refused = false;
    void on_iteration(const TrainingProgress&) override {}
    void on_note(int, const std::string& m) override {
      refused = refused || m.find("shared prefix not written") == 0;
    }
  };
  TrainOptions to;
  to.schedule = tiny_schedule(12);
  to.schedule.rate_start = 8;
  const std::string dir = tmp_dir("mixed_prefix");
  const std::string prefix = dir + "/prefix.pt";
  auto with = [&](const std::string& hash, const std::string& out, bool publish,
                  const std::string& key = "") {
    TrainOptions o = to;
    o.config_hash = hash;
    o.prefix_key = key;
    o.output_dir = out;
    o.prefix_path = publish ? prefix : "";
    return trainer(ds, o);
  };
  // Iterations 1-4 under config aaaa.
  auto a = with("aaaa", dir + "/a", false);
  for (int i = 0; i < 4; ++i) ASSERT_TRUE(a->step().ok());
  ASSERT_TRUE(a->save_checkpoint(a->checkpoint_path()).ok());
  // Resumed under bbbb: iterations 5-6 then a checkpoint, then on past rate_start.
  auto b = with("bbbb", dir + "/b", true);
  ASSERT_TRUE(b->load_checkpoint(a->checkpoint_path()).ok());
  for (int i = 0; i < 2; ++i) ASSERT_TRUE(b->step().ok());
  ASSERT_TRUE(b->save_checkpoint(dir + "/b6.pt").ok());
  Notes nb;
  ASSERT_TRUE(b->train(&nb).ok());
  EXPECT_FALSE(fs::exists(prefix));
  EXPECT_TRUE(nb.refused);
  // b's iteration-6 checkpoint resumed under bbbb itself: still mixed.
  auto b2 = with("bbbb", dir + "/b", true);
  ASSERT_TRUE(b2->load_checkpoint(dir + "/b6.pt").ok());
  ASSERT_EQ(b2->iteration(), 6);
  Notes nb2;
  ASSERT_TRUE(b2->train(&nb2).ok());
  EXPECT_FALSE(fs::exists(prefix));
  EXPECT_TRUE(nb2.refused);
  // a's checkpoint resumed under aaaa, its own config: published.
  auto a2 = with("aaaa", dir + "/a2", true);
  ASSERT_TRUE(a2->load_checkpoint(a->checkpoint_path()).ok());
  Notes na;
  ASSERT_TRUE(a2->train(&na).ok());
  EXPECT_TRUE(fs::exists(prefix));
  EXPECT_FALSE(na.refused);

  // With prefix keys recorded, the key decides: a config that differs only in what the key
  // leaves out (a rate weight, the thread counts) continues the same prefix; another key does not.
  fs::remove(prefix);
  auto k = with("kkkk", dir + "/k", false, "key1");
  for (int i = 0; i < 4; ++i) ASSERT_TRUE(k->step().ok());
  ASSERT_TRUE(k->save_checkpoint(k->checkpoint_path()).ok());
  auto other_key = with("llll", dir + "/l", true, "key2");
  ASSERT_TRUE(other_key->load_checkpoint(k->checkpoint_path()).ok());
  Notes nl;
  ASSERT_TRUE(other_key->train(&nl).ok());
  EXPECT_FALSE(fs::exists(prefix));
  EXPECT_TRUE(nl.refused);
  auto same_key = with("mmmm", dir + "/m", true, "key1");
  ASSERT_TRUE(same_key->load_checkpoint(k->checkpoint_path()).ok());
  Notes nm;
  ASSERT_TRUE(same_key->train(&nm).ok());
  EXPECT_TRUE(fs::exists(prefix));
  EXPECT_FALSE(nm.refused);
}

// A state remembers where it was trained: resumed on other thread counts and then again on the
// first ones, it is still not what one process would have trained, and says so.
TEST(Trainer, AStatesOriginSurvivesFurtherResumes) {
  Dataset ds = scene(32, 24, 6);
  TrainOptions one;
  one.schedule = tiny_schedule(4);
  one.threads = 1;
  TrainOptions two = one;
  two.threads = 2;
  const std::string dir = tmp_dir("origin");
  auto a = trainer(ds, one);
  ASSERT_TRUE(a->step().ok());
  ASSERT_TRUE(a->save_checkpoint(dir + "/a.pt").ok());
  EXPECT_EQ(a->state_origin_differences(), "");  // nothing loaded
  auto same = trainer(ds, one);
  ASSERT_TRUE(same->load_checkpoint(dir + "/a.pt").ok());
  EXPECT_EQ(same->state_origin_differences(), "");
  const std::string first = "trained with train.threads 1, rasterizer.threads 1, ";
  auto b = trainer(ds, two);
  ASSERT_TRUE(b->load_checkpoint(dir + "/a.pt").ok());
  const std::string& db = b->state_origin_differences();
  EXPECT_EQ(db.find(first), 0u) << db;
  EXPECT_NE(db.find("continued with train.threads 2, rasterizer.threads 1, "), std::string::npos)
      << db;
  EXPECT_EQ(db.find("another build"), std::string::npos) << db;
  ASSERT_TRUE(b->step().ok());
  ASSERT_TRUE(b->save_checkpoint(dir + "/b.pt").ok());
  auto c = trainer(ds, one);
  ASSERT_TRUE(c->load_checkpoint(dir + "/b.pt").ok());
  const std::string& dc = c->state_origin_differences();
  EXPECT_EQ(dc.find(first), 0u) << dc;  // b's resume, kept in the state
  EXPECT_NE(dc.find("; trained with train.threads 2, rasterizer.threads 1, "), std::string::npos)
      << dc;
  // Back to two threads: the same difference as b's resume, which the history holds once.
  ASSERT_TRUE(c->step().ok());
  ASSERT_TRUE(c->save_checkpoint(dir + "/c.pt").ok());
  auto d = trainer(ds, two);
  ASSERT_TRUE(d->load_checkpoint(dir + "/c.pt").ok());
  const std::string& dd = d->state_origin_differences();
  EXPECT_EQ(dd.find(first), 0u) << dd;
  EXPECT_EQ(dd.find(first, 1), std::string::npos) << dd;
  EXPECT_EQ(dd, dc) << "nothing new happened since c's resume";
}

struct Recorder : ProgressCallback {
  std::vector<TrainingProgress> seen;
  std::vector<std::string> checkpoints;
  TrainControl* control = nullptr;
  int stop_at = -1;
  void on_iteration(const TrainingProgress& p) override {
    seen.push_back(p);
    if (control && p.iteration == stop_at) control->stop = true;
  }
  void on_checkpoint(int, const std::string& path) override { checkpoints.push_back(path); }
};

TEST(Trainer, StopFlagSavesACheckpointAndCancels) {
  Dataset ds = scene(32, 24, 6);
  TrainOptions to;
  to.schedule = tiny_schedule(50);
  to.eval_interval = 4;
  to.output_dir = tmp_dir("stop");
  auto t = trainer(ds, to);
  TrainControl control;
  Recorder rec;
  rec.control = &control;
  rec.stop_at = 9;
  Status st = t->train(&rec, &control);
  EXPECT_EQ(st.code(), StatusCode::kCancelled);
  EXPECT_EQ(t->iteration(), 9);
  ASSERT_EQ(rec.checkpoints.size(), 1u);
  EXPECT_TRUE(fs::exists(t->checkpoint_path()));
  ASSERT_EQ(rec.seen.size(), 9u);
  EXPECT_TRUE(rec.seen[3].has_test_psnr);
  EXPECT_FALSE(rec.seen[2].has_test_psnr);
  EXPECT_GT(rec.seen.back().anchors, 0);
  EXPECT_GT(rec.seen.back().gaussians, 0);
  // No temporary files left next to the checkpoint.
  int files = 0;
  for (const auto& e : fs::directory_iterator(to.output_dir)) files += e.is_regular_file();
  EXPECT_EQ(files, 1);
}

// --- Non-finite values: detected, reported with iteration and group, never checkpointed ---------

torch::Tensor parameter(Trainer& t, const std::string& group) {
  for (const auto& [name, p] : t.model().named_parameters())
    if (name == group) return p;
  ADD_FAILURE() << "no parameter group " << group;
  return torch::Tensor();
}

/// Makes the next `*shots` gradients of `param` NaN (-1: all of them).
struct NanGradient {
  NanGradient(torch::Tensor param, int* shots) : param_(std::move(param)) {
    hook_ = param_.register_hook([shots](torch::Tensor g) {
      if (*shots == 0) return g;
      if (*shots > 0) --*shots;
      return torch::full_like(g, NAN);
    });
  }
  ~NanGradient() { param_.remove_hook(hook_); }
  torch::Tensor param_;
  unsigned hook_;
};

struct WarningRecorder : ProgressCallback {
  std::vector<std::pair<int, std::string>> warnings;
  std::function<void(int)> at_iteration;
  std::function<void()> after_warning;
  void on_iteration(const TrainingProgress& p) override {
    if (at_iteration) at_iteration(p.iteration);
  }
  void on_warning(int it, const std::string& m) override {
    warnings.emplace_back(it, m);
    if (after_warning) after_warning();
  }
};

/// For WarningRecorder::at_iteration: after iteration `at`, once, a NaN in anchor 0's feature
/// (as if an update had gone wrong).
std::function<void(int)> poison_feature_once(Trainer& t, int at, bool* injected) {
  return [&t, at, injected](int it) {
    if (it != at || *injected) return;
    *injected = true;
    torch::NoGradGuard no_grad;
    parameter(t, "feature")[0].fill_(NAN);
  };
}

TEST(Trainer, NonFiniteGradientIsReportedAndItsUpdateDiscarded) {
  Dataset ds = scene(32, 24, 6);
  TrainOptions to;
  to.schedule = tiny_schedule(20);
  to.schedule.rate_start = 10;  // the discarded update below is rate_start's
  const std::string dir = tmp_dir("discarded_update");
  to.prefix_path = dir + "/prefix.pt";
  auto t = trainer(ds, to);
  for (int i = 0; i < 5; ++i) ASSERT_TRUE(t->step().ok());
  int shots = 0;
  NanGradient nan(parameter(*t, "mlp_color.w2"), &shots);
  std::map<std::string, torch::Tensor> before;
  for (const auto& kv : t->model().state_dict()) before[kv.first] = kv.second.clone();

  shots = 1;
  auto r = t->step();
  ASSERT_EQ(shots, 0);
  ASSERT_FALSE(r.ok());
  EXPECT_EQ(r.status().code(), StatusCode::kNonFinite);
  EXPECT_NE(r.status().message().find("iteration 6"), std::string::npos) << r.status().message();
  EXPECT_NE(r.status().message().find("'mlp_color.w2'"), std::string::npos) << r.status().message();
  EXPECT_EQ(t->iteration(), 6);  // consumed, nothing updated: parameters, moments, statistics
  for (const auto& kv : t->model().state_dict())
    EXPECT_TRUE(torch::equal(kv.second, before.at(kv.first))) << kv.first;

  // train() reports such an iteration, skips it and goes on.
  WarningRecorder rec;
  rec.at_iteration = [&](int it) { shots = it == 9 ? 1 : shots; };
  ASSERT_TRUE(t->train(&rec).ok());
  ASSERT_EQ(rec.warnings.size(), 1u);
  EXPECT_EQ(rec.warnings[0].first, 10);
  EXPECT_NE(rec.warnings[0].second.find("update discarded"), std::string::npos);
  EXPECT_EQ(t->iteration(), 20);
  EXPECT_EQ(t->nonfinite_parameter_group(), "");
  // The shared prefix is published however training arrives at rate_start, even with that
  // iteration's update discarded.
  to.prefix_path.clear();
  auto from_prefix = trainer(ds, to);
  ASSERT_TRUE(from_prefix->start_from_prefix(dir + "/prefix.pt").ok());
  EXPECT_EQ(from_prefix->iteration(), 10);
}

// A checkpoint falls due once a multiple of the interval has passed since the last good state.
TEST(Trainer, ACheckpointIterationWhoseUpdateIsDiscardedCheckpointsAtTheNextStep) {
  Dataset ds = scene(32, 24, 6);
  TrainOptions to;
  to.schedule = tiny_schedule(16);
  to.checkpoint_interval = 5;
  to.checkpoint_minutes = 0;
  to.output_dir = tmp_dir("discarded_checkpoint_iteration");
  auto t = trainer(ds, to);
  struct Checkpoints : WarningRecorder {
    std::vector<int> at;
    void on_checkpoint(int it, const std::string&) override { at.push_back(it); }
  } rec;
  int shots = 0;
  NanGradient nan(parameter(*t, "mlp_color.w2"), &shots);
  rec.at_iteration = [&](int it) { shots = it == 9 ? 1 : shots; };  // iteration 10's update
  ASSERT_TRUE(t->train(&rec).ok());
  ASSERT_EQ(rec.warnings.size(), 1u);
  EXPECT_EQ(rec.warnings[0].first, 10);
  EXPECT_EQ(rec.at, (std::vector<int>{5, 11, 15, 16}));
}

// The first replay after a roll-back is exact; one that fails again draws differently.
TEST(Trainer, NonFiniteParameterRollsBackToTheLastCheckpointAndReplays) {
  Dataset ds = scene(32, 24, 6);
  TrainOptions to;
  to.schedule = tiny_schedule(30);
  to.seed = 5;
  to.checkpoint_interval = 10;
  to.eval_interval = 5;
  auto reference = trainer(ds, to);
  ASSERT_TRUE(reference->train().ok());

  to.output_dir = tmp_dir("nan_rollback");
  auto t = trainer(ds, to);
  WarningRecorder rec;
  bool injected = false;
  rec.at_iteration = poison_feature_once(*t, 15, &injected);
  ASSERT_TRUE(t->train(&rec).ok());
  ASSERT_TRUE(injected);
  ASSERT_FALSE(rec.warnings.empty());
  const std::string& last = rec.warnings.back().second;
  EXPECT_NE(last.find("'feature' is non-finite"), std::string::npos) << last;
  EXPECT_NE(last.find("rolled back to iteration 10"), std::string::npos) << last;
  // The replay from the checkpoint is deterministic: the run ends where the clean one does.
  EXPECT_EQ(t->iteration(), 30);
  // The trace was cut back with the roll-back: each evaluated iteration once.
  ASSERT_EQ(t->psnr_trace().size(), reference->psnr_trace().size());
  for (size_t i = 0; i < t->psnr_trace().size(); ++i)
    EXPECT_EQ(t->psnr_trace()[i].iteration, reference->psnr_trace()[i].iteration);
  expect_equal_states(*reference, *t);

  // A failure that comes back on the exact replay is in the draws: the next replay draws other
  // views and noise, and training gets past it.
  const int bad_view = reference->view_for_iteration(16);
  to.output_dir = tmp_dir("nan_recurring");
  auto u = trainer(ds, to);
  WarningRecorder recurring;
  int hits = 0;
  recurring.at_iteration = [&](int it) {  // a view that breaks training whenever it comes at 16
    if (it != 15 || u->view_for_iteration(16) != bad_view) return;
    ++hits;
    torch::NoGradGuard no_grad;
    parameter(*u, "feature")[0].fill_(NAN);
  };
  ASSERT_TRUE(u->train(&recurring).ok());
  ASSERT_GE(hits, 2);  // the exact replay met it again
  ASSERT_EQ(recurring.warnings.size(), size_t(hits));
  EXPECT_EQ(recurring.warnings[0].second.find("came back"), std::string::npos);
  EXPECT_NE(recurring.warnings.back().second.find("the failure came back: replaying with other"),
            std::string::npos)
      << recurring.warnings.back().second;
  EXPECT_EQ(u->iteration(), 30);
  EXPECT_EQ(u->nonfinite_parameter_group(), "");
  EXPECT_NE(u->view_for_iteration(16), bad_view);
  // A resume continues the changed draws.
  ASSERT_TRUE(u->save_checkpoint(to.output_dir + "/end.pt").ok());
  auto resumed = trainer(ds, to);
  ASSERT_TRUE(resumed->load_checkpoint(to.output_dir + "/end.pt").ok());
  for (int it = 1; it <= 30; ++it)
    EXPECT_EQ(resumed->view_for_iteration(it), u->view_for_iteration(it)) << it;
}

// A roll-back returns to a state loaded since the trainer's own snapshot of the same iteration.
TEST(Trainer, ARollBackAfterALoadReturnsToTheLoadedState) {
  Dataset ds = scene(32, 24, 6);
  TrainOptions to;
  to.schedule = tiny_schedule(24);
  to.seed = 5;
  to.eval_interval = 0;
  to.checkpoint_interval = 100;
  to.checkpoint_minutes = 0;
  const std::string dir = tmp_dir("rollback_after_load");
  // The state to load: iteration 12 of the same run with its features changed.
  auto other = trainer(ds, to);
  for (int i = 0; i < 12; ++i) ASSERT_TRUE(other->step().ok());
  {
    torch::NoGradGuard no_grad;
    parameter(*other, "feature").mul_(0.5);
  }
  ASSERT_TRUE(other->save_checkpoint(dir + "/other.pt").ok());
  ASSERT_TRUE(other->train().ok());  // the reference goes on from it uninterrupted

  to.output_dir = dir + "/run";
  auto t = trainer(ds, to);
  TrainControl control;
  Recorder stop;
  stop.control = &control;
  stop.stop_at = 12;
  ASSERT_EQ(t->train(&stop, &control).code(), StatusCode::kCancelled);  // its snapshot: 12
  ASSERT_TRUE(t->load_checkpoint(dir + "/other.pt").ok());
  WarningRecorder rec;
  bool injected = false;
  rec.at_iteration = poison_feature_once(*t, 15, &injected);
  ASSERT_TRUE(t->train(&rec).ok());
  ASSERT_TRUE(injected);
  ASSERT_FALSE(rec.warnings.empty());
  EXPECT_NE(rec.warnings.back().second.find("rolled back to iteration 12"), std::string::npos)
      << rec.warnings.back().second;
  expect_equal_states(*other, *t);
}

TEST(Trainer, PersistentNonFiniteGradientsStopWithoutABrokenCheckpoint) {
  Dataset ds = scene(32, 24, 6);
  TrainOptions to;
  to.schedule = tiny_schedule(30);
  to.checkpoint_interval = 5;
  to.max_skipped_steps = 2;
  to.max_rollbacks = 1;
  to.output_dir = tmp_dir("nan_diverged");
  auto t = trainer(ds, to);
  int shots = 0;
  auto nan = std::make_unique<NanGradient>(parameter(*t, "mlp_opacity.w1"), &shots);
  WarningRecorder rec;
  rec.at_iteration = [&](int it) { shots = it == 12 ? -1 : shots; };
  // A roll-back loads new parameter tensors: keep the fault on them.
  rec.after_warning = [&]() {
    nan = std::make_unique<NanGradient>(parameter(*t, "mlp_opacity.w1"), &shots);
  };
  Status st = t->train(&rec);
  ASSERT_EQ(st.code(), StatusCode::kNonFinite) << st.to_string();
  EXPECT_NE(st.message().find("diverged"), std::string::npos) << st.message();
  EXPECT_NE(st.message().find("'mlp_opacity.w1'"), std::string::npos) << st.message();
  EXPECT_NE(st.message().find("last good state is iteration 10"), std::string::npos)
      << st.message();
  // Skip, skip -> roll back to 10 -> skip, skip -> give up.
  EXPECT_EQ(rec.warnings.size(), 3u);
  auto restored = trainer(ds, to);
  ASSERT_TRUE(restored->load_checkpoint(t->checkpoint_path()).ok());
  EXPECT_EQ(restored->iteration(), 10);
  EXPECT_EQ(restored->nonfinite_parameter_group(), "");
}

TEST(Trainer, CheckpointsAlsoAfterTheConfiguredMinutes) {
  Dataset ds = scene(32, 24, 6);
  TrainOptions to;
  to.schedule = tiny_schedule(6);
  to.checkpoint_interval = 0;
  to.output_dir = tmp_dir("by_time");
  // Any positive time has passed after each iteration: a checkpoint after every one, and the
  // final one; minutes = 0 leaves only the final one.
  to.checkpoint_minutes = 1e-12;
  Recorder every;
  ASSERT_TRUE(trainer(ds, to)->train(&every).ok());
  EXPECT_EQ(every.checkpoints.size(), 6u);
  to.checkpoint_minutes = 0;
  to.output_dir = tmp_dir("by_time_off");
  Recorder off;
  ASSERT_TRUE(trainer(ds, to)->train(&off).ok());
  EXPECT_EQ(off.checkpoints.size(), 1u);
  // Not yet due: minutes, not seconds (the run takes seconds).
  to.checkpoint_minutes = 0.5;
  to.output_dir = tmp_dir("by_time_later");
  Recorder later;
  ASSERT_TRUE(trainer(ds, to)->train(&later).ok());
  EXPECT_EQ(later.checkpoints.size(), 1u);
}

// 20 iterations, the trace every 5, no periodic checkpoints.
TrainOptions traced_options(const std::string& name) {
  TrainOptions to;
  to.schedule = tiny_schedule(20);
  to.eval_interval = 5;
  to.checkpoint_interval = 0;
  to.output_dir = tmp_dir(name);
  return to;
}

// Stops `t` at iteration 10, as Ctrl-C would: it writes its checkpoint.
void stop_at_10(Trainer& t, Recorder& rec) {
  TrainControl control;
  rec.control = &control;
  rec.stop_at = 10;
  ASSERT_EQ(t.train(&rec, &control).code(), StatusCode::kCancelled);
  rec.control = nullptr;
}

TEST(Trainer, TrainingClockAndPsnrTraceSurviveAResume) {
  Dataset ds = scene(32, 24, 6);
  const TrainOptions to = traced_options("clock");
  auto first = trainer(ds, to);
  Recorder rec;
  ASSERT_NO_FATAL_FAILURE(stop_at_10(*first, rec));
  ASSERT_EQ(first->psnr_trace().size(), 2u);
  const double spent = first->elapsed_seconds();
  EXPECT_GT(spent, 0);
  EXPECT_DOUBLE_EQ(rec.seen.back().elapsed_seconds, spent);

  auto resumed = trainer(ds, to);
  ASSERT_TRUE(resumed->load_checkpoint(first->checkpoint_path()).ok());
  EXPECT_EQ(resumed->elapsed_seconds(), spent);
  ASSERT_EQ(resumed->psnr_trace().size(), 2u);
  ASSERT_TRUE(resumed->train().ok());
  const auto& trace = resumed->psnr_trace();
  ASSERT_EQ(trace.size(), 4u);
  for (size_t i = 0; i < trace.size(); ++i) {
    EXPECT_EQ(trace[i].iteration, 5 * int(i + 1));
    EXPECT_GT(trace[i].psnr, 0);
    if (i > 0) {
      EXPECT_GT(trace[i].seconds, trace[i - 1].seconds);
    }
  }
  EXPECT_EQ(trace[1].seconds, first->psnr_trace()[1].seconds);
  EXPECT_GT(resumed->elapsed_seconds(), spent);
  // The time per phase of the schedule spans both processes, as the clock does.
  const StepTimes &before = first->times(), &after = resumed->times();
  EXPECT_EQ(before.phase_iterations[0] + before.phase_iterations[1] + before.phase_iterations[2],
            10);
  EXPECT_EQ(after.phase_iterations[0] + after.phase_iterations[1] + after.phase_iterations[2], 20);
  EXPECT_EQ(after.iterations, 10);  // the stage split: this process's steps
  for (size_t p = 0; p < 3; ++p) EXPECT_GE(after.phase_seconds[p], before.phase_seconds[p]) << p;
}

TEST(Trainer, PsnrTraceIsTheMeanOfEvenlySpacedTestViews) {
  Dataset ds = scene(32, 24, 14);
  ds.test = ds.train;  // more held-out views than the trace takes
  ASSERT_EQ(ds.test.size(), 12u);
  const TrainOptions to = traced_options("trace_views");
  auto t = trainer(ds, to);
  const std::vector<std::string> names = t->trace_views();
  ASSERT_EQ(names.size(), size_t(Trainer::kMaxTraceViews));
  const std::vector<size_t> spaced = {0, 1, 3, 4, 6, 7, 9, 10};  // i * 12 / 8
  for (size_t i = 0; i < spaced.size(); ++i)
    EXPECT_EQ(names[i], ds.test[spaced[i]].camera.name) << i;
  ASSERT_TRUE(t->train().ok());
  ASSERT_EQ(t->psnr_trace().size(), 4u);
  double mean = 0;
  for (size_t i : spaced) mean += t->view_psnr(ds.test[i]) / double(spaced.size());
  EXPECT_DOUBLE_EQ(t->psnr_trace().back().psnr, mean);
  EXPECT_NE(t->psnr_trace().back().psnr, t->view_psnr(ds.test.front()));

  // Fewer test views than the cap: all of them.
  Dataset few = scene(32, 24, 6);
  ASSERT_GE(few.test.size(), 1u);
  EXPECT_EQ(trainer(few, to)->trace_views().size(), few.test.size());
}

TEST(Trainer, ATraceBegunOnTheFirstTestViewAloneStaysOnIt) {
  // A checkpoint from a build that traced the first test view only (no "trace_views" entry):
  // the resumed run goes on measuring that view, so its trace stays one measure.
  Dataset ds = scene(32, 24, 14);
  ds.test = ds.train;
  const TrainOptions to = traced_options("trace_legacy");
  auto first = trainer(ds, to);
  Recorder rec;
  ASSERT_NO_FATAL_FAILURE(stop_at_10(*first, rec));
  const std::string path = first->checkpoint_path();
  {
    torch::serialize::InputArchive in;
    in.load_from(path);
    torch::serialize::OutputArchive out;
    bool had_count = false;
    for (const auto& k : in.keys()) {
      if (k == "trace_views") {
        had_count = true;
        continue;
      }
      torch::Tensor v;
      in.read(k, v);
      out.write(k, v);
    }
    ASSERT_TRUE(had_count);
    out.save_to(path);
  }
  auto resumed = trainer(ds, to);
  ASSERT_EQ(resumed->trace_views().size(), size_t(Trainer::kMaxTraceViews));
  ASSERT_TRUE(resumed->load_checkpoint(path).ok());
  ASSERT_EQ(resumed->trace_views(), std::vector<std::string>{ds.test.front().camera.name});
  ASSERT_TRUE(resumed->train().ok());
  ASSERT_EQ(resumed->psnr_trace().size(), 4u);
  EXPECT_DOUBLE_EQ(resumed->psnr_trace().back().psnr, resumed->view_psnr(ds.test.front()));

  // Its own checkpoint records that count now.
  auto again = trainer(ds, to);
  ASSERT_TRUE(again->load_checkpoint(resumed->checkpoint_path()).ok());
  EXPECT_EQ(again->trace_views().size(), 1u);
}

TEST(Trainer, EvaluateWritesPngsAndMetrics) {
  Dataset ds = scene(32, 24, 9);
  TrainOptions to;
  to.schedule = tiny_schedule(5);
  auto t = trainer(ds, to);
  ASSERT_TRUE(t->train().ok());
  const std::string dir = tmp_dir("eval");
  auto r = t->evaluate(dir);
  ASSERT_TRUE(r.ok()) << r.status().to_string();
  ASSERT_EQ(r->views.size(), ds.test.size());
  // 3DGS's layout: renders/ and gt/, one PNG per test view in view order.
  for (size_t i = 0; i < ds.test.size(); ++i) {
    char name[32];
    std::snprintf(name, sizeof name, "%05zu.png", i);
    EXPECT_TRUE(fs::exists(fs::path(dir) / "renders" / name)) << name;
    EXPECT_TRUE(fs::exists(fs::path(dir) / "gt" / name)) << name;
  }
  EXPECT_TRUE(std::isfinite(r->mean_psnr));
  EXPECT_GT(r->mean_ssim, -1.0);
  EXPECT_LE(r->mean_ssim, 1.0);
  EXPECT_TRUE(std::isnan(r->mean_lpips));  // no LPIPS module given

  // With an LPIPS module (here a stand-in the test scripts: twice the mean absolute difference of
  // the [-1, 1] images), every view gets its distance, measured on the PNGs' 8-bit values.
  const std::string module = dir + "/l1.pt";
  {
    torch::jit::Module m("L1");
    m.define("def forward(self, x, y):\n    return (x - y).abs().mean()\n");
    m.save(module);
  }
  auto lpips = Lpips::load(module);
  ASSERT_TRUE(lpips.ok()) << lpips.status().to_string();
  auto with = t->evaluate(dir, lpips.value().get());
  ASSERT_TRUE(with.ok()) << with.status().to_string();
  double mean = 0;
  for (size_t i = 0; i < ds.test.size(); ++i) {
    char name[32];
    std::snprintf(name, sizeof name, "%05zu.png", i);
    auto render = load_image((fs::path(dir) / "renders" / name).string());
    auto gt = load_image((fs::path(dir) / "gt" / name).string());
    ASSERT_TRUE(render.ok() && gt.ok());
    double sum = 0;
    for (size_t k = 0; k < render->pixels.size(); ++k)
      sum += std::abs(double(render->pixels[k]) - double(gt->pixels[k]));
    const double expected = 2 * sum / double(render->pixels.size());
    EXPECT_NEAR(with->views[i].lpips, expected, 1e-5) << name;
    EXPECT_EQ(with->views[i].psnr, r->views[i].psnr);
    mean += expected / double(ds.test.size());
  }
  EXPECT_NEAR(with->mean_lpips, mean, 1e-5);
}

TEST(Lpips, AModuleThatIsNotLpipsShapedIsRefusedWithItsFileAndReason) {
  const std::string dir = tmp_dir("lpips_bad");
  std::ofstream(dir + "/text.pt") << "not a module";
  auto text = Lpips::load(dir + "/text.pt");
  ASSERT_FALSE(text.ok());
  EXPECT_NE(text.status().message().find(dir + "/text.pt: not a TorchScript module"),
            std::string::npos)
      << text.status().message();
  {
    torch::jit::Module m("PerPixel");
    m.define("def forward(self, x, y):\n    return (x - y).abs()\n");
    m.save(dir + "/per_pixel.pt");
  }
  auto per_pixel = Lpips::load(dir + "/per_pixel.pt");
  ASSERT_FALSE(per_pixel.ok());
  EXPECT_NE(per_pixel.status().message().find("expected one distance"), std::string::npos)
      << per_pixel.status().message();
  {
    torch::jit::Module m("OneInput");
    m.define("def forward(self, x):\n    return x.mean()\n");
    m.save(dir + "/one_input.pt");
  }
  auto one_input = Lpips::load(dir + "/one_input.pt");
  ASSERT_FALSE(one_input.ok());
  EXPECT_NE(one_input.status().message().find("forward(x, y) failed"), std::string::npos)
      << one_input.status().message();
}

TEST(Trainer, SetupFromConfigUsesTheSyntheticSceneAndEffects) {
  auto cfg = Config::from_string(
      "dataset: {format: synthetic, synthetic_width: 32, synthetic_height: 24, "
      "synthetic_views: 6}\n"
      "scene: {view_dependent: false, appearance_dim: 4}\n"
      "train: {schedule: fast, fast_factor: 0.001, threads: 1}\n"
      "rasterizer: {type: cpu, threads: 1}\n",
      "test.yaml");
  ASSERT_TRUE(cfg.ok()) << cfg.status().to_string();
  auto reg = builtin_registry();
  auto resolved = cfg->resolve(reg);
  ASSERT_TRUE(resolved.ok()) << resolved.status().to_string();
  SetupOptions so;
  so.output_dir = tmp_dir("setup");
  auto t = setup_training(resolved.value(), reg, so);
  ASSERT_TRUE(t.ok()) << t.status().to_string();
  EXPECT_EQ((*t)->options().schedule.iterations, 30);
  EXPECT_EQ((*t)->model().mlp_input_dim(), 51);
  EXPECT_EQ((*t)->model().color_input_dim(), 55);
  EXPECT_EQ((*t)->dataset().test.size(), 1u);
  ASSERT_TRUE((*t)->train().ok());
  EXPECT_TRUE(fs::exists((*t)->checkpoint_path()));
  // Resuming a finished run loads the checkpoint and has nothing left to do.
  so.resume = true;
  auto again = setup_training(resolved.value(), reg, so);
  ASSERT_TRUE(again.ok()) << again.status().to_string();
  EXPECT_EQ((*again)->iteration(), 30);
}

}  // namespace
}  // namespace crpgs
