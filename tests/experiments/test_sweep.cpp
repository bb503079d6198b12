// Sweep files: expansion, run preparation, local execution with a fake runner, resume after a
// crashed run and after the whole sweep was killed, and the Slurm script.
#include <gtest/gtest.h>
#include <signal.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>
#include <set>
#include <sstream>
#include <thread>

#include "cli_output.h"
#include "crpgs/config.h"
#include "crpgs/dir_lock.h"
#include "crpgs/experiments/run_metrics.h"
#include "crpgs/experiments/sweep.h"
#include "experiments/exp_test_util.h"

namespace crpgs::experiments {
namespace {
namespace fs = std::filesystem;
using test::fresh_dir;
using test::read_text;
using test::write_text;

/// Two base configs, a 3 x 2 grid and two datasets.
std::string sweep_yaml(const std::string& dir, const std::string& extra = "") {
  write_text(dir + "/a.yaml", "tag: a\nentropy: {lambda: 0.5}\nmodel: {sfa: 1.0}\n");
  write_text(dir + "/b.yaml", "tag: b\nentropy: {lambda: 0.5}\nmodel: {sfa: 1.0}\n");
  return "name: test_sweep\n"
         "output: " +
         dir +
         "/runs\n"
         "configs:\n"
         "  - " +
         dir +
         "/a.yaml\n"
         "  - {name: bee, path: " +
         dir +
         "/b.yaml, set: {model.extra: 7}}\n"
         "overrides:\n"
         "  entropy.lambda: [1.0e-4, 1.0e-3, 4.0e-3]\n"
         "  model.sfa: [0.5, 1]\n"
         "datasets:\n"
         "  - {name: fern, set: {dataset.path: /data/fern, dataset.format: llff}}\n"
         "  - {name: lego, set: {dataset.path: /data/lego}}\n"
         "resources: {cpus: 2, mem: 4G, time: \"01:00:00\", partition: debug}\n"
         "workers: 3\n" +
         extra;
}

TEST(Sweep, ParsesAndExpandsDeterministically) {
  const std::string dir = fresh_dir("expand");
  auto spec = parse_sweep(sweep_yaml(dir), "sweep.yaml");
  ASSERT_TRUE(spec.ok()) << spec.status().message();
  EXPECT_EQ(spec->name, "test_sweep");
  EXPECT_EQ(spec->rate_key, "entropy.lambda");  // found by name
  EXPECT_EQ(spec->workers, 3);
  EXPECT_EQ(spec->resources.mem, "4G");
  ASSERT_EQ(spec->configs.size(), 2u);
  EXPECT_EQ(spec->configs[0].name, "a");

  const auto runs = expand_sweep(spec.value());
  ASSERT_EQ(runs.size(), 2u * 2u * 3u * 2u);
  std::set<std::string> ids;
  for (size_t i = 0; i < runs.size(); ++i) {
    EXPECT_EQ(runs[i].index, static_cast<int>(i));
    ids.insert(runs[i].id);
    EXPECT_EQ(runs[i].dir, dir + "/runs/" + runs[i].id);
  }
  EXPECT_EQ(ids.size(), runs.size()) << "run ids must be unique";
  // Datasets outermost, then configs, then the grid with its first key slowest.
  EXPECT_EQ(runs[0].id, "fern/a/lambda-1.0e-4_sfa-0.5");
  EXPECT_EQ(runs[1].id, "fern/a/lambda-1.0e-4_sfa-1");
  EXPECT_EQ(runs[2].id, "fern/a/lambda-1.0e-3_sfa-0.5");
  EXPECT_EQ(runs[6].id, "fern/bee/lambda-1.0e-4_sfa-0.5");
  EXPECT_EQ(runs[12].dataset, "lego");
  // A run keeps its number in the whole sweep, whatever --only selects.
  EXPECT_EQ(run_tag(runs[12], runs.size()), "[13/24] " + runs[12].id);
  // The rate key moves along a curve; other grid keys make separate methods.
  EXPECT_EQ(runs[0].method, "a sfa=0.5");
  EXPECT_EQ(runs[1].method, "a sfa=1");
  EXPECT_DOUBLE_EQ(runs[2].rate, 1e-3);
  // Overrides in order: config set, dataset set, grid.
  const auto& o = runs[6].overrides;
  ASSERT_EQ(o.size(), 5u);
  EXPECT_EQ(o[0], (std::pair<std::string, std::string>{"model.extra", "7"}));
  EXPECT_EQ(o[1].first, "dataset.path");
  EXPECT_EQ(o[4], (std::pair<std::string, std::string>{"model.sfa", "0.5"}));

  const auto again = expand_sweep(parse_sweep(sweep_yaml(dir), "sweep.yaml").value());
  for (size_t i = 0; i < runs.size(); ++i) EXPECT_EQ(again[i].id, runs[i].id);
  // Another runs directory only moves the dirs.
  EXPECT_EQ(expand_sweep(spec.value(), "/elsewhere")[5].dir, "/elsewhere/" + runs[5].id);
}

TEST(Sweep, OnlyAndSetPickRunsAndOverrideEveryOne) {
  const std::string dir = fresh_dir("only");
  const auto runs = expand_sweep(parse_sweep(sweep_yaml(dir), "sweep.yaml").value());
  auto lego = select_runs(runs, {"lego/*"});
  ASSERT_EQ(lego.size(), runs.size() / 2);
  EXPECT_EQ(lego[0].index, 12);  // the whole sweep's numbering
  for (const auto& r : lego) EXPECT_EQ(r.dataset, "lego");
  const auto two = select_runs(runs, {"fern/a/lambda-1.0e-3_*", "*/bee/*_sfa-1"});
  ASSERT_EQ(two.size(), 2u + 6u);
  EXPECT_EQ(two[0].id, "fern/a/lambda-1.0e-3_sfa-0.5");
  EXPECT_TRUE(select_runs(runs, {"mic/*"}).empty());
  EXPECT_EQ(select_runs(runs, {}).size(), runs.size());

  ASSERT_TRUE(add_overrides(lego, {"train.device=cuda", "rasterizer.type=cuda"}).ok());
  for (const auto& r : lego) {
    ASSERT_GE(r.overrides.size(), 2u);
    EXPECT_EQ(r.overrides.back(), (std::pair<std::string, std::string>{"rasterizer.type", "cuda"}));
  }
  // Another rasterizer type drops the settings of the sweep's own (its threads).
  std::vector<SweepRun> gpu(1);
  gpu[0].overrides = {{"rasterizer.threads", "1"}, {"train.threads", "1"}, {"rasterizer2.x", "3"}};
  ASSERT_TRUE(add_overrides(gpu, {"rasterizer.type=cuda"}).ok());
  EXPECT_EQ(
      gpu[0].overrides,
      (Overrides{{"train.threads", "1"}, {"rasterizer2.x", "3"}, {"rasterizer.type", "cuda"}}));
  const Status bad = add_overrides(lego, {"train.device"});
  EXPECT_EQ(bad.code(), StatusCode::kInvalidArgument);
  EXPECT_NE(bad.message().find("KEY=VALUE"), std::string::npos) << bad.message();
}

TEST(Sweep, RejectsBadFiles) {
  EXPECT_FALSE(parse_sweep("configs: []\n", "s.yaml").ok());
  EXPECT_FALSE(parse_sweep("configs: [a.yaml]\nbogus: 1\n", "s.yaml").ok());
  EXPECT_FALSE(parse_sweep("configs: [x/a.yaml, y/a.yaml]\n", "s.yaml").ok());  // same name
  EXPECT_FALSE(parse_sweep("configs: [a.yaml]\nworkers: 0\n", "s.yaml").ok());
  // Resources are pasted into #SBATCH lines: one word each.
  EXPECT_FALSE(parse_sweep("configs: [a.yaml]\nresources: {mem: \"4 G\"}\n", "s.yaml").ok());
  EXPECT_FALSE(
      parse_sweep("configs: [a.yaml]\nresources: {partition: \"a\\nb\"}\n", "s.yaml").ok());
  EXPECT_FALSE(parse_sweep("configs: [a.yaml]\ndatasets: [{set: {}}]\n", "s.yaml").ok());
  auto st = parse_sweep("configs: [a.yaml]\nbogus: 1\n", "s.yaml");
  EXPECT_NE(st.status().message().find("bogus"), std::string::npos);
  st = parse_sweep("configs: [a.yaml]\nworker: 2\n", "s.yaml");
  EXPECT_NE(st.status().message().find("unknown key 'worker', did you mean 'workers'? (expected "
                                       "name, output, configs,"),
            std::string::npos)
      << st.status().message();
  // A key that is not text: the message still names the file.
  st = parse_sweep("configs: [a.yaml]\n[1, 2]: 3\n", "s.yaml");
  ASSERT_FALSE(st.ok());
  EXPECT_NE(st.status().message().find("s.yaml"), std::string::npos) << st.status().message();
  // Names that differ only where run directories cannot: refused, not merged into one run.
  st = parse_sweep("configs: [{name: a b, path: a.yaml}, {name: a_b, path: b.yaml}]\n", "s.yaml");
  ASSERT_FALSE(st.ok());
  EXPECT_NE(st.status().message().find("two runs would share the directory 'default/a_b/base'"),
            std::string::npos)
      << st.status().message();
  EXPECT_FALSE(
      parse_sweep("configs: [a.yaml]\noverrides: {train.tag: [x/y, x_y]}\n", "s.yaml").ok());
  // "." and ".." do not lead out of the runs directory.
  auto dots = parse_sweep("configs: [a.yaml]\ndatasets: [{name: ..}]\n", "s.yaml");
  ASSERT_TRUE(dots.ok()) << dots.status().message();
  EXPECT_EQ(expand_sweep(dots.value())[0].id, "__/a/base");
  // No grid: one run per config and dataset, named "base".
  auto one = parse_sweep("configs: [a.yaml]\n", "dir/s.yaml");
  ASSERT_TRUE(one.ok());
  EXPECT_EQ(one->output, "runs/s");
  const auto runs = expand_sweep(one.value());
  ASSERT_EQ(runs.size(), 1u);
  EXPECT_EQ(runs[0].id, "default/a/base");
}

TEST(Sweep, PrepareRunWritesConfigAndRunJson) {
  const std::string dir = fresh_dir("prepare");
  const auto runs = expand_sweep(parse_sweep(sweep_yaml(dir), "s.yaml").value());
  const SweepRun& r = runs[7];  // fern/bee/lambda-1.0e-4_sfa-1
  ASSERT_TRUE(prepare_run(r, nullptr).ok());
  auto cfg = Config::load_file(r.dir + "/config.yaml");
  ASSERT_TRUE(cfg.ok()) << cfg.status().message();
  EXPECT_DOUBLE_EQ(cfg->root()["entropy"]["lambda"].as<double>(), 1e-4);
  EXPECT_EQ(cfg->root()["model"]["sfa"].as<int>(), 1);
  EXPECT_EQ(cfg->root()["model"]["extra"].as<int>(), 7);
  EXPECT_EQ(cfg->root()["dataset"]["path"].as<std::string>(), "/data/fern");
  // Relative dataset paths become absolute: from a base config, against its directory; from the
  // sweep file, against the working directory.
  write_text(dir + "/rel.yaml", "dataset: {path: ../data/x}\n");
  SweepRun rel = r;
  rel.config_path = dir + "/rel.yaml";
  rel.overrides = {};
  auto c1 = build_run_config(rel, nullptr);
  ASSERT_TRUE(c1.ok());
  EXPECT_EQ(c1->root()["dataset"]["path"].as<std::string>(),
            (fs::path(dir).parent_path() / "data/x").string());
  rel.overrides = {{"dataset.path", "some/where"}};
  auto c2 = build_run_config(rel, nullptr);
  ASSERT_TRUE(c2.ok());
  EXPECT_EQ(c2->root()["dataset"]["path"].as<std::string>(),
            (fs::current_path() / "some/where").string());
  EXPECT_EQ(cfg->root()["tag"].as<std::string>(), "b");
  const std::string info = read_text(r.dir + "/run.json");
  EXPECT_NE(info.find("\"method\": \"bee sfa=1\""), std::string::npos) << info;
  EXPECT_NE(info.find("\"rate\": 0.0001"), std::string::npos) << info;
  EXPECT_EQ(run_state(r.dir), RunState::kPending);
}

// A dataset entry may name a scene file (configs/scenes/*/scene.yaml): its keys are laid over
// each config before the sweep's overrides, its relative dataset path is against the scene
// file, and it is recorded in run.json; a component block there is refused.
TEST(Sweep, ADatasetsSceneFileIsLaidOverEachConfig) {
  const std::string dir = fresh_dir("scene");
  fs::create_directories(dir + "/scenes/lego");
  write_text(dir + "/scenes/lego/scene.yaml",
             "dataset: {path: ../../data/lego, format: nerf_synthetic, downscale: 2}\n"
             "scene: {background: [1, 1, 1]}\nmodel: {voxel_size: 0.01}\n");
  write_text(dir + "/a.yaml",
             "dataset: {path: fern, format: colmap, images: images_8}\nmodel: {voxel_size: 0, "
             "sfa: 1.0}\nentropy: {lambda: 0.5}\n");
  const std::string yaml = "output: " + dir + "/runs\nconfigs: [" + dir +
                           "/a.yaml]\noverrides: {entropy.lambda: [1.0e-3]}\n"
                           "datasets:\n  - {name: lego, scene: " +
                           dir + "/scenes/lego/scene.yaml, set: {model.voxel_size: 0.02}}\n";
  auto spec = parse_sweep(yaml, "s.yaml");
  ASSERT_TRUE(spec.ok()) << spec.status().message();
  const auto runs = expand_sweep(*spec);
  ASSERT_EQ(runs.size(), 1u);
  EXPECT_EQ(runs[0].scene, dir + "/scenes/lego/scene.yaml");
  auto cfg = build_run_config(runs[0], nullptr);
  ASSERT_TRUE(cfg.ok()) << cfg.status().message();
  const YAML::Node& root = cfg->root();
  EXPECT_EQ(root["dataset"]["path"].as<std::string>(), (fs::path(dir) / "data/lego").string());
  EXPECT_EQ(root["dataset"]["format"].as<std::string>(), "nerf_synthetic");
  EXPECT_EQ(root["dataset"]["images"].as<std::string>(), "images_8");  // the scene leaves it
  EXPECT_EQ(root["dataset"]["downscale"].as<int>(), 2);
  EXPECT_EQ(root["scene"]["background"][2].as<double>(), 1.0);
  EXPECT_DOUBLE_EQ(root["model"]["voxel_size"].as<double>(), 0.02);  // the sweep's set wins
  EXPECT_DOUBLE_EQ(root["model"]["sfa"].as<double>(), 1.0);
  EXPECT_DOUBLE_EQ(root["entropy"]["lambda"].as<double>(), 1e-3);
  ASSERT_TRUE(prepare_run(runs[0], nullptr).ok());
  EXPECT_NE(read_text(runs[0].dir + "/run.json").find("\"scene\": \"" + runs[0].scene + "\""),
            std::string::npos);

  write_text(dir + "/scenes/bad.yaml", "features: {type: sfa}\n");
  SweepRun bad = runs[0];
  bad.scene = dir + "/scenes/bad.yaml";
  auto refused = build_run_config(bad, nullptr);
  ASSERT_FALSE(refused.ok());
  EXPECT_NE(refused.status().message().find("found 'features'"), std::string::npos)
      << refused.status().message();
  bad.scene = dir + "/scenes/missing.yaml";
  EXPECT_FALSE(build_run_config(bad, nullptr).ok());
  auto typo = parse_sweep(yaml + "  - {name: mic, scen: x.yaml}\n", "s.yaml");
  ASSERT_FALSE(typo.ok());
  EXPECT_NE(typo.status().message().find("unknown key 'scen'"), std::string::npos)
      << typo.status().message();
}

struct LocalSweep {
  std::string dir, runner, log;
  std::vector<SweepRun> runs;
  ExecOptions opt;
  std::vector<std::string> lines;

  explicit LocalSweep(const std::string& name) {
    dir = fresh_dir(name);
    runner = test::write_fake_runner(dir);
    log = dir + "/calls.log";
    // Smaller: one dataset, 2 configs x 3 lambdas.
    const std::string yaml = "output: " + dir + "/runs\nconfigs: [" + dir + "/a.yaml, " + dir +
                             "/b.yaml]\noverrides: {entropy.lambda: [1.0e-4, 1.0e-3, 4.0e-3]}\n"
                             "datasets: [{name: fern}]\n";
    write_text(dir + "/a.yaml", "tag: a\nentropy:\n  lambda: 0.5\n");
    write_text(dir + "/b.yaml", "tag: b\nentropy:\n  lambda: 0.5\n");
    runs = expand_sweep(parse_sweep(yaml, "s.yaml").value());
    opt.runner = runner;
    opt.workers = 2;
    opt.log = [this](const std::string& s) { lines.push_back(s); };
    setenv("FAKE_LOG", log.c_str(), 1);
    unsetenv("FAKE_CRASH");
    unsetenv("FAKE_HANG");
  }
  ~LocalSweep() {
    unsetenv("FAKE_LOG");
    unsetenv("FAKE_CRASH");
    unsetenv("FAKE_HANG");
  }
  /// Lines of the fake runner's call log.
  std::vector<std::string> calls() const {
    std::vector<std::string> out;
    std::istringstream in(read_text(log));
    for (std::string l; std::getline(in, l);) out.push_back(l);
    return out;
  }
};

TEST(Sweep, OneModelRunsAreReEncodedAtEachScaleOnce) {
  LocalSweep s("one_model");
  const std::string yaml =
      "output: " + s.dir + "/runs\nconfigs: [" + s.dir +
      "/a.yaml]\noverrides: {entropy.lambda: [1.0e-4, 1.0e-3]}\n"
      "datasets: [{name: fern}]\none_model: {rate: 1.0e-3, scales: [1, 2.5]}\n";
  auto spec = parse_sweep(yaml, "s.yaml");
  ASSERT_TRUE(spec.ok()) << spec.status().message();
  EXPECT_EQ(spec->one_model_scales, (std::vector<double>{1, 2.5}));
  const auto runs = expand_sweep(spec.value());
  s.opt.one_model_rate = spec->one_model_rate;
  s.opt.one_model_scales = spec->one_model_scales;
  auto sum = run_sweep_local(runs, s.opt);
  ASSERT_TRUE(sum.ok()) << sum.status().message();
  EXPECT_EQ(sum->succeeded, 2);
  EXPECT_EQ(sum->failed, 0);
  const SweepRun& at = runs[1];  // λ 1e-3
  ASSERT_EQ(at.id, "fern/a/lambda-1.0e-3");
  for (double v : {1.0, 2.5}) {
    auto m = read_run_metrics(rate_scale_dir(at.dir, v) + "/metrics.json");
    ASSERT_TRUE(m.ok()) << m.status().message();
    EXPECT_EQ(m->rate_scale, v);
    EXPECT_EQ(m->base_method, at.method);
  }
  EXPECT_FALSE(fs::exists(runs[0].dir + "/rates"));  // another λ: not re-encoded
  auto calls = s.calls();
  ASSERT_EQ(calls.size(), 3u);
  EXPECT_EQ(calls.back(), "encode " + at.dir + " 1,2.5");
  EXPECT_NE(read_text(at.dir + "/stdout.log").find("encode " + at.dir + " --rate-scales 1,2.5"),
            std::string::npos);

  // Done: nothing runs again; a scale lost is re-encoded (the finished run is not retrained).
  auto again = run_sweep_local(runs, s.opt);
  ASSERT_TRUE(again.ok());
  EXPECT_EQ(s.calls().size(), 3u);
  fs::remove_all(rate_scale_dir(at.dir, 2.5));
  again = run_sweep_local(runs, s.opt);
  ASSERT_TRUE(again.ok());
  EXPECT_EQ(again->skipped, 2);
  calls = s.calls();
  ASSERT_EQ(calls.size(), 4u);
  EXPECT_EQ(calls.back(), "encode " + at.dir + " 1,2.5");
  EXPECT_TRUE(fs::exists(rate_scale_dir(at.dir, 2.5) + "/metrics.json"));

  for (const char* bad : {"one_model: {rate: 1.0e-3}", "one_model: {rate: 1.0e-3, scales: [0]}",
                          "one_model: {rate: 1.0e-3, scales: [2], extra: 1}"}) {
    auto b = parse_sweep(
        "configs: [a.yaml]\noverrides: {rate.lambda: [1.0e-3]}\n" + std::string(bad) + "\n",
        "bad.yaml");
    ASSERT_FALSE(b.ok()) << bad;
    EXPECT_NE(b.status().message().find("one_model"), std::string::npos) << b.status().message();
  }
}

TEST(Sweep, LocalRunSkipsFinishedRunsAndRerunsACrashedOne) {
  LocalSweep s("local");
  setenv("FAKE_CRASH", "fern/b/lambda-1.0e-3", 1);
  auto sum = run_sweep_local(s.runs, s.opt);
  ASSERT_TRUE(sum.ok()) << sum.status().message();
  EXPECT_EQ(sum->total, 6);
  EXPECT_EQ(sum->succeeded, 5);
  EXPECT_EQ(sum->failed, 1);
  ASSERT_EQ(sum->failed_ids.size(), 1u);
  EXPECT_EQ(sum->failed_ids[0], "fern/b/lambda-1.0e-3");
  EXPECT_EQ(s.calls().size(), 6u);
  const SweepRun& crashed = s.runs[4];
  ASSERT_EQ(crashed.id, "fern/b/lambda-1.0e-3");
  EXPECT_EQ(run_state(crashed.dir), RunState::kInterrupted);
  EXPECT_NE(read_text(crashed.dir + "/stderr.log").find("fake crash"), std::string::npos);
  for (const auto& r : s.runs) {
    EXPECT_TRUE(fs::exists(r.dir + "/config.yaml")) << r.id;
    EXPECT_TRUE(fs::exists(r.dir + "/stdout.log")) << r.id;
    // The run's method reaches `crpgs train`, so metrics.json names it as run.json does.
    EXPECT_EQ(read_text(r.dir + "/method_arg"), r.method + "\n") << r.id;
    if (&r != &crashed) {
      EXPECT_EQ(run_state(r.dir), RunState::kComplete) << r.id;
    }
  }

  // Second pass: only the crashed run runs again, resuming from its checkpoint.
  auto again = run_sweep_local(s.runs, s.opt);
  ASSERT_TRUE(again.ok());
  EXPECT_EQ(again->skipped, 5);
  EXPECT_EQ(again->succeeded, 1);
  EXPECT_EQ(again->failed, 0);
  const auto calls = s.calls();
  ASSERT_EQ(calls.size(), 7u);
  EXPECT_EQ(calls.back(), crashed.dir + " --resume");
  for (const auto& r : s.runs) EXPECT_EQ(run_state(r.dir), RunState::kComplete) << r.id;

  // Third pass: nothing to do.
  auto third = run_sweep_local(s.runs, s.opt);
  ASSERT_TRUE(third.ok());
  EXPECT_EQ(third->skipped, 6);
  EXPECT_EQ(s.calls().size(), 7u);
}

TEST(Sweep, ResumesAfterTheSweepItselfWasKilled) {
  LocalSweep s("killed");
  const SweepRun& hung = s.runs[2];  // fern/a/lambda-4.0e-3
  setenv("FAKE_HANG", hung.id.c_str(), 1);
  s.opt.workers = 1;  // runs 0 and 1 finish before run 2 hangs; 3..5 never start
  const pid_t child = fork();
  ASSERT_GE(child, 0);
  if (child == 0) {
    setpgid(0, 0);  // its own process group, so the kill below takes the runner too
    auto sum = run_sweep_local(s.runs, s.opt);
    _exit(sum.ok() ? 0 : 1);
  }
  setpgid(child, child);
  // Wait (bounded) for the hanging run to start, then kill the sweep and its runner.
  for (int i = 0; i < 600 && !fs::exists(hung.dir + "/hang_started"); ++i)
    std::this_thread::sleep_for(std::chrono::milliseconds(50));
  ASSERT_TRUE(fs::exists(hung.dir + "/hang_started")) << "the fake runner never started";
  kill(-child, SIGKILL);
  int status = 0;
  waitpid(child, &status, 0);
  EXPECT_TRUE(WIFSIGNALED(status));
  // The runner held the run's lock (handed over by the sweep) and is not our child: the kernel
  // releases the lock when it has died, which may be a moment after the sweep.
  for (int i = 0; i < 200 && !directory_lock_holder(hung.dir).empty(); ++i)
    std::this_thread::sleep_for(std::chrono::milliseconds(10));
  ASSERT_EQ(directory_lock_holder(hung.dir), "") << "the killed runner still holds the run";

  EXPECT_EQ(run_state(s.runs[0].dir), RunState::kComplete);
  EXPECT_EQ(run_state(s.runs[1].dir), RunState::kComplete);
  EXPECT_EQ(run_state(hung.dir), RunState::kInterrupted);  // the .running marker is left
  EXPECT_EQ(run_state(s.runs[3].dir), RunState::kPending);
  ASSERT_EQ(s.calls().size(), 3u);

  unsetenv("FAKE_HANG");
  s.opt.workers = 2;
  auto sum = run_sweep_local(s.runs, s.opt);
  ASSERT_TRUE(sum.ok());
  EXPECT_EQ(sum->skipped, 2);
  EXPECT_EQ(sum->succeeded, 4);
  const auto calls = s.calls();
  ASSERT_EQ(calls.size(), 7u);
  std::multiset<std::string> rerun(calls.begin() + 3, calls.end());
  EXPECT_EQ(rerun.count(hung.dir + " --resume"), 1u);  // resumed from its checkpoint
  EXPECT_EQ(rerun.count(s.runs[0].dir), 0u);           // finished runs are not rerun
  EXPECT_EQ(rerun.count(s.runs[1].dir), 0u);
  for (const auto& r : s.runs) EXPECT_EQ(run_state(r.dir), RunState::kComplete) << r.id;
}

TEST(Sweep, SkipsARunAnotherProcessHolds) {
  LocalSweep s("locked");
  auto lock = lock_directory(s.runs[2].dir);  // as a `crpgs train -o` elsewhere would
  ASSERT_TRUE(lock.ok());
  auto sum = run_sweep_local(s.runs, s.opt);
  ASSERT_TRUE(sum.ok());
  EXPECT_EQ(sum->succeeded, 5);
  EXPECT_EQ(sum->skipped, 1);
  EXPECT_EQ(s.calls().size(), 5u);
  EXPECT_EQ(run_state(s.runs[2].dir), RunState::kPending);
  const std::string expected =
      s.runs[2].id + ": running in another process (pid " + std::to_string(::getpid()) + " since ";
  EXPECT_TRUE(std::any_of(s.lines.begin(), s.lines.end(), [&](const std::string& l) {
    return l.find(expected) != std::string::npos;
  }));

  lock = DirectoryLock();  // the other process is done: the next pass runs it
  auto again = run_sweep_local(s.runs, s.opt);
  ASSERT_TRUE(again.ok());
  EXPECT_EQ(again->succeeded, 1);
  EXPECT_EQ(again->skipped, 5);
  EXPECT_EQ(run_state(s.runs[2].dir), RunState::kComplete);
}

// Taken after the sweep's first look, while an earlier run trains: the sweep neither writes into
// that directory nor starts it.
TEST(Sweep, LeavesARunAloneThatAnotherProcessTookSinceTheStart) {
  LocalSweep s("locked_later");
  s.opt.workers = 1;
  DirectoryLock lock;
  s.opt.log = [&](const std::string& line) {
    s.lines.push_back(line);
    if (!lock.held() && line.find(s.runs[0].id + ": started") != std::string::npos)
      lock = lock_directory(s.runs[2].dir).value();
  };
  auto sum = run_sweep_local(s.runs, s.opt);
  ASSERT_TRUE(sum.ok());
  ASSERT_TRUE(lock.held());
  EXPECT_EQ(sum->succeeded, 5);
  EXPECT_EQ(sum->skipped, 1);
  EXPECT_FALSE(fs::exists(s.runs[2].dir + "/config.yaml"));  // not prepared, not started
  EXPECT_EQ(run_state(s.runs[2].dir), RunState::kPending);
  EXPECT_TRUE(std::any_of(s.lines.begin(), s.lines.end(), [&](const std::string& l) {
    return l.find(s.runs[2].id + ": running in another process (pid ") != std::string::npos;
  }));
}

TEST(Sweep, StopStartsNothingMoreAndStopsTheRunningRun) {
  LocalSweep s("stop");
  const SweepRun& hung = s.runs[1];
  setenv("FAKE_HANG", hung.id.c_str(), 1);
  s.opt.workers = 1;  // run 0 finishes, run 1 hangs until stopped, 2..5 must not start
  std::atomic<bool> stop{false};
  s.opt.stop = &stop;
  std::thread ctrl_c([&] {  // what the CLI's SIGINT/SIGTERM handler does
    for (int i = 0; i < 600 && !fs::exists(hung.dir + "/hang_started"); ++i)
      std::this_thread::sleep_for(std::chrono::milliseconds(50));
    stop = true;
  });
  auto sum = run_sweep_local(s.runs, s.opt);
  ctrl_c.join();
  ASSERT_TRUE(sum.ok()) << sum.status().message();
  EXPECT_EQ(sum->succeeded, 1);
  EXPECT_EQ(sum->interrupted, 1);
  EXPECT_EQ(sum->failed, 0);
  EXPECT_EQ(s.calls().size(), 2u);
  EXPECT_EQ(run_state(hung.dir), RunState::kInterrupted);
  for (size_t i = 2; i < s.runs.size(); ++i)
    EXPECT_EQ(run_state(s.runs[i].dir), RunState::kPending) << s.runs[i].id;
  EXPECT_TRUE(std::any_of(s.lines.begin(), s.lines.end(), [&](const std::string& l) {
    return l.find(hung.id + ": stopped (killed by signal 15)") != std::string::npos;
  }));

  // The same sweep again resumes the stopped run and runs the rest.
  unsetenv("FAKE_HANG");
  stop = false;
  auto again = run_sweep_local(s.runs, s.opt);
  ASSERT_TRUE(again.ok());
  EXPECT_EQ(again->succeeded, 5);
  EXPECT_EQ(again->interrupted, 0);
  const auto calls = s.calls();
  ASSERT_EQ(calls.size(), 7u);
  EXPECT_EQ(calls[2], hung.dir + " --resume");
}

TEST(Sweep, TheRunnerHoldsTheRunsLockFromItsStart) {
  // The sweep hands its lock to the runner, so there is no moment in which another sweep could
  // take the run (the fake runner never locks by itself).
  LocalSweep s("handed_lock");
  const SweepRun& hung = s.runs[0];
  setenv("FAKE_HANG", hung.id.c_str(), 1);
  s.opt.workers = 1;
  std::atomic<bool> stop{false};
  s.opt.stop = &stop;
  std::string holder;
  std::thread watch([&] {
    for (int i = 0; i < 600 && !fs::exists(hung.dir + "/hang_started"); ++i)
      std::this_thread::sleep_for(std::chrono::milliseconds(50));
    holder = directory_lock_holder(hung.dir);
    stop = true;
  });
  auto sum = run_sweep_local(s.runs, s.opt);
  watch.join();
  unsetenv("FAKE_HANG");
  ASSERT_TRUE(sum.ok()) << sum.status().message();
  EXPECT_EQ(sum->interrupted, 1);
  EXPECT_NE(holder, "") << "the run was unlocked while its runner ran";
  EXPECT_EQ(directory_lock_holder(hung.dir), "");  // released with the runner
}

TEST(Sweep, AFinishedRunWhoseConfigChangedIsKeptAndNamed) {
  LocalSweep s("changed");
  auto first = run_sweep_local(s.runs, s.opt);
  ASSERT_TRUE(first.ok());
  EXPECT_EQ(config_change(s.runs[0], nullptr), "");
  SweepRun edited = s.runs[0];
  edited.overrides.emplace_back("entropy.lambda", "0.25");
  EXPECT_EQ(config_change(edited, nullptr), "entropy.lambda: 1.0e-4 -> 0.25");
  // Thread counts change how a run is computed, not what it is: a finished run stands.
  SweepRun threads = s.runs[0];
  threads.overrides.emplace_back("train.threads", "2");
  EXPECT_EQ(config_change(threads, nullptr, true), "");
  EXPECT_EQ(config_change(threads, nullptr), "train.threads: (none) -> 2");
  // So does where it ran (a GPU machine, `crpgs sweep --set train.device=cuda`).
  SweepRun gpu = s.runs[0];
  gpu.overrides.emplace_back("train.device", "cuda");
  gpu.overrides.emplace_back("rasterizer.type", "cuda");
  EXPECT_EQ(config_change(gpu, nullptr, true), "");
  EXPECT_NE(config_change(gpu, nullptr).find("train.device: (none) -> cuda"), std::string::npos);
  edited.overrides.emplace_back("train.threads", "2");
  EXPECT_EQ(config_change(edited, nullptr, true), "entropy.lambda: 1.0e-4 -> 0.25");
  s.lines.clear();
  auto again = run_sweep_local({edited}, s.opt);
  ASSERT_TRUE(again.ok());
  EXPECT_EQ(again->skipped, 1);
  ASSERT_EQ(s.lines.size(), 1u);
  EXPECT_NE(s.lines[0].find(": done, but the sweep now asks for another config (entropy.lambda: "
                            "1.0e-4 -> 0.25); kept: delete "),
            std::string::npos)
      << s.lines[0];
  EXPECT_EQ(s.calls().size(), s.runs.size());  // nothing rerun
}

TEST(Sweep, DryRunStartsNothing) {
  LocalSweep s("dry");
  s.opt.dry_run = true;
  auto sum = run_sweep_local(s.runs, s.opt);
  ASSERT_TRUE(sum.ok());
  EXPECT_EQ(sum->total, 6);
  EXPECT_EQ(sum->succeeded, 0);
  EXPECT_FALSE(fs::exists(s.log));
  EXPECT_FALSE(fs::exists(s.runs[0].dir));
  EXPECT_EQ(s.lines.size(), 6u);
  EXPECT_EQ(sum->failed, 0);
  // A broken config is reported, still without running anything.
  fs::remove(s.runs[4].config_path);
  auto bad = run_sweep_local(s.runs, s.opt);
  ASSERT_TRUE(bad.ok());
  EXPECT_EQ(bad->failed, 3);  // the three runs of b.yaml
  EXPECT_NE(s.lines.back().find("CONFIG ERROR"), std::string::npos) << s.lines.back();
  EXPECT_FALSE(fs::exists(s.log));
}

TEST(Sweep, RunOneRunsASingleRun) {
  LocalSweep s("one");
  std::vector<std::string> lines;
  s.opt.log = [&](const std::string& line) { lines.push_back(line); };
  s.opt.sweep_size = int(s.runs.size());
  ASSERT_TRUE(run_one(s.runs[3], s.opt).ok());
  ASSERT_FALSE(lines.empty());  // tagged with its place in the whole sweep
  EXPECT_EQ(lines[0].rfind("[4/" + std::to_string(s.runs.size()) + "] ", 0), 0u) << lines[0];
  EXPECT_EQ(run_state(s.runs[3].dir), RunState::kComplete);
  EXPECT_EQ(run_state(s.runs[2].dir), RunState::kPending);
  ASSERT_TRUE(run_one(s.runs[3], s.opt).ok());  // already complete: not run again
  EXPECT_EQ(s.calls().size(), 1u);
  setenv("FAKE_CRASH", s.runs[1].id.c_str(), 1);
  EXPECT_FALSE(run_one(s.runs[1], s.opt).ok());
}

TEST(Sweep, TheRunsMethodWithItsGridKeysReachesTheTrainer) {
  LocalSweep s("method");
  // A second grid key: the method is "a schedule=fast", not the config's name.
  const std::string yaml = "output: " + s.dir + "/runs2\nconfigs: [" + s.dir +
                           "/a.yaml]\noverrides: {entropy.lambda: [1.0e-3], train.schedule: "
                           "[fast]}\nrate_key: entropy.lambda\ndatasets: [{name: fern}]\n";
  const auto runs = expand_sweep(parse_sweep(yaml, "s.yaml").value());
  ASSERT_EQ(runs.size(), 1u);
  EXPECT_EQ(runs[0].method, "a schedule=fast");
  ASSERT_TRUE(run_one(runs[0], s.opt).ok());
  EXPECT_EQ(read_text(runs[0].dir + "/method_arg"), "a schedule=fast\n");
  // The log's command line quotes it, so it can be pasted back into a shell.
  EXPECT_NE(read_text(runs[0].dir + "/stdout.log").find("--method 'a schedule=fast'"),
            std::string::npos);
}

TEST(Sweep, RunsGetTheSharedPrefixDirectory) {
  LocalSweep s("prefix_dir");
  EXPECT_TRUE(parse_sweep("configs: [a.yaml]\n", "s.yaml")->share_prefix);  // the default
  EXPECT_FALSE(parse_sweep("configs: [a.yaml]\nshare_prefix: false\n", "s.yaml")->share_prefix);
  s.opt.prefix_dir = sweep_prefix_dir(s.dir + "/runs");
  EXPECT_EQ(s.opt.prefix_dir, s.dir + "/runs/prefixes");  // the layout docs/operations.md documents
  ASSERT_TRUE(run_one(s.runs[0], s.opt).ok());
  EXPECT_NE(read_text(s.runs[0].dir + "/stdout.log").find("--share-prefix " + s.opt.prefix_dir),
            std::string::npos);
}

// Two groups (H, C) of runs that can share a prefix, and one run (-) that shares nothing.
TEST(Sweep, NextRunStartsAPrefixEarlyThenUsesThem) {
  std::set<std::string> published;
  auto is_published = [&](const std::string& k) { return published.count(k) > 0; };
  const std::vector<PendingRun> waiting = {{"H", false}, {"H", false}, {"C", false}, {"", false}};
  // Nothing runs: the first H computes H's prefix.
  EXPECT_EQ(next_run_to_start(waiting, {}, is_published), 0u);
  // An H runs: C's first run starts C's prefix rather than a second H redoing H's.
  EXPECT_EQ(next_run_to_start(waiting, {"H"}, is_published), 2u);
  // Both prefixes under way: the run that shares nothing goes before the ones that wait.
  EXPECT_EQ(next_run_to_start(waiting, {"H", "C"}, is_published), 3u);
  // H published: an H run starts from it.
  published.insert("H");
  EXPECT_EQ(next_run_to_start({{"H", false}, {"C", false}}, {"C"}, is_published), 0u);
  // A waiting C with its own checkpoint is C's prefix under way: it goes before a fresh C, and
  // before an H that could start from H's published prefix; with nothing else to do a worker
  // does not wait (the first run starts).
  EXPECT_EQ(next_run_to_start({{"C", false}, {"C", true}}, {}, is_published), 1u);
  EXPECT_EQ(next_run_to_start({{"H", false}, {"C", true}}, {}, is_published), 1u);
  EXPECT_EQ(next_run_to_start({{"H", false}, {"C", true}}, {"C"}, is_published), 0u);
  // A stopped H past H's published prefix resumes before a fresh H and a fresh C's prefix: the
  // nearest result.
  EXPECT_EQ(next_run_to_start({{"H", false}, {"C", false}, {"H", true}}, {}, is_published), 2u);
  published.clear();
  EXPECT_EQ(next_run_to_start({{"C", false}, {"C", false}}, {"C"}, is_published), 0u);
}

// `crpgs sweep --status` names each shared prefix, how many runs share it and whether it is
// published yet; waiting runs say they will start from it.
TEST(Sweep, StatusShowsTheSharedPrefixes) {
#ifndef CRPGS_CLI_PATH
  GTEST_SKIP() << "the crpgs executable is not built";
#else
  if (!fs::exists(std::string(CRPGS_PLUGIN_BUILD_DIR) + "/libcrpgs_context_hash_grid.so"))
    GTEST_SKIP() << "the hash_grid plugin is not built (a rate path is what shares a prefix)";
  const std::string dir = fresh_dir("status_prefix");
  write_text(dir + "/h.yaml", "context: {type: hash_grid}\nentropy: {type: gaussian}\n");
  write_text(dir + "/sweep.yaml", "output: " + dir + "/runs\nconfigs: [" + dir +
                                      "/h.yaml]\noverrides: {rate.lambda: [1.0e-3, 4.0e-3]}\n");
  auto status = [&] {
    return crpgs::test::crpgs_output("sweep '" + dir + "/sweep.yaml' --status");
  };
  std::string out = status();
  const size_t at = out.find("shared prefix ");
  ASSERT_NE(at, std::string::npos) << out;
  const std::string key = out.substr(at + 14, 16);
  EXPECT_NE(out.find("shared prefix " + key + " (2 runs): not yet published"), std::string::npos)
      << out;
  EXPECT_EQ(out.find("will start from its shared prefix"), std::string::npos) << out;
  // One of the two computes the prefix (30k iterations), the other trains from rate_start (20k).
  EXPECT_NE(out.find("left: 50000 iterations; no run has measured a rate yet"), std::string::npos)
      << out;
  fs::create_directories(dir + "/runs/prefixes");
  write_text(dir + "/runs/prefixes/" + key + ".pt", "x");
  out = status();
  EXPECT_NE(out.find("shared prefix " + key + " (2 runs): published"), std::string::npos) << out;
  EXPECT_NE(out.find("waiting (will start from its shared prefix)"), std::string::npos) << out;
  EXPECT_NE(out.find("left: 40000 iterations;"), std::string::npos) << out;  // both from 10k
  // A run of the same group that another sweep file put in the directory measured a rate: the
  // time left uses it, and says whose it is. 2 x 20000 iterations on 1 worker at 2/s: 20000 s.
  fs::create_directories(dir + "/runs/default/h/lambda-9.0e-3");
  write_text(dir + "/runs/default/h/lambda-9.0e-3/stderr.log",
             "train  10% 3000/30000 2.0/s 25m00s ETA 3h45m loss 0.02\n");
  out = status();
  EXPECT_NE(out.find("left: 40000 iterations, about 5h33m with 1 worker at the rates last "
                     "measured (default/h 2.00 it/s by other runs of the directory)"),
            std::string::npos)
      << out;
#endif
}

// `crpgs sweep --status`: one run of each state, with the progress read back from its log.
TEST(Sweep, StatusShowsEachRunsStateAndProgress) {
#ifndef CRPGS_CLI_PATH
  GTEST_SKIP() << "the crpgs executable is not built";
#else
  const std::string dir = fresh_dir("status");
  write_text(dir + "/a.yaml", "tag: a\nentropy: {lambda: 0.5}\n");
  const std::string yaml = "name: st\noutput: " + dir + "/runs\nconfigs: [" + dir +
                           "/a.yaml]\noverrides: {entropy.lambda: [1.0e-4, 1.0e-3, 4.0e-3, "
                           "1.0e-2]}\n";
  write_text(dir + "/sweep.yaml", yaml);
  const auto runs = expand_sweep(parse_sweep(yaml, "sweep.yaml").value());
  for (const auto& r : runs) ASSERT_TRUE(prepare_run(r, nullptr).ok());
  // 0: done.
  write_text(runs[0].dir + "/metrics.json",
             "{\"format\": \"crpgs.run_metrics/1\", \"method\": \"a\", \"size_bytes\": 2563198, "
             "\"psnr_mean\": 27.4561, \"train_seconds\": 18720}\n");
  // 1: running (this process holds its lock), its log with plain progress lines.
  auto lock = lock_directory(runs[1].dir);
  ASSERT_TRUE(lock.ok() && lock->held());
  write_text(runs[1].dir + "/stderr.log",
             "== header\ntrain  43% 13029/30000 0.7/s 13m02s ETA 6h24m loss 0.02\n"
             "train  43% 13030/30000 0.7/s 13m12s ETA 6h22m loss 0.0219  test PSNR 27.46 dB\n");
  // 2: stopped, with a checkpoint; its log ends in a TTY redraw.
  write_text(runs[2].dir + "/checkpoint.pt", "x");
  write_text(runs[2].dir + "/.running", "started\n");
  write_text(runs[2].dir + "/stderr.log",
             "\r\033[Ktrain [#...] 0% 139/40000 5.3/s 26.0s ETA 2h05m a\r\033[Ktrain [#...] 0% "
             "140/40000 5.4/s 26.1s ETA 2h03m b\ninterrupted\n");
  // 3: waiting.
  int rc = -1;
  const std::string out = crpgs::test::crpgs_output("sweep '" + dir + "/sweep.yaml' --status", &rc);
  ASSERT_EQ(rc, 0) << out;
  EXPECT_NE(out.find("4 runs in " + dir + "/runs: 1 done, 1 running, 1 stopped, 1 waiting"),
            std::string::npos)
      << out;
  EXPECT_NE(out.find("27.456 dB, 2563198 B, trained 5h12m"), std::string::npos) << out;
  EXPECT_NE(out.find("running (pid " + std::to_string(getpid())), std::string::npos) << out;
  EXPECT_NE(out.find("13030/30000, 0.70 it/s, ETA 6h22m  last test PSNR 27.46 dB"),
            std::string::npos)
      << out;
  EXPECT_NE(out.find("last seen 140/40000"), std::string::npos) << out;
  EXPECT_EQ(out.find("last test PSNR", out.find("last seen 140/40000")), std::string::npos)
      << out;  // its log never showed one
  // Left: 16,970 + 39,860, one worker at the running run's 0.7 it/s (the stopped one's 5.4 it/s
  // is older, and the running runs' rates win): 81,186 s. The waiting run's schedule is unknown:
  // its config (entropy.lambda for the default entropy model) does not resolve, and it has no log.
  EXPECT_NE(out.find("left: 56830 iterations and 1 run whose config does not resolve, about "
                     "22h33m with 1 worker at the rates last measured (default/a 0.70 it/s)"),
            std::string::npos)
      << out;
  EXPECT_FALSE(fs::exists(runs[3].dir + "/stdout.log"));  // nothing ran
#endif
}

TEST(Sweep, TimeLeftStartsEachRunOnTheFirstFreeWorker) {
  EXPECT_EQ(sweep_time_left({}, 2), 0.0);
  // Two workers: 100 s on one; 50 s, then 60 iterations at 2/s (30 s) on the other.
  const std::vector<RunLeft> runs = {{100, 1}, {50, 1}, {60, 2}};
  EXPECT_DOUBLE_EQ(sweep_time_left(runs, 2), 100.0);
  EXPECT_DOUBLE_EQ(sweep_time_left(runs, 1), 180.0);
  EXPECT_DOUBLE_EQ(sweep_time_left({{100, 1}, {50, 1}, {120, 2}}, 2), 110.0);  // 50 + 60
  EXPECT_DOUBLE_EQ(sweep_time_left(runs, 8), 100.0);
  EXPECT_DOUBLE_EQ(sweep_time_left({{0, 0}, {10, 5}}, 1), 2.0);  // nothing left: no rate needed
  EXPECT_TRUE(std::isnan(sweep_time_left({{10, 5}, {10, 0}}, 2)));
}

TEST(Sweep, SlurmScriptHasArrayAndResources) {
  const std::string dir = fresh_dir("slurm_script");
  auto spec = parse_sweep(sweep_yaml(dir, ""), "s.yaml");
  ASSERT_TRUE(spec.ok());
  spec->resources.max_parallel = 4;
  const std::string s =
      slurm_script(spec.value(), {0, 1, 2, 3, 5, 7, 8}, "/opt/crpgs", "/x/s.yaml", "/x/runs");
  EXPECT_EQ(s.rfind("#!/bin/bash\n", 0), 0u);
  EXPECT_NE(s.find("#SBATCH --array=0-3,5,7-8%4\n"), std::string::npos) << s;
  EXPECT_NE(s.find("#SBATCH --cpus-per-task=2\n"), std::string::npos) << s;
  EXPECT_NE(s.find("#SBATCH --mem=4G\n"), std::string::npos) << s;
  EXPECT_NE(s.find("#SBATCH --time=01:00:00\n"), std::string::npos) << s;
  EXPECT_NE(s.find("#SBATCH --partition=debug\n"), std::string::npos) << s;
  EXPECT_NE(s.find("#SBATCH --output=\"/x/runs/slurm/%A_%a.out\"\n"), std::string::npos) << s;
  EXPECT_NE(s.find("#SBATCH --chdir=\""), std::string::npos) << s;
  // A '%' of the path is not a Slurm file-name pattern.
  EXPECT_NE(slurm_script(spec.value(), {0}, "/opt/crpgs", "/x/s.yaml", "/x/100% runs")
                .find("#SBATCH --output=\"/x/100%% runs/slurm/%A_%a.out\"\n"),
            std::string::npos);
  EXPECT_NE(s.find("'/opt/crpgs' sweep '/x/s.yaml' -o '/x/runs' --run-index "
                   "\"$SLURM_ARRAY_TASK_ID\""),
            std::string::npos)
      << s;
}

}  // namespace
}  // namespace crpgs::experiments
