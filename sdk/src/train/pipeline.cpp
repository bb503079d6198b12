/// @file pipeline.cpp
/// @brief The pipeline front ends drive (crpgs/pipeline.h): configs with overrides, models opened
/// from what a user points at, bitstreams written and checked, decoded-model files.
#include "crpgs/pipeline.h"

#include <ATen/Parallel.h>

#include <chrono>
#include <cstring>
#include <filesystem>
#include <map>
#include <sstream>

#include <yaml-cpp/yaml.h>

#include "crpgs/atomic_file.h"
#include "crpgs/components.h"
#include "crpgs/hashing.h"
#include "crpgs/image.h"
#include "crpgs/image_tensor.h"
#include "crpgs/link_report.h"
#include "crpgs/metrics.h"
#include "crpgs/runtime.h"

namespace crpgs {
namespace fs = std::filesystem;

StatusOr<Config> load_config(const std::string& path, const std::vector<std::string>& sets,
                             const ComponentRegistry& registry, const std::string& fallback_yaml) {
  StatusOr<Config> cfg = path.empty() ? Config::from_string(fallback_yaml, "<built-in config>")
                                      : Config::load_file(path);
  if (!cfg.ok()) return cfg.status();
  // load_file made a file's relative dataset path absolute; a --set one is relative to the
  // working directory, and made absolute here so that a run's saved config keeps working.
  for (const auto& s : sets) CRPGS_RETURN_IF_ERROR(cfg->apply_override(s));
  std::error_code ec;
  CRPGS_RETURN_IF_ERROR(
      make_dataset_path_absolute(cfg.value(), std::filesystem::current_path(ec).string()));
  return cfg->resolve(registry);
}

SetupOptions reading_setup(const std::string& run_dir) {
  SetupOptions o{run_dir, !run_dir.empty()};
  o.model_on_cpu = true;
  return o;
}

namespace {

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
StatusOr<Config> setup_config(const Config& resolved, const std::vector<std::string>& sets,
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
  for (const auto& s : sets) {
    CRPGS_ASSIGN_OR_RETURN(Config before, Config::from_string(c.dump(), "<model config>"));
    CRPGS_RETURN_IF_ERROR(c.apply_override(s));
    if (!fixed_kind.empty())
      CRPGS_RETURN_IF_ERROR(check_model_is_untouched(before, c, s, fixed_kind));
  }
  std::error_code ec;
  CRPGS_RETURN_IF_ERROR(make_dataset_path_absolute(c, fs::current_path(ec).string()));
  return c.resolve(r);
}

constexpr int64_t kDecodedFormat = 1;  // bump when the key set below changes meaning

torch::Tensor bytes_tensor(const std::string& s) {  // [len] uint8
  auto t = torch::empty({int64_t(s.size())}, torch::kUInt8);
  if (!s.empty()) std::memcpy(t.data_ptr<uint8_t>(), s.data(), s.size());
  return t;
}

std::string tensor_bytes(const torch::Tensor& t) {
  const auto c = t.to(torch::kUInt8).contiguous();
  return std::string(reinterpret_cast<const char*>(c.data_ptr<uint8_t>()), size_t(c.numel()));
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

StatusOr<ModelSource> load_model_source(const ComponentRegistry& r, const std::string& source,
                                        const std::vector<std::string>& sets, int threads) {
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
    CRPGS_ASSIGN_OR_RETURN(model_config, load_config((dir / "config.yaml").string(), {}, r));
    CRPGS_ASSIGN_OR_RETURN(s.decoded,
                           read_decoded_model((dir / kDecodedModelFile).string(), model_config, r));
  } else if (fs::is_regular_file(dir / "config.yaml")) {
    s.kind = "run";
    CRPGS_ASSIGN_OR_RETURN(model_config, load_config((dir / "config.yaml").string(), {}, r));
  } else {
    return not_a_model_source(source);
  }
  s.load_seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  const bool run = s.kind == "run";
  CRPGS_ASSIGN_OR_RETURN(Config cfg,
                         setup_config(model_config, sets, r, threads,
                                      run                     ? std::string()
                                      : s.kind == "bitstream" ? std::string("bitstream")
                                                              : std::string("decode directory")));
  CRPGS_RETURN_IF_ERROR(check_dataset(cfg));
  {
    const YAML::Node trained = model_config.section("dataset"), now = cfg.section("dataset");
    for (const char* k : {"test_every", "max_images"})
      if (trained && now && !same_yaml(trained[k], now[k])) s.train_views_as_trained = false;
  }
  CRPGS_ASSIGN_OR_RETURN(s.setup, setup_training(cfg, r, reading_setup(run ? source : "")));
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

/// Writes the decoded model as a torch archive: the integer symbols exactly as decoded, the
/// dequantised attributes a renderer needs (symbol x step, as model_from_decoded computes them),
/// the MLPs and the feature model's state. Keys have no '.', which the archive treats as nesting.
Status write_decoded_model(const std::string& path, const DecodeResult& d) {
  const CodedModel& m = d.model;
  const EntropyParams& p = d.params;
  const int64_t n = m.voxels.size(0);
  try {
    torch::serialize::OutputArchive ar;
    ar.write("format_version", torch::tensor(kDecodedFormat, torch::kLong));
    ar.write("voxel_size", torch::tensor(m.voxel_size, torch::kDouble));
    ar.write("bounds", m.bounds);                             // [2, 3]
    ar.write("chunk", torch::tensor(m.chunk, torch::kLong));  // anchors per coded chunk
    ar.write("q0", torch::tensor({m.q0.feature, m.q0.scaling, m.q0.offset}, torch::kDouble));
    ar.write("voxels", m.voxels);                                    // [N, 3] int32
    ar.write("offset_masks", m.offset_masks);                        // [N, K] bool
    ar.write("feature_symbols", m.feature_sym);                      // [N, Dc] int32
    ar.write("scaling_symbols", m.scaling_sym);                      // [N, 6] int32
    ar.write("offset_symbols", m.offset_sym);                        // [N, K, 3] int32
    ar.write("q_f", p.q_f);                                          // [N, 1] steps
    ar.write("q_s", p.q_s);                                          // [N, 1]
    ar.write("q_o", p.q_o);                                          // [N, 1]
    ar.write("positions", voxel_positions(m.voxels, m.voxel_size));  // [N, 3] float32
    ar.write("features", m.feature_sym.to(torch::kFloat) * p.q_f);   // [N, Dc]
    ar.write("scaling", m.scaling_sym.to(torch::kFloat) * p.q_s);    // [N, 6] activated
    ar.write("offsets", m.offset_sym.to(torch::kFloat) * p.q_o.view({n, 1, 1}));  // [N, K, 3]
    std::string names;
    int64_t i = 0;
    for (const auto& [name, t] : m.mlps) {
      names += name + "\n";
      ar.write("mlp_" + std::to_string(i++), t);
    }
    ar.write("mlp_names", bytes_tensor(names));
    const auto st = d.components.features->save_state();
    ar.write("features_state", bytes_tensor(std::string(st.begin(), st.end())));
    std::ostringstream os;
    ar.save_to(os);
    return write_file_atomic(path, os.str());
  } catch (const std::exception& e) {
    return Status(StatusCode::kIoError, "writing " + path + ": " + e.what());
  }
}

StatusOr<std::unique_ptr<AnchorModel>> read_decoded_model(const std::string& path,
                                                          const Config& cfg,
                                                          const ComponentRegistry& r) {
  CRPGS_ASSIGN_OR_RETURN(std::vector<uint8_t> bytes, read_file_bytes(path));
  try {
    torch::serialize::InputArchive ar;
    ar.load_from(reinterpret_cast<const char*>(bytes.data()), bytes.size());
    auto get = [&](const char* key) {
      torch::Tensor t;  // read() into a defined tensor would resize it in place
      ar.read(key, t);
      return t;
    };
    if (get("format_version").item<int64_t>() != kDecodedFormat)
      return Status(StatusCode::kUnsupportedVersion, path + ": unknown decoded-model version");
    std::map<std::string, torch::Tensor> mlps;
    std::istringstream names(tensor_bytes(get("mlp_names")));
    std::string name;
    for (int64_t i = 0; std::getline(names, name); ++i)
      mlps[name] = get(("mlp_" + std::to_string(i)).c_str());
    crpgs_create_args args = create_args_for(cfg);
    CRPGS_ASSIGN_OR_RETURN(std::shared_ptr<FeatureModel> features,
                           create_component<FeatureModel>(r, cfg.section("features"), args));
    const std::string state = tensor_bytes(get("features_state"));
    std::string err;
    if (!state.empty() &&
        !features->load_state(std::vector<uint8_t>(state.begin(), state.end()), &err))
      return Status(StatusCode::kCorruptBitstream, path + ": feature model state: " + err);
    CRPGS_ASSIGN_OR_RETURN(AnchorModelOptions options, model_options_from_config(cfg));
    return AnchorModel::from_decoded(options, features, get("positions"), get("features"),
                                     get("scaling"), get("offsets"), get("offset_masks"), mlps,
                                     get("bounds"), get("voxel_size").item<double>());
  } catch (const std::exception& e) {
    return Status(StatusCode::kCorruptBitstream, "reading " + path + ": " + e.what());
  }
}

StatusOr<EvalResult> evaluate_ply(const PlyGaussians& ply, Rasterizer& rasterizer,
                                  const std::vector<View>& views,
                                  const std::array<float, 3>& background,
                                  const std::string& png_dir) {
  torch::NoGradGuard no_grad;
  if (views.empty()) return Status(StatusCode::kInvalidArgument, "evaluation: no test views");
  if (std::error_code ec; !png_dir.empty() && !fs::create_directories(png_dir, ec) && ec)
    return Status(StatusCode::kIoError, "cannot create " + png_dir + ": " + ec.message());
  RenderSettings settings;
  settings.background = background;
  EvalResult res;
  double seconds = 0;
  for (size_t i = 0; i < views.size(); ++i) {
    const View& v = views[i];
    const auto t0 = std::chrono::steady_clock::now();
    auto img = rasterizer.render(ply_to_batch(ply, v.camera), v.camera, settings).image;
    seconds += std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    const Image render = quantize_8bit(tensor_to_image(img));
    CRPGS_ASSIGN_OR_RETURN(ImageMetrics m, compare_images(render, quantize_8bit(v.image)));
    ViewMetrics vm;
    vm.name = v.camera.name;
    vm.psnr = m.psnr;
    vm.ssim = m.ssim;
    res.views.push_back(vm);
    res.mean_psnr += m.psnr / double(views.size());
    res.mean_ssim += m.ssim / double(views.size());
    if (!png_dir.empty()) {
      char name[32];
      std::snprintf(name, sizeof name, "test_%05zu.png", i);
      CRPGS_RETURN_IF_ERROR(save_png(render, (fs::path(png_dir) / name).string()));
    }
  }
  res.seconds_per_view = seconds / double(views.size());
  return res;
}

StatusOr<ExportResult> export_gaussians(ModelSource& src, const ExportOptions& o,
                                        const std::function<void(int, double)>& on_refine) {
  AnchorModel& model = src.model();
  const Dataset& ds = src.setup->dataset();
  ExportResult out;
  BakeOptions opt;
  opt.sh_degree = o.sh_degree;
  opt.directions = o.directions;
  opt.view_weight = o.view_weight;
  opt.opacity_over_views = o.opacity_over_views;
  for (const auto& v : ds.train) opt.camera_centers.push_back(v.camera.center());
  if (opt.camera_centers.empty()) {
    // The test views then give the representative views only: fitting the colours they see
    // would make the PSNR measured on them below optimistic.
    for (const auto& v : ds.test) opt.camera_centers.push_back(v.camera.center());
    opt.view_weight = 0;
    out.notes.push_back("note: no training views; SH fitted on the sphere alone");
  }
  out.view_weight = opt.view_weight;
  if (o.refine > 0 && ds.train.empty())  // before the bake, which may take a while
    return Status(StatusCode::kInvalidArgument,
                  "--refine needs the training views, and the dataset has none");
  if (o.refine > 0 && !src.train_views_as_trained)
    out.notes.push_back(
        "warning: --set changed the train/test split: --refine fits the new training views, and "
        "the model may have been trained on the test views measured below");
  using clock = std::chrono::steady_clock;
  const auto t0 = clock::now();
  CRPGS_ASSIGN_OR_RETURN(out.gaussians,
                         bake_gaussians(model, opt, src.quantized ? &src.q : nullptr));
  out.bake_seconds = std::chrono::duration<double>(clock::now() - t0).count();
  if (o.refine > 0) {
    RefineOptions ro;
    ro.iterations = o.refine;
    ro.lambda_dssim = src.setup->options().lambda_dssim;  // the model's own training loss
    ro.seed = src.setup->options().seed;
    const auto t1 = clock::now();
    CRPGS_ASSIGN_OR_RETURN(out.refine,
                           refine_gaussians(out.gaussians, src.setup->rasterizer(), ds.train,
                                            model.options().effects.background, ro, on_refine));
    out.refine_seconds = std::chrono::duration<double>(clock::now() - t1).count();
  }
  return out;
}

StatusOr<BitstreamReport> write_and_check_bitstream(Trainer& t, const Config& cfg,
                                                    const ComponentRegistry& registry,
                                                    const std::string& path,
                                                    const std::string& png_dir, double rate_scale) {
  using clock = std::chrono::steady_clock;
  auto secs = [](clock::time_point a) {
    return std::chrono::duration<double>(clock::now() - a).count();
  };
  BitstreamReport rep;
  rep.path = path;
  rep.rate_scale = rate_scale;
  // The codec reads the model on the CPU (its arithmetic is the CPU's); training is over.
  t.model().to(torch::kCPU);
  auto t0 = clock::now();
  QuantizedAttributes q;
  CRPGS_ASSIGN_OR_RETURN(CodedModel coded, coded_model_from(t.model(), &q, rate_scale));
  CRPGS_ASSIGN_OR_RETURN(EncodeResult enc,
                         encode_model(coded, cfg, codec_components_of(t.model())));
  CRPGS_RETURN_IF_ERROR(write_file_atomic(path, enc.bytes));
  rep.encode_seconds = secs(t0);
  rep.estimated_vs_coded_bits = enc.estimated_vs_coded_bits;
  if (t.model().links().defined()) {
    rep.links_built = (t.model().links() >= 0).sum().item<int64_t>();
    rep.links_coded = coded.links.defined() ? count_links(coded.links).leaves : 0;
  }

  // The training-side quantised model, on exactly the rows and steps of the bitstream.
  t.model().set_quantized(q);
  auto qeval = evaluate_views(t.model(), t.rasterizer(), t.dataset().test, "");
  t.model().clear_quantized();
  if (!qeval.ok()) return qeval.status();
  rep.quantized_psnr = qeval->mean_psnr;

  // Everything reported from here on comes from the file on disk.
  t0 = clock::now();
  CRPGS_ASSIGN_OR_RETURN(std::vector<uint8_t> bytes, read_file_bytes(path));
  CRPGS_ASSIGN_OR_RETURN(DecodeResult dec, decode_model(bytes, registry));
  CRPGS_ASSIGN_OR_RETURN(std::unique_ptr<AnchorModel> decoded,
                         model_from_decoded(dec, t.model().options()));
  rep.decode_seconds = secs(t0);
  rep.file_bytes = bytes.size();
  rep.anchors = dec.model.voxels.size(0);
  rep.gaussians = dec.model.offset_masks.sum().item<int64_t>();
  if (dec.model.links.defined()) {
    CRPGS_ASSIGN_OR_RETURN(
        rep.link_rate,
        link_rate_report(dec.model, dec.params, *dec.components.context, *dec.components.entropy));
    for (const auto& s : dec.sections)
      if (s.id == "LINK" || s.id == "AMSK") rep.link_side_bytes += s.bytes;
  }
  rep.sections = dec.sections;
  CRPGS_ASSIGN_OR_RETURN(EvalResult deval,
                         evaluate_views(*decoded, t.rasterizer(), t.dataset().test, png_dir));
  rep.decoded_psnr = deval.mean_psnr;
  for (const auto& v : deval.views) {
    rep.view_names.push_back(v.name);
    rep.decoded_views.push_back({v.psnr, v.ssim, deval.seconds_per_view});
  }
  return rep;
}

StatusOr<FinishedRun> open_finished_run(const ComponentRegistry& r, const std::string& run_dir,
                                        const std::vector<std::string>& sets) {
  FinishedRun run;
  CRPGS_ASSIGN_OR_RETURN(run.config, load_config(run_dir + "/config.yaml", sets, r));
  CRPGS_RETURN_IF_ERROR(check_dataset(run.config));
  CRPGS_ASSIGN_OR_RETURN(run.trainer, setup_training(run.config, r, reading_setup(run_dir)));
  if (run.trainer->iteration() == 0)
    return Status(StatusCode::kNotFound, "no checkpoint in " + run_dir);
  return run;
}

StatusOr<double> scale_for_target_size(Trainer& t, const Config& cfg, uint64_t target) {
  t.model().to(torch::kCPU);
  auto size_at = [&](double scale) -> StatusOr<uint64_t> {
    CRPGS_ASSIGN_OR_RETURN(CodedModel coded, coded_model_from(t.model(), nullptr, scale));
    CRPGS_ASSIGN_OR_RETURN(EncodeResult enc,
                           encode_model(coded, cfg, codec_components_of(t.model())));
    return uint64_t(enc.bytes.size());
  };
  double lo = 1.0 / 16, hi = 256;  // log-scale bracket: size(hi) <= target < size(lo)
  CRPGS_ASSIGN_OR_RETURN(const uint64_t smallest, size_at(hi));
  if (smallest > target)
    return Status(StatusCode::kInvalidArgument,
                  "--target-size " + std::to_string(target) +
                      " B is below what this model reaches: " + std::to_string(smallest) +
                      " B at rate scale " + std::to_string(int(hi)) +
                      " (positions, MLPs, grids and masks do not shrink with the steps); train "
                      "with a larger rate.lambda for a smaller file");
  CRPGS_ASSIGN_OR_RETURN(const uint64_t largest, size_at(lo));
  if (largest <= target) return lo;  // the finest steps searched fit
  for (int i = 0; i < 24 && hi / lo > 1.0005; ++i) {
    const double mid = std::sqrt(lo * hi);
    CRPGS_ASSIGN_OR_RETURN(const uint64_t size, size_at(mid));
    (size <= target ? hi : lo) = mid;
  }
  return hi;
}

experiments::RunMetrics bitstream_metrics(const BitstreamReport& r, const Config& config) {
  experiments::RunMetrics m;
  m.size_bytes = r.file_bytes;
  m.anchors = r.anchors;
  m.gaussians = r.gaussians;
  for (const auto& s : r.sections) {
    const std::string c = section_category(s.id);
    for (int k = 0; k < experiments::kNumBitstreamCategories; ++k)
      if (c == experiments::category_name(static_cast<experiments::BitstreamCategory>(k)))
        m.breakdown[size_t(k)] += s.bytes;
  }
  uint64_t listed = 0;
  for (auto b : m.breakdown) listed += b;
  m.breakdown[size_t(experiments::BitstreamCategory::kOther)] += m.size_bytes - listed;
  m.encode_seconds = r.encode_seconds;
  m.decode_seconds = r.decode_seconds;
  m.lambda = config.section("rate")["lambda"].as<double>();
  for (size_t i = 0; i < r.view_names.size(); ++i)
    m.views.push_back(
        {r.view_names[i], r.decoded_views[i][0], r.decoded_views[i][1], r.decoded_views[i][2]});
  return m;
}

StatusOr<PreparedRun> prepare_run_directory(const Config& cfg, const ComponentRegistry& registry,
                                            const RunOptions& o) {
  const std::string& out_dir = o.out_dir;
  // What the lock adds (the directory, DIR/.lock) goes again if the set-up fails: a mistyped
  // path leaves the file system as it was.
  std::error_code ec;
  const bool dir_existed = fs::exists(out_dir, ec),
             lock_existed = fs::exists(out_dir + "/.lock", ec);
  auto undo = [&](const Status& st) {
    if (!lock_existed) fs::remove(out_dir + "/.lock", ec);
    if (!dir_existed) fs::remove(out_dir, ec);  // only when empty: nothing else was written
    return st;
  };
  // Held until the run is done: a second trainer here is refused before it writes.
  CRPGS_ASSIGN_OR_RETURN(DirectoryLock lock, lock_directory(out_dir));
  PreparedRun run{std::move(lock), nullptr, 0};
  if (run.lock.held())  // nobody else writes here: a killed attempt's half-written files can go
    run.stale_files_removed = remove_stale_temp_files(out_dir);
  if (!o.resume && !o.replace)
    for (const char* kept : {"checkpoint.pt", "metrics.json"})
      if (fs::exists(out_dir + "/" + kept, ec))
        return undo(Status(
            StatusCode::kInvalidArgument,
            out_dir + " holds a run (" + kept +
                "): --resume continues it, --force trains a new one over it, or pick another -o"));
  // Nothing in the directory changes until the set-up (dataset, plugins, checkpoint) succeeded:
  // a typo in a path must not cost a finished run its results.
  SetupOptions setup{out_dir, o.resume, o.prefix_dir};
  setup.start_from = o.start_from;
  auto trainer = setup_training(cfg, registry, setup);
  if (!trainer.ok()) return undo(trainer.status());
  run.trainer = std::move(trainer).value();
  // Training anew: an earlier run's files go now, or a run killed before its first checkpoint
  // would leave the old one for a later resume (or a sweep) to take for its own.
  if (!o.resume)
    for (const char* old : {"checkpoint.pt", "metrics.json", "scene.crpgs"})
      if (fs::remove(fs::path(out_dir) / old, ec), ec)
        return Status(StatusCode::kIoError, "cannot remove the earlier run's " + out_dir + "/" +
                                                old + ": " + ec.message());
  CRPGS_RETURN_IF_ERROR(experiments::mark_run_started(out_dir));
  CRPGS_RETURN_IF_ERROR(cfg.save(out_dir + "/config.yaml"));
  return run;
}

StatusOr<experiments::RunMetrics> finish_run(Trainer& t, const Config& cfg,
                                             const ComponentRegistry& registry, const RunOptions& o,
                                             BitstreamReport* bitstream, EvalResult* eval) {
  const std::string& out_dir = o.out_dir;
  const double train_s = t.elapsed_seconds();  // resumed runs included, evaluation excluded
  experiments::RunMetrics m;
  if (t.model().has_rate()) {
    // HAC/CRP-GS: the result is the bitstream; everything reported comes from decoding it.
    CRPGS_ASSIGN_OR_RETURN(
        BitstreamReport rep,
        write_and_check_bitstream(t, cfg, registry, out_dir + "/scene.crpgs", out_dir + "/test"));
    m = bitstream_metrics(rep, cfg);
    if (bitstream) *bitstream = std::move(rep);
  } else {
    CRPGS_ASSIGN_OR_RETURN(EvalResult ev, t.evaluate(out_dir + "/test"));
    for (const auto& v : ev.views) m.views.push_back({v.name, v.psnr, v.ssim, ev.seconds_per_view});
    if (eval) *eval = std::move(ev);
  }
  m.method = !o.method.empty()                            ? o.method
             : cfg.file().empty() || cfg.file()[0] == '<' ? "demo"
                                                          : fs::path(cfg.file()).stem().string();
  m.dataset = t.dataset().name;
  m.config_hash = hex64(cfg.hash());
  m.train_seconds = train_s;
  if (t.model().has_rate()) {
    const StepTimes& tm = t.times();
    for (size_t p = 0; p < 3; ++p)
      if (tm.phase_iterations[p] > 0)
        m.phases.push_back(
            {StepTimes::kPhaseNames[p].key, tm.phase_iterations[p], tm.phase_seconds[p]});
  }
  for (const auto& pt : t.psnr_trace()) m.trace.push_back({pt.seconds, pt.iteration, pt.psnr});
  if (!m.trace.empty()) m.trace_views = t.trace_views();
  m.peak_memory_bytes = experiments::peak_rss_bytes();
  m.provenance = experiments::this_process_provenance(int64_t(t.options().seed),
                                                      at::get_num_threads(), t.options().device);
  CRPGS_RETURN_IF_ERROR(experiments::write_run_metrics(out_dir + "/metrics.json", m));
  experiments::mark_run_finished(out_dir);
  return m;
}

}  // namespace crpgs
