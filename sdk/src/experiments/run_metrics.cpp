/// @file run_metrics.cpp
#include "crpgs/experiments/run_metrics.h"

#include <sys/resource.h>

#include <cmath>
#include <filesystem>
#include <fstream>
#include <thread>

#include "core/time_text.h"
#include "crpgs/atomic_file.h"
#include "crpgs/version.h"
#include "io/json.h"
#include "io/json_writer.h"

namespace crpgs::experiments {
namespace {

using io::JsonValue;

double num(const JsonValue& obj, const char* key, double fallback = NAN) {
  const JsonValue* v = obj.find(key);
  return v && v->is_number() ? v->number : fallback;
}
std::string str(const JsonValue& obj, const char* key) {
  const JsonValue* v = obj.find(key);
  return v && v->is_string() ? v->string : std::string();
}

/// A byte count or a counter: JSON numbers are doubles, exact up to 2^53; anything else (negative,
/// fractional, huge) is refused rather than cast.
StatusOr<uint64_t> count(const JsonValue& obj, const char* key, bool required) {
  const JsonValue* v = obj.find(key);
  if (!v) {
    if (required)
      return Status(StatusCode::kInvalidArgument, std::string("metrics: missing \"") + key + "\"");
    return uint64_t{0};
  }
  if (!v->is_number() || !(v->number >= 0) || v->number > 9007199254740992.0 ||
      v->number != std::floor(v->number))
    return Status(StatusCode::kInvalidArgument,
                  std::string("metrics: \"") + key + "\" must be a whole number in [0, 2^53]");
  return static_cast<uint64_t>(v->number);
}

}  // namespace

const char* category_name(BitstreamCategory c) {
  static const char* const kNames[kNumBitstreamCategories] = {"geometry",   "features", "scaling",
                                                              "offsets",    "masks",    "links",
                                                              "hash_grids", "mlps",     "other"};
  const int i = static_cast<int>(c);
  return i >= 0 && i < kNumBitstreamCategories ? kNames[i] : "other";
}

int64_t peak_rss_bytes() {
  rusage ru{};
  if (getrusage(RUSAGE_SELF, &ru) != 0) return 0;
  return static_cast<int64_t>(ru.ru_maxrss) * 1024;  // Linux reports KiB
}

Provenance this_process_provenance(int64_t seed, int threads, const std::string& device) {
  const BuildInfo b = build_info();
  Provenance p;
  p.version = b.version;
  p.commit = b.git_commit;
  p.libtorch = b.torch_version;
  std::ifstream cpuinfo("/proc/cpuinfo");
  for (std::string line; std::getline(cpuinfo, line);)
    if (line.rfind("model name", 0) == 0 && line.find(':') != std::string::npos) {
      p.cpu = line.substr(line.find(':') + 1);
      p.cpu.erase(0, p.cpu.find_first_not_of(' '));
      break;
    }
  p.cpus = int(std::thread::hardware_concurrency());
  p.threads = threads;
  p.device = device;
  p.seed = seed;
  return p;
}

void fill_means(RunMetrics& m) {
  if (m.views.empty()) return;
  double p = 0, s = 0, r = 0;
  int nr = 0;
  for (const auto& v : m.views) {
    p += v.psnr;
    s += v.ssim;
    if (std::isfinite(v.render_seconds)) r += v.render_seconds, ++nr;
  }
  const double n = static_cast<double>(m.views.size());
  if (std::isnan(m.psnr_mean)) m.psnr_mean = p / n;
  if (std::isnan(m.ssim_mean)) m.ssim_mean = s / n;
  if (std::isnan(m.render_seconds_per_view) && nr > 0) m.render_seconds_per_view = r / nr;
}

std::string to_json(const RunMetrics& in) {
  RunMetrics m = in;
  fill_means(m);
  io::JsonWriter w;
  w.begin_object();
  w.key("format").value(kRunMetricsFormat);
  w.key("method").value(m.method);
  w.key("dataset").value(m.dataset);
  w.key("lambda").value(m.lambda);
  w.key("config_hash").value(m.config_hash);
  w.key("size_bytes").value(m.size_bytes);
  w.key("bitstream").begin_object();
  for (int c = 0; c < kNumBitstreamCategories; ++c)
    w.key(category_name(static_cast<BitstreamCategory>(c))).value(m.breakdown[c]);
  w.end_object();
  if (m.anchors >= 0) w.key("anchors").value(m.anchors);
  if (m.gaussians >= 0) w.key("gaussians").value(m.gaussians);
  w.key("psnr_mean").value(m.psnr_mean);
  w.key("ssim_mean").value(m.ssim_mean);
  w.key("train_seconds").value(m.train_seconds);
  w.key("encode_seconds").value(m.encode_seconds);
  w.key("decode_seconds").value(m.decode_seconds);
  w.key("render_seconds_per_view").value(m.render_seconds_per_view);
  w.key("peak_memory_bytes").value(m.peak_memory_bytes);
  if (!m.phases.empty()) {
    w.key("phases").begin_array();
    for (const auto& ph : m.phases)
      w.raw("{\"name\": " + io::json_quote(ph.name) + ", \"iterations\": " +
            std::to_string(ph.iterations) + ", \"seconds\": " + io::json_number(ph.seconds) + "}");
    w.end_array();
  }
  w.key("views").begin_array();
  for (const auto& v : m.views) {
    w.raw("{\"name\": " + io::json_quote(v.name) + ", \"psnr\": " + io::json_number(v.psnr) +
          ", \"ssim\": " + io::json_number(v.ssim) +
          ", \"render_seconds\": " + io::json_number(v.render_seconds) + "}");
  }
  w.end_array();
  // [seconds, iteration, psnr] triples, one per line.
  w.key("trace").begin_array();
  for (const auto& t : m.trace)
    w.raw("[" + io::json_number(t.seconds) + ", " + std::to_string(t.iteration) + ", " +
          io::json_number(t.psnr) + "]");
  w.end_array();
  w.key("trace_views").begin_array();
  for (const auto& v : m.trace_views) w.raw(io::json_quote(v));
  w.end_array();
  if (!std::isnan(m.rate_scale)) {
    w.key("rate_scale").value(m.rate_scale);
    w.key("base_method").value(m.base_method);
  }
  if (const Provenance& p = m.provenance; !p.version.empty()) {
    w.key("provenance").begin_object();
    w.key("crpgs").value(p.version);
    w.key("commit").value(p.commit);
    w.key("libtorch").value(p.libtorch);
    w.key("cpu").value(p.cpu);
    w.key("cpus").value(int64_t(p.cpus));
    w.key("threads").value(int64_t(p.threads));
    w.key("device").value(p.device);
    w.key("seed").value(p.seed);
    w.end_object();
  }
  w.end_object();
  return w.str();
}

std::string trace_measure(const std::vector<std::string>& views) {
  if (views.empty()) return "held-out views not recorded";
  return views.size() == 1 ? "test view " + views.front()
                           : "mean of " + std::to_string(views.size()) + " test views";
}

StatusOr<RunMetrics> run_metrics_from_json(const std::string& text) {
  CRPGS_ASSIGN_OR_RETURN(JsonValue doc, io::parse_json(text));
  if (!doc.is_object()) return Status(StatusCode::kInvalidArgument, "metrics: not a JSON object");
  if (str(doc, "format") != kRunMetricsFormat)
    return Status(StatusCode::kInvalidArgument,
                  std::string("metrics: \"format\" is not \"") + kRunMetricsFormat + "\"");
  RunMetrics m;
  m.method = str(doc, "method");
  m.dataset = str(doc, "dataset");
  m.lambda = num(doc, "lambda");
  m.config_hash = str(doc, "config_hash");
  CRPGS_ASSIGN_OR_RETURN(m.size_bytes, count(doc, "size_bytes", true));
  if (const JsonValue* b = doc.find("bitstream"); b && b->is_object())
    for (int c = 0; c < kNumBitstreamCategories; ++c) {
      CRPGS_ASSIGN_OR_RETURN(m.breakdown[c],
                             count(*b, category_name(static_cast<BitstreamCategory>(c)), false));
    }
  for (auto [key, out] :
       {std::pair<const char*, int64_t*>{"anchors", &m.anchors}, {"gaussians", &m.gaussians}})
    if (doc.find(key)) {
      CRPGS_ASSIGN_OR_RETURN(const uint64_t n, count(doc, key, true));
      *out = static_cast<int64_t>(n);
    }
  m.psnr_mean = num(doc, "psnr_mean");
  m.ssim_mean = num(doc, "ssim_mean");
  m.train_seconds = num(doc, "train_seconds");
  m.encode_seconds = num(doc, "encode_seconds");
  m.decode_seconds = num(doc, "decode_seconds");
  m.render_seconds_per_view = num(doc, "render_seconds_per_view");
  CRPGS_ASSIGN_OR_RETURN(const uint64_t peak, count(doc, "peak_memory_bytes", false));
  m.peak_memory_bytes = static_cast<int64_t>(peak);
  if (const JsonValue* views = doc.find("views"); views && views->is_array())
    for (const auto& v : views->array) {
      if (!v.is_object()) return Status(StatusCode::kInvalidArgument, "metrics: bad view entry");
      m.views.push_back({str(v, "name"), num(v, "psnr"), num(v, "ssim"), num(v, "render_seconds")});
    }
  if (const JsonValue* phases = doc.find("phases"); phases && phases->is_array())
    for (const auto& ph : phases->array) {
      const double it = ph.is_object() ? num(ph, "iterations") : NAN;
      if (!ph.is_object() || !(it >= 0 && it <= 2147483647.0) || !(num(ph, "seconds") >= 0))
        return Status(StatusCode::kInvalidArgument,
                      "metrics: phases entries must be {name, iterations, seconds}");
      m.phases.push_back({str(ph, "name"), int(it), num(ph, "seconds")});
    }
  if (const JsonValue* trace = doc.find("trace"); trace && trace->is_array())
    for (const auto& t : trace->array) {
      if (!t.is_array() || t.array.size() != 3 || !t.array[0].is_number() ||
          !t.array[1].is_number() || !t.array[2].is_number() || !(t.array[1].number >= 0) ||
          t.array[1].number > 2147483647.0)
        return Status(StatusCode::kInvalidArgument,
                      "metrics: trace entries must be [seconds, iteration, psnr]");
      m.trace.push_back(
          {t.array[0].number, static_cast<int>(t.array[1].number), t.array[2].number});
    }
  if (const JsonValue* names = doc.find("trace_views"); names && names->is_array())
    for (const auto& v : names->array) {
      if (!v.is_string())
        return Status(StatusCode::kInvalidArgument, "metrics: trace_views must be view names");
      m.trace_views.push_back(v.string);
    }
  if (doc.find("rate_scale")) {
    m.rate_scale = num(doc, "rate_scale");
    m.base_method = str(doc, "base_method");
    if (!(m.rate_scale > 0))
      return Status(StatusCode::kInvalidArgument, "metrics: \"rate_scale\" must be > 0");
  }
  if (const JsonValue* p = doc.find("provenance"); p && p->is_object()) {
    Provenance& v = m.provenance;
    v.version = str(*p, "crpgs");
    v.commit = str(*p, "commit");
    v.libtorch = str(*p, "libtorch");
    v.cpu = str(*p, "cpu");
    v.device = str(*p, "device");
    for (auto [key, out] : {std::pair<const char*, int*>{"cpus", &v.cpus}, {"threads", &v.threads}})
      if (const double x = num(*p, key); x >= 0 && x < 1e6) *out = int(x);
    if (const double x = num(*p, "seed"); x >= 0 && x < 9e15) v.seed = int64_t(x);
  }
  if (m.trace_views.empty() && !m.trace.empty() && !m.views.empty())
    m.trace_views = {m.views.front().name};
  fill_means(m);
  if (std::isnan(m.psnr_mean))
    return Status(StatusCode::kInvalidArgument, "metrics: no \"psnr_mean\" and no views");
  return m;
}

Status write_run_metrics(const std::string& path, const RunMetrics& m) {
  return write_file_atomic(path, to_json(m));
}

StatusOr<RunMetrics> read_run_metrics(const std::string& path) {
  CRPGS_ASSIGN_OR_RETURN(std::vector<uint8_t> bytes, read_file_bytes(path));
  auto m = run_metrics_from_json(std::string(bytes.begin(), bytes.end()));
  if (!m.ok()) return Status(m.status().code(), path + ": " + m.status().message());
  return m;
}

namespace {
std::string marker(const std::string& run_dir) {
  return run_dir + "/.running";
}
}  // namespace

Status mark_run_started(const std::string& run_dir) {
  std::error_code ec;
  std::filesystem::remove(run_dir + "/metrics.json", ec);  // stale from an earlier attempt
  return write_file_atomic(marker(run_dir), "started " + local_time_text() + "\n");
}

void mark_run_finished(const std::string& run_dir) {
  std::error_code ec;
  std::filesystem::remove(marker(run_dir), ec);
}

bool run_marked_started(const std::string& run_dir) {
  std::error_code ec;
  return std::filesystem::exists(marker(run_dir), ec);
}

}  // namespace crpgs::experiments
