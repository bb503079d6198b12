/// @file pipeline.h
/// @brief The pipeline every front end drives (the `crpgs` CLI, the Python module): a config
/// with overrides, a trained model opened from what a user points at (a .crpgs file, a `crpgs
/// decode` directory, a training run), a trained model's bitstream written and checked, and the
/// metrics.json fields it yields. Nothing here prints: warnings stay in the dataset
/// (Dataset::warnings) for the front end to show.
#pragma once

#include <array>
#include <functional>
#include <map>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "crpgs/codec.h"
#include "crpgs/config.h"
#include "crpgs/dir_lock.h"
#include "crpgs/experiments/run_metrics.h"
#include "crpgs/gaussian_export.h"
#include "crpgs/link_report.h"
#include "crpgs/registry.h"
#include "crpgs/trainer.h"

namespace crpgs {

/// Loads `path` (or `fallback_yaml` when path is empty), applies the "key=value" overrides
/// `sets` (a relative dataset.path among them is taken against the working directory), resolves
/// against the registry. Errors name file, line, column and YAML path.
StatusOr<Config> load_config(const std::string& path, const std::vector<std::string>& sets,
                             const ComponentRegistry& registry,
                             const std::string& fallback_yaml = "");

/// Rendering needs the cameras (and ground truth) of the dataset the model was trained on:
/// kNotFound naming dataset.path, and how to point elsewhere (--set dataset.path=DIR).
Status check_dataset(const Config& c);

/// The set-up of a reader of a run's model (from run_dir's checkpoint; "" = none) rather than a
/// trainer: the model on the CPU, whatever device it was trained on.
SetupOptions reading_setup(const std::string& run_dir);

/// The model file of a `crpgs decode` directory (next to its config.yaml).
constexpr const char* kDecodedModelFile = "decoded.pt";
/// Writes a decoded bitstream as a torch archive, atomically: the integer symbols exactly as
/// decoded, the dequantised attributes a renderer needs (symbol x step, as model_from_decoded
/// computes them), the MLPs and the feature model's state.
Status write_decoded_model(const std::string& path, const DecodeResult& d);
/// Reads a write_decoded_model file with the components of `cfg`.
StatusOr<std::unique_ptr<AnchorModel>> read_decoded_model(const std::string& path,
                                                          const Config& cfg,
                                                          const ComponentRegistry& r);

/// A trained model with the dataset and rasterizer its config names.
struct ModelSource {
  std::string kind;                      ///< "bitstream", "decoded", "run"
  std::unique_ptr<Trainer> setup;        ///< dataset, rasterizer; the model of a run
  std::unique_ptr<AnchorModel> decoded;  ///< null for a run
  /// A run with the rate path renders its quantised rows in the bitstream's canonical order
  /// (set_quantized(q)), so that it renders and exports exactly as its decoded file.
  QuantizedAttributes q;
  bool quantized = false;
  uint64_t file_bytes = 0;  ///< a bitstream's size
  /// False when `sets` changed the train/test split (dataset.test_every or max_images): train
  /// view i is then not the view the model's appearance embedding i was trained on.
  bool train_views_as_trained = true;
  double load_seconds = 0;  ///< reading and decoding (not the run's checkpoint)
  AnchorModel& model() { return decoded ? *decoded : setup->model(); }
};
/// What a reader says of a path that holds no model.
Status not_a_model_source(const std::string& source);
/// Opens a .crpgs bitstream, a `crpgs decode` directory or a training run directory. The model
/// is built from the model's own config; `sets` ("key=value") then apply to the config that sets
/// up the dataset and rasterizer (e.g. dataset.path), which is refused with a message when its
/// dataset is absent. For a bitstream or decode directory an override that changes anything
/// else (the model's own settings, which it would not follow) is refused. threads > 0 sets
/// libtorch's threads, train.threads and the rasterizer's threads; 0 keeps the config's.
StatusOr<ModelSource> load_model_source(const ComponentRegistry& r, const std::string& source,
                                        const std::vector<std::string>& sets, int threads);

/// What `crpgs export` makes of a model: a bake, then a fit to the training photos
/// (bench/results/export_360.md).
struct ExportOptions {
  int sh_degree = 3;
  int directions = BakeOptions{}.directions;
  double view_weight = BakeOptions{}.view_weight;
  bool opacity_over_views = BakeOptions{}.opacity_over_views;
  /// refine_gaussians iterations on the training views; 0 = the bake alone. 1,000: at 200 the
  /// fit is still improving (lego CRP-GS 31.5 -> 32.9 dB, bench/results/export.md).
  int refine = 1000;
};
struct ExportResult {
  PlyGaussians gaussians;
  double view_weight = 0;  ///< as used: 0 when the dataset has no training views
  double bake_seconds = 0, refine_seconds = 0;
  std::optional<RefineReport> refine;  ///< when refined
  std::vector<std::string> notes;      ///< "note: ..." / "warning: ..." for the user
};
/// Bakes the source's model into standard 3DGS Gaussians (its bitstream rows when it has them;
/// SH fitted over the training cameras' views and a sphere of directions) and refines them on
/// the training photos. Refining needs training views (kInvalidArgument before baking).
/// `on_refine_iteration(iteration, loss)` follows the fit.
StatusOr<ExportResult> export_gaussians(
    ModelSource& source, const ExportOptions& options,
    const std::function<void(int, double)>& on_refine_iteration = {});

/// Renders .ply Gaussians on `views` and measures them as evaluate_views does (8-bit PNG round
/// trip); PNGs go to png_dir when set.
StatusOr<EvalResult> evaluate_ply(const PlyGaussians& ply, Rasterizer& rasterizer,
                                  const std::vector<View>& views,
                                  const std::array<float, 3>& background,
                                  const std::string& png_dir);

/// What writing a trained model's bitstream and checking it produced.
struct BitstreamReport {
  std::string path;
  uint64_t file_bytes = 0;
  double rate_scale = 1.0;
  std::vector<SectionSize> sections;
  std::map<std::string, std::pair<double, double>> estimated_vs_coded_bits;
  double encode_seconds = 0, decode_seconds = 0;
  double quantized_psnr = 0;                         ///< training-side quantised model, test views
  double decoded_psnr = 0;                           ///< the model decoded from the file on disk
  std::vector<std::array<double, 3>> decoded_views;  ///< psnr, ssim, render seconds per view
  std::vector<std::string> view_names;
  int64_t anchors = 0;    ///< coded anchors
  int64_t gaussians = 0;  ///< their neural Gaussians with the offset mask on
  /// With links: leaves at the end of training and leaves coded (links whose leaf or root is
  /// masked are dropped at encode time), and what the coded links buy.
  int64_t links_built = -1, links_coded = -1;
  std::optional<LinkRateReport> link_rate;
  uint64_t link_side_bytes = 0;  ///< AMSK + LINK on disk
};
/// Encodes the trained model (rate path required) to `path` atomically, decodes that file
/// again, and evaluates both the training-side quantised model and the decoded one on the test
/// views (decoded renders go to png_dir when set). Sizes are the file's size on disk.
/// `rate_scale` scales the quantisation steps (coded_model_from).
StatusOr<BitstreamReport> write_and_check_bitstream(Trainer& trainer, const Config& config,
                                                    const ComponentRegistry& registry,
                                                    const std::string& path,
                                                    const std::string& png_dir,
                                                    double rate_scale = 1.0);

/// A finished run opened to encode it again: its config (with `sets`) and its trainer, the
/// model loaded from the checkpoint on the CPU. kNotFound without a checkpoint or dataset.
struct FinishedRun {
  Config config;
  std::unique_ptr<Trainer> trainer;
};
StatusOr<FinishedRun> open_finished_run(const ComponentRegistry& registry,
                                        const std::string& run_dir,
                                        const std::vector<std::string>& sets = {});
/// The rate scale of the best-quality file at or under `target` bytes: the smallest scale whose
/// file fits (the steps grow with the scale, so the size falls with it), by bisection on
/// log(scale) over [1/16, 256] with in-memory encodes. kInvalidArgument, naming the smallest
/// size the model reaches, when the target is below it.
StatusOr<double> scale_for_target_size(Trainer& trainer, const Config& config, uint64_t target);

/// metrics.json's fields of a written and checked bitstream: λ, size and its breakdown, coded
/// anchors and Gaussians, codec times, the decoded model's test views.
experiments::RunMetrics bitstream_metrics(const BitstreamReport& r, const Config& config);

/// A training run in a directory, as `crpgs train -o DIR` and crpgs.train make one.
struct RunOptions {
  std::string out_dir;
  bool resume = false;     ///< continue DIR's checkpoint
  bool replace = true;     ///< false: refuse a directory that holds a run (unless resume)
  std::string method;      ///< the run's name in metrics.json; "" = the config file's stem
  std::string prefix_dir;  ///< shared training prefixes (SetupOptions::prefix_dir); "" = off
  std::string start_from;  ///< another run's checkpoint to continue under this config
};
/// A run directory ready to train: locked for this process, its trainer set up, and — only
/// once the set-up succeeded, so that a mistyped path costs nothing — an earlier run's results
/// removed (unless resuming), the run marked started and the resolved config saved.
struct PreparedRun {
  DirectoryLock lock;
  std::unique_ptr<Trainer> trainer;
  int stale_files_removed = 0;  ///< half-written files of an earlier, killed attempt
};
/// What a failed set-up adds (the directory, DIR/.lock) goes again.
StatusOr<PreparedRun> prepare_run_directory(const Config& config, const ComponentRegistry& registry,
                                            const RunOptions& options);
/// After training: on the rate path the bitstream DIR/scene.crpgs written and checked
/// (`bitstream`, when given, receives the report), else the test views evaluated (`eval`); then
/// DIR/metrics.json (written atomically) and the run marked finished.
StatusOr<experiments::RunMetrics> finish_run(Trainer& trainer, const Config& config,
                                             const ComponentRegistry& registry,
                                             const RunOptions& options,
                                             BitstreamReport* bitstream = nullptr,
                                             EvalResult* eval = nullptr);

}  // namespace crpgs
