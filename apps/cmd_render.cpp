/// @file cmd_render.cpp
/// @brief `crpgs decode` (bitstream -> render-ready model directory) and `crpgs render` (one PNG
/// per view from a bitstream, a decode directory or a training run).
#include <ATen/Parallel.h>
#include <torch/serialize/input-archive.h>
#include <torch/serialize/output-archive.h>

#include <chrono>
#include <cstring>
#include <filesystem>
#include <sstream>

#include "cli_common.h"
#include "crpgs/atomic_file.h"
#include "crpgs/image.h"
#include "crpgs/metrics.h"
#include "crpgs/runtime.h"

namespace crpgs::cli {
namespace {
namespace fs = std::filesystem;
using Clock = std::chrono::steady_clock;

double seconds_since(Clock::time_point t0) {
  return std::chrono::duration<double>(Clock::now() - t0).count();
}

int decode_command(const GlobalOptions& g, const std::string& path, const std::string& out_dir,
                   int threads) {
  ComponentRegistry r = load_registry(g);
  set_compute_threads(threads);
  auto t0 = Clock::now();
  auto bytes = read_file_bytes(path);
  if (!bytes.ok()) return report_error(bytes.status());
  auto dec = decode_model(bytes.value(), r);
  if (!dec.ok())
    return report_error(Status(dec.status().code(), path + ": " + dec.status().message()));
  const double decode_s = seconds_since(t0);
  std::error_code ec;
  // A training run's config.yaml (its dataset path, its kind of directory) is not to be replaced.
  if (fs::exists(fs::path(out_dir) / "checkpoint.pt", ec))
    return report_error(Status(StatusCode::kInvalidArgument,
                               out_dir + " holds a training run (checkpoint.pt); decode into "
                                         "another directory"));
  fs::create_directories(out_dir, ec);
  if (ec)
    return report_error(
        Status(StatusCode::kIoError, "cannot create " + out_dir + ": " + ec.message()));
  const std::string config_path = (fs::path(out_dir) / "config.yaml").string();
  const std::string model_path = (fs::path(out_dir) / kDecodedModelFile).string();
  t0 = Clock::now();
  // The model first: a directory with config.yaml alone would pass for a training run.
  Status st = write_decoded_model(model_path, dec.value());
  if (st.ok()) st = dec->config.save(config_path);
  if (!st.ok()) return report_error(st);
  const double write_s = seconds_since(t0);
  const auto& m = dec->model;
  std::printf(
      "%s: %zu bytes, decoded in %.3f s (%d threads, BLAS kernels %s): %lld anchors, %lld "
      "offsets each (%lld active), feature width %lld, voxel %.6g\n",
      path.c_str(), bytes->size(), decode_s, at::get_num_threads(),
      blas_kernels_explained().c_str(), static_cast<long long>(m.voxels.size(0)),
      static_cast<long long>(m.offset_masks.size(1)),
      static_cast<long long>(m.offset_masks.sum().item<int64_t>()),
      static_cast<long long>(m.feature_sym.size(1)), m.voxel_size);
  std::printf("wrote %s (the bitstream's resolved config)\n", config_path.c_str());
  std::printf("wrote %s (%llu bytes, %.3f s): symbols, dequantised attributes, masks, MLPs\n",
              model_path.c_str(), static_cast<unsigned long long>(fs::file_size(model_path, ec)),
              write_s);
  return 0;
}

int render_command(const GlobalOptions& g, const std::string& source, const std::string& out_dir,
                   const std::string& which, int requested_threads) {
  const int threads = resolve_threads(requested_threads);
  ComponentRegistry r = load_registry(g);
  auto src = load_model_source(g, r, source, threads);
  if (!src.ok()) return report_error(src.status());
  AnchorModel& model = src->model();
  const Dataset& ds = src->setup->dataset();
  std::vector<std::pair<std::string, const std::vector<View>*>> splits;
  if (which != "test") splits.push_back({"train", &ds.train});
  if (which != "train") splits.push_back({"test", &ds.test});
  std::error_code ec;
  fs::create_directories(out_dir, ec);
  if (ec)
    return report_error(
        Status(StatusCode::kIoError, "cannot create " + out_dir + ": " + ec.message()));
  torch::NoGradGuard no_grad;
  // A run with the rate path renders its quantised model (load_model_source): the bitstream's
  // rows in its canonical order, so the pixels equal those of the decoded file.
  std::printf("%s (%s, %s in %.2f s): %lld anchors; rendering with %d threads\n", source.c_str(),
              src->kind.c_str(), src->kind == "run" ? "loaded" : "decoded", src->load_seconds,
              static_cast<long long>(src->kind == "run" ? model.num_anchors()
                                                        : src->decoded->num_anchors()),
              threads);
  if (!src->train_views_as_trained && model.options().effects.appearance_dim > 0 &&
      std::any_of(splits.begin(), splits.end(), [](const auto& sp) { return sp.first == "train"; }))
    std::fprintf(stderr,
                 "note: --set changed the train/test split, so train views are rendered with the "
                 "mean appearance embedding, not their own\n");
  RenderSettings settings;
  settings.background = model.options().effects.background;
  std::vector<std::vector<std::string>> rows = {{"VIEW", "CAMERA", "RENDER (ms)", "PSNR (dB)"}};
  double total_s = 0;
  size_t count = 0;
  char ms[32], db[32], name[64];
  for (const auto& [split, views] : splits) {
    for (size_t i = 0; i < views->size(); ++i) {
      const View& v = (*views)[i];
      const auto t0 = Clock::now();
      // A train view has its own appearance embedding (as in training); others get the mean.
      const int camera_index = split == "train" && src->train_views_as_trained ? int(i) : -1;
      NeuralGaussians ng =
          model.generate(v.camera, camera_index, src->setup->rasterizer(), settings, false);
      auto img = src->setup->rasterizer().render(ng.batch, v.camera, settings).image;
      const double s = seconds_since(t0);
      total_s += s;
      ++count;
      const Image render = quantize_8bit(tensor_to_image(img));
      std::snprintf(name, sizeof name, "%s_%05zu.png", split.c_str(), i);
      Status st = save_png(render, (fs::path(out_dir) / name).string());
      if (!st.ok()) return report_error(st);
      auto p = psnr(render, quantize_8bit(v.image));  // the 8-bit round trip, as `crpgs eval`
      std::snprintf(ms, sizeof ms, "%.1f", s * 1e3);
      std::snprintf(db, sizeof db, "%.3f", p.ok() ? p.value() : 0.0);
      rows.push_back({name, v.camera.name, ms, p.ok() ? db : "-"});
    }
  }
  if (count == 0)
    return report_error(Status(StatusCode::kInvalidArgument, "no " + which + " views to render"));
  print_table(rows);
  std::printf("%zu PNGs in %s; render %.1f ms/view (generate + rasterize)\n", count,
              out_dir.c_str(), total_s * 1e3 / double(count));
  return 0;
}

}  // namespace

void add_render_commands(CLI::App& app, GlobalOptions& g) {
  static std::string path, out_dir, source, views = "test";
  static int decode_threads = 0, render_threads = 0;

  auto* dec = app.add_subcommand(
      "decode",
      "Decode a .crpgs bitstream into a directory holding the render-ready model: config.yaml "
      "(the bitstream's resolved config) and decoded.pt (a torch archive: decoded integer "
      "symbols, dequantised features/scaling/offsets, masks, MLPs, bounds, voxel size)");
  dec->add_option("FILE", path, "bitstream")->required();
  dec->add_option("-o,--output", out_dir, "output directory")->required();
  add_threads_option(dec, decode_threads);
  dec->callback(
      [&g] { throw CLI::RuntimeError(decode_command(g, path, out_dir, decode_threads)); });

  auto* ren = app.add_subcommand(
      "render",
      "Render one PNG per view of a model: a .crpgs file, a `crpgs decode` directory or a "
      "training run directory (its quantised model when it has the rate path), on the cameras of "
      "the dataset its config names");
  ren->add_option("SOURCE", source, ".crpgs file, decode directory or run directory")->required();
  ren->add_option("-o,--output", out_dir, "where the PNGs go")->required();
  ren->add_option("--views", views, "which views: test, train or all")
      ->check(CLI::IsMember({"test", "train", "all"}));
  add_threads_option(ren, render_threads);
  ren->add_option("--set", g.sets,
                  "override a key of the model's config, e.g. --set dataset.path=DIR");
  ren->callback(
      [&g] { throw CLI::RuntimeError(render_command(g, source, out_dir, views, render_threads)); });
}

}  // namespace crpgs::cli
