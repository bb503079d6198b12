/// @file cli_common.cpp
#include "cli_common.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <filesystem>
#include <thread>

#include "crpgs/atomic_file.h"

namespace crpgs::cli {
namespace fs = std::filesystem;

ComponentRegistry load_registry(const GlobalOptions& g) {
  ComponentRegistry r = builtin_registry();
  r.load_plugins(default_plugin_dirs(g.plugin_dirs));
  return r;
}

void print_eval(const EvalResult& r) {
  const bool lpips = std::isfinite(r.mean_lpips);
  std::vector<std::vector<std::string>> rows = {{"VIEW", "PSNR (dB)", "SSIM"}};
  if (lpips) rows[0].push_back("LPIPS");
  char a[32], b[32], c[32];
  auto row = [&](const std::string& name, double psnr, double ssim, double lp) {
    std::snprintf(a, sizeof a, "%.3f", psnr);
    std::snprintf(b, sizeof b, "%.4f", ssim);
    std::snprintf(c, sizeof c, "%.4f", lp);
    rows.push_back({name, a, b});
    if (lpips) rows.back().push_back(c);
  };
  for (const auto& v : r.views) row(v.name, v.psnr, v.ssim, v.lpips);
  row("mean", r.mean_psnr, r.mean_ssim, r.mean_lpips);
  print_table(rows);
  std::printf("render time: %.1f ms/view\n", r.seconds_per_view * 1e3);
  if (!lpips)
    std::printf(
        "LPIPS: not computed (its VGG weights are not shipped: --lpips-weights FILE with "
        "a TorchScript module you export, docs/lpips.md)\n");
}

void print_table(const std::vector<std::vector<std::string>>& rows, FILE* out) {
  std::vector<size_t> width;
  for (const auto& r : rows)
    for (size_t i = 0; i < r.size(); ++i) {
      if (width.size() <= i) width.push_back(0);
      width[i] = std::max(width[i], r[i].size());
    }
  for (const auto& r : rows) {
    std::string line;
    for (size_t i = 0; i < r.size(); ++i) {
      line += r[i];
      if (i + 1 < r.size()) line += std::string(width[i] - r[i].size() + 2, ' ');
    }
    std::fprintf(out, "%s\n", line.c_str());
  }
}

int report_error(const Status& st) {
  std::fprintf(stderr, "crpgs: error: %s\n", st.message().c_str());
  return 1;
}

void print_dataset_warnings(const Dataset& d) {
  for (const std::string& w : d.warnings) std::fprintf(stderr, "warning: %s\n", w.c_str());
}

StatusOr<std::unique_ptr<Trainer>> setup_training_and_warn(const Config& cfg,
                                                           const ComponentRegistry& registry,
                                                           const SetupOptions& options) {
  auto trainer = setup_training(cfg, registry, options);
  if (trainer.ok()) print_dataset_warnings(trainer.value()->dataset());
  return trainer;
}

Status check_output_is_not_input(const std::string& out, const std::string& source,
                                 const std::string& own_output) {
  std::error_code ec;
  if (fs::is_directory(out, ec))
    return Status(StatusCode::kInvalidArgument,
                  out + " is a directory; -o names the file to write");
  if (fs::equivalent(out, source, ec))
    return Status(StatusCode::kInvalidArgument, "-o " + out + " is the input itself");
  if (fs::is_directory(source, ec) && fs::equivalent(fs::absolute(out).parent_path(), source, ec))
    for (const char* f : {"checkpoint.pt", "config.yaml", kDecodedModelFile, "metrics.json",
                          "run.json", "scene.crpgs"})
      if (fs::path(out).filename() == f && f != own_output)
        return Status(StatusCode::kInvalidArgument, "-o " + out + " would replace the " + f +
                                                        " of " + source + "; pick another name");
  return OkStatus();
}

StatusOr<ModelSource> load_model_source(const GlobalOptions& g, const ComponentRegistry& r,
                                        const std::string& source, int threads) {
  auto s = crpgs::load_model_source(r, source, g.sets, threads);
  if (s.ok()) print_dataset_warnings(s->setup->dataset());
  return s;
}

}  // namespace crpgs::cli
