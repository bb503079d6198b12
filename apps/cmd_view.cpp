/// @file cmd_view.cpp
/// @brief `crpgs view`: a scene (a .crpgs file, a run or decode directory, or a standard 3DGS
/// .ply) served to a web browser on this machine, drawn by the Spark Gaussian-splat viewer
/// (viewer/, its npm packages installed by scripts/setup; nothing is fetched at run time).
#include <signal.h>

#include <atomic>
#include <cerrno>
#include <chrono>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <sstream>
#include <thread>

#include "cli_common.h"
#include "crpgs/atomic_file.h"
#include "crpgs/ply.h"
#include "io/json_writer.h"

// Last: httplib.h includes <resolv.h>, whose `_res` macro breaks Eigen's headers after it.
#include <httplib.h>

namespace crpgs::cli {
namespace {
namespace fs = std::filesystem;

/// The files of viewer/ the page loads, as the build and install trees hold them: the list
/// apps/CMakeLists.txt copies (CRPGS_VIEWER_FILES, comma-separated).
std::vector<std::string> viewer_files() {
  std::vector<std::string> files;
  std::stringstream list(CRPGS_VIEWER_FILES);
  for (std::string f; std::getline(list, f, ',');) files.push_back(f);
  return files;
}

/// CRPGS_VIEWER_DIR, else share/crpgs/viewer beside this executable's bin/ (the build tree
/// mirrors the install tree).
StatusOr<fs::path> viewer_directory() {
  fs::path dir;
  if (const char* env = std::getenv("CRPGS_VIEWER_DIR"); env && *env) {
    dir = env;
  } else {
    std::error_code ec;
    const fs::path exe = fs::read_symlink("/proc/self/exe", ec);
    if (ec) return Status(StatusCode::kNotFound, "cannot locate this executable: " + ec.message());
    dir = exe.parent_path().parent_path() / "share" / "crpgs" / "viewer";
  }
  for (const std::string& f : viewer_files())
    if (std::error_code ec; !fs::is_regular_file(dir / f, ec))
      return Status(StatusCode::kNotFound,
                    "the viewer is incomplete: " + (dir / f).string() +
                        " is missing (its web packages come from npm: scripts/setup runs `npm ci "
                        "--prefix viewer` in the source tree, and records there why when it "
                        "fails, in viewer/node_modules/.crpgs-install-failed; then rebuild. Or "
                        "set CRPGS_VIEWER_DIR)");
  return dir;
}

/// A directory of our own under the system's temporary directory, removed when this ends.
struct TempDir {
  fs::path path;
  ~TempDir() {
    std::error_code ec;
    if (!path.empty()) fs::remove_all(path, ec);
  }
};

StatusOr<fs::path> make_temp_dir(TempDir& owner) {
  std::error_code ec;
  std::string pattern = (fs::temp_directory_path(ec) / "crpgs-view-XXXXXX").string();
  if (ec || !mkdtemp(pattern.data()))
    return Status(StatusCode::kIoError, "cannot create a temporary directory: " +
                                            (ec ? ec.message() : std::strerror(errno)));
  owner.path = pattern;
  return owner.path;
}

/// A camera in THREE.js's convention (x right, y up, looking down −z): camera-to-world,
/// column-major, as Matrix4.fromArray reads it.
void write_camera(io::JsonWriter& w, const std::string& name, const Camera& c) {
  Eigen::Matrix4d c2w = Eigen::Matrix4d::Identity();
  c2w.topLeftCorner<3, 3>() = c.R.transpose() * Eigen::Vector3d(1, -1, -1).asDiagonal();
  c2w.topRightCorner<3, 1>() = c.center();
  w.begin_object();
  w.key("name").value(name);
  w.key("width").value(c.width);
  w.key("height").value(c.height);
  w.key("fx").value(c.fx);
  w.key("fy").value(c.fy);
  w.key("cx").value(c.cx);
  w.key("cy").value(c.cy);
  w.key("c2w").begin_array(true);
  for (int col = 0; col < 4; ++col)
    for (int row = 0; row < 4; ++row) w.value(c2w(row, col));
  w.end_array();
  w.end_object();
}

/// scene.json (viewer/viewer.js reads it): the splat file, the background, and the dataset's
/// cameras, test views first (camera K of `?camera=K` is test view K of `crpgs eval`).
std::string scene_json(const std::string& title, const std::array<float, 3>& background,
                       const Dataset* dataset) {
  io::JsonWriter w;
  w.begin_object();
  w.key("title").value(title);
  w.key("splat").value("scene.ply");
  w.key("background").begin_array(true);
  for (float v : background) w.value(double(v));
  w.end_array();
  w.key("cameras").begin_array();
  if (dataset) {
    for (const View& v : dataset->test) write_camera(w, "test " + v.camera.name, v.camera);
    for (const View& v : dataset->train) write_camera(w, "train " + v.camera.name, v.camera);
  }
  w.end_array();
  w.end_object();
  return w.str();
}

struct ViewOptions {
  std::string source, config, ply_out, host = "127.0.0.1";
  // A shorter fit than `crpgs export`'s, so that the page opens quickly (a fifth of its time).
  int port = 8080, sh_degree = 3, refine = 200, threads = 0;
};

std::atomic<bool> g_stop_requested{false};
extern "C" void request_stop(int) {
  g_stop_requested = true;
}

/// Serves `dirs` (searched in order) until SIGINT or SIGTERM. The handlers only raise a flag
/// (whichever thread the signal lands on) that a thread of ours turns into a clean stop, so the
/// temporary files go.
int serve(const std::vector<fs::path>& dirs, const ViewOptions& o, const std::string& what) {
  httplib::Server server;
  for (const fs::path& d : dirs) server.set_mount_point("/", d.string());
  const int port = o.port == 0 ? server.bind_to_any_port(o.host)
                               : (server.bind_to_port(o.host, o.port) ? o.port : -1);
  if (port < 0)
    return report_error(
        Status(StatusCode::kIoError, "cannot listen on " + o.host + ":" + std::to_string(o.port) +
                                         " (in use? --port 0 takes any free port)"));
  struct sigaction sa = {};
  sa.sa_handler = request_stop;
  sigemptyset(&sa.sa_mask);
  sigaction(SIGINT, &sa, nullptr);
  sigaction(SIGTERM, &sa, nullptr);
  std::atomic<bool> served{false};
  std::thread stopper([&server, &served] {
    while (!g_stop_requested && !served)
      std::this_thread::sleep_for(std::chrono::milliseconds(100));
    server.stop();
  });
  std::printf("serving %s at http://%s:%d/ (open it in a web browser; Ctrl-C stops)\n",
              what.c_str(), o.host.c_str(), port);
  std::fflush(stdout);
  const bool listened = server.listen_after_bind();
  served = true;
  stopper.join();
  if (!listened && !g_stop_requested)
    return report_error(Status(StatusCode::kIoError, "the web server stopped unexpectedly"));
  std::printf("stopped\n");
  return 0;
}

int view_command(const GlobalOptions& g, const ViewOptions& o) {
  auto viewer = viewer_directory();
  if (!viewer.ok()) return report_error(viewer.status());
  if (!o.ply_out.empty())
    if (Status st = check_output_is_not_input(o.ply_out, o.source); !st.ok())
      return report_error(st);
  TempDir temp;
  auto dir = make_temp_dir(temp);
  if (!dir.ok()) return report_error(dir.status());
  const fs::path ply_path = *dir / "scene.ply";
  std::string json;
  std::error_code ec;
  ComponentRegistry r = load_registry(g);
  const std::string title = fs::path(o.source).filename().string();
  if (fs::path(o.source).extension() == ".ply" && fs::is_regular_file(o.source, ec)) {
    // A .ply is shown as it is; a config (-c) adds its dataset's cameras and background.
    auto ply = read_ply(o.source);  // refused here, with its reason, rather than in the browser
    if (!ply.ok()) return report_error(ply.status());
    fs::create_symlink(fs::absolute(o.source), ply_path, ec);
    if (ec)
      return report_error(Status(StatusCode::kInternal, ply_path.string() + ": " + ec.message()));
    PlyReadingSetup reading;
    if (!o.config.empty()) {
      set_compute_threads(o.threads);
      auto s = ply_reading_setup(g, r, o.config);
      if (!s.ok()) return report_error(s.status());
      reading = std::move(s.value());
    }
    std::printf("%s: %zu Gaussians, SH degree %d\n", o.source.c_str(), ply->size(), ply->sh_degree);
    json =
        scene_json(title, reading.background, reading.setup ? &reading.setup->dataset() : nullptr);
  } else {
    if (!o.config.empty())
      return report_error(
          Status(StatusCode::kInvalidArgument,
                 "-c/--config is for a .ply source; " + o.source + " brings its own config"));
    auto src = load_model_source(g, r, o.source, resolve_threads(o.threads));
    if (!src.ok()) return report_error(src.status());
    ExportOptions opt;
    opt.sh_degree = o.sh_degree;
    opt.refine = src->setup->dataset().train.empty() ? 0 : o.refine;
    auto exported = export_with_progress(*src, opt);
    if (!exported.ok()) return report_error(exported.status());
    const std::string out = o.ply_out.empty() ? ply_path.string() : o.ply_out;
    if (Status st = write_ply(out, exported->gaussians); !st.ok()) return report_error(st);
    if (!o.ply_out.empty()) {
      fs::create_symlink(fs::absolute(o.ply_out), ply_path, ec);
      if (ec)
        return report_error(Status(StatusCode::kInternal, ply_path.string() + ": " + ec.message()));
    }
    std::printf("exported %zu Gaussians, SH degree %d%s\n", exported->gaussians.size(), o.sh_degree,
                o.ply_out.empty() ? "" : (" to " + o.ply_out).c_str());
    json = scene_json(title, src->model().options().effects.background, &src->setup->dataset());
  }
  if (Status st = write_file_atomic((*dir / "scene.json").string(), json); !st.ok())
    return report_error(st);
  return serve({*dir, *viewer}, o, o.source);
}

}  // namespace

void add_view_commands(CLI::App& app, GlobalOptions& g) {
  static ViewOptions o;
  auto* v = app.add_subcommand(
      "view",
      "Show a scene in a web browser: a .crpgs file or run directory is exported to a 3DGS .ply "
      "(as `crpgs export`), then served with an interactive Gaussian-splat viewer on this "
      "machine (arrow keys step through the dataset's cameras)");
  v->add_option("SOURCE", o.source, ".crpgs file, run or decode directory, or a 3DGS .ply")
      ->required();
  v->add_option("--port", o.port, "TCP port; 0 takes any free one")
      ->check(CLI::Range(0, 65535))
      ->capture_default_str();
  v->add_option("--host", o.host,
                "address to listen on (0.0.0.0 shows it to other machines: nothing is "
                "protected)")
      ->capture_default_str();
  v->add_option("-c,--config", o.config,
                "for a .ply: a config whose dataset gives the cameras and background");
  v->add_option("--ply", o.ply_out, "also keep the exported .ply here");
  v->add_option("--sh-degree", o.sh_degree, "SH degree of the exported colours (0..3)")
      ->check(CLI::Range(0, 3))
      ->capture_default_str();
  v->add_option("--refine", o.refine,
                "iterations of the export's fit to the training views (`crpgs export`); 0 = the "
                "bake alone, quicker")
      ->check(CLI::Range(0, 1000000))
      ->capture_default_str();
  add_threads_option(v, o.threads);
  v->add_option("--set", g.sets, "override a config key, e.g. --set dataset.path=DIR");
  v->callback([&g] { throw CLI::RuntimeError(view_command(g, o)); });
}

}  // namespace crpgs::cli
