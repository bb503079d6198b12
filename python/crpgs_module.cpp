/// @file crpgs_module.cpp
/// @brief The `crpgs._crpgs` Python extension: the SDK's pipeline (crpgs/pipeline.h) with
/// tensors as torch.Tensor (shared with libtorch, no copy where the layout allows) and SDK
/// errors as crpgs.Error. python/crpgs/__init__.py is the public face; docs/python.md.
#include <atomic>
#include <exception>
#include <filesystem>
#include <memory>
#include <string>
#include <vector>

#include <pybind11/functional.h>
#include <pybind11/pybind11.h>
#include <pybind11/stl.h>
#include <pybind11/stl/filesystem.h>  // str or os.PathLike for paths
#include <torch/csrc/utils/pybind.h>  // torch::Tensor <-> torch.Tensor

#include "crpgs/atomic_file.h"
#include "crpgs/components.h"
#include "crpgs/dir_lock.h"
#include "crpgs/experiments/bd_rate.h"
#include "crpgs/experiments/run_metrics.h"
#include "crpgs/image_tensor.h"
#include "crpgs/pipeline.h"
#include "crpgs/ply.h"
#include "crpgs/registry.h"
#include "crpgs/runtime.h"
#include "crpgs/version.h"

namespace py = pybind11;
namespace fs = std::filesystem;

namespace crpgs {
namespace {

/// crpgs.Error, created at import.
PyObject* g_error = nullptr;

/// A failed Status becomes crpgs.Error carrying the SDK's message (with the GIL held).
void raise_if_error(const Status& s) {
  if (!s.ok()) {
    PyErr_SetString(g_error, s.message().c_str());
    throw py::error_already_set();
  }
}
template <typename T>
T value_or_raise(StatusOr<T> s) {
  raise_if_error(s.status());
  return std::move(s).value();
}

/// Built-ins, then the plugins of `plugin_dirs`, CRPGS_PLUGIN_PATH, this build's plugin folder
/// and the installed one (default_plugin_dirs; the interpreter is not crpgs, so the build's
/// folder is named here).
ComponentRegistry registry_with(std::vector<std::string> plugin_dirs) {
  ComponentRegistry r = builtin_registry();
  plugin_dirs.push_back(CRPGS_PYTHON_BUILD_PLUGIN_DIR);
  r.load_plugins(default_plugin_dirs(plugin_dirs));
  return r;
}

/// The views of a split ("train" or "test").
const std::vector<View>& split_views(const Dataset& d, const std::string& split) {
  if (split == "train") return d.train;
  if (split == "test") return d.test;
  throw py::value_error("split must be 'train' or 'test', not '" + split + "'");
}

/// cameras(split) and image(split, i) of whatever holds a dataset (Model, Scene).
template <typename T, typename Class>
void bind_views(Class& cls) {
  cls.def(
         "cameras",
         [](const T& self, const std::string& split) {
           std::vector<Camera> out;
           for (const View& v : split_views(self.dataset(), split)) out.push_back(v.camera);
           return out;
         },
         py::arg("split") = "test", "the split's cameras")
      .def(
          "image",
          [](const T& self, const std::string& split, size_t i) {
            const auto& v = split_views(self.dataset(), split);
            if (i >= v.size()) throw py::index_error("view " + std::to_string(i) + " of " + split);
            return image_to_tensor(v[i].image);
          },
          py::arg("split"), py::arg("index"), "view i's photo: [H, W, 3] float32 in [0, 1]")
      .def_property_readonly("name", [](const T& self) { return self.dataset().name; })
      .def_property_readonly(
          "warnings", [](const T& self) { return self.dataset().warnings; },
          "what loading the dataset warned of");
}

/// A dataset opened from a config, with the rasterizer it names (crpgs.open_dataset).
class Scene {
 public:
  Scene(const std::string& config, const std::vector<std::string>& sets,
        const std::vector<std::string>& plugin_dirs) {
    const ComponentRegistry r = registry_with(plugin_dirs);
    const Config cfg = value_or_raise(load_config(config, sets, r));
    setup_ = value_or_raise(setup_training(cfg, r, reading_setup("")));
  }
  const Dataset& dataset() const { return setup_->dataset(); }

 private:
  std::unique_ptr<Trainer> setup_;
};

/// A model opened from a .crpgs file, a `crpgs decode` directory or a training run, with the
/// cameras and photos of its dataset (crpgs.open).
class Model {
 public:
  Model(const std::string& source, const std::vector<std::string>& sets, int threads,
        const std::vector<std::string>& plugin_dirs)
      : registry_(registry_with(plugin_dirs)),
        src_(value_or_raise(load_model_source(registry_, source, sets, threads))) {}

  std::string kind() const { return src_.kind; }
  int64_t num_anchors() { return src_.model().num_anchors(); }

  const Dataset& dataset() const { return src_.setup->dataset(); }

  /// [H, W, 3] float32 render of `camera`; `train_index` >= 0 renders with that training view's
  /// appearance embedding (as training did), else the mean.
  torch::Tensor render(const Camera& camera, int train_index) {
    if (camera.width <= 0 || camera.height <= 0 || !(camera.fx > 0) || !(camera.fy > 0))
      throw py::value_error("camera: width, height, fx and fy must be positive");
    const int n_train = int(src_.setup->dataset().train.size());
    if (train_index >= n_train)
      throw py::index_error("train_index " + std::to_string(train_index) + ": the dataset has " +
                            std::to_string(n_train) + " training views");
    py::gil_scoped_release release;
    torch::NoGradGuard no_grad;
    AnchorModel& model = src_.model();
    RenderSettings settings;
    settings.background = model.options().effects.background;
    const int index = src_.train_views_as_trained ? train_index : -1;
    NeuralGaussians ng = model.generate(camera, index, src_.setup->rasterizer(), settings, false);
    return src_.setup->rasterizer().render(ng.batch, camera, settings).image.contiguous();
  }

  /// `crpgs export`: bake, refine on the training photos, write the .ply (what every viewer
  /// reads), then render it back from the file on the test views beside the anchor model.
  py::dict export_ply(const fs::path& file, int sh_degree, int refine, const std::string& opacity,
                      double view_weight) {
    const std::string path = file.string();
    if (sh_degree < 0 || sh_degree > 3) throw py::value_error("sh_degree must be 0..3");
    if (refine < 0) throw py::value_error("refine must be >= 0");
    if (opacity != "representative" && opacity != "views")
      throw py::value_error("opacity must be 'representative' or 'views'");
    ExportOptions o;
    o.sh_degree = sh_degree;
    o.refine = refine;
    o.opacity_over_views = opacity == "views";
    o.view_weight = view_weight;
    StatusOr<ExportResult> exported = Status(StatusCode::kInternal, "not exported");
    StatusOr<EvalResult> anchor = exported.status(), back_eval = exported.status();
    Status written;
    size_t gaussians = 0;
    {
      py::gil_scoped_release release;
      exported = export_gaussians(src_, o);
      if (exported.ok()) written = write_ply(path, exported->gaussians);
      if (exported.ok() && written.ok() && !src_.setup->dataset().test.empty()) {
        auto back = read_ply(path);  // what is measured is what was written
        if (!back.ok()) {
          written = back.status();
        } else {
          gaussians = back->size();
          anchor = evaluate_views(src_.model(), src_.setup->rasterizer(),
                                  src_.setup->dataset().test, "");
          back_eval =
              evaluate_ply(back.value(), src_.setup->rasterizer(), src_.setup->dataset().test,
                           src_.model().options().effects.background, "");
        }
      }
    }
    const ExportResult r = value_or_raise(std::move(exported));
    raise_if_error(written);
    for (const std::string& note : r.notes) PyErr_WarnEx(PyExc_RuntimeWarning, note.c_str(), 1);
    py::dict out(py::arg("path") = path, py::arg("gaussians") = r.gaussians.size(),
                 py::arg("bytes") = fs::file_size(path),
                 py::arg("refine_iterations") = r.refine ? r.refine->iterations : 0);
    if (gaussians > 0) {
      out["anchor_psnr"] = value_or_raise(std::move(anchor)).mean_psnr;
      out["psnr"] = value_or_raise(std::move(back_eval)).mean_psnr;
    }
    return out;
  }

  /// PSNR/SSIM per test view and mean, as `crpgs eval` measures them (8-bit round trip).
  py::dict evaluate(const std::string& png_dir) {
    StatusOr<EvalResult> result = Status(StatusCode::kInternal, "not evaluated");
    {
      py::gil_scoped_release release;
      result = evaluate_views(src_.model(), src_.setup->rasterizer(), src_.setup->dataset().test,
                              png_dir);
    }
    const EvalResult r = value_or_raise(std::move(result));
    py::list views;
    for (const auto& v : r.views)
      views.append(
          py::dict(py::arg("name") = v.name, py::arg("psnr") = v.psnr, py::arg("ssim") = v.ssim));
    return py::dict(py::arg("views") = views, py::arg("psnr") = r.mean_psnr,
                    py::arg("ssim") = r.mean_ssim,
                    py::arg("seconds_per_view") = r.seconds_per_view);
  }

 private:
  ComponentRegistry registry_;
  ModelSource src_;
};

/// Reports training progress to a Python callable; an exception it raises, or Ctrl-C, stops
/// the training at the next iteration (the trainer checkpoints) and is raised again after.
class PythonProgress final : public ProgressCallback {
 public:
  PythonProgress(py::object callback, TrainControl* control)
      : callback_(std::move(callback)), control_(control) {}
  void on_iteration(const TrainingProgress& p) override {
    py::gil_scoped_acquire gil;
    if (error_) return;
    try {
      if (PyErr_CheckSignals() != 0) throw py::error_already_set();  // Ctrl-C
      if (!callback_.is_none())
        callback_(
            py::dict(py::arg("iteration") = p.iteration, py::arg("total") = p.total_iterations,
                     py::arg("loss") = p.loss,
                     py::arg("test_psnr") = p.has_test_psnr ? py::cast(p.test_psnr) : py::none(),
                     py::arg("anchors") = p.anchors, py::arg("gaussians") = p.gaussians,
                     py::arg("iterations_per_second") = p.iterations_per_second));
    } catch (py::error_already_set& e) {
      error_ = std::make_unique<py::error_already_set>(std::move(e));
      control_->stop = true;
    }
  }
  void on_checkpoint(int, const std::string&) override {}
  void on_warning(int, const std::string& message) override { warn(message); }
  void on_note(int, const std::string&) override {}
  /// Raises what the callback (or Ctrl-C) raised, if anything.
  void rethrow() {
    if (error_) {
      error_->restore();
      error_.reset();
      throw py::error_already_set();
    }
  }

 private:
  void warn(const std::string& message) {
    py::gil_scoped_acquire gil;
    PyErr_WarnEx(PyExc_RuntimeWarning, message.c_str(), 1);
  }
  py::object callback_;
  TrainControl* control_;
  std::unique_ptr<py::error_already_set> error_;
};

py::dict bitstream_dict(const BitstreamReport& r) {
  return py::dict(py::arg("path") = r.path, py::arg("bytes") = r.file_bytes,
                  py::arg("psnr") = r.decoded_psnr, py::arg("quantized_psnr") = r.quantized_psnr,
                  py::arg("anchors") = r.anchors, py::arg("gaussians") = r.gaussians,
                  py::arg("encode_seconds") = r.encode_seconds,
                  py::arg("decode_seconds") = r.decode_seconds);
}

/// Trains `config` (with `sets`) into out_dir as `crpgs train -o` does (prepare_run_directory,
/// then finish_run): checkpoints, config.yaml, for the rate path scene.crpgs written and
/// checked, and metrics.json.
py::dict train(const std::string& config, const std::string& out_dir,
               const std::vector<std::string>& sets, const py::object& progress, bool resume,
               const std::string& method, const std::vector<std::string>& plugin_dirs) {
  const ComponentRegistry r = registry_with(plugin_dirs);
  const Config cfg = value_or_raise(load_config(config, sets, r));
  RunOptions run;
  run.out_dir = out_dir;
  run.resume = resume;
  run.method = method;
  PreparedRun prepared = value_or_raise(prepare_run_directory(cfg, r, run));
  Trainer& t = *prepared.trainer;
  for (const std::string& w : t.dataset().warnings)
    PyErr_WarnEx(PyExc_RuntimeWarning, w.c_str(), 1);
  for (const std::string& w : t.setting_warnings())
    PyErr_WarnEx(PyExc_RuntimeWarning, w.c_str(), 1);
  TrainControl control;
  PythonProgress callback(progress, &control);
  Status st;
  {
    py::gil_scoped_release release;
    st = t.train(&callback, &control);
  }
  callback.rethrow();
  raise_if_error(st);
  BitstreamReport rep;
  StatusOr<experiments::RunMetrics> m = Status(StatusCode::kInternal, "not finished");
  {
    py::gil_scoped_release release;
    m = finish_run(t, cfg, r, run, &rep);
  }
  py::dict out(py::arg("iterations") = t.iteration(), py::arg("seconds") = t.elapsed_seconds(),
               py::arg("checkpoint") = t.checkpoint_path(),
               py::arg("metrics_json") = experiments::to_json(value_or_raise(std::move(m))));
  if (t.model().has_rate()) out["bitstream"] = bitstream_dict(rep);
  return out;
}

/// The bitstream of a finished run (rate path), its steps scaled by rate_scale, or the best
/// file at or under target_size bytes (> 0), written to `out` and checked.
py::dict encode(const std::string& run_dir, const std::string& out, double rate_scale,
                uint64_t target_size, const std::vector<std::string>& plugin_dirs) {
  if (!(rate_scale > 0)) throw py::value_error("rate_scale must be positive");
  const ComponentRegistry r = registry_with(plugin_dirs);
  FinishedRun run = value_or_raise(open_finished_run(r, run_dir));
  if (!run.trainer->model().has_rate())
    raise_if_error(Status(StatusCode::kInvalidArgument,
                          run_dir + " has no rate path (rate.lambda): nothing to encode"));
  StatusOr<double> scale = rate_scale;
  StatusOr<BitstreamReport> rep = Status(StatusCode::kInternal, "not written");
  {
    py::gil_scoped_release release;
    if (target_size > 0) scale = scale_for_target_size(*run.trainer, run.config, target_size);
    if (scale.ok())
      rep = write_and_check_bitstream(*run.trainer, run.config, r, out, "", scale.value());
  }
  const double used = value_or_raise(std::move(scale));
  py::dict d = bitstream_dict(value_or_raise(std::move(rep)));
  d["rate_scale"] = used;
  return d;
}

/// A bitstream's sections: id, component, bytes and category, and its total size.
py::dict info(const std::string& path, const std::vector<std::string>& plugin_dirs) {
  const ComponentRegistry r = registry_with(plugin_dirs);
  const std::vector<uint8_t> bytes = value_or_raise(read_file_bytes(path));
  auto decoded = decode_model(bytes, r);
  if (!decoded.ok())
    raise_if_error(Status(decoded.status().code(), path + ": " + decoded.status().message()));
  py::list sections;
  for (const auto& s : decoded->sections)
    sections.append(py::dict(py::arg("id") = s.id, py::arg("component") = s.component,
                             py::arg("bytes") = s.bytes,
                             py::arg("category") = section_category(s.id)));
  return py::dict(py::arg("bytes") = bytes.size(),
                  py::arg("anchors") = decoded->model.voxels.size(0),
                  py::arg("sections") = sections);
}

std::vector<experiments::RdPoint> rd_points(const std::vector<std::pair<double, double>>& p) {
  std::vector<experiments::RdPoint> out;
  for (const auto& [size, psnr] : p) out.push_back({size, psnr});
  return out;
}

}  // namespace
}  // namespace crpgs

PYBIND11_MODULE(_crpgs, m) {
  using namespace crpgs;
  m.doc() = "crpgs: compress 3D Gaussian Splatting scenes (CRP-GS, HAC) — the C++ SDK's pipeline";
  g_error = PyErr_NewException("crpgs.Error", PyExc_RuntimeError, nullptr);
  m.attr("Error") = py::handle(g_error);
  m.attr("__version__") = build_info().version;
  m.attr("commit") = build_info().git_commit;

  py::class_<Camera>(m, "Camera",
                     "A pinhole camera: intrinsics in pixels and the world-to-camera pose "
                     "x_cam = R x_world + t (OpenCV axes: x right, y down, z forward).")
      .def(py::init([](int width, int height, double fx, double fy, double cx, double cy,
                       const torch::Tensor& world_to_camera, const std::string& name) {
             const auto w = world_to_camera.to(torch::kCPU, torch::kDouble).contiguous();
             if (w.dim() != 2 || w.size(0) < 3 || w.size(0) > 4 || w.size(1) != 4)
               throw py::value_error("world_to_camera must be 3x4 or 4x4");
             Camera c;
             c.width = width, c.height = height, c.fx = fx, c.fy = fy, c.cx = cx, c.cy = cy;
             c.name = name;
             const double* a = w.data_ptr<double>();
             for (int i = 0; i < 3; ++i) {
               for (int j = 0; j < 3; ++j) c.R(i, j) = a[i * 4 + j];
               c.t(i) = a[i * 4 + 3];
             }
             return c;
           }),
           py::arg("width"), py::arg("height"), py::arg("fx"), py::arg("fy"), py::arg("cx"),
           py::arg("cy"), py::arg("world_to_camera"), py::arg("name") = "")
      .def_readwrite("width", &Camera::width)
      .def_readwrite("height", &Camera::height)
      .def_readwrite("fx", &Camera::fx)
      .def_readwrite("fy", &Camera::fy)
      .def_readwrite("cx", &Camera::cx)
      .def_readwrite("cy", &Camera::cy)
      .def_readwrite("name", &Camera::name)
      .def_property_readonly(
          "world_to_camera",
          [](const Camera& c) {
            auto t = torch::empty({4, 4}, torch::kDouble);
            const Eigen::Matrix4d v = c.view_matrix();
            for (int i = 0; i < 4; ++i)
              for (int j = 0; j < 4; ++j) t[i][j] = v(i, j);
            return t;
          },
          "4x4 float64 world-to-camera matrix")
      .def("__repr__", [](const Camera& c) {
        return "Camera(" + std::to_string(c.width) + "x" + std::to_string(c.height) +
               ", fx=" + std::to_string(c.fx) + ", name='" + c.name + "')";
      });

  py::class_<Scene> scene(m, "Scene", "A dataset opened from a config (crpgs.open_dataset).");
  scene.def(py::init<const std::string&, const std::vector<std::string>&,
                     const std::vector<std::string>&>(),
            py::arg("config"), py::arg("sets") = std::vector<std::string>{},
            py::arg("plugin_dirs") = std::vector<std::string>{});
  bind_views<Scene>(scene);

  py::class_<Model> model(m, "Model");
  bind_views<Model>(model);
  model
      .def(py::init<const std::string&, const std::vector<std::string>&, int,
                    const std::vector<std::string>&>(),
           py::arg("source"), py::arg("sets") = std::vector<std::string>{}, py::arg("threads") = 0,
           py::arg("plugin_dirs") = std::vector<std::string>{})
      .def_property_readonly("kind", &Model::kind, "'bitstream', 'decoded' or 'run'")
      .def_property_readonly("num_anchors", &Model::num_anchors)
      .def("render", &Model::render, py::arg("camera"), py::arg("train_index") = -1)
      .def("evaluate", &Model::evaluate, py::arg("png_dir") = "")
      .def("export_ply", &Model::export_ply, py::arg("path"), py::arg("sh_degree") = 3,
           py::arg("refine") = ExportOptions{}.refine, py::arg("opacity") = "representative",
           py::arg("view_weight") = ExportOptions{}.view_weight);

  m.def("train", &train, py::arg("config"), py::arg("out_dir"),
        py::arg("sets") = std::vector<std::string>{}, py::arg("progress") = py::none(),
        py::arg("resume") = false, py::arg("method") = "",
        py::arg("plugin_dirs") = std::vector<std::string>{});
  m.def("encode", &encode, py::arg("run_dir"), py::arg("out"), py::arg("rate_scale") = 1.0,
        py::arg("target_size") = 0, py::arg("plugin_dirs") = std::vector<std::string>{});
  m.def("info", &info, py::arg("path"), py::arg("plugin_dirs") = std::vector<std::string>{});
  m.def(
      "metrics_json",
      [](const std::string& path) {
        return experiments::to_json(value_or_raise(experiments::read_run_metrics(path)));
      },
      py::arg("path"));
  m.def(
      "bd_rate",
      [](const std::vector<std::pair<double, double>>& anchor,
         const std::vector<std::pair<double, double>>& test) {
        return experiments::bd_rate(rd_points(anchor), rd_points(test));
      },
      py::arg("anchor"), py::arg("test"));
  m.def(
      "bd_psnr",
      [](const std::vector<std::pair<double, double>>& anchor,
         const std::vector<std::pair<double, double>>& test) {
        return experiments::bd_psnr(rd_points(anchor), rd_points(test));
      },
      py::arg("anchor"), py::arg("test"));
}
