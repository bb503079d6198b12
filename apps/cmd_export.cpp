/// @file cmd_export.cpp
/// @brief `crpgs export` (anchor model -> standard 3DGS .ply with SH colours) and `crpgs import`
/// (render and evaluate a standard 3DGS .ply on the test views of a dataset).
#include <ATen/Parallel.h>

#include <chrono>
#include <cstring>
#include <filesystem>
#include <optional>

#include "cli_common.h"
#include "crpgs/atomic_file.h"
#include "crpgs/gaussian_export.h"
#include "crpgs/image.h"
#include "crpgs/metrics.h"
#include "crpgs/ply.h"
#include "progress_bar.h"

namespace crpgs::cli {

namespace {
namespace fs = std::filesystem;

/// Test-view PSNR below the anchor model's beyond which `crpgs export` warns, in dB.
constexpr double kExportGapWarning = 0.5;

}  // namespace

StatusOr<ExportResult> export_with_progress(ModelSource& source, const ExportOptions& options) {
  std::optional<ProgressBar> bar;
  const int refine = options.refine;
  auto exported = export_gaussians(source, options, [&bar, refine](int it, double loss) {
    if (!bar) bar.emplace("refine", refine);
    char extra[32];
    std::snprintf(extra, sizeof extra, "loss %.4f", loss);
    bar->update(it, extra);
  });
  if (bar) bar->finish();
  if (!exported.ok()) return exported.status();
  for (const std::string& note : exported->notes) std::fprintf(stderr, "%s\n", note.c_str());
  if (const auto& rep = exported->refine) {
    std::string losses;  // the first and last complete passes, when there are two
    char text[96];
    if (rep->passes >= 2)
      std::snprintf(text, sizeof text, ", loss %.4f -> %.4f (mean of the first and last pass)",
                    rep->first_pass_loss, rep->last_pass_loss);
    else if (rep->passes == 1)
      std::snprintf(text, sizeof text, ", loss %.4f (mean of its one pass)", rep->first_pass_loss);
    else
      text[0] = '\0';
    losses = text;
    if (rep->skipped > 0)
      losses += ", " + std::to_string(rep->skipped) + " with a non-finite loss or gradient skipped";
    std::printf("refined on %zu training views: %d iteration%s%s, %.1f s\n",
                source.setup->dataset().train.size(), rep->iterations,
                rep->iterations == 1 ? "" : "s", losses.c_str(), exported->refine_seconds);
  }
  return exported;
}

StatusOr<PlyReadingSetup> ply_reading_setup(const GlobalOptions& g, const ComponentRegistry& r,
                                            const std::string& config) {
  CRPGS_ASSIGN_OR_RETURN(Config cfg, load_config(config, g.sets, r));
  CRPGS_ASSIGN_OR_RETURN(AnchorModelOptions options, model_options_from_config(cfg));
  PlyReadingSetup out;
  CRPGS_ASSIGN_OR_RETURN(out.setup, setup_training_and_warn(cfg, r, reading_setup("")));
  out.background = options.effects.background;
  return out;
}

namespace {

int export_command(const GlobalOptions& g, const std::string& source, const std::string& out,
                   int degree, int directions, double view_weight, const std::string& opacity_from,
                   int refine, int threads) {
  if (Status st = check_output_is_not_input(out, source); !st.ok()) return report_error(st);
  ComponentRegistry r = load_registry(g);
  auto src = load_model_source(g, r, source, resolve_threads(threads));
  if (!src.ok()) return report_error(src.status());
  AnchorModel& model = src->model();
  const Dataset& ds = src->setup->dataset();
  ExportOptions opt;
  opt.sh_degree = degree;
  opt.directions = directions;
  opt.view_weight = view_weight;
  opt.opacity_over_views = opacity_from == "views";
  opt.refine = refine;
  auto exported = export_with_progress(*src, opt);
  if (!exported.ok()) return report_error(exported.status());
  const PlyGaussians& baked = exported->gaussians;
  const double bake_s = exported->bake_seconds;
  Status st = write_ply(out, baked);
  if (!st.ok()) return report_error(st);
  std::error_code ec;
  std::printf(
      "wrote %s: %zu Gaussians, SH degree %d (%d directions, view weight %.2f), opacity from "
      "the %s, %llu bytes, baked in %.2f s\n",
      out.c_str(), baked.size(), degree, directions, exported->view_weight,
      opt.opacity_over_views ? "views" : "representative view",
      static_cast<unsigned long long>(fs::file_size(out, ec)), bake_s);
  if (ds.test.empty()) return 0;
  // Read the file back: what is measured is what was written.
  auto back = read_ply(out);
  if (!back.ok()) return report_error(back.status());
  auto anchor_eval = evaluate_views(model, src->setup->rasterizer(), ds.test, "");
  if (!anchor_eval.ok()) return report_error(anchor_eval.status());
  auto ply_eval = evaluate_ply(back.value(), src->setup->rasterizer(), ds.test,
                               model.options().effects.background, "");
  if (!ply_eval.ok()) return report_error(ply_eval.status());
  std::vector<std::vector<std::string>> rows = {
      {"VIEW", "ANCHOR MODEL PSNR", "EXPORTED PSNR", "ANCHOR MODEL SSIM", "EXPORTED SSIM"}};
  auto row = [&rows](const std::string& name, double pa, double pb, double sa, double sb) {
    char v[4][32];
    std::snprintf(v[0], sizeof v[0], "%.3f", pa);
    std::snprintf(v[1], sizeof v[1], "%.3f", pb);
    std::snprintf(v[2], sizeof v[2], "%.4f", sa);
    std::snprintf(v[3], sizeof v[3], "%.4f", sb);
    rows.push_back({name, v[0], v[1], v[2], v[3]});
  };
  for (size_t i = 0; i < ply_eval->views.size(); ++i)
    row(ply_eval->views[i].name, anchor_eval->views[i].psnr, ply_eval->views[i].psnr,
        anchor_eval->views[i].ssim, ply_eval->views[i].ssim);
  row("mean", anchor_eval->mean_psnr, ply_eval->mean_psnr, anchor_eval->mean_ssim,
      ply_eval->mean_ssim);
  print_table(rows);
  // A bake from each anchor's representative view holds where views are near it; orbits and
  // 360-degree captures lose more (bench/results/export_360.md).
  const double gap = anchor_eval->mean_psnr - ply_eval->mean_psnr;
  if (gap > kExportGapWarning)
    std::fprintf(stderr,
                 "warning: the exported Gaussians are %.2f dB below the anchor model on the test "
                 "views; %s\n",
                 gap,
                 refine == 0 ? "--refine (1000 by default) fits them to the training photos"
                             : "more --refine iterations, or --sh-degree 3 if lower, may close "
                               "it");
  return 0;
}

int import_command(const GlobalOptions& g, const std::string& path, const std::string& config,
                   const std::string& png_dir, int threads) {
  if (std::error_code ec;
      !png_dir.empty() && fs::exists(png_dir, ec) && !fs::is_directory(png_dir, ec))
    return report_error(Status(StatusCode::kInvalidArgument,
                               png_dir + " is not a directory (-o names where the PNGs go)"));
  ComponentRegistry r = load_registry(g);
  set_compute_threads(threads);
  auto ply = read_ply(path);
  if (!ply.ok()) return report_error(ply.status());
  if (ply->dropped_non_finite > 0)
    std::fprintf(stderr, "warning: %s: %zu Gaussians with a NaN or infinite value left out\n",
                 path.c_str(), ply->dropped_non_finite);
  auto reading = ply_reading_setup(g, r, config);
  if (!reading.ok()) return report_error(reading.status());
  Trainer& setup = *reading->setup;
  auto ev = evaluate_ply(ply.value(), setup.rasterizer(), setup.dataset().test, reading->background,
                         png_dir);
  if (!ev.ok()) return report_error(ev.status());
  std::printf("%s: %zu Gaussians, SH degree %d; %.1f ms/view\n", path.c_str(), ply->size(),
              ply->sh_degree, ev->seconds_per_view * 1e3);
  print_eval(ev.value());
  return 0;
}

}  // namespace

void add_export_commands(CLI::App& app, GlobalOptions& g) {
  static std::string source, out, ply, config, png_dir;
  static int degree = ExportOptions{}.sh_degree, directions = ExportOptions{}.directions,
             refine = ExportOptions{}.refine, threads = 0;
  static double view_weight = BakeOptions{}.view_weight;
  static std::string opacity_from = BakeOptions{}.opacity_over_views ? "views" : "representative";
  auto* ex = app.add_subcommand(
      "export",
      "Bake an anchor model (a .crpgs file or a training run) into a standard 3DGS .ply (INRIA "
      "layout, SH colours fitted to the view-dependent colour MLP) and compare the test-view "
      "PSNR of the exported Gaussians with the anchor model's");
  ex->add_option("SOURCE", source, ".crpgs file or training run directory")->required();
  ex->add_option("-o,--output", out, "the .ply to write")->required();
  ex->add_option("--sh-degree", degree, "SH degree of the colours (0..3)")->check(CLI::Range(0, 3));
  ex->add_option("--directions", directions, "directions of the sphere the SH are also fitted on")
      ->check(CLI::Range(16, 4096));
  ex->add_option("--view-weight", view_weight,
                 "share of the SH fit on the training cameras' own views (the rest on the sphere "
                 "of directions); 0 fits the sphere alone")
      ->check(CLI::Range(0.0, kMaxViewWeight));
  ex->add_option("--opacity", opacity_from,
                 "opacity of the exported Gaussians: 'views' (the mean over the training "
                 "cameras' views) or 'representative' (the anchor's mean view only)")
      ->check(CLI::IsMember({"views", "representative"}));
  ex->add_option("--refine", refine,
                 "after baking, optimise the exported Gaussians on the training views for this "
                 "many iterations (3DGS's loss and learning rates, no densification): the bake "
                 "holds near each anchor's own view, the fit for every view "
                 "(bench/results/export_360.md); 0 = the bake alone")
      ->check(CLI::Range(0, 1000000))
      ->capture_default_str();
  add_threads_option(ex, threads);
  ex->add_option("--set", g.sets, "override a key of the model's config (e.g. dataset.path=DIR)");
  ex->callback([&g] {
    throw CLI::RuntimeError(export_command(g, source, out, degree, directions, view_weight,
                                           opacity_from, refine, threads));
  });

  auto* im = app.add_subcommand(
      "import",
      "Render a standard 3DGS .ply (binary, SH degree 0..3) on the test views of the dataset a "
      "crpgs config names, and report PSNR/SSIM per view (as `crpgs eval`)");
  im->add_option("FILE", ply, ".ply file")->required();
  im->add_option("-c,--config", config, "config whose dataset (and rasterizer) is used")
      ->required();
  im->add_option("-o,--output", png_dir, "write the renders as PNGs here");
  add_threads_option(im, threads);
  im->add_option("--set", g.sets, "override a config key, e.g. --set dataset.path=DIR");
  im->callback([&g] { throw CLI::RuntimeError(import_command(g, ply, config, png_dir, threads)); });
}

}  // namespace crpgs::cli
