/// @file cli_common.cpp
#include "cli_common.h"

#include <algorithm>
#include <filesystem>

namespace crpgs::cli {

ComponentRegistry load_registry(const GlobalOptions& g) {
  ComponentRegistry r = builtin_registry();
  r.load_plugins(default_plugin_dirs(g.plugin_dirs));
  return r;
}

StatusOr<Config> load_config(const std::string& path, const GlobalOptions& g,
                             const ComponentRegistry& registry, const std::string& fallback_yaml) {
  StatusOr<Config> cfg = path.empty() ? Config::from_string(fallback_yaml, "<built-in config>")
                                      : Config::load_file(path);
  if (!cfg.ok()) return cfg.status();
  // A relative dataset path in a config file is relative to that file, so configs work from any
  // directory and the resolved copy in a run directory stays valid. (--set paths: relative to cwd.)
  const YAML::Node ds = cfg->root()["dataset"];
  if (!path.empty() && ds.IsDefined() && ds.IsMap() && ds["path"] && ds["path"].IsScalar() &&
      !ds["path"].Scalar().empty() && std::filesystem::path(ds["path"].Scalar()).is_relative()) {
    const auto base = std::filesystem::absolute(path).parent_path();
    const auto abs = (base / ds["path"].Scalar()).lexically_normal().string();
    CRPGS_RETURN_IF_ERROR(cfg->apply_override("dataset.path=" + abs));
  }
  for (const auto& s : g.sets) CRPGS_RETURN_IF_ERROR(cfg->apply_override(s));
  return cfg->resolve(registry);
}

void print_eval(const EvalResult& r) {
  std::vector<std::vector<std::string>> rows = {{"VIEW", "PSNR (dB)", "SSIM"}};
  char a[32], b[32];
  for (const auto& v : r.views) {
    std::snprintf(a, sizeof a, "%.3f", v.psnr);
    std::snprintf(b, sizeof b, "%.4f", v.ssim);
    rows.push_back({v.name, a, b});
  }
  std::snprintf(a, sizeof a, "%.3f", r.mean_psnr);
  std::snprintf(b, sizeof b, "%.4f", r.mean_ssim);
  rows.push_back({"mean", a, b});
  print_table(rows);
  std::printf("render time: %.1f ms/view\n", r.seconds_per_view * 1e3);
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

}  // namespace crpgs::cli
