/// @file sweep.cpp
#include "crpgs/experiments/sweep.h"

#include <fcntl.h>
#include <fnmatch.h>
#include <spawn.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <cctype>
#include <cerrno>
#include <chrono>
#include <cmath>
#include <csignal>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <map>
#include <set>
#include <string_view>
#include <thread>

#include <yaml-cpp/yaml.h>

#include "core/text_list.h"
#include "core/time_text.h"
#include "crpgs/atomic_file.h"
#include "crpgs/config.h"
#include "crpgs/dir_lock.h"
#include "crpgs/experiments/run_metrics.h"
#include "crpgs/shared_prefix.h"
#include "io/json_writer.h"

extern char** environ;

namespace crpgs::experiments {
namespace {
namespace fs = std::filesystem;

Status bad(const std::string& file, const std::string& what) {
  return Status(StatusCode::kInvalidArgument, file + ": " + what);
}

/// A YAML value as override text: scalars as written, the rest in flow style.
std::string yaml_text(const YAML::Node& n) {
  if (n.IsScalar()) return n.Scalar();
  YAML::Emitter e;
  e.SetMapFormat(YAML::Flow);
  e.SetSeqFormat(YAML::Flow);
  e << n;
  return e.c_str();
}

Status parse_set(const YAML::Node& n, const std::string& where, Overrides& out) {
  if (!n) return OkStatus();
  if (!n.IsMap()) return bad(where, "'set' must be a map of key.path: value");
  for (const auto& kv : n) out.emplace_back(kv.first.as<std::string>(), yaml_text(kv.second));
  return OkStatus();
}

std::string sanitize(const std::string& s) {
  std::string out;
  for (char c : s)
    out +=
        (std::isalnum(static_cast<unsigned char>(c)) || c == '.' || c == '+' || c == '-') ? c : '_';
  // "." and ".." would name the directory itself or its parent.
  return out.empty() || out == "." || out == ".."
             ? std::string(std::max<size_t>(1, out.size()), '_')
             : out;
}

std::string last_part(const std::string& key) {
  const size_t dot = key.rfind('.');
  return dot == std::string::npos ? key : key.substr(dot + 1);
}

std::string shell_quote(const std::string& s) {
  std::string out = "'";
  for (char c : s) out += c == '\'' ? std::string("'\\''") : std::string(1, c);
  return out + "'";
}

}  // namespace

StatusOr<SweepSpec> parse_sweep(const std::string& yaml_text_in, const std::string& name) {
  YAML::Node root;
  try {
    root = YAML::Load(yaml_text_in);
  } catch (const YAML::Exception& e) {
    return bad(name, std::string("YAML error: ") + e.what());
  }
  if (!root.IsMap()) return bad(name, "a sweep file is a YAML map");
  static const std::vector<std::string> kKeys = {
      "name",     "output",    "configs", "overrides",    "rate_key",
      "datasets", "resources", "workers", "share_prefix", "one_model"};
  SweepSpec s;
  s.file = name;
  try {
    for (const auto& kv : root) {
      const std::string k = kv.first.as<std::string>();
      if (std::find(kKeys.begin(), kKeys.end(), k) == kKeys.end())
        return bad(name, "unknown key '" + k + "'" + did_you_mean(k, kKeys) + " (expected " +
                             join(kKeys) + ")");
    }
    s.name = root["name"] ? root["name"].as<std::string>() : fs::path(name).stem().string();
    s.output = root["output"] ? root["output"].as<std::string>() : "runs/" + s.name;
    const YAML::Node configs = root["configs"];
    if (!configs || !configs.IsSequence() || configs.size() == 0)
      return bad(name, "'configs' must list at least one config file");
    std::set<std::string> names;
    for (const auto& c : configs) {
      SweepConfig sc;
      if (c.IsScalar()) {
        sc.path = c.Scalar();
      } else if (c.IsMap()) {
        if (!c["path"]) return bad(name, "a config entry needs 'path'");
        sc.path = c["path"].as<std::string>();
        if (c["name"]) sc.name = c["name"].as<std::string>();
        CRPGS_RETURN_IF_ERROR(parse_set(c["set"], name, sc.set));
      } else {
        return bad(name, "a config entry is a path or {name, path, set}");
      }
      if (sc.name.empty()) sc.name = fs::path(sc.path).stem().string();
      if (!names.insert(sc.name).second)
        return bad(name, "two configs are named '" + sc.name + "' (give one a 'name')");
      s.configs.push_back(std::move(sc));
    }
    if (const YAML::Node g = root["overrides"]) {
      if (!g.IsMap()) return bad(name, "'overrides' maps key.path to a list of values");
      for (const auto& kv : g) {
        std::vector<std::string> values;
        if (kv.second.IsSequence()) {
          for (const auto& v : kv.second) values.push_back(yaml_text(v));
        } else {
          values.push_back(yaml_text(kv.second));
        }
        if (values.empty())
          return bad(name, "override '" + kv.first.as<std::string>() + "' has no values");
        s.grid.emplace_back(kv.first.as<std::string>(), std::move(values));
      }
    }
    if (root["rate_key"]) {
      s.rate_key = root["rate_key"].as<std::string>();
    } else {
      for (const auto& [k, v] : s.grid)
        if (last_part(k).find("lambda") != std::string::npos) {
          s.rate_key = k;
          break;
        }
    }
    if (const YAML::Node ds = root["datasets"]) {
      if (!ds.IsSequence()) return bad(name, "'datasets' is a list of {name, scene, set}");
      names.clear();
      for (const auto& d : ds) {
        if (!d.IsMap() || !d["name"]) return bad(name, "a dataset entry needs 'name'");
        SweepDataset sd;
        sd.name = d["name"].as<std::string>();
        if (d["scene"]) sd.scene = d["scene"].as<std::string>();
        for (const auto& kv : d) {
          const std::string k = kv.first.as<std::string>();
          if (k != "name" && k != "scene" && k != "set")
            return bad(name, "dataset '" + sd.name + "': unknown key '" + k +
                                 "' (expected name, scene, set)");
        }
        CRPGS_RETURN_IF_ERROR(parse_set(d["set"], name, sd.set));
        if (!names.insert(sd.name).second) return bad(name, "two datasets named " + sd.name);
        s.datasets.push_back(std::move(sd));
      }
    }
    if (const YAML::Node r = root["resources"]) {
      if (!r.IsMap()) return bad(name, "'resources' is a map");
      if (r["cpus"]) s.resources.cpus = r["cpus"].as<int>();
      if (r["mem"]) s.resources.mem = r["mem"].as<std::string>();
      if (r["time"]) s.resources.time = r["time"].as<std::string>();
      if (r["partition"]) s.resources.partition = r["partition"].as<std::string>();
      if (r["max_parallel"]) s.resources.max_parallel = r["max_parallel"].as<int>();
    }
    if (root["workers"]) s.workers = root["workers"].as<int>();
    if (root["share_prefix"]) s.share_prefix = root["share_prefix"].as<bool>();
    if (const YAML::Node o = root["one_model"]) {
      if (!o.IsMap() || !o["rate"] || !o["scales"] || !o["scales"].IsSequence() ||
          o["scales"].size() == 0 || o.size() != 2)
        return bad(name,
                   "'one_model' is {rate: R, scales: [S, ...]}: the runs at rate_key R "
                   "re-encoded at each step scale S");
      s.one_model_rate = o["rate"].as<double>();
      for (const auto& v : o["scales"]) s.one_model_scales.push_back(v.as<double>());
      for (double v : s.one_model_scales)
        if (!(v > 0) || !std::isfinite(v))
          return bad(name, "'one_model.scales' must be positive numbers");
      if (s.rate_key.empty())
        return bad(name, "'one_model' needs a rate_key (the runs' λ it picks R from)");
    }
  } catch (const YAML::Exception& e) {
    return bad(name, std::string("bad value: ") + e.what());
  }
  if (s.workers < 1) return bad(name, "'workers' must be >= 1");
  if (s.resources.cpus < 1) return bad(name, "'resources.cpus' must be >= 1");
  // Pasted into #SBATCH lines: one word each.
  for (const auto& [key, v] : {std::pair<const char*, const std::string&>{"mem", s.resources.mem},
                               {"time", s.resources.time},
                               {"partition", s.resources.partition}})
    if (v.find_first_of(" \t\r\n\"'\\#") != std::string::npos)
      return bad(name, std::string("'resources.") + key +
                           "' must be one word without quotes, '#' or '\\' (got '" + v + "')");
  std::set<std::string> ids;
  for (const SweepRun& r : expand_sweep(s, "."))
    if (!ids.insert(r.id).second)
      return bad(name, "two runs would share the directory '" + r.id +
                           "' (names are kept to letters, digits, '.', '+' and '-'): rename one");
  return s;
}

StatusOr<SweepSpec> load_sweep(const std::string& path) {
  CRPGS_ASSIGN_OR_RETURN(std::vector<uint8_t> bytes, read_file_bytes(path));
  return parse_sweep(std::string(bytes.begin(), bytes.end()), path);
}

std::string sweep_prefix_dir(const std::string& runs_dir) {
  return (fs::path(runs_dir) / "prefixes").string();
}

std::string rate_scale_dir(const std::string& run_dir, double scale) {
  return (fs::path(run_dir) / "rates" / ("scale-" + g_text(scale))).string();
}

std::string run_tag(const SweepRun& run, size_t sweep_size) {
  return "[" + std::to_string(run.index + 1) + "/" + std::to_string(sweep_size) + "] " + run.id;
}

std::vector<SweepRun> expand_sweep(const SweepSpec& spec, const std::string& runs_dir_in) {
  const std::string runs_dir = runs_dir_in.empty() ? spec.output : runs_dir_in;
  // Short labels for grid keys: the last part, or the whole key where last parts collide.
  std::map<std::string, int> count;
  for (const auto& [k, v] : spec.grid) ++count[last_part(k)];
  std::vector<std::string> label;
  for (const auto& [k, v] : spec.grid) label.push_back(count[last_part(k)] > 1 ? k : last_part(k));

  std::vector<SweepDataset> datasets = spec.datasets;
  if (datasets.empty()) datasets.push_back({"default", {}, {}});
  size_t combos = 1;
  for (const auto& [k, v] : spec.grid) combos *= v.size();

  std::vector<SweepRun> runs;
  for (const auto& ds : datasets)
    for (const auto& cfg : spec.configs)
      for (size_t c = 0; c < combos; ++c) {
        SweepRun r;
        r.index = static_cast<int>(runs.size());
        r.dataset = ds.name;
        r.config_path = cfg.path;
        r.scene = ds.scene;
        r.method = cfg.name;
        r.overrides = cfg.set;
        r.overrides.insert(r.overrides.end(), ds.set.begin(), ds.set.end());
        std::string tail;
        size_t rest = c, stride = combos;
        for (size_t g = 0; g < spec.grid.size(); ++g) {  // first key varies slowest
          const auto& [key, values] = spec.grid[g];
          stride /= values.size();
          const std::string& v = values[rest / stride];
          rest %= stride;
          r.overrides.emplace_back(key, v);
          tail += (tail.empty() ? "" : "_") + sanitize(label[g]) + "-" + sanitize(v);
          if (key == spec.rate_key) {
            char* end = nullptr;
            const double x = std::strtod(v.c_str(), &end);
            if (end && *end == '\0' && end != v.c_str()) r.rate = x;
          } else {
            r.method += " " + label[g] + "=" + v;
          }
        }
        r.id = sanitize(ds.name) + "/" + sanitize(cfg.name) + "/" + (tail.empty() ? "base" : tail);
        r.dir = (fs::path(runs_dir) / r.id).string();
        runs.push_back(std::move(r));
      }
  return runs;
}

namespace {

/// Lays a scene file's keys over `cfg`, leaf by leaf (what `--set` would do for each). A scene
/// holds what a benchmark fixes per scene; a component block there would mix two components'
/// parameters, so only the core sections are accepted.
Status lay_scene_over(Config& cfg, const std::string& scene_path) {
  CRPGS_ASSIGN_OR_RETURN(Config scene, Config::load_file(scene_path));
  static const std::set<std::string> kSections = {"dataset", "scene", "model", "train", "rate"};
  std::vector<std::pair<std::string, YAML::Node>> todo;
  for (const auto& kv : scene.root()) {
    const std::string k = kv.first.as<std::string>();
    if (!kSections.count(k))
      return bad(scene_path,
                 "a scene file holds only the dataset, scene, model, train and rate "
                 "sections (found '" +
                     k + "')");
    todo.emplace_back(k, kv.second);
  }
  while (!todo.empty()) {
    auto [key, node] = todo.back();
    todo.pop_back();
    if (node.IsMap()) {
      for (const auto& kv : node)
        todo.emplace_back(key + "." + kv.first.as<std::string>(), kv.second);
    } else {
      CRPGS_RETURN_IF_ERROR(cfg.set(key, YAML::Clone(node)));
    }
  }
  return OkStatus();
}

}  // namespace

std::vector<SweepRun> select_runs(const std::vector<SweepRun>& runs,
                                  const std::vector<std::string>& globs) {
  if (globs.empty()) return runs;
  std::vector<SweepRun> out;
  for (const auto& r : runs)
    if (std::any_of(globs.begin(), globs.end(),
                    [&](const std::string& g) { return fnmatch(g.c_str(), r.id.c_str(), 0) == 0; }))
      out.push_back(r);
  return out;
}

Status add_overrides(std::vector<SweepRun>& runs, const std::vector<std::string>& assignments) {
  for (const auto& a : assignments) {
    const size_t eq = a.find('=');
    if (eq == std::string::npos || eq == 0)
      return Status(StatusCode::kInvalidArgument,
                    "--set " + a + ": expected KEY=VALUE (e.g. train.device=cuda)");
    const std::string key = a.substr(0, eq);
    // Another component type replaces the component's block, as in a config's `base:`: the
    // run's own settings of the old one (e.g. rasterizer.threads) would not apply to it.
    const bool type = key.size() > 5 && key.compare(key.size() - 5, 5, ".type") == 0;
    const std::string block = type ? key.substr(0, key.size() - 4) : "";
    for (auto& r : runs) {
      if (type)
        r.overrides.erase(
            std::remove_if(r.overrides.begin(), r.overrides.end(),
                           [&](const auto& o) { return o.first.rfind(block, 0) == 0; }),
            r.overrides.end());
      r.overrides.emplace_back(key, a.substr(eq + 1));
    }
  }
  return OkStatus();
}

StatusOr<Config> build_run_config(const SweepRun& run, const ComponentRegistry* registry) {
  // As `crpgs train`: load_file makes a config file's dataset path absolute against that file
  // (a scene file's too); one set by the sweep file (like --set) is relative to the working
  // directory.
  CRPGS_ASSIGN_OR_RETURN(Config cfg, Config::load_file(run.config_path));
  if (!run.scene.empty()) CRPGS_RETURN_IF_ERROR(lay_scene_over(cfg, run.scene));
  for (const auto& [k, v] : run.overrides) CRPGS_RETURN_IF_ERROR(cfg.apply_override(k + "=" + v));
  std::error_code ec;
  CRPGS_RETURN_IF_ERROR(make_dataset_path_absolute(cfg, fs::current_path(ec).string()));
  if (!registry) return cfg;
  auto resolved = cfg.resolve(*registry);
  if (!resolved.ok())
    return Status(resolved.status().code(), "run " + run.id + ": " + resolved.status().message());
  return resolved;
}

Status prepare_run(const SweepRun& run, const ComponentRegistry* registry) {
  CRPGS_ASSIGN_OR_RETURN(Config cfg, build_run_config(run, registry));
  std::error_code ec;
  fs::create_directories(run.dir, ec);
  if (ec) return Status(StatusCode::kInternal, "cannot create " + run.dir + ": " + ec.message());
  CRPGS_RETURN_IF_ERROR(cfg.save(run.dir + "/config.yaml"));
  io::JsonWriter w;
  w.begin_object();
  w.key("id").value(run.id);
  w.key("index").value(run.index);
  w.key("method").value(run.method);
  w.key("dataset").value(run.dataset);
  w.key("rate").value(run.rate);
  w.key("config").value(run.config_path);
  if (!run.scene.empty()) w.key("scene").value(run.scene);
  w.key("overrides").begin_object();
  for (const auto& [k, v] : run.overrides) w.key(k).value(v);
  w.end_object();
  w.end_object();
  return write_file_atomic(run.dir + "/run.json", w.str());
}

namespace {

/// Scalar (and sequence) values of a YAML tree by dotted key.
void flatten(const YAML::Node& n, const std::string& prefix,
             std::map<std::string, std::string>& out) {
  if (n.IsMap()) {
    for (const auto& kv : n)
      flatten(kv.second, prefix + (prefix.empty() ? "" : ".") + kv.first.as<std::string>(), out);
    return;
  }
  YAML::Emitter e;
  e << YAML::Flow << n;
  out[prefix] = e.c_str();
}

}  // namespace

std::string config_change(const SweepRun& run, const ComponentRegistry* registry,
                          bool ignore_placement) {
  const std::string saved_path = run.dir + "/config.yaml";
  std::error_code ec;
  if (!fs::exists(saved_path, ec)) return "";
  auto now = build_run_config(run, registry);
  if (!now.ok()) return "";  // the sweep reports the config error itself
  // The saved copy resolved by this build, so that defaults added since do not count.
  auto saved = Config::load_file(saved_path);
  if (saved.ok() && ignore_placement) {
    // The rasterizer is where the run computed (its type, threads or GPU), and this build need
    // not have the one it ran with: compare with the sweep's own.
    auto raw = build_run_config(run, nullptr);
    const YAML::Node r = raw.ok() ? raw->root()["rasterizer"] : YAML::Node();
    if (Status st = saved->set("rasterizer", r ? YAML::Clone(r) : YAML::Node(YAML::NodeType::Map));
        !st.ok())
      return st.message();
  }
  if (saved.ok() && registry) saved = saved->resolve(*registry);
  if (!saved.ok()) return "its config.yaml is unreadable (" + saved.status().message() + ")";
  if (saved->dump() == now->dump()) return "";
  std::map<std::string, std::string> a, b;
  flatten(saved->root(), "", a);
  flatten(now->root(), "", b);
  if (ignore_placement) {
    for (const char* key : {"train.threads", "train.device"}) a.erase(key), b.erase(key);
    if (a == b) return "";
  }
  std::vector<std::string> diffs;
  for (const auto& [k, v] : a)
    if (auto it = b.find(k); it == b.end() || it->second != v)
      diffs.push_back(k + ": " + v + " -> " + (it == b.end() ? "(none)" : it->second));
  for (const auto& [k, v] : b)
    if (!a.count(k)) diffs.push_back(k + ": (none) -> " + v);
  if (diffs.empty()) return "its config.yaml differs";  // e.g. only in key order
  std::string text;
  for (size_t i = 0; i < diffs.size() && i < 3; ++i) text += (i ? ", " : "") + diffs[i];
  if (diffs.size() > 3) text += ", and " + std::to_string(diffs.size() - 3) + " more";
  return text;
}

RunState run_state(const std::string& run_dir) {
  std::error_code ec;
  if (run_marked_started(run_dir)) return RunState::kInterrupted;
  if (!fs::exists(run_dir + "/metrics.json", ec)) return RunState::kPending;
  return read_run_metrics(run_dir + "/metrics.json").ok() ? RunState::kComplete
                                                          : RunState::kPending;
}

namespace {

struct Active {
  pid_t pid;
  const SweepRun* run;
  bool rates = false;  ///< `encode --rate-scales` of a finished run, not its training
};

/// A finished run the sweep should re-encode at the one-model scales and that lacks some.
bool wants_rates(const SweepRun& r, const ExecOptions& opt) {
  if (opt.one_model_scales.empty() || !std::isfinite(r.rate) ||
      std::abs(r.rate - opt.one_model_rate) > 1e-9 * std::abs(opt.one_model_rate))
    return false;
  return std::any_of(opt.one_model_scales.begin(), opt.one_model_scales.end(), [&](double s) {
    return !read_run_metrics(rate_scale_dir(r.dir, s) + "/metrics.json").ok();
  });
}

/// Starts `args` (args[0]: the executable) with stdin from /dev/null and stdout and stderr
/// appended to `dir`'s logs after a line naming the command. `lock`, when held, is handed to the
/// child (which keeps the directory locked until it exits).
StatusOr<pid_t> spawn_logged(const std::string& dir, std::vector<std::string> args,
                             const DirectoryLock* lock) {
  const std::string header = "== " + local_time_text() + " " + [&] {
    std::string cmd;
    for (const auto& a : args)  // quoted where needed, so the line can be pasted into a shell
      cmd += (cmd.empty() ? "" : " ") +
             (a.find_first_of(" '\"$\\*?;&|<>()") != std::string::npos ? shell_quote(a) : a);
    return cmd;
  }() + "\n";
  for (const char* log : {"/stdout.log", "/stderr.log"}) {
    FILE* f = std::fopen((dir + log).c_str(), "a");
    if (!f) return Status(StatusCode::kInternal, "cannot open " + dir + log);
    std::fputs(header.c_str(), f);
    std::fclose(f);
  }
  posix_spawn_file_actions_t fa;
  posix_spawn_file_actions_init(&fa);
  posix_spawn_file_actions_addopen(&fa, 0, "/dev/null", O_RDONLY, 0);
  const std::string out = dir + "/stdout.log", err = dir + "/stderr.log";
  posix_spawn_file_actions_addopen(&fa, 1, out.c_str(), O_WRONLY | O_APPEND | O_CREAT, 0644);
  posix_spawn_file_actions_addopen(&fa, 2, err.c_str(), O_WRONLY | O_APPEND | O_CREAT, 0644);
  const bool hand_over = lock && lock->held();
  std::vector<std::string> env;
  if (hand_over) {
    const int child_fd = lock->fd() == 200 ? 201 : 200;  // a dup2 onto itself would keep CLOEXEC
    posix_spawn_file_actions_adddup2(&fa, lock->fd(), child_fd);
    const std::string handed = DirectoryLock::child_environment(child_fd);
    const std::string name = handed.substr(0, handed.find('=') + 1);
    for (char** e = environ; *e; ++e)
      if (std::string_view(*e).substr(0, name.size()) != name) env.emplace_back(*e);
    env.push_back(handed);
  }
  std::vector<char*> argv, envp;
  for (auto& a : args) argv.push_back(a.data());
  argv.push_back(nullptr);
  for (auto& e : env) envp.push_back(e.data());
  envp.push_back(nullptr);
  pid_t pid = 0;
  const int rc = posix_spawn(&pid, args[0].c_str(), &fa, nullptr, argv.data(),
                             hand_over ? envp.data() : environ);
  posix_spawn_file_actions_destroy(&fa);
  if (rc != 0)
    return Status(StatusCode::kInternal, "cannot start " + args[0] + ": " + std::strerror(rc));
  return pid;
}

/// Starts `runner encode RUN --rate-scales ...` on a finished run, with the directory locked;
/// 0 when another process holds it.
StatusOr<pid_t> launch_rates(const SweepRun& run, const ExecOptions& opt) {
  auto lock = lock_directory(run.dir);
  if (!lock.ok()) {
    if (directory_lock_holder(run.dir).empty()) return lock.status();
    return 0;
  }
  std::string scales;
  for (double v : opt.one_model_scales) scales += (scales.empty() ? "" : ",") + g_text(v);
  return spawn_logged(run.dir, {opt.runner, "encode", run.dir, "--rate-scales", scales},
                      &lock.value());
}

/// Prepares the directory and starts `runner train ...` with the logs appended. Returns 0 with
/// `*skipped` saying why when, since the sweep's first look, the run was finished or another
/// process took it. `*note`: what the start line should add (a resume under a changed config).
StatusOr<pid_t> launch(const SweepRun& run, const ExecOptions& opt, std::string* skipped,
                       std::string* note) {
  // Held while the directory is prepared, so nothing here overwrites another process's run, and
  // handed to the trainer, so no other process can take the run between this one and it.
  auto lock = lock_directory(run.dir);
  if (!lock.ok()) {
    const std::string holder = directory_lock_holder(run.dir);
    if (holder.empty()) return lock.status();
    *skipped = "running in another process (" + holder + "), skipped";
    return 0;
  }
  if (run_state(run.dir) == RunState::kComplete) {
    *skipped = "done, skipped";
    return 0;
  }
  std::error_code ec;
  const bool resume = fs::exists(run.dir + "/checkpoint.pt", ec);
  if (!opt.use_prepared_configs || !fs::exists(run.dir + "/config.yaml", ec)) {
    if (const std::string change = resume ? config_change(run, opt.registry) : ""; !change.empty())
      *note = "; it resumes its checkpoint under a changed config: " + change;
    CRPGS_RETURN_IF_ERROR(prepare_run(run, opt.registry));
  }
  CRPGS_RETURN_IF_ERROR(mark_run_started(run.dir));

  std::vector<std::string> args = {opt.runner, "train", "-c",       run.dir + "/config.yaml",
                                   "-o",       run.dir, "--method", run.method};
  // Not resuming, the sweep has decided the run is (re)done: whatever an earlier attempt left
  // there goes.
  args.push_back(resume ? "--resume" : "--force");
  if (!opt.prefix_dir.empty()) args.insert(args.end(), {"--share-prefix", opt.prefix_dir});
  auto pid = spawn_logged(run.dir, args, &lock.value());
  if (!pid.ok()) mark_run_finished(run.dir);  // nothing ran: back to pending
  return pid;
}

std::string exit_text(int status) {
  if (WIFEXITED(status)) return "exit code " + std::to_string(WEXITSTATUS(status));
  if (WIFSIGNALED(status)) return "killed by signal " + std::to_string(WTERMSIG(status));
  return "status " + std::to_string(status);
}

}  // namespace

size_t next_run_to_start(const std::vector<PendingRun>& pending,
                         const std::vector<std::string>& running,
                         const std::function<bool(const std::string&)>& published) {
  // Runs that compute a prefix others wait for: first a stopped one of a group whose prefix is
  // not published and that has no running run (it may be on its way to rate_start); then any
  // other stopped run past its group's prefix; then the first of a group nobody has started.
  auto needed = [&](const PendingRun& p) {
    return !p.prefix_key.empty() && !published(p.prefix_key) &&
           std::find(running.begin(), running.end(), p.prefix_key) == running.end();
  };
  for (size_t i = 0; i < pending.size(); ++i)
    if (pending[i].has_checkpoint && needed(pending[i])) return i;
  // Then a stopped run that needs no prefix computed: its result is the nearest.
  for (size_t i = 0; i < pending.size(); ++i)
    if (pending[i].has_checkpoint &&
        (pending[i].prefix_key.empty() || published(pending[i].prefix_key)))
      return i;
  for (size_t i = 0; i < pending.size(); ++i)
    if (needed(pending[i]) &&
        std::none_of(pending.begin(), pending.end(), [&](const PendingRun& q) {
          return q.has_checkpoint && q.prefix_key == pending[i].prefix_key;
        }))
      return i;
  for (size_t i = 0; i < pending.size(); ++i) {
    const PendingRun& p = pending[i];
    if (p.prefix_key.empty() || p.has_checkpoint || published(p.prefix_key)) return i;
  }
  return 0;
}

double sweep_time_left(const std::vector<RunLeft>& left, int workers) {
  std::vector<double> free_at(size_t(std::max(1, workers)), 0.0);  // when each worker is free
  for (const RunLeft& r : left) {
    if (r.iterations <= 0) continue;
    if (!(r.rate > 0)) return std::nan("");
    double& first = *std::min_element(free_at.begin(), free_at.end());
    first += r.iterations / r.rate;
  }
  return *std::max_element(free_at.begin(), free_at.end());
}

StatusOr<SweepSummary> run_sweep_local(const std::vector<SweepRun>& runs, const ExecOptions& opt) {
  auto log = opt.log ? opt.log : [](const std::string& s) { std::printf("%s\n", s.c_str()); };
  if (!opt.dry_run && opt.runner.empty())
    return Status(StatusCode::kInvalidArgument, "sweep: no runner executable");
  SweepSummary sum;
  sum.total = static_cast<int>(runs.size());
  std::vector<const SweepRun*> rates_todo;  // finished runs to re-encode (one_model)
  const size_t n = opt.sweep_size > 0 ? size_t(opt.sweep_size) : runs.size();
  std::vector<const SweepRun*> todo;
  for (const auto& r : runs) {
    const RunState st = run_state(r.dir);
    const std::string tag = run_tag(r, n);
    if (st == RunState::kComplete) {
      ++sum.skipped;
      const std::string change = config_change(r, opt.registry, true);
      log(tag + (change.empty() ? ": done, skipped"
                                : ": done, but the sweep now asks for another config (" + change +
                                      "); kept: delete " + r.dir + " to rerun it"));
      if (wants_rates(r, opt)) {
        if (opt.dry_run) log(tag + ": would re-encode at the one-model rate scales");
        rates_todo.push_back(&r);
      }
    } else if (const std::string holder = directory_lock_holder(r.dir); !holder.empty()) {
      ++sum.skipped;  // another sweep or `crpgs train` is on it
      log(tag + ": running in another process (" + holder + "), skipped");
    } else {
      if (opt.dry_run) {
        auto cfg = build_run_config(r, opt.registry);
        log(tag + (st == RunState::kInterrupted ? ": interrupted, would rerun" : ": would run") +
            (cfg.ok() ? std::string() : " -- CONFIG ERROR: " + cfg.status().message()));
        if (!cfg.ok()) ++sum.failed, sum.failed_ids.push_back(r.id);
      }
      todo.push_back(&r);
    }
  }
  if (opt.dry_run) return sum;

  std::vector<Active> active;
  // Prefix keys, to start runs in the order that shares most (next_run_to_start).
  std::map<const SweepRun*, std::string> prefix_key;
  if (!opt.prefix_dir.empty() && opt.registry)
    for (const SweepRun* r : todo)
      if (auto cfg = build_run_config(*r, opt.registry); cfg.ok())
        prefix_key[r] = shared_prefix_key(cfg.value());
  auto pick = [&]() -> const SweepRun* {
    std::vector<PendingRun> pending;
    std::error_code ec;
    for (const SweepRun* r : todo)
      pending.push_back({prefix_key[r], fs::exists(r->dir + "/checkpoint.pt", ec)});
    std::vector<std::string> running;
    for (const Active& a : active) running.push_back(prefix_key[a.run]);
    const size_t i = next_run_to_start(pending, running, [&](const std::string& key) {
      return fs::exists(shared_prefix_path(opt.prefix_dir, key), ec);
    });
    const SweepRun* r = todo[i];
    todo.erase(todo.begin() + std::ptrdiff_t(i));
    return r;
  };

  const size_t workers = static_cast<size_t>(std::max(1, opt.workers));
  bool stopping = false;
  while (((!todo.empty() || !rates_todo.empty()) && !stopping) || !active.empty()) {
    if (!stopping && opt.stop && opt.stop->load()) {
      stopping = true;
      log("stopping: no further runs start; the running ones checkpoint and stop");
      for (const Active& a : active) kill(a.pid, SIGTERM);
    }
    // Re-encodings first: minutes each, and they finish a curve.
    while (!stopping && !rates_todo.empty() && active.size() < workers) {
      const SweepRun& r = *rates_todo.front();
      rates_todo.erase(rates_todo.begin());
      const std::string tag = run_tag(r, n);
      auto pid = launch_rates(r, opt);
      if (!pid.ok()) {
        ++sum.failed;
        sum.failed_ids.push_back(r.id + " (one-model rates)");
        log(tag + ": cannot re-encode: " + pid.status().message());
      } else if (pid.value() == 0) {
        log(tag + ": in use by another process; not re-encoded now");
      } else {
        log(tag + ": re-encoding at the one-model rate scales (RUN/rates/)");
        active.push_back({pid.value(), &r, true});
      }
    }
    while (!stopping && !todo.empty() && active.size() < workers) {
      const SweepRun& r = *pick();
      std::string skipped, note;
      auto pid = launch(r, opt, &skipped, &note);
      if (pid.ok() && pid.value() == 0) {
        ++sum.skipped;
        log(run_tag(r, n) + ": " + skipped);
        continue;
      }
      if (!pid.ok()) {
        ++sum.failed;
        sum.failed_ids.push_back(r.id);
        log(run_tag(r, n) + ": cannot start: " + pid.status().message());
        continue;
      }
      log(run_tag(r, n) + ": started (logs in " + r.dir + ")" + note);
      active.push_back({pid.value(), &r});
    }
    if (active.empty()) continue;
    // Poll our own children only (a caller of the SDK may have others), which also lets a stop
    // flag be noticed while the runs go on.
    int status = 0;
    auto it = active.begin();
    for (; it != active.end(); ++it) {
      const pid_t done = waitpid(it->pid, &status, WNOHANG);
      if (done == it->pid) break;
      if (done < 0 && errno != EINTR)
        return Status(StatusCode::kInternal, std::string("waitpid: ") + std::strerror(errno));
    }
    if (it == active.end()) {
      std::this_thread::sleep_for(std::chrono::milliseconds(100));
      continue;
    }
    const SweepRun& r = *it->run;
    const bool rates = it->rates;
    active.erase(it);
    const std::string tag = run_tag(r, n);
    const bool exited_ok = WIFEXITED(status) && WEXITSTATUS(status) == 0;
    if (rates) {
      if (exited_ok && !wants_rates(r, opt)) {
        log(tag + ": one-model rates done (" + rate_scale_dir(r.dir, opt.one_model_scales[0]) +
            ", ...)");
      } else if (!(stopping || (opt.stop && opt.stop->load()))) {
        ++sum.failed;
        sum.failed_ids.push_back(r.id + " (one-model rates)");
        log(tag + ": one-model re-encoding FAILED (" + exit_text(status) + "); see " + r.dir +
            "/stderr.log");
      }
      continue;
    }
    auto metrics = read_run_metrics(r.dir + "/metrics.json");
    std::error_code ec;
    if (exited_ok && metrics.ok()) {
      mark_run_finished(r.dir);
      ++sum.succeeded;
      char buf[128];
      std::snprintf(buf, sizeof buf, ": done (%.3f dB, %llu bytes)", metrics->psnr_mean,
                    static_cast<unsigned long long>(metrics->size_bytes));
      log(tag + buf);
      if (wants_rates(r, opt)) rates_todo.push_back(&r);
    } else if (stopping || (opt.stop && opt.stop->load())) {
      ++sum.interrupted;  // .running stays: the next `crpgs sweep` resumes it
      log(tag + ": stopped (" + exit_text(status) + "); the next `crpgs sweep` resumes it");
    } else {
      // The .running marker stays, so the next `crpgs sweep` reruns (resumes) it.
      ++sum.failed;
      sum.failed_ids.push_back(r.id);
      log(tag + ": FAILED (" + exit_text(status) +
          (exited_ok ? ", but " + metrics.status().message() : std::string()) + "); see " + r.dir +
          "/stderr.log");
    }
  }
  return sum;
}

Status run_one(const SweepRun& run, const ExecOptions& opt) {
  CRPGS_ASSIGN_OR_RETURN(SweepSummary s, run_sweep_local({run}, opt));
  if (s.interrupted > 0)
    return Status(StatusCode::kCancelled, "run " + run.id + " stopped; the next run resumes it");
  if (s.failed > 0)
    return Status(StatusCode::kInternal,
                  "run " + run.id + " failed; see " + run.dir + "/stderr.log");
  return OkStatus();
}

std::string slurm_script(const SweepSpec& spec, const std::vector<int>& indices,
                         const std::string& crpgs_exe, const std::string& sweep_file,
                         const std::string& runs_dir) {
  // Indices as ranges: 0-3,5,7-9.
  std::string array;
  for (size_t i = 0; i < indices.size();) {
    size_t j = i;
    while (j + 1 < indices.size() && indices[j + 1] == indices[j] + 1) ++j;
    array += (array.empty() ? "" : ",") + std::to_string(indices[i]) +
             (j > i ? "-" + std::to_string(indices[j]) : "");
    i = j + 1;
  }
  if (spec.resources.max_parallel > 0) array += "%" + std::to_string(spec.resources.max_parallel);
  std::error_code ec;
  const std::string cwd = fs::current_path(ec).string();
  std::string s = "#!/bin/bash\n# Written by `crpgs sweep --slurm` for " + spec.file + "\n";
  s += "#SBATCH --job-name=crpgs-" + sanitize(spec.name) + "\n";
  s += "#SBATCH --array=" + array + "\n";
  s += "#SBATCH --ntasks=1\n";
  s += "#SBATCH --cpus-per-task=" + std::to_string(spec.resources.cpus) + "\n";
  if (!spec.resources.mem.empty()) s += "#SBATCH --mem=" + spec.resources.mem + "\n";
  if (!spec.resources.time.empty()) s += "#SBATCH --time=" + spec.resources.time + "\n";
  if (!spec.resources.partition.empty())
    s += "#SBATCH --partition=" + spec.resources.partition + "\n";
  // Quoted for sbatch's directive parser; '%' starts a file-name pattern in --output.
  std::string out_path;
  for (char c : runs_dir) out_path += c == '%' ? std::string("%%") : std::string(1, c);
  s += "#SBATCH --output=\"" + out_path + "/slurm/%A_%a.out\"\n";
  s += "#SBATCH --chdir=\"" + cwd + "\"\n";
  s += "set -eu\n";
  s += "exec " + shell_quote(crpgs_exe) + " sweep " + shell_quote(sweep_file) + " -o " +
       shell_quote(runs_dir) + " --run-index \"$SLURM_ARRAY_TASK_ID\"\n";
  return s;
}

StatusOr<std::string> submit_slurm(const SweepSpec& spec, const std::vector<int>& indices,
                                   const std::string& crpgs_exe, const std::string& sweep_file,
                                   const std::string& runs_dir) {
  if (indices.empty()) return Status(StatusCode::kInvalidArgument, "nothing to submit");
  std::error_code ec;
  fs::create_directories(runs_dir + "/slurm", ec);
  const std::string script = runs_dir + "/sweep.sbatch";
  CRPGS_RETURN_IF_ERROR(
      write_file_atomic(script, slurm_script(spec, indices, crpgs_exe, sweep_file, runs_dir)));
  const std::string cmd = "sbatch --parsable " + shell_quote(script) + " 2>&1";
  FILE* p = popen(cmd.c_str(), "r");
  if (!p) return Status(StatusCode::kInternal, "cannot run sbatch");
  std::string out;
  char buf[256];
  while (std::fgets(buf, sizeof buf, p)) out += buf;
  const int status = pclose(p);
  while (!out.empty() && (out.back() == '\n' || out.back() == '\r')) out.pop_back();
  if (status != 0)
    return Status(StatusCode::kInternal, "sbatch failed (" + exit_text(status) + "): " + out +
                                             " (script: " + script + ")");
  return out.substr(0, out.find(';'));  // "jobid[;cluster]"
}

std::string self_executable() {
  std::error_code ec;
  const auto p = fs::read_symlink("/proc/self/exe", ec);
  return ec ? std::string() : p.string();
}

}  // namespace crpgs::experiments
