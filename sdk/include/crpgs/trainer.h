/// @file trainer.h
/// @brief Training and evaluation of the anchor model. `setup_training` wires dataset, model,
/// components and rasterizer from a resolved config; `Trainer::train` runs the loop, reports
/// through a ProgressCallback, writes checkpoints atomically and resumes bit-identically.
#pragma once

#include <array>
#include <cmath>
#include <memory>
#include <string>
#include <string_view>
#include <vector>

#include <torch/types.h>

#include "crpgs/anchor_model.h"
#include "crpgs/config.h"
#include "crpgs/dataset.h"
#include "crpgs/image_tensor.h"
#include "crpgs/progress.h"
#include "crpgs/rasterizer.h"
#include "crpgs/registry.h"
#include "crpgs/shared_prefix.h"
#include "crpgs/status.h"

namespace crpgs {

/// Phase boundaries in iterations (docs/method.md §1.4, §2.3). Densification statistics run for
/// start_stat < it < update_until; anchors are adjusted when it > update_from and
/// it % update_interval == 0, except for pause_from <= it < pause_until.
struct Schedule {
  int iterations = 30000;
  int start_stat = 500;
  int update_from = 1500;
  int update_interval = 100;
  int update_until = 15000;
  int pause_from = 3000, pause_until = 4000;
  /// Rate path only (docs/method.md §2.3): raw attributes for it <= quant_start, + U(-1/2,1/2)*Q0
  /// up to rate_start, bounds recomputed at rate_start (rate.recompute_bounds), adaptive-step noise
  /// plus rate and mask terms for it > rate_start.
  int quant_start = 3000;
  int rate_start = 10000;
  /// Learning-rate schedules run over lr_steps iterations and stay at their final values after
  /// (CRP-GS trains 40k iterations on HAC's 30k schedules, docs/method.md §7.7).
  int lr_steps = 30000;
  /// Iterations at which the anchor links are (re)built from scratch (docs/method.md §7.6); only
  /// used with a `links` component.
  std::vector<int> link_builds{30000, 33000, 36000};
  /// HAC's 30k schedule.
  static Schedule full();
  /// Every boundary (and the iteration count) of full() multiplied by `factor` (0 < f <= 1),
  /// rounded, with update_interval >= 1.
  static Schedule scaled(double factor);
  /// Anchors grow and are pruned at the end of iteration `it`.
  bool adjusts_at(int it) const {
    return it > start_stat && it > update_from && it < update_until && it % update_interval == 0 &&
           !(it >= pause_from && it < pause_until);
  }
  /// The same scaling applied to this schedule (e.g. a 40k CRP-GS schedule).
  Schedule scaled_by(double factor) const;
};

struct TrainOptions {
  Schedule schedule;
  uint64_t seed = 0;
  double lambda_dssim = 0.2;
  double lambda_scaling = 0.01;
  int eval_interval = 1000;        ///< held-out PSNR every N iterations; 0 = never
  int checkpoint_interval = 5000;  ///< 0 = only on request / at the end (and by minutes)
  /// Also checkpoint when this many minutes of training passed since the last one (a 4k-iteration
  /// run never reaches checkpoint_interval; a machine reset should not lose an hour); 0 = off.
  double checkpoint_minutes = 15;
  /// at::set_num_threads for train(); 0 = the process's count (setup_training sets all cores)
  int threads = 0;
  /// Where the model trains: "cpu", or "cuda" (its tensors on the GPU; needs the `cuda`
  /// rasterizer and a libtorch built with CUDA).
  std::string device = "cpu";
  /// Non-finite iterations in a row whose updates are discarded before rolling back to the last
  /// good state (the last checkpoint, kept in memory), and roll-backs before giving up.
  int max_skipped_steps = 5;
  int max_rollbacks = 3;
  std::string output_dir;  ///< checkpoints go to output_dir/checkpoint.pt; "" = none
  /// Where to publish the state after iteration schedule.rate_start, the end of the part of
  /// training that the rate weights do not touch (see shared_prefix_key); written once, when
  /// absent. "" = nowhere.
  std::string prefix_path;
  /// hex64 of the resolved config, recorded in checkpoints so that a resume under another
  /// config can say so (train_options_from_config sets it); "" = not recorded.
  std::string config_hash;
  /// shared_prefix_key of the resolved config (train_options_from_config sets it), recorded in
  /// checkpoints: a state trained partly under another key is never published as a prefix, one
  /// resumed under a config that differs only in what the key leaves out (the rate weights,
  /// thread counts) is. "" = not recorded: config_hash decides instead.
  std::string prefix_key;
};

struct ViewMetrics {
  std::string name;
  double psnr = 0;  ///< dB, on the 8-bit round trip
  double ssim = 0;
  double lpips = NAN;  ///< with an LPIPS module (crpgs/lpips.h), on the same round trip
};

struct EvalResult {
  std::vector<ViewMetrics> views;
  double mean_psnr = 0;
  double mean_ssim = 0;
  double mean_lpips = NAN;
  double seconds_per_view = 0;  ///< rendering only
};

/// Held-out PSNR at a point of training.
struct PsnrPoint {
  double seconds = 0;  ///< training wall-clock (all processes of a resumed run, no evaluation)
  int iteration = 0;
  double psnr = 0;  ///< dB, mean over Trainer::trace_views(), 8-bit round trip
};

/// The rate path's terms of the last iteration (rate phase only; `on` false otherwise).
struct RateReport {
  bool on = false;
  double bits_per_param = 0;   ///< subset bpp x active fraction (docs/method.md §2.5)
  double hash_bits = 0;        ///< B_h of the context
  double rate = 0;             ///< bits_per_param + hash_bits / (N_all (Dc + 6 + 3K)); x lambda
  double mask_loss = 0;        ///< mean(sigmoid(mask logits)); x mask_lambda
  int64_t subset = 0;          ///< anchors the rate was measured on
  double active_fraction = 0;  ///< active anchors / all anchors
  int64_t leaves = 0;          ///< anchors linked to a root (0 without links)
};

/// Wall-clock split of the iterations run so far (seconds, summed).
struct StepTimes {
  double generate = 0;   ///< prefilter + MLPs (forward)
  double render = 0;     ///< rasterizer forward
  double loss = 0;       ///< loss forward
  double backward = 0;   ///< the whole backward pass (rasterizer + MLPs + loss)
  double optimizer = 0;  ///< statistics, growing/pruning, Adam
  int iterations = 0;
  /// Whole steps (link builds included) per phase of the schedule, in QuantPhase order: raw
  /// attributes (it <= quant_start), fixed noise (<= rate_start), the rate phase. Unlike the
  /// fields above, over the whole run: a checkpoint carries them to the resumed process.
  std::array<double, 3> phase_seconds{};
  std::array<int, 3> phase_iterations{};
  /// Each phase's name as metrics.json records it ("phases") and as the CLI prints it.
  struct PhaseName {
    const char* key;
    const char* words;
  };
  static constexpr PhaseName kPhaseNames[3] = {
      {"raw", "raw attributes"}, {"fixed_noise", "fixed noise"}, {"rate", "rate phase"}};
};

class Lpips;

class Trainer {
 public:
  /// `dataset.train` must be non-empty. The model must have been created for this dataset.
  Trainer(TrainOptions options, Dataset dataset, std::shared_ptr<Rasterizer> rasterizer,
          std::unique_ptr<AnchorModel> model, torch::Generator gen);
  ~Trainer();

  /// Runs until schedule.iterations (from the current iteration). Writes checkpoints every
  /// checkpoint_interval iterations and at the end (when output_dir is set). When `control->stop`
  /// becomes true, writes a checkpoint and returns kCancelled; `control->save` saves and goes on.
  /// A non-finite iteration (step() returned kNonFinite) is reported and skipped; after
  /// max_skipped_steps in a row, or when a parameter itself is non-finite, training rolls back to
  /// the last checkpointed state and replays from there; after max_rollbacks with no checkpoint
  /// written in between it returns kNonFinite. A state with a non-finite parameter is never
  /// checkpointed. Runs on options().threads (when > 0), and puts the process's thread counts
  /// back after.
  Status train(ProgressCallback* progress = nullptr, TrainControl* control = nullptr);
  /// One iteration (iteration() + 1). Returns the loss, or kNonFinite (naming the iteration and
  /// the parameter group) when the loss or a gradient is NaN/Inf: then nothing was updated and
  /// the iteration counts as done.
  StatusOr<double> step();
  int iteration() const { return iteration_; }
  /// Training wall-clock so far, evaluation excluded, summed over resumed runs (checkpointed).
  double elapsed_seconds() const { return elapsed_; }
  /// Held-out PSNR every eval_interval iterations since iteration 0 (checkpointed).
  const std::vector<PsnrPoint>& psnr_trace() const { return psnr_trace_; }
  /// The test views the trace averages: up to kMaxTraceViews of them, evenly spaced from the
  /// first. A trace begun by a build that traced the first test view alone (a checkpoint or
  /// prefix without the count) goes on with that view, so one run's trace stays one measure.
  std::vector<std::string> trace_views() const;
  static constexpr int kMaxTraceViews = 8;

  /// Writes everything needed to resume (model, optimizer, statistics, RNG, iteration) via a
  /// temporary file and rename.
  Status save_checkpoint(const std::string& path) const;
  Status load_checkpoint(const std::string& path);
  /// Continues from a shared prefix (a state published at iteration schedule.rate_start by a run
  /// whose config has the same shared_prefix_key). When the prefix is unusable (unreadable,
  /// another iteration, another model) the trainer is left exactly as it was and the status says
  /// why; kInternal only when it could not be put back (then it must not be used).
  Status start_from_prefix(const std::string& path);
  /// One line on the shared prefix for the log: the one this run started from, or why one was
  /// not used; "" when none was looked for.
  const std::string& prefix_status() const { return prefix_status_; }
  /// code_build_id() of the process that wrote the loaded checkpoint or prefix ("" for none, or
  /// one written before checkpoints recorded it).
  const std::string& state_build_id() const { return state_build_id_; }
  /// TrainOptions::config_hash of the run that wrote the loaded checkpoint or prefix ("" for
  /// none, or a checkpoint from before it was recorded).
  const std::string& state_config_hash() const { return state_config_hash_; }
  /// How this process trains: thread counts and BLAS kernels, which change the last bits of a
  /// training but not its config (e.g. "train.threads 2, rasterizer.threads 2, OpenBLAS
  /// SkylakeX"). Checkpointed, so that a start from another process's state can name the
  /// difference.
  std::string execution() const;
  /// execution() of the process that wrote the loaded checkpoint or prefix ("" for none, or one
  /// written before checkpoints recorded it).
  const std::string& state_execution() const { return state_execution_; }
  /// What differed, over the loaded state's history, between the processes that trained it and
  /// the ones that continued it ("; "-separated): another build, other thread counts or BLAS
  /// kernels, each of which makes the state differ in the last bits from one trained in this
  /// process alone. Checkpointed, so a later resume on the first process's settings still says
  /// so. "" when nothing differed, or nothing was loaded.
  const std::string& state_origin_differences() const { return origin_; }
  void set_prefix_status(std::string status) { prefix_status_ = std::move(status); }
  /// output_dir/checkpoint.pt, or "" without an output dir.
  std::string checkpoint_path() const;
  /// Settings that work but are likely not what was meant for the training still to come, one
  /// line each (e.g. a shared feature whose grid lookup moves when rate_start recomputes the
  /// bounds, docs/method.md §7.4).
  std::vector<std::string> setting_warnings() const;
  /// The first parameter group holding a NaN/Inf, or "" when every parameter is finite.
  std::string nonfinite_parameter_group() const;

  /// Renders the dataset's test views (or `views` when given) and measures them.
  StatusOr<EvalResult> evaluate(const std::string& png_dir = "", const Lpips* lpips = nullptr);
  /// PSNR (8-bit round trip) of one view.
  double view_psnr(const View& view);

  AnchorModel& model() { return *model_; }
  const Dataset& dataset() const { return dataset_; }
  Rasterizer& rasterizer() { return *rasterizer_; }
  const TrainOptions& options() const { return options_; }
  const StepTimes& times() const { return times_; }
  int64_t last_gaussian_count() const { return last_gaussians_; }
  const RateReport& last_rate() const { return last_rate_; }

  /// The training view of `iteration`: deterministic from the seed (so a resume sees the same
  /// views), and from how many replays after a roll-back had to draw differently.
  int view_for_iteration(int iteration) const;

 private:
  StatusOr<std::string> serialize_state() const;
  static Status write_checkpoint(const std::string& path, std::string_view bytes);
  /// `rollback`: keep the training clock (the time was spent) but take the snapshot's trace.
  Status restore_state(const std::vector<uint8_t>& bytes, const std::string& origin, bool rollback);
  /// Remembers the current state as the last good one (and writes it to checkpoint_path()).
  Status checkpoint(ProgressCallback* progress);
  /// Writes options_.prefix_path once (when absent, every parameter is finite and the state was
  /// trained under this config alone).
  void publish_prefix(ProgressCallback* progress) const;
  TrainOptions options_;
  Dataset dataset_;
  std::shared_ptr<Rasterizer> rasterizer_;
  std::unique_ptr<AnchorModel> model_;
  torch::Generator gen_;
  /// 0 normally; raised by a roll-back whose replay failed again (train()), so that the next
  /// replay draws other views and noise. Checkpointed: a resume continues the same draws.
  uint64_t replay_salt_ = 0;
  int iteration_ = 0;
  StepTimes times_;
  int64_t last_gaussians_ = 0;
  double last_l1_ = 0;
  RateReport last_rate_;
  std::vector<torch::Tensor> train_images_;  // [H, W, 3] per train view
  std::vector<uint8_t> last_good_;           // serialized state of the last checkpoint
  int last_good_iteration_ = -1;
  double elapsed_ = 0;
  std::vector<PsnrPoint> psnr_trace_;
  int trace_view_count_ = 0;  // trace_views().size(); checkpointed
  std::vector<const View*> trace_view_ptrs() const;
  std::string prefix_status_;
  std::string state_build_id_;
  std::string state_config_hash_;
  std::string state_execution_;
  std::string origin_;  // state_origin_differences()
  /// What differs between a writer of (build_id, execution_text) and this process, one
  /// sentence each.
  std::vector<std::string> differences_from(const std::string& build_id,
                                            const std::string& execution_text) const;
  /// True once the state holds iterations trained under a config of another prefix key (a
  /// resume after such a change); checkpointed. Such a state is never published as a shared
  /// prefix: its consumers would not continue a training from the start.
  bool mixed_config_ = false;
};

/// Renders `views` with the model and measures PSNR and SSIM (and LPIPS with `lpips`) on the
/// 8-bit round trip (docs/method.md §4); with png_dir, writes the renders and the ground truth as
/// `<png_dir>/renders/00000.png` and `<png_dir>/gt/00000.png` (3DGS's layout), numbered in view
/// order. A model with the rate path that is not already quantised is evaluated quantised
/// (model.quantize(), HAC's test-time attributes) and left as it was.
StatusOr<EvalResult> evaluate_views(AnchorModel& model, Rasterizer& rasterizer,
                                    const std::vector<View>& views, const std::string& png_dir,
                                    const Lpips* lpips = nullptr);

/// Reads the `scene`, `model` and `train` sections of a resolved config.
StatusOr<AnchorModelOptions> model_options_from_config(const Config& resolved);
StatusOr<TrainOptions> train_options_from_config(const Config& resolved);
/// Reads the `rate` section.
StatusOr<RateOptions> rate_options_from_config(const Config& resolved);
/// The leaf-MLP options of the `rate` section; its lr window runs from the schedule's first link
/// build to its end.
StatusOr<LinkOptions> link_options_from_config(const Config& resolved, const Schedule& schedule);

/// The rate path's components (both null: plain Scaffold-GS training, nothing rate-related).
struct RateSetup {
  std::shared_ptr<ContextModel> context;
  std::shared_ptr<EntropyModel> entropy;
  RateOptions options;
  std::shared_ptr<ContextModel> links;  ///< a link strategy (CRP-GS); null: none
  LinkOptions link_options;
};

struct SetupOptions {
  std::string output_dir;  ///< overrides nothing in the config; where checkpoints go
  bool resume = false;     ///< continue from output_dir/checkpoint.pt if it exists
  /// Shared training prefixes (rate path only): a run without its own checkpoint starts from
  /// prefix_dir/<shared_prefix_key>.pt when present (an unusable one is renamed *.unusable), and
  /// every run publishes it at schedule.rate_start when absent. "" = off.
  std::string prefix_dir{};  // {}: SetupOptions{dir, resume} may leave it out
  /// Keep the model on the CPU whatever train.device says: for commands that read a trained
  /// model (evaluate, encode, render, export) rather than train it.
  bool model_on_cpu = false;
  /// A checkpoint another run wrote: a run without its own checkpoint continues from that state
  /// under this config (a fine-tune at another rate.lambda, say), up to its train.iterations,
  /// which must lie beyond the checkpoint's iteration. "" = off.
  std::string start_from{};
};

/// Wires everything from a resolved config: dataset (or the synthetic scene), rasterizer and
/// feature model from the registry, the anchor model, the trainer; optionally resumes. With both
/// a `context` and an `entropy` section the rate path is attached (config `rate`); with only
/// one of them it is an error.
StatusOr<std::unique_ptr<Trainer>> setup_training(const Config& resolved,
                                                  const ComponentRegistry& registry,
                                                  const SetupOptions& setup);

/// The same from already-built parts (tests, benchmarks, embedding applications).
StatusOr<std::unique_ptr<Trainer>> make_trainer(const TrainOptions& train_options,
                                                const AnchorModelOptions& model_options,
                                                Dataset dataset,
                                                std::shared_ptr<Rasterizer> rasterizer,
                                                std::shared_ptr<FeatureModel> features,
                                                const RateSetup& rate = RateSetup());

}  // namespace crpgs
