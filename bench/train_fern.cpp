// Training speed on fern (COLMAP binary, images_8 = 504x378) and lego (NeRF-synthetic at
// 200x200, white background, random initialisation): iterations per second and the split of one
// iteration between MLPs (generation), rasterizer, loss, backward and optimizer.
// Results: bench/results/train_fern.md.
//
// Env: CRPGS_BENCH_WARMUP (iterations before timing, default 600: past the start of anchor
// growing, so the anchor count is representative), CRPGS_BENCH_VOXEL (default 0.01).
//
// BM_TrainRun times any phase of any config: CRPGS_BENCH_RUN=RUN_DIR resumes that run's
// checkpoint (RUN_DIR/config.yaml + checkpoint.pt, e.g. a sweep run past rate_start) and times
// CRPGS_BENCH_STEPS iterations (default 30) from there; nothing is written to RUN_DIR. Run from
// the directory the run was trained from (its dataset.path may be relative to it).
// CRPGS_BENCH_PROFILE=FILE also records libtorch's op-level profile of the timed steps as a
// Chrome trace (chrome://tracing; operators with their CPU times, forward and backward).
// CRPGS_BENCH_OPS=FILE writes a table of the timed steps' operators by name and input shapes:
// self time (wall, nested operators subtracted) and calls per step, largest first.
//
// BM_MlpGemm/{0,1,2}: one chunk's GEMMs of the neural-Gaussian MLPs on one thread (forward
// x w1^T, weight gradient dh^T x, input gradient dh w1: 1024 rows, 54 inputs, 50 hidden), in
// the kernels OpenBLAS picked (the label; OPENBLAS_CORETYPE=Haswell forces the AVX2 ones).
#include <benchmark/benchmark.h>
#include <torch/csrc/autograd/profiler_legacy.h>
#include <torch/torch.h>

#include <algorithm>
#include <chrono>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <map>
#include <memory>
#include <sstream>
#include <vector>

#include "crpgs/components.h"
#include "crpgs/registry.h"
#include "crpgs/runtime.h"
#include "crpgs/trainer.h"
#include "raster/cpu_rasterizer.h"

namespace {

using namespace crpgs;

double env_or(const char* name, double fallback) {
  const char* v = std::getenv(name);
  return v ? std::atof(v) : fallback;
}

/// A full-schedule trainer without the rate path on a shared dataset (d.path: its name there).
std::unique_ptr<Trainer> make_shared_data_trainer(benchmark::State& state, DatasetOptions d,
                                                  AnchorModelOptions mo = {}) {
  const std::string name = d.path;
  d.path = std::string(CRPGS_SHARED_DATA_DIR) + "/" + name;
  if (!std::filesystem::exists(d.path)) {
    state.SkipWithError((name + " dataset not found under CRPGS_SHARED_DATA_DIR").c_str());
    return nullptr;
  }
  auto ds = load_dataset(d);
  if (!ds.ok()) {
    state.SkipWithError(ds.status().to_string().c_str());
    return nullptr;
  }
  TrainOptions to;  // full schedule
  mo.voxel_size = env_or("CRPGS_BENCH_VOXEL", 0.01);
  auto features = identity_feature_model(50);
  auto t = make_trainer(to, mo, std::move(ds).value(), std::make_shared<raster::CpuRasterizer>(0),
                        features);
  if (!t.ok()) {
    state.SkipWithError(t.status().to_string().c_str());
    return nullptr;
  }
  return std::move(t).value();
}

/// Writes CRPGS_BENCH_OPS's table from the legacy profiler's push/pop events (per thread, nested).
void write_op_table(const torch::autograd::profiler::thread_event_lists& lists,
                    const std::string& path, double steps) {
  using torch::autograd::profiler::EventKind;
  using torch::autograd::profiler::LegacyEvent;
  struct Row {
    double self_us = 0;
    int64_t calls = 0;
  };
  std::map<std::string, Row> rows;
  for (const auto& events : lists) {
    std::vector<std::pair<const LegacyEvent*, double>> open;  // push event, child time
    for (const LegacyEvent& e : events) {
      if (e.kind() == EventKind::PushRange) {
        open.push_back({&e, 0.0});
      } else if (e.kind() == EventKind::PopRange && !open.empty()) {
        const auto [push, child_us] = open.back();
        open.pop_back();
        const double us = push->cpuElapsedUs(e);
        std::ostringstream key;
        key << push->name() << '\t';
        for (const auto& shape : push->shapes()) {
          key << '[';
          for (size_t i = 0; i < shape.size(); ++i) key << (i ? "," : "") << shape[i];
          key << ']';
        }
        Row& r = rows[key.str()];
        r.self_us += us - child_us;
        ++r.calls;
        if (!open.empty()) open.back().second += us;
      }
    }
  }
  std::vector<std::pair<std::string, Row>> sorted(rows.begin(), rows.end());
  std::sort(sorted.begin(), sorted.end(),
            [](const auto& a, const auto& b) { return a.second.self_us > b.second.self_us; });
  std::ofstream out(path);
  out << "self_ms_per_step\tcalls_per_step\top\tinput_shapes\n";
  for (const auto& [key, r] : sorted)
    out << r.self_us / 1e3 / steps << '\t' << double(r.calls) / steps << '\t' << key << '\n';
}

/// Times the benchmark's iterations and reports it/s, the per-stage split and the model size.
void time_steps(benchmark::State& state, Trainer& t) {
  state.SetLabel(blas_kernels());  // OPENBLAS_CORETYPE may have forced other kernels
  const StepTimes before = t.times();
  for (auto _ : state) {
    auto loss = t.step();
    benchmark::DoNotOptimize(loss);
  }
  const StepTimes& after = t.times();
  const double n = after.iterations - before.iterations;
  state.counters["anchors"] = double(t.model().num_anchors());
  state.counters["gaussians"] = double(t.last_gaussian_count());
  state.counters["ms_mlp_fwd"] = 1e3 * (after.generate - before.generate) / n;
  state.counters["ms_raster_fwd"] = 1e3 * (after.render - before.render) / n;
  state.counters["ms_loss_fwd"] = 1e3 * (after.loss - before.loss) / n;
  state.counters["ms_backward"] = 1e3 * (after.backward - before.backward) / n;
  state.counters["ms_optimizer"] = 1e3 * (after.optimizer - before.optimizer) / n;
  // A rate counter divides by CPU time unless the benchmark uses real time, and the main
  // thread's CPU time leaves out its waits for the pool: every BM_Train* uses real time.
  state.counters["it_per_s"] =
      benchmark::Counter(double(state.iterations()), benchmark::Counter::kIsRate);
}

void BM_TrainLego(benchmark::State& state) {
  set_compute_threads(0);
  DatasetOptions d;
  d.path = "lego";
  d.format = "nerf_synthetic";
  d.max_width = 200;
  d.background = {1.f, 1.f, 1.f};
  AnchorModelOptions mo;  // configs/lego.yaml: white background
  mo.effects.background = d.background;
  auto t = make_shared_data_trainer(state, d, mo);
  if (!t) return;
  const int warmup = int(env_or("CRPGS_BENCH_WARMUP", 600));
  for (int i = 0; i < warmup; ++i) (void)t->step();
  time_steps(state, *t);
}
BENCHMARK(BM_TrainLego)->Unit(benchmark::kMillisecond)->Iterations(100)->UseRealTime();

void BM_TrainFern(benchmark::State& state) {
  set_compute_threads(0);
  DatasetOptions d;
  d.path = "fern";
  d.format = "colmap";
  d.images = "images_8";
  auto t = make_shared_data_trainer(state, d);
  if (!t) return;
  const int warmup = int(env_or("CRPGS_BENCH_WARMUP", 600));
  for (int i = 0; i < warmup; ++i) (void)t->step();
  time_steps(state, *t);
  // Backward split: the rasterizer's backward alone on the current Gaussians (detached leaves).
  const View& v = t->dataset().train.front();
  RenderSettings rs;
  auto g = t->model().generate(v.camera, 0, t->rasterizer(), rs, false);
  GaussianBatch b;
  b.means = g.batch.means.detach().requires_grad_(true);
  b.scales = g.batch.scales.detach().requires_grad_(true);
  b.rotations = g.batch.rotations.detach().requires_grad_(true);
  b.opacities = g.batch.opacities.detach().requires_grad_(true);
  b.colors = g.batch.colors.detach().requires_grad_(true);
  double bwd = 0;
  for (int i = 0; i < 5; ++i) {
    auto img = t->rasterizer().render(b, v.camera, rs).image;
    auto t0 = std::chrono::steady_clock::now();
    img.sum().backward();
    bwd += std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  }
  state.counters["ms_raster_bwd"] = 1e3 * bwd / 5;
}
BENCHMARK(BM_TrainFern)->Unit(benchmark::kMillisecond)->Iterations(100)->UseRealTime();

void BM_TrainRun(benchmark::State& state) {
  const char* dir = std::getenv("CRPGS_BENCH_RUN");
  if (!dir) {
    state.SkipWithError("set CRPGS_BENCH_RUN=RUN_DIR (a run with config.yaml + checkpoint.pt)");
    return;
  }
  ComponentRegistry registry = builtin_registry();
  registry.load_plugins(default_plugin_dirs({}));
  auto cfg = Config::load_file(std::string(dir) + "/config.yaml");
  auto resolved = cfg.ok() ? cfg->resolve(registry) : cfg;
  if (!resolved.ok()) {
    state.SkipWithError(resolved.status().to_string().c_str());
    return;
  }
  // resume reads RUN_DIR/checkpoint.pt; the benchmark calls step() only, which writes nothing.
  auto t = setup_training(resolved.value(), registry, SetupOptions{dir, true});
  if (!t.ok()) {
    state.SkipWithError(t.status().to_string().c_str());
    return;
  }
  state.counters["from_iteration"] = double(t.value()->iteration());
  std::unique_ptr<torch::autograd::profiler::RecordProfile> profile;
  if (const char* trace = std::getenv("CRPGS_BENCH_PROFILE"))
    profile = std::make_unique<torch::autograd::profiler::RecordProfile>(std::string(trace));
  std::unique_ptr<torch::autograd::profiler::TLSLegacyProfilerGuard> ops;
  if (const char* table = std::getenv("CRPGS_BENCH_OPS")) {
    const double steps = env_or("CRPGS_BENCH_STEPS", 30);
    ops = std::make_unique<torch::autograd::profiler::TLSLegacyProfilerGuard>(
        torch::profiler::impl::ProfilerConfig(torch::profiler::impl::ProfilerState::CPU, true),
        [path = std::string(table), steps](const auto& lists) {
          write_op_table(lists, path, steps);
        });
  }
  time_steps(state, *t.value());
}
BENCHMARK(BM_TrainRun)
    ->Unit(benchmark::kMillisecond)
    ->Iterations(int64_t(env_or("CRPGS_BENCH_STEPS", 30)))
    ->UseRealTime();

void BM_MlpGemm(benchmark::State& state) {
  set_compute_threads(1);
  state.SetLabel(blas_kernels());
  torch::manual_seed(0);
  const int64_t rows = 1024, in = 54, hidden = 50;
  const auto x = torch::randn({rows, in}), w = torch::randn({hidden, in});
  const auto dh = torch::randn({rows, hidden});
  auto out = torch::empty({rows, hidden}), dw = torch::empty({hidden, in}),
       dx = torch::empty({rows, in});
  for (auto _ : state) {
    switch (state.range(0)) {
      case 0:
        at::mm_out(out, x, w.t());
        break;
      case 1:
        at::mm_out(dw, dh.t(), x);
        break;
      default:
        at::mm_out(dx, dh, w);
        break;
    }
  }
  state.counters["GFLOPS"] = benchmark::Counter(2.0 * double(rows * in * hidden),
                                                benchmark::Counter::kIsIterationInvariantRate);
}
BENCHMARK(BM_MlpGemm)->DenseRange(0, 2)->Unit(benchmark::kMicrosecond);

}  // namespace

// main(): bench/main/bench_main.cpp
