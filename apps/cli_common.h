/// @file cli_common.h
/// @brief What every `crpgs` subcommand shares: global options, the registry, config loading,
/// and plain-text tables.
#pragma once

#include <optional>
#include <string>
#include <vector>

#include <CLI/CLI.hpp>

#include "crpgs/codec.h"
#include "crpgs/components.h"
#include "crpgs/config.h"
#include "crpgs/experiments/run_metrics.h"
#include "crpgs/link_report.h"
#include "crpgs/registry.h"
#include "crpgs/runtime.h"
#include "crpgs/trainer.h"

namespace crpgs::cli {

struct GlobalOptions {
  std::vector<std::string> plugin_dirs;  ///< --plugin-dir, searched first
  std::vector<std::string> sets;         ///< --set key.path=value overrides
};

/// Built-ins plus every plugin on the search path.
ComponentRegistry load_registry(const GlobalOptions& g);

/// Loads `path` (or `fallback_yaml` when path is empty), applies --set, resolves against the
/// registry. Errors are returned with file, line, column and YAML path.
StatusOr<Config> load_config(const std::string& path, const GlobalOptions& g,
                             const ComponentRegistry& registry,
                             const std::string& fallback_yaml = "");

/// Prints rows as aligned columns (first row is the header).
void print_table(const std::vector<std::vector<std::string>>& rows, FILE* out = stdout);
/// Per-view PSNR/SSIM table with the mean, then the render time per view.
void print_eval(const EvalResult& r);

/// Prints a Status to stderr as "crpgs: error: ..." and returns exit code 1.
int report_error(const Status& st);

/// Rendering needs the cameras (and ground truth) of the dataset the model was trained on:
/// kNotFound naming dataset.path, and how to point elsewhere (--set dataset.path=DIR).
Status check_dataset(const Config& c);

/// The `--threads N` option of the commands that compute (0 = all cores).
inline CLI::Option* add_threads_option(CLI::App* cmd, int& threads) {
  return cmd->add_option("--threads", threads, "CPU threads; 0 = all cores")
      ->check(CLI::Number)
      ->check(CLI::Range(0, 1024));
}

/// Refuses an output that would replace the command's input: `source` itself, or a file of the
/// run or decode directory `source` (checkpoint, config, model, metrics). Also an output path
/// that is a directory. `own_output`: the one file of the run this command writes itself (encode:
/// scene.crpgs), which may be replaced.
Status check_output_is_not_input(const std::string& out, const std::string& source,
                                 const std::string& own_output = "");

/// setup_training, then the dataset's warnings (ignored lens distortion, no SfM points, ...) on
/// stderr: the SDK only collects them.
StatusOr<std::unique_ptr<Trainer>> setup_training_and_warn(const Config& cfg,
                                                           const ComponentRegistry& registry,
                                                           const SetupOptions& options);
/// The set-up of a command that reads a run's model (from run_dir's checkpoint; "" = none)
/// instead of training it: the model on the CPU, whatever device it was trained on.
SetupOptions reading_setup(const std::string& run_dir);

/// The model file of a `crpgs decode` directory (next to its config.yaml).
constexpr const char* kDecodedModelFile = "decoded.pt";
/// Reads a `crpgs decode` model file with the components of `cfg` (cmd_render.cpp, next to
/// its writer).
StatusOr<std::unique_ptr<AnchorModel>> read_decoded_model(const std::string& path,
                                                          const Config& cfg,
                                                          const ComponentRegistry& r);

/// A trained model from what the CLI accepts as SOURCE, with the dataset and rasterizer its
/// config names.
struct ModelSource {
  std::string kind;                      ///< "bitstream", "decoded", "run"
  std::unique_ptr<Trainer> setup;        ///< dataset, rasterizer; the model of a run
  std::unique_ptr<AnchorModel> decoded;  ///< null for a run
  /// A run with the rate path renders its quantised rows in the bitstream's canonical order
  /// (set_quantized(q)), so that it renders and exports exactly as its decoded file.
  QuantizedAttributes q;
  bool quantized = false;
  uint64_t file_bytes = 0;  ///< a bitstream's size
  /// False when --set changed the train/test split (dataset.test_every or max_images): train
  /// view i is then not the view the model's appearance embedding i was trained on.
  bool train_views_as_trained = true;
  double load_seconds = 0;  ///< reading and decoding (not the run's checkpoint)
  AnchorModel& model() { return decoded ? *decoded : setup->model(); }
};
/// What `eval`, `export` and `render` say of a path that holds no model.
Status not_a_model_source(const std::string& source);
/// Opens a .crpgs bitstream, a `crpgs decode` directory or a training run directory. The model
/// is built from the model's own config; --set (g.sets) then applies to the config that sets up
/// the dataset and rasterizer (e.g. dataset.path), which is refused with a message when its
/// dataset is absent. For a bitstream or decode directory a --set that changes anything else
/// (the model's own settings, which it would not follow) is refused. threads > 0 sets libtorch's
/// threads, train.threads and the rasterizer's threads; 0 keeps the config's.
StatusOr<ModelSource> load_model_source(const GlobalOptions& g, const ComponentRegistry& r,
                                        const std::string& source, int threads);

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
void print_bitstream_report(const BitstreamReport& r);
/// metrics.json's fields of a written and checked bitstream: λ, size and its breakdown, coded
/// anchors and Gaussians, codec times, the decoded model's test views.
experiments::RunMetrics bitstream_metrics(const BitstreamReport& r, const Config& config);
/// `crpgs eval FILE.crpgs`: decode, then evaluate on the test views of the dataset in its config.
int eval_bitstream_file(const GlobalOptions& g, const std::string& path, const std::string& png_dir,
                        const Lpips* lpips);

/// Subcommand registration (each in its own .cpp).
void add_plugin_commands(CLI::App& app, GlobalOptions& g);
void add_config_commands(CLI::App& app, GlobalOptions& g);
void add_train_commands(CLI::App& app, GlobalOptions& g);
void add_codec_commands(CLI::App& app, GlobalOptions& g);
void add_sweep_commands(CLI::App& app, GlobalOptions& g);   // cmd_sweep.cpp
void add_report_commands(CLI::App& app, GlobalOptions& g);  // cmd_report.cpp
void add_render_commands(CLI::App& app, GlobalOptions& g);  // cmd_render.cpp: decode, render
void add_export_commands(CLI::App& app, GlobalOptions& g);  // cmd_export.cpp: .ply export, import

}  // namespace crpgs::cli
