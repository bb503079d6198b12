/// @file cli_common.h
/// @brief What every `crpgs` subcommand shares: global options, the registry, config loading,
/// and plain-text tables.
#pragma once

#include <array>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include <CLI/CLI.hpp>

#include "crpgs/codec.h"
#include "crpgs/components.h"
#include "crpgs/config.h"
#include "crpgs/experiments/run_metrics.h"
#include "crpgs/link_report.h"
#include "crpgs/pipeline.h"
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

/// Prints rows as aligned columns (first row is the header).
void print_table(const std::vector<std::vector<std::string>>& rows, FILE* out = stdout);
/// Per-view PSNR/SSIM table with the mean, then the render time per view.
void print_eval(const EvalResult& r);

/// Prints a Status to stderr as "crpgs: error: ..." and returns exit code 1.
int report_error(const Status& st);

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

/// The dataset's warnings (ignored lens distortion, no SfM points, ...) on stderr: the SDK only
/// collects them.
void print_dataset_warnings(const Dataset& d);
/// setup_training, then the dataset's warnings (ignored lens distortion, no SfM points, ...) on
/// stderr: the SDK only collects them.
StatusOr<std::unique_ptr<Trainer>> setup_training_and_warn(const Config& cfg,
                                                           const ComponentRegistry& registry,
                                                           const SetupOptions& options);

void print_bitstream_report(const BitstreamReport& r);
/// load_model_source with --set (g.sets), then the dataset's warnings on stderr (the SDK only
/// collects them).
StatusOr<ModelSource> load_model_source(const GlobalOptions& g, const ComponentRegistry& r,
                                        const std::string& source, int threads);
/// `crpgs eval FILE.crpgs`: decode, then evaluate on the test views of the dataset in its config.
int eval_bitstream_file(const GlobalOptions& g, const std::string& path, const std::string& png_dir,
                        const Lpips* lpips);

/// export_gaussians with a progress bar over the refinement, its notes on stderr and a line on
/// the fit (cmd_export.cpp; `crpgs export` and `crpgs view`).
StatusOr<ExportResult> export_with_progress(ModelSource& source, const ExportOptions& options);

/// What a .ply is read against (`crpgs import`, `crpgs view -c`): the config's dataset and
/// rasterizer as it sets them up (its model is not used; the dataset's warnings on stderr) and
/// the scene's background (cmd_export.cpp).
struct PlyReadingSetup {
  std::unique_ptr<Trainer> setup;
  std::array<float, 3> background{};
};
StatusOr<PlyReadingSetup> ply_reading_setup(const GlobalOptions& g, const ComponentRegistry& r,
                                            const std::string& config);

/// Subcommand registration (each in its own .cpp).
void add_plugin_commands(CLI::App& app, GlobalOptions& g);
void add_config_commands(CLI::App& app, GlobalOptions& g);
void add_train_commands(CLI::App& app, GlobalOptions& g);
void add_codec_commands(CLI::App& app, GlobalOptions& g);
void add_sweep_commands(CLI::App& app, GlobalOptions& g);   // cmd_sweep.cpp
void add_report_commands(CLI::App& app, GlobalOptions& g);  // cmd_report.cpp
void add_render_commands(CLI::App& app, GlobalOptions& g);  // cmd_render.cpp: decode, render
void add_export_commands(CLI::App& app, GlobalOptions& g);  // cmd_export.cpp: .ply export, import
void add_view_commands(CLI::App& app, GlobalOptions& g);    // cmd_view.cpp: a scene in a browser

}  // namespace crpgs::cli
