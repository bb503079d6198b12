/// @file cmd_sweep.cpp
/// @brief `crpgs sweep`: run a sweep file's grid of configs x overrides x datasets, locally with
/// N workers or as a Slurm job array.
#include <atomic>
#include <cmath>
#include <csignal>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <map>
#include <numeric>
#include <set>

#include "cli_common.h"
#include "core/text_list.h"
#include "crpgs/atomic_file.h"
#include "crpgs/dir_lock.h"
#include "crpgs/experiments/run_metrics.h"
#include "crpgs/experiments/sweep.h"
#include "crpgs/hashing.h"
#include "crpgs/shared_prefix.h"
#include "progress_bar.h"

namespace crpgs::cli {
namespace {
namespace fs = std::filesystem;
namespace ex = crpgs::experiments;

struct SweepArgs {
  std::string file, out;
  std::vector<std::string> only, sets;
  int jobs = 0;
  int run_index = -1;
  bool slurm = false, dry_run = false, status = false;
};

std::atomic<bool> g_stop{false};
// SIGINT (Ctrl-C), SIGTERM (e.g. Slurm's time limit) and SIGHUP (the terminal closed): start
// nothing more, let the running trainings checkpoint, then exit.
extern "C" void on_stop_signal(int) {
  g_stop = true;
}

// An unfinished run's last held-out PSNR, as its progress line showed it.
std::string trace_psnr_text(const ProgressLine& p) {
  if (std::isnan(p.test_psnr)) return "";
  char buf[64];
  std::snprintf(buf, sizeof buf, "last test PSNR %.2f dB", p.test_psnr);
  return buf;
}

/// The last `bytes` of a file ("" if unreadable): enough for a progress bar's last lines.
std::string file_tail(const std::string& path, std::streamoff bytes = 16384) {
  std::ifstream in(path, std::ios::binary | std::ios::ate);
  if (!in) return "";
  const std::streamoff size = in.tellg();
  in.seekg(std::max<std::streamoff>(0, size - bytes));
  return std::string(std::istreambuf_iterator<char>(in), {});
}

/// An unfinished run for the sweep's time left: its group ("fern/hac": runs of one method on one
/// scene train at one rate) and its iterations left.
struct UnfinishedRun {
  std::string group;
  double iterations = 0;  ///< NaN: unknown
  bool running = false;
};

/// "left: 112830 iterations, about 15h40m with 2 workers at the rates last measured (fern/crpgs
/// 0.73 it/s, fern/hac 1.10 it/s)". A group no run of which measured a rate takes the mean of the
/// others'. A run without a log or a config that resolves has no schedule to count: it is named
/// instead.
/// `borrowed`: groups whose rate other runs of the runs directory measured, not the sweep's own.
void print_time_left(const std::vector<UnfinishedRun>& left,
                     const std::map<std::string, double>& rates,
                     const std::set<std::string>& borrowed, int workers) {
  double iterations = 0, mean = 0;
  int unknown = 0;
  std::vector<std::string> measured;
  for (const auto& [group, r] : rates) {
    mean += r / double(rates.size());
    measured.push_back(group + " " + format_rate(r) + " it/s" +
                       (borrowed.count(group) ? " by other runs of the directory" : ""));
  }
  std::vector<ex::RunLeft> order;  // the running runs first: they hold their workers
  std::set<std::string> guessed;
  for (bool running : {true, false})
    for (const UnfinishedRun& l : left) {
      if (l.running != running) continue;
      if (std::isnan(l.iterations)) ++unknown;
      if (!(l.iterations > 0)) continue;
      iterations += l.iterations;
      const auto r = rates.find(l.group);
      if (r == rates.end()) guessed.insert(l.group);
      order.push_back({l.iterations, r == rates.end() ? mean : r->second});
    }
  if (order.empty() && unknown == 0) return;
  char buf[96];
  std::snprintf(buf, sizeof buf, "left: %.0f iterations", iterations);
  std::string line = buf;
  if (unknown > 0)
    line += " and " + std::to_string(unknown) +
            (unknown == 1 ? " run whose config does not resolve"
                          : " runs whose configs do not resolve");
  if (rates.empty()) {
    line += "; no run has measured a rate yet";
  } else {
    line += ", about " + format_duration(ex::sweep_time_left(order, workers)) + " with " +
            std::to_string(workers) + (workers == 1 ? " worker" : " workers") +
            " at the rates last measured (" + join(measured) + ")";
    if (!guessed.empty())
      line += "; " + join({guessed.begin(), guessed.end()}) + " at the mean of these";
  }
  std::printf("%s\n", line.c_str());
}

/// `crpgs sweep --status`: each run's state, its progress (from its log) or its result.
int print_sweep_status(const ex::SweepSpec& spec, const std::vector<ex::SweepRun>& runs,
                       size_t sweep_size, const std::string& runs_dir,
                       const ComponentRegistry& registry) {
  std::vector<std::vector<std::string>> rows{{"run", "state", "progress", "result"}};
  int done = 0, running = 0, stopped = 0, waiting = 0;
  char buf[160];
  // Shared prefixes: each run's key, and how many runs share each. Each run's schedule, for
  // the time left.
  const std::string prefix_dir = ex::sweep_prefix_dir(runs_dir);
  std::vector<std::string> keys(runs.size());
  std::vector<std::optional<Schedule>> schedules(runs.size());
  std::map<std::string, int> sharing;
  for (size_t i = 0; i < runs.size(); ++i) {
    auto cfg = ex::build_run_config(runs[i], &registry);
    if (!cfg.ok()) continue;
    if (auto opt = train_options_from_config(cfg.value()); opt.ok()) schedules[i] = opt->schedule;
    if (spec.share_prefix)
      if (keys[i] = shared_prefix_key(cfg.value()); !keys[i].empty()) ++sharing[keys[i]];
  }
  auto published = [&](const std::string& key) {
    std::error_code ec;
    return !key.empty() && fs::exists(shared_prefix_path(prefix_dir, key), ec);
  };
  // What is left of each unfinished run, and the rates its group (e.g. fern/hac) measured.
  std::vector<UnfinishedRun> left;
  std::map<std::string, std::vector<double>> running_rates, stopped_rates;
  // Prefixes that a started (running, stopped or finished) run computes or computed.
  std::set<std::string> prefix_computed_by;
  auto shares_prefix = [&](size_t i) {
    const auto it = sharing.find(keys[i]);
    return it != sharing.end() && it->second > 1;
  };
  for (size_t i = 0; i < runs.size(); ++i)
    if (shares_prefix(i) && (ex::run_state(runs[i].dir) != ex::RunState::kPending ||
                             fs::exists(runs[i].dir + "/checkpoint.pt")))
      prefix_computed_by.insert(keys[i]);
  auto group_of = [](const std::string& id) { return id.substr(0, id.rfind('/')); };
  for (const auto& r : runs) {
    const size_t i = size_t(&r - runs.data());
    // From the log's last progress line, else the whole schedule; NaN when neither is known.
    auto iterations_left = [&](const std::optional<ProgressLine>& p) {
      return p              ? double(p->total - p->done)
             : schedules[i] ? double(schedules[i]->iterations)
                            : std::nan("");
    };
    std::vector<std::string> row{ex::run_tag(r, sweep_size), "", "", ""};
    const auto progress = last_progress(file_tail(r.dir + "/stderr.log"), "train");
    const std::string holder = directory_lock_holder(r.dir);
    std::error_code ec;
    if (ex::run_state(r.dir) == ex::RunState::kComplete) {
      ++done;
      row[1] = "done";
      if (const std::string change = ex::config_change(r, &registry, true); !change.empty())
        row[1] += ", but the sweep now asks for another config (" + change + ")";
      if (auto m = ex::read_run_metrics(r.dir + "/metrics.json"); m.ok()) {
        std::snprintf(buf, sizeof buf, "%.3f dB, %llu B, trained %s", m->psnr_mean,
                      static_cast<unsigned long long>(m->size_bytes),
                      format_duration(m->train_seconds).c_str());
        row[3] = buf;
      }
    } else if (!holder.empty()) {
      ++running;
      row[1] = "running (" + holder + ")";
      if (progress) {
        std::snprintf(buf, sizeof buf, "%ld/%ld, %s it/s, ETA %s", progress->done, progress->total,
                      format_rate(progress->rate).c_str(), progress->eta.c_str());
        row[2] = buf;
        row[3] = trace_psnr_text(*progress);
        running_rates[group_of(r.id)].push_back(progress->rate);
      }
      left.push_back({group_of(r.id), iterations_left(progress), true});
    } else if (fs::exists(r.dir + "/checkpoint.pt", ec)) {
      ++stopped;
      row[1] = "stopped (resumes from its checkpoint)";
      if (const std::string change = ex::config_change(r, &registry); !change.empty())
        row[1] = "stopped (resumes from its checkpoint under a changed config: " + change + ")";
      if (progress) {
        row[2] =
            "last seen " + std::to_string(progress->done) + "/" + std::to_string(progress->total);
        row[3] = trace_psnr_text(*progress);
        stopped_rates[group_of(r.id)].push_back(progress->rate);
      }
      left.push_back({group_of(r.id), iterations_left(progress)});
    } else {
      ++waiting;
      row[1] = "waiting";
      if (published(keys[i])) row[1] += " (will start from its shared prefix)";
      // A run that shares a prefix trains from rate_start on, unless it is the one to compute it.
      const bool from_prefix =
          published(keys[i]) || (shares_prefix(i) && !prefix_computed_by.insert(keys[i]).second);
      left.push_back({group_of(r.id), schedules[i]
                                          ? double(schedules[i]->iterations -
                                                   (from_prefix ? schedules[i]->rate_start : 0))
                                          : std::nan("")});
    }
    rows.push_back(std::move(row));
  }
  std::printf("sweep %s: %zu runs in %s: %d done, %d running, %d stopped, %d waiting\n",
              spec.name.c_str(), runs.size(), runs_dir.c_str(), done, running, stopped, waiting);
  print_table(rows);
  // A group's rate: the mean of its running runs' (they run now, beside each other), else of
  // its stopped runs'.
  std::map<std::string, double> rates;
  for (const auto* measured : {&stopped_rates, &running_rates})
    for (const auto& [group, r] : *measured)
      rates[group] = std::accumulate(r.begin(), r.end(), 0.0) / double(r.size());
  // A group none of the sweep's runs measured: the other runs of that group in the directory
  // (another sweep file writing there, e.g. fern_rd_low_rate.yaml beside fern_rd.yaml).
  std::set<std::string> own_dirs, borrowed;
  for (const auto& r : runs) own_dirs.insert(fs::path(r.dir).lexically_normal().string());
  for (const auto& l : left) {
    std::error_code ec;
    const fs::path group_dir = fs::path(runs_dir) / l.group;
    if (rates.count(l.group) || !fs::is_directory(group_dir, ec)) continue;
    std::vector<double> others;
    for (const auto& e : fs::directory_iterator(group_dir, ec))
      if (e.is_directory(ec) && !own_dirs.count(e.path().lexically_normal().string()))
        if (auto p = last_progress(file_tail((e.path() / "stderr.log").string()), "train"))
          others.push_back(p->rate);
    if (others.empty()) continue;
    rates[l.group] = std::accumulate(others.begin(), others.end(), 0.0) / double(others.size());
    borrowed.insert(l.group);
  }
  print_time_left(left, rates, borrowed, spec.workers);
  for (const auto& [key, n] : sharing) {
    if (n < 2) continue;  // nothing to share
    std::printf("shared prefix %s (%d runs): %s\n", key.c_str(), n,
                published(key) ? ("published, " + shared_prefix_path(prefix_dir, key)).c_str()
                               : "not yet published (the first of them to reach rate_start "
                                 "writes it)");
  }
  return 0;
}

int run_sweep_command(const SweepArgs& a, const GlobalOptions& g) {
  auto spec = ex::load_sweep(a.file);
  if (!spec.ok()) return report_error(spec.status());
  const std::string runs_dir = a.out.empty() ? spec->output : a.out;
  const auto all_runs = ex::expand_sweep(spec.value(), runs_dir);
  auto runs = ex::select_runs(all_runs, a.only);
  if (runs.empty())
    return report_error(Status(StatusCode::kInvalidArgument, "--only: no run of " + a.file +
                                                                 " matches (its runs are named "
                                                                 "like " +
                                                                 all_runs.front().id + ")"));
  if (Status st = ex::add_overrides(runs, a.sets); !st.ok()) return report_error(st);
  ComponentRegistry registry = load_registry(g);
  if (a.status) return print_sweep_status(spec.value(), runs, all_runs.size(), runs_dir, registry);

  ex::ExecOptions opt;
  opt.workers = a.jobs > 0 ? a.jobs : spec->workers;
  opt.registry = &registry;
  opt.dry_run = a.dry_run;
  opt.sweep_size = static_cast<int>(all_runs.size());
  opt.stop = &g_stop;
  if (spec->share_prefix) opt.prefix_dir = ex::sweep_prefix_dir(runs_dir);
  opt.one_model_rate = spec->one_model_rate;
  opt.one_model_scales = spec->one_model_scales;
  std::signal(SIGINT, on_stop_signal);
  std::signal(SIGTERM, on_stop_signal);
  if (std::signal(SIGHUP, on_stop_signal) == SIG_IGN) std::signal(SIGHUP, SIG_IGN);  // nohup
  // `scancel --signal=USR1` reaches every process of the task: the trainings checkpoint, the
  // sweep goes on.
  std::signal(SIGUSR1, SIG_IGN);
  // Tests substitute a fake trainer; normally every run is `crpgs train` of this executable.
  const char* runner = std::getenv("CRPGS_SWEEP_RUNNER");
  opt.runner = runner && *runner ? runner : ex::self_executable();

  if (a.run_index >= 0) {
    opt.use_prepared_configs = true;  // as submitted, whatever the base configs say by now
    const auto it = std::find_if(runs.begin(), runs.end(),
                                 [&](const ex::SweepRun& r) { return r.index == a.run_index; });
    if (it == runs.end())
      return report_error(Status(StatusCode::kInvalidArgument,
                                 "--run-index " + std::to_string(a.run_index) + ": the sweep has " +
                                     std::to_string(all_runs.size()) + " runs" +
                                     (a.only.empty() ? "" : ", and --only leaves it out")));
    Status st = ex::run_one(*it, opt);
    if (st.code() == StatusCode::kCancelled) {
      std::fprintf(stderr, "crpgs: %s\n", st.message().c_str());
      return 130;
    }
    return st.ok() ? 0 : report_error(st);
  }

  if (runs.size() == all_runs.size())
    std::printf("sweep %s: %zu runs in %s\n", spec->name.c_str(), runs.size(), runs_dir.c_str());
  else
    std::printf("sweep %s: %zu of its %zu runs (--only) in %s\n", spec->name.c_str(), runs.size(),
                all_runs.size(), runs_dir.c_str());
  if (a.slurm) {
    if (!spec->one_model_scales.empty())
      std::printf(
          "one_model: the array trains; re-encode the finished runs at the one-model "
          "scales with a local `crpgs sweep %s` afterwards (minutes per run)\n",
          a.file.c_str());
    std::vector<int> pending;
    size_t running = 0;
    for (const auto& r : runs) {
      if (ex::run_state(r.dir) == ex::RunState::kComplete) continue;
      // Write (and validate) every config now rather than in the array tasks; not the config of
      // a run another process is training.
      const std::string holder = directory_lock_holder(r.dir);
      if (!holder.empty()) {
        std::printf("%s: running in another process (%s), not submitted\n", r.id.c_str(),
                    holder.c_str());
        ++running;
        continue;
      }
      Status st = ex::build_run_config(r, &registry).status();
      if (!st.ok()) return report_error(st);
      std::error_code ec;
      if (const std::string change = ex::config_change(r, &registry);
          !change.empty() && fs::exists(r.dir + "/checkpoint.pt", ec))
        std::printf("%s: resumes its checkpoint under a changed config: %s\n", r.id.c_str(),
                    change.c_str());
      if (!a.dry_run) {
        auto lock = lock_directory(r.dir);
        if (!lock.ok()) {  // started since the look above
          std::printf("%s: %s, not submitted\n", r.id.c_str(), lock.status().message().c_str());
          ++running;
          continue;
        }
        if (st = ex::prepare_run(r, &registry); !st.ok()) return report_error(st);
      }
      pending.push_back(r.index);
    }
    std::printf("%zu finished, %zu running elsewhere, %zu to submit\n",
                runs.size() - pending.size() - running, running, pending.size());
    if (pending.empty()) return 0;
    const std::string exe = ex::self_executable();
    const std::string runs_abs = fs::absolute(runs_dir).string();
    // The tasks read the sweep file when they start, maybe hours from now: they get a copy, so
    // that editing the file meanwhile cannot shift the run indices they were submitted for.
    auto text = read_file_bytes(a.file);
    if (!text.ok()) return report_error(text.status());
    const std::string_view bytes(reinterpret_cast<const char*>(text->data()), text->size());
    const std::string sweep_abs =
        runs_abs + "/slurm/sweep-" + hex64(fnv1a64(bytes)) + fs::path(a.file).extension().string();
    if (!a.dry_run) {
      std::error_code ec;
      fs::create_directories(runs_abs + "/slurm", ec);
      if (Status st = write_file_atomic(sweep_abs, *text); !st.ok()) return report_error(st);
    }
    if (a.dry_run) {
      std::printf("%s", ex::slurm_script(spec.value(), pending, exe, sweep_abs, runs_abs).c_str());
      return 0;
    }
    auto job = ex::submit_slurm(spec.value(), pending, exe, sweep_abs, runs_abs);
    if (!job.ok()) return report_error(job.status());
    std::printf(
        "submitted Slurm job array %s (%s/sweep.sbatch); when it is done: crpgs report %s\n",
        job->c_str(), runs_abs.c_str(), runs_abs.c_str());
    return 0;
  }

  auto sum = ex::run_sweep_local(runs, opt);
  if (!sum.ok()) return report_error(sum.status());
  if (a.dry_run) return sum->failed > 0 ? 1 : 0;
  std::printf("sweep %s: %d finished now, %d already done, %d failed, %d stopped\n",
              spec->name.c_str(), sum->succeeded, sum->skipped, sum->failed, sum->interrupted);
  if (sum->failed > 0) {
    std::fprintf(stderr, "crpgs: error: %d runs failed (rerun `crpgs sweep` to retry them):\n",
                 sum->failed);
    for (const auto& id : sum->failed_ids) std::fprintf(stderr, "  %s\n", id.c_str());
    return 1;
  }
  if (sum->interrupted > 0 || g_stop) {
    std::printf("stopped; the same command continues the sweep (stopped runs resume)\n");
    return 130;
  }
  std::printf("results: crpgs report %s\n", runs_dir.c_str());
  return 0;
}

}  // namespace

void add_sweep_commands(CLI::App& app, GlobalOptions& g) {
  static SweepArgs a;
  auto* cmd = app.add_subcommand(
      "sweep",
      "Run a sweep: every base config x override grid x dataset of SWEEP.yaml (see "
      "configs/sweeps/), each run in its own directory with its resolved config, logs and "
      "metrics.json. Finished runs are skipped; crashed or killed ones are rerun (resuming from "
      "their checkpoint); a run another process is training is skipped. Ctrl-C (or SIGTERM) "
      "starts nothing more and lets the running trainings checkpoint; the same command then "
      "continues. Summarise with `crpgs report RUNS_DIR`.");
  cmd->add_option("SWEEP", a.file, "sweep file (YAML)")->required()->check(CLI::ExistingFile);
  cmd->add_option("-o,--output", a.out, "runs directory (default: the sweep file's 'output')");
  cmd->add_option("-j,--jobs", a.jobs, "runs at a time (default: the sweep file's 'workers')")
      ->check(CLI::Number)
      ->check(CLI::Range(1, 1024));
  cmd->add_flag("--slurm", a.slurm,
                "submit the unfinished runs as a Slurm job array (sbatch; resources from the "
                "sweep file) instead of running them here");
  cmd->add_option("--run-index", a.run_index,
                  "run only the run with this index (what each Slurm array task does)")
      ->check(CLI::Number)
      ->check(CLI::Range(0, 1 << 30));
  cmd->add_option("--only", a.only,
                  "run (or show) only the runs whose name matches this pattern, e.g. "
                  "'bonsai/*' or '*/lambda-4.0e-3_*' (repeatable: any of them)");
  cmd->add_option("--set", a.sets,
                  "override a config key of every run, after the sweep's own values, e.g. "
                  "--set train.device=cuda --set rasterizer.type=cuda to run it on a GPU; a "
                  "finished run counts as done wherever it ran (repeatable)");
  cmd->add_flag("--status", a.status,
                "show each run's state, progress (iteration, rate, ETA: from its log) or result, "
                "which waiting runs will start from a shared prefix, and the sweep's time left "
                "at the rates the runs last measured (or, for a method and scene none of them "
                "has run yet, other runs of it in the runs directory); runs nothing");
  cmd->add_flag("--dry-run", a.dry_run,
                "list what would run (with --slurm: print the sbatch script); run nothing");
  cmd->callback([&g] { throw CLI::RuntimeError(run_sweep_command(a, g)); });
}

}  // namespace crpgs::cli
