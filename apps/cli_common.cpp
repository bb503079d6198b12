/// @file cli_common.cpp
#include "cli_common.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <filesystem>
#include <thread>

#include "crpgs/atomic_file.h"

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
  // load_file made a file's relative dataset path absolute; a --set one is relative to the
  // working directory, and made absolute here so that a run's saved config keeps working.
  for (const auto& s : g.sets) CRPGS_RETURN_IF_ERROR(cfg->apply_override(s));
  std::error_code ec;
  CRPGS_RETURN_IF_ERROR(
      make_dataset_path_absolute(cfg.value(), std::filesystem::current_path(ec).string()));
  return cfg->resolve(registry);
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

StatusOr<std::unique_ptr<Trainer>> setup_training_and_warn(const Config& cfg,
                                                           const ComponentRegistry& registry,
                                                           const SetupOptions& options) {
  auto trainer = setup_training(cfg, registry, options);
  if (trainer.ok())
    for (const std::string& w : trainer.value()->dataset().warnings)
      std::fprintf(stderr, "warning: %s\n", w.c_str());
  return trainer;
}

SetupOptions reading_setup(const std::string& run_dir) {
  SetupOptions o{run_dir, !run_dir.empty()};
  o.model_on_cpu = true;
  return o;
}

namespace {
namespace fs = std::filesystem;

/// YAML equality by value: scalars equal as text, or as numbers, or as booleans
/// (`0.0` == `0`, `True` == `true`).
bool same_yaml(const YAML::Node& a, const YAML::Node& b) {
  if (a.Type() != b.Type()) return false;
  if (a.IsScalar()) {
    if (a.Scalar() == b.Scalar()) return true;
    double x, y;
    if (YAML::convert<double>::decode(a, x) && YAML::convert<double>::decode(b, y)) return x == y;
    bool p, q;
    return YAML::convert<bool>::decode(a, p) && YAML::convert<bool>::decode(b, q) && p == q;
  }
  if (a.IsSequence()) {
    if (a.size() != b.size()) return false;
    for (size_t i = 0; i < a.size(); ++i)
      if (!same_yaml(a[i], b[i])) return false;
    return true;
  }
  if (a.IsMap()) {
    if (a.size() != b.size()) return false;
    for (const auto& kv : a) {
      const YAML::Node other = b[kv.first.Scalar()];
      if (!other || !same_yaml(kv.second, other)) return false;
    }
  }
  return true;
}

bool is_known_section(const std::string& key) {
  for (const auto& c : component_sections())
    if (key == c.key) return true;
  for (const auto& c : core_sections())
    if (key == c.key) return true;
  return false;
}

/// A bitstream or decode directory holds a model built from its own config: a --set that
/// changes anything but where the cameras come from and how to rasterize would be ignored by the
/// model while the dataset follows it (e.g. scene.background), so it is refused. Unknown
/// sections are left to resolve(), which names them.
Status check_model_is_untouched(const Config& before, const Config& after,
                                const std::string& assignment, const std::string& kind) {
  const std::string key = assignment.substr(0, assignment.find('='));
  const std::string top = key.substr(0, key.find('.'));
  if (top == "dataset" || top == "rasterizer" || key == "train.threads" || !is_known_section(top))
    return OkStatus();
  auto section = [&](const Config& c) {
    YAML::Node n = YAML::Clone(c.section(top));
    if (top == "train" && n.IsMap()) n.remove("threads");
    return n;
  };
  if (same_yaml(section(before), section(after))) return OkStatus();
  return Status(StatusCode::kInvalidArgument,
                "--set " + key + ": a " + kind +
                    " fixes the model it holds, so only dataset.*, rasterizer.* and train.threads "
                    "can be changed; its " +
                    top + " settings are those it was trained with");
}

/// The model's config with the thread count and --set applied, re-resolved (a copy: YAML nodes
/// are shared). For a bitstream or decode directory (`fixed_kind` not empty) only the dataset and
/// rasterizer may change.
StatusOr<Config> setup_config(const Config& resolved, const GlobalOptions& g,
                              const ComponentRegistry& r, int threads,
                              const std::string& fixed_kind) {
  CRPGS_ASSIGN_OR_RETURN(Config c, Config::from_string(resolved.dump(), "<model config>"));
  const YAML::Node rast = c.section("rasterizer");
  if (threads > 0) {
    CRPGS_RETURN_IF_ERROR(c.apply_override("train.threads=" + std::to_string(threads)));
    if (!rast || (rast.IsMap() && rast["threads"]))
      CRPGS_RETURN_IF_ERROR(c.apply_override("rasterizer.threads=" + std::to_string(threads)));
  }
  if (!rast) CRPGS_RETURN_IF_ERROR(c.apply_override("rasterizer.type=cpu"));
  for (const auto& s : g.sets) {
    CRPGS_ASSIGN_OR_RETURN(Config before, Config::from_string(c.dump(), "<model config>"));
    CRPGS_RETURN_IF_ERROR(c.apply_override(s));
    if (!fixed_kind.empty())
      CRPGS_RETURN_IF_ERROR(check_model_is_untouched(before, c, s, fixed_kind));
  }
  std::error_code ec;
  CRPGS_RETURN_IF_ERROR(make_dataset_path_absolute(c, fs::current_path(ec).string()));
  return c.resolve(r);
}

}  // namespace

Status check_dataset(const Config& c) {
  const YAML::Node ds = c.section("dataset");
  if (!ds || !ds.IsMap()) return OkStatus();
  const std::string format = ds["format"] ? ds["format"].as<std::string>() : "auto";
  const std::string path = ds["path"] ? ds["path"].as<std::string>() : "";
  if (format == "synthetic" || path.empty() || fs::exists(path)) return OkStatus();
  return Status(StatusCode::kNotFound,
                "the dataset this model was trained on is absent: " + path +
                    " (dataset.path of its config); rendering needs its cameras. Point to a copy "
                    "with --set dataset.path=DIR");
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

Status not_a_model_source(const std::string& source) {
  std::error_code ec;
  return Status(StatusCode::kNotFound, source +
                                           (fs::exists(source, ec) ? " is neither"
                                                                   : ": no such file or directory; "
                                                                     "expected") +
                                           " a .crpgs file, a `crpgs decode` directory (" +
                                           kDecodedModelFile +
                                           ") nor a training run directory (config.yaml)");
}

StatusOr<ModelSource> load_model_source(const GlobalOptions& g, const ComponentRegistry& r,
                                        const std::string& source, int threads) {
  ModelSource s;
  if (threads > 0) set_compute_threads(threads);
  const auto t0 = std::chrono::steady_clock::now();
  Config model_config;
  const fs::path dir(source);
  if (fs::is_regular_file(source)) {
    s.kind = "bitstream";
    CRPGS_ASSIGN_OR_RETURN(std::vector<uint8_t> bytes, read_file_bytes(source));
    s.file_bytes = bytes.size();
    auto decoded = decode_model(bytes, r);
    if (!decoded.ok())  // the file's name, as `crpgs info` gives it
      return Status(decoded.status().code(), source + ": " + decoded.status().message());
    DecodeResult& dec = decoded.value();
    CRPGS_ASSIGN_OR_RETURN(AnchorModelOptions options, model_options_from_config(dec.config));
    CRPGS_ASSIGN_OR_RETURN(s.decoded, model_from_decoded(dec, options));
    model_config = dec.config;
  } else if (fs::is_regular_file(dir / kDecodedModelFile)) {
    s.kind = "decoded";
    CRPGS_ASSIGN_OR_RETURN(model_config,
                           load_config((dir / "config.yaml").string(), GlobalOptions{}, r));
    CRPGS_ASSIGN_OR_RETURN(s.decoded,
                           read_decoded_model((dir / kDecodedModelFile).string(), model_config, r));
  } else if (fs::is_regular_file(dir / "config.yaml")) {
    s.kind = "run";
    CRPGS_ASSIGN_OR_RETURN(model_config,
                           load_config((dir / "config.yaml").string(), GlobalOptions{}, r));
  } else {
    return not_a_model_source(source);
  }
  s.load_seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  const bool run = s.kind == "run";
  CRPGS_ASSIGN_OR_RETURN(Config cfg,
                         setup_config(model_config, g, r, threads,
                                      run                     ? std::string()
                                      : s.kind == "bitstream" ? std::string("bitstream")
                                                              : std::string("decode directory")));
  CRPGS_RETURN_IF_ERROR(check_dataset(cfg));
  {
    const YAML::Node trained = model_config.section("dataset"), now = cfg.section("dataset");
    for (const char* k : {"test_every", "max_images"})
      if (trained && now && !same_yaml(trained[k], now[k])) s.train_views_as_trained = false;
  }
  CRPGS_ASSIGN_OR_RETURN(s.setup,
                         setup_training_and_warn(cfg, r, reading_setup(run ? source : "")));
  if (run && s.setup->iteration() == 0)
    return Status(StatusCode::kNotFound, "no checkpoint in " + source + " (train first)");
  if (run && s.setup->model().has_rate()) {
    auto coded = coded_model_from(s.setup->model(), &s.q);  // only its row order is needed
    if (!coded.ok()) return coded.status();
    s.setup->model().set_quantized(s.q);
    s.quantized = true;
  }
  return s;
}

}  // namespace crpgs::cli
