/// @file sweep.h
/// @brief Sweeps: a YAML file lists base configs, a grid of overrides and datasets; it expands
/// to runs (one directory each, with its resolved config, run.json, logs and metrics.json) that
/// run locally with N workers or as a Slurm job array. Resumable: a run whose metrics.json is
/// readable and that left no `.running` marker is finished and skipped; any other is rerun
/// (with `--resume` when its directory holds a checkpoint).
///
/// Sweep file:
///   name: fern_rd
///   output: runs/fern_rd            # runs directory (relative to the working directory)
///   configs:                        # a path, or {name, path, set: {key: value}}
///     - configs/hac.yaml
///     - {name: crpgs, path: configs/crpgs.yaml}
///   overrides:                      # grid, expanded as a Cartesian product (first key slowest)
///     entropy.lambda: [1.0e-4, 5.0e-4, 1.0e-3, 4.0e-3]
///   rate_key: entropy.lambda        # the grid key that moves along an RD curve (default: the
///                                   # first key whose last part contains "lambda")
///   datasets:
///     - {name: fern, set: {dataset.format: llff, dataset.path: /data/fern}}
///   resources: {cpus: 4, mem: 16G, time: "08:00:00", partition: batch}   # Slurm
///   workers: 2                      # local parallel runs
///   share_prefix: true              # default; runs that differ only in the rate weights
///                                   # (or thread counts) share their training up to
///                                   # rate_start (RUNS/prefixes, see crpgs/shared_prefix.h)
///   one_model: {rate: 1.0e-3, scales: [1, 1.5, 2, 3]}   # each finished run at this rate is
///                                   # re-encoded at these step scales (`crpgs encode
///                                   # --rate-scales`, RUN/rates/): a "one model, many rates"
///                                   # curve that `crpgs report` draws beside the per-λ ones
#pragma once

#include <atomic>
#include <cmath>
#include <functional>
#include <string>
#include <utility>
#include <vector>

#include "crpgs/config.h"
#include "crpgs/status.h"

namespace crpgs::experiments {

/// key=value pairs, the value as YAML text (e.g. "1.0e-4", "[1, 2]").
using Overrides = std::vector<std::pair<std::string, std::string>>;

struct SweepConfig {
  std::string name;  ///< method label; default: the file's stem
  std::string path;
  Overrides set;
};

struct SweepDataset {
  std::string name;
  std::string scene;  ///< configs/scenes/*/scene.yaml laid over each config; may be empty
  Overrides set;
};

struct SweepResources {
  int cpus = 1;
  std::string mem;        ///< Slurm --mem, e.g. "16G"; empty = cluster default
  std::string time;       ///< Slurm --time, e.g. "08:00:00"
  std::string partition;  ///< Slurm --partition
  int max_parallel = 0;   ///< array throttle (%N); 0 = none
};

struct SweepSpec {
  std::string name;
  std::string file;    ///< where it was loaded from (for messages and the Slurm script)
  std::string output;  ///< runs directory
  std::vector<SweepConfig> configs;
  std::vector<std::pair<std::string, std::vector<std::string>>> grid;
  std::string rate_key;
  std::vector<SweepDataset> datasets;  ///< empty = one unnamed dataset (the configs' own)
  SweepResources resources;
  int workers = 1;
  bool share_prefix = true;
  double one_model_rate = NAN;           ///< one_model.rate; NaN: no one-model curves
  std::vector<double> one_model_scales;  ///< one_model.scales
};

StatusOr<SweepSpec> parse_sweep(const std::string& yaml_text, const std::string& name);
StatusOr<SweepSpec> load_sweep(const std::string& path);

/// Where a sweep's runs publish their shared training prefixes: RUNS/prefixes.
std::string sweep_prefix_dir(const std::string& runs_dir);

struct SweepRun {
  int index = 0;
  std::string id;      ///< "<dataset>/<config>/<key>-<value>_...", deterministic
  std::string dir;     ///< runs_dir/id
  std::string method;  ///< config name plus the non-rate overrides, e.g. "crpgs sfa=0.5"
  std::string dataset;
  std::string config_path;
  std::string scene;    ///< the dataset's scene file, laid over the config before the overrides
  Overrides overrides;  ///< config set, then dataset set, then grid values (applied in order)
  double rate = NAN;    ///< the rate_key value, when numeric
};

/// "[i/n] <id>": how the sweep's log and its --status name a run; n is the whole sweep's size,
/// so a run keeps its number whatever --only selects.
std::string run_tag(const SweepRun& run, size_t sweep_size);

/// Datasets x configs x grid, in that nesting order. `runs_dir` empty = spec.output.
std::vector<SweepRun> expand_sweep(const SweepSpec& spec, const std::string& runs_dir = "");

/// The runs whose id matches one of `globs` (fnmatch patterns, e.g. "bonsai/*" or
/// "*/lambda-4.0e-3_*"), their indices kept; all of them when `globs` is empty.
std::vector<SweepRun> select_runs(const std::vector<SweepRun>& runs,
                                  const std::vector<std::string>& globs);

/// Appends "key=value" assignments (`crpgs sweep --set`) to every run's overrides, after the grid
/// values: e.g. train.device=cuda to run a sweep on a GPU machine. KEY.type=... (another
/// component) drops the run's other KEY.* overrides, as a config's `base:` replaces a block that
/// names another type. Refuses text without '='.
Status add_overrides(std::vector<SweepRun>& runs, const std::vector<std::string>& assignments);

/// The run's config: base config, then the scene file's keys, then the overrides, resolved
/// against `registry` when non-null.
StatusOr<Config> build_run_config(const SweepRun& run, const ComponentRegistry* registry);

/// Writes RUN/config.yaml (base config + overrides, resolved against `registry` when non-null)
/// and RUN/run.json (id, method, dataset, rate, overrides), atomically.
Status prepare_run(const SweepRun& run, const ComponentRegistry* registry);

/// How the config the run directory was prepared with (RUN/config.yaml, resolved by this build)
/// differs from the one the sweep builds now: "" when the same (or never prepared), else up to 3
/// "key: old -> new" items. A finished run whose sweep changed is kept, not rerun: the user
/// decides, as the results may be wanted. `ignore_placement`: what says where a run computes,
/// not what (train.threads, train.device and the rasterizer section: the CUDA rasterizer is held
/// to the CPU one by parity tests), does not count: a finished run's result stands wherever it
/// was computed, also when this build lacks its rasterizer; a resume elsewhere is not bit-exact,
/// so there it counts.
std::string config_change(const SweepRun& run, const ComponentRegistry* registry,
                          bool ignore_placement = false);

enum class RunState { kPending, kComplete, kInterrupted };
/// kComplete: metrics.json readable and no `.running` marker. kInterrupted: a marker was left
/// behind (the run or the sweep was killed). kPending otherwise.
RunState run_state(const std::string& run_dir);

struct ExecOptions {
  int workers = 1;
  /// Executable called as `runner train -c RUN/config.yaml -o RUN --resume|--force ...`. It
  /// receives the run directory's lock on an inherited descriptor: a wrapper must exec the
  /// trainer (not keep running beside it), or the directory stays locked.
  std::string runner;
  const ComponentRegistry* registry =
      nullptr;           ///< to resolve configs; null = write them unresolved
  bool dry_run = false;  ///< print what would run, run nothing
  int sweep_size = 0;    ///< runs in the whole sweep, for the "[i/n]" tags; 0 = runs given
  std::function<void(const std::string&)> log;  ///< progress lines (default: stdout)
  /// Set (e.g. by a SIGINT/SIGTERM handler) to stop: no run starts after it, the running ones get
  /// SIGTERM (`crpgs train` checkpoints and exits) and are waited for. Null: never stops.
  const std::atomic<bool>* stop = nullptr;
  /// Slurm array tasks: train RUN/config.yaml as `crpgs sweep --slurm` prepared it at
  /// submission (when there), not the base configs as they read now.
  bool use_prepared_configs = false;
  /// Passed to each run as `--share-prefix`; "" = off. With it, the next run to start is chosen
  /// to share most (next_run_to_start).
  std::string prefix_dir;
  /// One-model curves (SweepSpec::one_model_*): each finished run whose rate is
  /// one_model_rate is then re-encoded, `runner encode RUN --rate-scales ...`, as a job of its
  /// own (logs appended to the run's).
  double one_model_rate = NAN;
  std::vector<double> one_model_scales;
};

/// RUN/rates/scale-<s>: where `crpgs encode RUN --rate-scales` writes scale s.
std::string rate_scale_dir(const std::string& run_dir, double scale);

/// What a waiting run needs from the shared prefixes.
struct PendingRun {
  std::string prefix_key;       ///< shared_prefix_key of its config; "" = shares nothing
  bool has_checkpoint = false;  ///< resumes from its own checkpoint
};

/// Index into `pending` of the run to start next, so that each group's prefix is computed once
/// and early: first a run with its own checkpoint in a group whose prefix is neither published
/// nor in a running run (it may be on its way to rate_start), then the first run of a group
/// nobody has started; then one that needs no prefix (published, own checkpoint, or nothing to
/// share); else the first (a worker does not wait for a prefix). `running`: prefix keys of the
/// running runs; `published(key)`: the prefix file exists. Sweep order within each class.
/// `pending` must be non-empty.
size_t next_run_to_start(const std::vector<PendingRun>& pending,
                         const std::vector<std::string>& running,
                         const std::function<bool(const std::string&)>& published);

/// A run still to train, for sweep_time_left.
struct RunLeft {
  double iterations = 0;  ///< left to train
  double rate = 0;        ///< iterations per second
};

/// Seconds until the runs left are trained, `workers` at a time, each started in the order of
/// `left` as soon as a worker is free (the running ones first); NaN when a run with iterations
/// left has no positive rate.
double sweep_time_left(const std::vector<RunLeft>& left, int workers);

struct SweepSummary {
  int total = 0, skipped = 0, succeeded = 0, failed = 0;
  int interrupted = 0;  ///< runs stopped by `stop`; the next sweep resumes them
  std::vector<std::string> failed_ids;
};

/// Runs every unfinished run, `workers` at a time, each as a subprocess with stdout/stderr
/// appended to RUN/stdout.log and RUN/stderr.log. A run succeeded when its process exits 0 and
/// left a readable metrics.json.
StatusOr<SweepSummary> run_sweep_local(const std::vector<SweepRun>& runs, const ExecOptions& opt);

/// Runs one run in this process's foreground (used by Slurm array tasks). Already complete:
/// returns OK without running.
Status run_one(const SweepRun& run, const ExecOptions& opt);

/// The sbatch script for a job array over `indices` (each task: `crpgs_exe sweep SWEEP -o RUNS
/// --run-index $SLURM_ARRAY_TASK_ID`). Paths should be absolute.
std::string slurm_script(const SweepSpec& spec, const std::vector<int>& indices,
                         const std::string& crpgs_exe, const std::string& sweep_file,
                         const std::string& runs_dir);
/// Writes RUNS/sweep.sbatch and submits it with `sbatch --parsable`; returns the job id.
/// `indices` must be non-empty.
StatusOr<std::string> submit_slurm(const SweepSpec& spec, const std::vector<int>& indices,
                                   const std::string& crpgs_exe, const std::string& sweep_file,
                                   const std::string& runs_dir);

/// readlink(/proc/self/exe).
std::string self_executable();

}  // namespace crpgs::experiments
