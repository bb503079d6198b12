/// @file cmd_train.cpp
/// @brief `crpgs train`, `crpgs eval`, `crpgs demo`.
#include <csignal>
#include <cstdlib>
#include <filesystem>

#include <ATen/Parallel.h>

#include "cli_common.h"
#include "core/text_list.h"
#include "crpgs/atomic_file.h"
#include "crpgs/dir_lock.h"
#include "crpgs/experiments/run_metrics.h"
#include "crpgs/hashing.h"
#include "crpgs/lpips.h"
#include "crpgs/runtime.h"
#include "crpgs/trainer.h"
#include "progress_bar.h"

namespace crpgs::cli {
namespace {
namespace fs = std::filesystem;

TrainControl* g_control = nullptr;
// SIGINT (Ctrl-C), SIGTERM (e.g. Slurm at its time limit) and SIGHUP (the terminal closed):
// checkpoint and stop. SIGUSR1: checkpoint now and go on (ignored outside training).
extern "C" void on_signal(int sig) {
  if (!g_control) return;
  if (sig == SIGUSR1)
    g_control->save = true;
  else
    g_control->stop = true;
}

/// Draws the trainer's reports as a progress bar (TTY) or plain lines (logs).
class CliProgress final : public ProgressCallback {
 public:
  CliProgress(int total, int already_done) : bar_("train", total, already_done) {}
  void on_iteration(const TrainingProgress& p) override {
    if (p.has_test_psnr) last_psnr_ = p.test_psnr;
    char psnr[32] = "-", extra[160];
    if (last_psnr_ > 0) std::snprintf(psnr, sizeof psnr, "%.2f dB", last_psnr_);
    std::snprintf(extra, sizeof extra, "loss %.4f  test PSNR %s  anchors %lld  gaussians %lld",
                  p.loss, psnr, static_cast<long long>(p.anchors),
                  static_cast<long long>(p.gaussians));
    last_extra_ = extra;
    bar_.update(p.iteration, extra);
  }
  void on_checkpoint(int, const std::string&) override {}
  void on_warning(int, const std::string& message) override { bar_.message("warning: " + message); }
  void on_note(int, const std::string& message) override { bar_.message(message); }
  void finish() { bar_.finish(last_extra_); }

 private:
  ProgressBar bar_;
  double last_psnr_ = 0;
  std::string last_extra_;
};

/// Train from a resolved config into `out_dir`; evaluates the test views at the end.
/// `method` names the run in metrics.json; empty: the config's file name ("demo" for the demo).
/// `prefix_dir`: shared training prefixes (SetupOptions::prefix_dir); "" = off.
/// `start_from`: another run's checkpoint to continue from under this config (SetupOptions).
int run_training(const Config& cfg, const ComponentRegistry& registry, const RunOptions& run) {
  const std::string& out_dir = run.out_dir;
  // `scancel --signal=USR1` during set-up or the final encode must not end the run.
  std::signal(SIGUSR1, SIG_IGN);
  auto prepared = prepare_run_directory(cfg, registry, run);
  if (!prepared.ok()) return report_error(prepared.status());
  if (!prepared->lock.held())
    std::fprintf(stderr, "warning: %s cannot be locked here; make sure no other run writes there\n",
                 out_dir.c_str());
  if (const int n = prepared->stale_files_removed; n > 0)
    std::printf("removed %d half-written file(s) of an earlier, killed attempt\n", n);
  Trainer& t = *prepared->trainer;
  print_dataset_warnings(t.dataset());
  for (const std::string& w : t.setting_warnings())
    std::fprintf(stderr, "warning: %s\n", w.c_str());
  const bool resume = run.resume;
  const std::string& start_from = run.start_from;
  Status st;
  std::printf("resolved config: %s/config.yaml\n", out_dir.c_str());
  std::printf("scene: %zu train / %zu test views of %dx%d, %lld anchors\n",
              t.dataset().train.size(), t.dataset().test.size(),
              t.dataset().train.empty() ? 0 : t.dataset().train[0].camera.width,
              t.dataset().train.empty() ? 0 : t.dataset().train[0].camera.height,
              static_cast<long long>(t.model().num_anchors()));
  if (const auto views = t.trace_views(); !views.empty() && t.options().eval_interval > 0) {
    std::string measure = experiments::trace_measure(views);
    if (views.size() > 1) measure += " (" + join(views) + ")";
    std::printf("test PSNR (progress, trace): %s\n", measure.c_str());
  }
  if (!t.prefix_status().empty())
    std::printf("%s\n", t.prefix_status().c_str());
  else if (t.iteration() > 0)
    std::printf(
        "%s at iteration %d%s%s\n",
        resume && fs::exists(t.checkpoint_path()) ? "resumed" : ("continues " + start_from).c_str(),
        t.iteration(),
        t.state_origin_differences().empty() ? ""
                                             : (" (" + t.state_origin_differences() + ")").c_str(),
        t.state_config_hash().empty() || t.state_config_hash() == t.options().config_hash
            ? ""
            : " (written under another config: training goes on with this one, "
              "config.yaml)");
  std::printf("idle compute threads: %s\n", idle_thread_settings().c_str());
  std::printf("BLAS kernels: %s\n", blas_kernels_explained().c_str());

  TrainControl control;
  g_control = &control;
  const int signals[] = {SIGINT, SIGTERM, SIGHUP, SIGUSR1};
  void (*previous[4])(int);
  for (int i = 0; i < 4; ++i) {
    previous[i] = std::signal(signals[i], on_signal);
    if (signals[i] == SIGHUP && previous[i] == SIG_IGN) std::signal(SIGHUP, SIG_IGN);  // nohup
  }
  CliProgress progress(t.options().schedule.iterations, t.iteration());
  st = t.train(&progress, &control);
  for (int i = 0; i < 4; ++i) std::signal(signals[i], previous[i]);
  g_control = nullptr;
  if (st.code() == StatusCode::kCancelled) {
    std::printf("\ninterrupted: checkpoint written to %s (continue with --resume)\n",
                t.checkpoint_path().c_str());
    return 130;
  }
  if (!st.ok()) return report_error(st);
  progress.finish();
  const double train_s = t.elapsed_seconds();  // resumed runs included, evaluation excluded
  std::printf("trained %d iterations in %s; checkpoint: %s\n", t.iteration(),
              format_duration(train_s).c_str(), t.checkpoint_path().c_str());
  if (const StepTimes& tm = t.times(); tm.iterations > 0) {
    // The stage split is this process's iterations only; the phases span the whole run.
    const double ms = 1e3 / tm.iterations;
    std::printf(
        "time per iteration over %d iterations: MLPs %.1f ms, raster %.1f ms, loss+rate %.1f ms, "
        "backward %.1f ms, optimizer+densify %.1f ms\n",
        tm.iterations, tm.generate * ms, tm.render * ms, tm.loss * ms, tm.backward * ms,
        tm.optimizer * ms);
    if (t.model().has_rate()) {  // the phases of docs/method.md §2.3
      std::printf("speed by phase:");
      const char* sep = " ";
      for (size_t p = 0; p < 3; ++p)
        if (tm.phase_iterations[p] > 0) {
          std::printf("%s%s %d it at %.2f it/s", sep, StepTimes::kPhaseNames[p].words,
                      tm.phase_iterations[p], tm.phase_iterations[p] / tm.phase_seconds[p]);
          sep = "; ";
        }
      std::printf("\n");
    }
  }

  BitstreamReport rep;
  EvalResult eval;
  auto m = finish_run(t, cfg, registry, run, &rep, &eval);
  if (!m.ok()) return report_error(m.status());
  if (t.model().has_rate()) {
    print_bitstream_report(rep);
  } else {
    std::printf("test views (PNGs in %s/test/renders and gt):\n", out_dir.c_str());
    print_eval(eval);
  }
  std::printf("metrics: %s/metrics.json\n", out_dir.c_str());
  return 0;
}

const char* kDemoConfig = R"yaml(
# The embedded default scene: procedural objects (some repeated far apart), ground truth
# rendered by our own rasterizer; CRP-GS (configs/crpgs.yaml's components: SFA features,
# hash-grid context, Gaussian entropy model, COHS links) on the fast schedule at 3/80 of the
# paper's 40k-iteration phase boundaries. Ends with the bitstream, decoded.
dataset: {format: synthetic}
features: {type: sfa, ratio: 0.4, n_levels: 5, resolutions: [18, 41, 96, 222, 514],
           n_levels_2d: 0, resolutions_2d: [], zero_init: true}
context: {type: hash_grid}
entropy: {type: gaussian}
links: {type: link_cohs}
rate: {lambda: 0.002, recompute_bounds: false}
train: {schedule: fast, fast_factor: 0.0375, full_iterations: 40000, eval_interval: 100,
        checkpoint_interval: 500, feature_model_start: growing_end}
)yaml";

}  // namespace

void add_train_commands(CLI::App& app, GlobalOptions& g) {
  static std::string config, out_dir, run_dir, png_dir, method, prefix_dir, lpips_file, from;
  static bool resume = false, force = false;

  auto* train =
      app.add_subcommand("train", "Train an anchor model from posed images (config-driven)");
  train->add_option("-c,--config", config, "YAML run config (see configs/)")->required();
  train->add_option("-o,--output", out_dir, "run directory (config, checkpoint, renders)")
      ->default_val("runs/train");
  train->add_option("--set", g.sets, "override a config key: --set train.iterations=1000");
  train->add_flag("--resume", resume, "continue from the run directory's last checkpoint");
  train->add_flag("--force", force,
                  "train from the start into a directory that holds a run (its checkpoint and "
                  "results are replaced); without it such a directory is refused");
  train->add_option(
      "--share-prefix", prefix_dir,
      "directory of shared training prefixes (rate path): start from the state at rate_start "
      "of a run that differs only in rate.lambda/rate.mask_lambda or thread counts when one "
      "is there, and publish this run's when it is not (`crpgs sweep` passes RUNS/prefixes)");
  train->add_option("--from", from,
                    "start from the final state of another run (its directory or checkpoint.pt) "
                    "under this config: a short fine-tune, e.g. at another rate.lambda with "
                    "train.iterations a few hundred above that run's (bench/results/rates.md)");
  train->add_option("--method", method,
                    "name of the method in metrics.json and reports (default: the config's file "
                    "name; `crpgs sweep` passes the config name plus its non-rate grid keys)");
  train->callback([&g] {
    ComponentRegistry r = load_registry(g);
    auto cfg = load_config(config, g.sets, r);
    if (!cfg.ok()) throw CLI::RuntimeError(report_error(cfg.status()));
    const std::string start_from =
        from.empty() || !fs::is_directory(from) ? from : from + "/checkpoint.pt";
    if (!start_from.empty() && !fs::is_regular_file(start_from))
      throw CLI::RuntimeError(report_error(Status(
          StatusCode::kNotFound, "--from " + from + ": no checkpoint there (" + start_from + ")")));
    RunOptions run;
    run.out_dir = out_dir;
    run.resume = resume;
    run.replace = force;
    run.method = method;
    run.prefix_dir = prefix_dir;
    run.start_from = start_from;
    throw CLI::RuntimeError(run_training(cfg.value(), r, run));
  });

  auto* eval = app.add_subcommand(
      "eval",
      "Render the test views of a trained run and report PSNR and SSIM per view and mean "
      "(8-bit PNG round trip; SSIM 11x11, sigma 1.5), and LPIPS with --lpips-weights (its VGG "
      "weights cannot be shipped or downloaded here: docs/lpips.md).");
  eval->add_option("RUN", run_dir,
                   "directory written by `crpgs train`, a .crpgs bitstream or a `crpgs decode` "
                   "directory")
      ->required();
  eval->add_option("-o,--output", png_dir,
                   "where to write the PNGs, as OUT/renders/00000.png and OUT/gt/00000.png "
                   "(default: RUN_DIR/test for a training run; none for a bitstream or a decode "
                   "directory)");
  eval->add_option("--lpips-weights", lpips_file,
                   "an LPIPS network as a TorchScript module you exported (docs/lpips.md): "
                   "LPIPS is reported beside PSNR and SSIM")
      ->check(CLI::ExistingFile);
  eval->add_option("--set", g.sets,
                   "override a key of the model's config (e.g. dataset.path=DIR when the dataset "
                   "has moved)");
  eval->callback([&g] {
    std::shared_ptr<Lpips> lpips;
    if (!lpips_file.empty()) {
      auto loaded = Lpips::load(lpips_file);
      if (!loaded.ok()) throw CLI::RuntimeError(report_error(loaded.status()));
      lpips = loaded.value();
    }
    if (fs::is_regular_file(run_dir) || fs::is_regular_file(fs::path(run_dir) / kDecodedModelFile))
      throw CLI::RuntimeError(eval_bitstream_file(g, run_dir, png_dir, lpips.get()));
    if (!fs::is_regular_file(fs::path(run_dir) / "config.yaml"))
      throw CLI::RuntimeError(report_error(not_a_model_source(run_dir)));
    ComponentRegistry r = load_registry(g);
    auto cfg = load_config(run_dir + "/config.yaml", g.sets, r);
    if (!cfg.ok()) throw CLI::RuntimeError(report_error(cfg.status()));
    if (Status st = check_dataset(cfg.value()); !st.ok()) throw CLI::RuntimeError(report_error(st));
    auto trainer = setup_training_and_warn(cfg.value(), r, reading_setup(run_dir));
    if (!trainer.ok()) throw CLI::RuntimeError(report_error(trainer.status()));
    if (trainer.value()->iteration() == 0)
      throw CLI::RuntimeError(report_error(
          Status(StatusCode::kNotFound, "no checkpoint in " + run_dir + " (train first)")));
    auto res =
        trainer.value()->evaluate(png_dir.empty() ? run_dir + "/test" : png_dir, lpips.get());
    if (!res.ok()) throw CLI::RuntimeError(report_error(res.status()));
    std::printf("model at iteration %d\n", trainer.value()->iteration());
    print_eval(res.value());
  });

  auto* demo = app.add_subcommand(
      "demo",
      "Generate the embedded synthetic scene, train on it with the fast schedule, evaluate");
  demo->add_option("-o,--output", out_dir, "run directory (an earlier demo there is replaced)")
      ->default_val("runs/demo");
  demo->add_option("--set", g.sets, "override a key of the demo config");
  demo->callback([&g] {
    ComponentRegistry r = load_registry(g);
    auto cfg = load_config("", g.sets, r, kDemoConfig);
    if (!cfg.ok()) throw CLI::RuntimeError(report_error(cfg.status()));
    std::printf(
        "crpgs demo: synthetic scene -> train (fast schedule) -> bitstream -> decode -> "
        "evaluate the decoded model\n");
    RunOptions run;
    run.out_dir = out_dir;
    throw CLI::RuntimeError(run_training(cfg.value(), r, run));
  });
}

}  // namespace crpgs::cli
