/// @file report.cpp
#include "crpgs/experiments/report.h"

#include <stdlib.h>

#include <algorithm>
#include <cerrno>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <map>
#include <set>

#include "core/text_list.h"
#include "crpgs/atomic_file.h"
#include "crpgs/experiments/bd_rate.h"
#include "io/json.h"

namespace crpgs::experiments {
namespace {
namespace fs = std::filesystem;

using Table = std::vector<std::vector<std::string>>;  // first row is the header

std::string fmt(const char* f, double v) {
  if (!std::isfinite(v)) return "—";
  char buf[64];
  std::snprintf(buf, sizeof buf, f, v);
  return buf;
}

/// The field's "MB" (HAC's and the survey's tables) is 2^20 bytes: sizes are reported in MiB.
constexpr double kMiB = 1048576.0;

std::string rate_text(double r) {
  return std::isfinite(r) ? g_text(r) : "—";
}

/// λ of a point, with the step scale of a re-encoded one ("0.001 ×2").
std::string rate_text(const ReportRun& r) {
  std::string t = rate_text(r.rate);
  if (std::isfinite(r.metrics.rate_scale)) t += " ×" + g_text(r.metrics.rate_scale);
  return t;
}

std::string mib(double bytes) {
  return fmt("%.4f", bytes / kMiB);
}

// Training seconds, with the device where it was not the CPU: a GPU's minutes and a CPU's hours
// side by side in one table must not read as the methods' cost.
std::string train_time_text(const RunMetrics& m) {
  const std::string& d = m.provenance.device;
  return fmt("%.1f", m.train_seconds) + (d.empty() || d == "cpu" ? "" : " (" + d + ")");
}

std::string count_text(int64_t n) {
  return n >= 0 ? std::to_string(n) : "—";
}

std::string file_part(const std::string& s) {
  std::string out;
  for (char c : s) out += std::isalnum(static_cast<unsigned char>(c)) || c == '-' ? c : '_';
  return out;
}

std::string md_escape(const std::string& s) {
  std::string out;
  for (char c : s) out += c == '|' ? std::string("\\|") : std::string(1, c);
  return out;
}
std::string html_escape(const std::string& s) {
  std::string out;
  for (char c : s) {
    if (c == '<')
      out += "&lt;";
    else if (c == '>')
      out += "&gt;";
    else if (c == '&')
      out += "&amp;";
    else if (c == '"')
      out += "&quot;";
    else
      out += c;
  }
  return out;
}
/// A gnuplot double-quoted string.
std::string gp_quote(const std::string& s) {
  std::string out = "\"";
  for (char c : s) out += (c == '"' || c == '\\') ? std::string("\\") + c : std::string(1, c);
  return out + "\"";
}

std::string md_table(const Table& t) {
  std::string s;
  for (size_t r = 0; r < t.size(); ++r) {
    s += "|";
    for (const auto& c : t[r]) s += " " + md_escape(c) + " |";
    s += "\n";
    if (r == 0) {
      s += "|";
      for (size_t c = 0; c < t[0].size(); ++c) s += c == 0 ? " --- |" : " ---: |";
      s += "\n";
    }
  }
  return s + "\n";
}
std::string html_table(const Table& t) {
  std::string s = "<table>\n";
  for (size_t r = 0; r < t.size(); ++r) {
    s += "<tr>";
    for (const auto& c : t[r])
      s += (r == 0 ? "<th>" : "<td>") + html_escape(c) + (r == 0 ? "</th>" : "</td>");
    s += "</tr>\n";
  }
  return s + "</table>\n";
}

/// Runs a command, returns its exit status and combined output.
int run_capture(const std::string& cmd, std::string& out) {
  FILE* p = popen((cmd + " 2>&1").c_str(), "r");
  if (!p) return -1;
  char buf[512];
  while (std::fgets(buf, sizeof buf, p)) out += buf;
  return pclose(p);
}

std::string shell_quote(const std::string& s) {
  std::string out = "'";
  for (char c : s) out += c == '\'' ? std::string("'\\''") : std::string(1, c);
  return out + "'";
}

/// One report section (a dataset): its runs grouped by method in sweep order.
struct Group {
  std::string dataset;
  std::vector<std::string> methods;
  std::map<std::string, std::vector<const ReportRun*>> by_method;  // sorted by size
};

std::vector<RdPoint> rd_points(const std::vector<const ReportRun*>& runs) {
  std::vector<RdPoint> p;
  for (const auto* r : runs)
    p.push_back({static_cast<double>(r->metrics.size_bytes), r->metrics.psnr_mean});
  return p;
}

/// What of a curve BD-rate uses: its non-dominated points and their PSNR range, so that a "—"
/// in the BD table says which curve is too short or where the ranges miss each other.
std::string front_text(const std::vector<RdPoint>& points) {
  const auto front = pareto_front(points);
  if (front.empty()) return "no points";
  const std::string n =
      std::to_string(front.size()) + (front.size() == 1 ? " point, " : " points, ");
  if (front.size() == 1) return n + fmt("%.3f dB", front[0].psnr);
  return n + fmt("%.3f", front.front().psnr) + "–" + fmt("%.3f dB", front.back().psnr);
}

/// Draws plots with gnuplot: data files and scripts in a scratch dir, each PNG rendered there
/// and then moved into place with write_file_atomic.
class Plotter {
 public:
  Plotter(std::string gnuplot, std::string out_dir, std::string scratch)
      : gnuplot_(std::move(gnuplot)), out_(std::move(out_dir)), tmp_(std::move(scratch)) {}

  /// Writes a data file; returns its path.
  std::string data(const std::string& name, const std::string& text) {
    const std::string path = tmp_ + "/" + name;
    FILE* f = std::fopen(path.c_str(), "w");
    if (f) {
      std::fputs(text.c_str(), f);
      std::fclose(f);
    }
    return path;
  }

  /// Renders `body` (gnuplot commands after the terminal setup) to OUT/png_name.
  Status plot(const std::string& png_name, const std::string& body, int width = 900,
              int height = 600) {
    const std::string tmp_png = tmp_ + "/" + png_name;
    std::string script = "set terminal pngcairo size " + std::to_string(width) + "," +
                         std::to_string(height) + " font \"sans,10\" noenhanced\n";
    script += "set output " + gp_quote(tmp_png) + "\nset grid\nset key outside right top\n";
    script += body + "\nunset output\n";
    const std::string script_path = data(png_name + ".gp", script);
    std::string out;
    const int rc = run_capture(shell_quote(gnuplot_) + " " + shell_quote(script_path), out);
    if (rc != 0) {
      // gnuplot's own message, on one line, for a note in the report.
      std::string msg;
      for (char c : out) msg += c == '\n' ? ' ' : c;
      while (!msg.empty() && msg.back() == ' ') msg.pop_back();
      if (msg.size() > 400) msg = msg.substr(0, 400) + "...";
      return Status(StatusCode::kInternal, png_name + " not drawn: gnuplot: " + msg);
    }
    CRPGS_ASSIGN_OR_RETURN(std::vector<uint8_t> png, read_file_bytes(tmp_png));
    CRPGS_RETURN_IF_ERROR(write_file_atomic(out_ + "/" + png_name, png));
    pngs.push_back(png_name);
    return OkStatus();
  }

  std::vector<std::string> pngs;

 private:
  std::string gnuplot_, out_, tmp_;
};

const char* kTimeLabel[3] = {"encode time (s)", "decode time (s)", "render time per view (ms)"};

/// File-name parts for labels (datasets, methods): file_part(label), with a number appended when
/// another label already maps to it ("a b" and "a_b"), so no plot overwrites another's.
class FileNames {
 public:
  const std::string& operator()(const std::string& label) {
    auto it = assigned_.find(label);
    if (it != assigned_.end()) return it->second;
    std::string part = file_part(label);
    for (int n = 2; !used_.insert(part).second; ++n)
      part = file_part(label) + "_" + std::to_string(n);
    return assigned_[label] = part;
  }

 private:
  std::map<std::string, std::string> assigned_;
  std::set<std::string> used_;
};

/// Draws a group's plots. A plot gnuplot cannot draw becomes a note, and the other plots and the
/// tables are still written; panels with no finite values are left out rather than failing.
void plots_for_group(Plotter& p, const Group& g, FileNames& datasets, FileNames& breakdowns,
                     std::vector<std::string>& names, std::vector<std::string>& notes) {
  const std::string ds = datasets(g.dataset);
  auto draw = [&](const std::string& name, const std::string& body, int w, int h) {
    Status st = p.plot(name, body, w, h);
    if (st.ok())
      names.push_back(name);
    else
      notes.push_back(st.message());
  };
  // Data files: one per method: size_MiB psnr enc dec render_ms (NaN: not measured; size 0, a
  // run without a bitstream, is NaN too, as log scales cannot show it).
  auto nan_text = [](double v) { return std::isfinite(v) ? std::to_string(v) : "NaN"; };
  std::vector<std::string> files;
  // Per time column: a run with it and a PSNR, a run with it and a size (the two panel rows).
  bool any_size = false, with_psnr[3] = {false, false, false}, with_size[3] = {false, false, false};
  for (size_t i = 0; i < g.methods.size(); ++i) {
    std::string text = "# size_MiB psnr encode_s decode_s render_ms\n";
    for (const auto* r : g.by_method.at(g.methods[i])) {
      const auto& m = r->metrics;
      const double t[3] = {m.encode_seconds, m.decode_seconds, m.render_seconds_per_view * 1e3};
      any_size |= m.size_bytes > 0;
      for (int k = 0; k < 3; ++k) {
        with_psnr[k] |= std::isfinite(t[k]) && std::isfinite(m.psnr_mean);
        with_size[k] |= std::isfinite(t[k]) && m.size_bytes > 0;
      }
      text += nan_text(m.size_bytes > 0 ? m.size_bytes / kMiB : NAN) + " " + nan_text(m.psnr_mean) +
              " " + nan_text(t[0]) + " " + nan_text(t[1]) + " " + nan_text(t[2]) + "\n";
    }
    files.push_back(p.data(ds + "_m" + std::to_string(i) + ".dat", text));
  }
  // Each method's points joined in the order of the x column (`smooth unique` sorts by x): the
  // files are in size order, and joining a time axis in that order zig-zags.
  auto series = [&](const std::string& using_clause) {
    std::string s;
    for (size_t i = 0; i < files.size(); ++i)
      s += (i ? ", " : "") + gp_quote(files[i]) + " using " + using_clause +
           " smooth unique with linespoints lw 2 pt 7 title " + gp_quote(g.methods[i]);
    return s;
  };

  // RD curves.
  if (any_size) {
    std::string b = "set title " + gp_quote("Rate-distortion: " + g.dataset) + "\n";
    b += "set xlabel \"size (MiB, log scale)\"\nset ylabel \"PSNR (dB)\"\nset logscale x\n";
    b += "plot " + series("1:2");
    draw("rd_" + ds + ".png", b, 900, 600);
  } else {
    notes.push_back(g.dataset + ": no RD plot, no run wrote a bitstream");
  }
  // PSNR vs training wall-clock, one line per run.
  {
    std::string plot_list;
    int k = 0;
    std::set<std::string> measures;  // runs of older builds traced the first test view alone
    for (const auto& method : g.methods)
      for (const auto* r : g.by_method.at(method)) {
        if (r->metrics.trace.empty()) continue;
        measures.insert(trace_measure(r->metrics.trace_views));
        std::string text = "# seconds iteration psnr\n";
        for (const auto& t : r->metrics.trace)
          text += nan_text(t.seconds) + " " + std::to_string(t.iteration) + " " + nan_text(t.psnr) +
                  "\n";
        const std::string f = p.data(ds + "_trace" + std::to_string(k++) + ".dat", text);
        const std::string label = method + (std::isfinite(r->rate) ? " λ=" + rate_text(*r) : "");
        plot_list += (plot_list.empty() ? "" : ", ") + gp_quote(f) +
                     " using 1:3 with lines lw 2 title " + gp_quote(label);
      }
    if (!plot_list.empty()) {
      const std::string measure =
          measures.size() == 1 ? *measures.begin() : "per run: see trace_views in metrics.json";
      std::string b = "set title " +
                      gp_quote("Held-out PSNR (" + measure + ") vs training time: " + g.dataset) +
                      "\n";
      b += "set xlabel \"training wall-clock (s)\"\nset ylabel \"PSNR (dB)\"\nplot " + plot_list;
      draw("time_" + ds + ".png", b, 1000, 600);
    }
  }
  // Size and PSNR against encode, decode and render time: the panels that have values.
  {
    std::vector<int> cols;
    bool size_row = false;
    for (int col = 0; col < 3; ++col)
      if (with_psnr[col] || with_size[col]) {
        cols.push_back(col);
        size_row |= with_size[col];
      }
    const int rows = size_row ? 2 : 1;
    if (!cols.empty()) {
      std::string b = "set multiplot layout " + std::to_string(rows) + "," +
                      std::to_string(cols.size()) + " title " +
                      gp_quote("What quality and size cost in time: " + g.dataset) + "\n";
      b += "set key inside bottom right\n";
      for (int row = 0; row < rows; ++row)
        for (int col : cols) {
          if (!(row == 0 ? with_psnr[col] : with_size[col])) {
            b += "set multiplot next\n";  // nothing to draw: an empty panel, not an error
            continue;
          }
          b += "set xlabel " + gp_quote(kTimeLabel[col]) + "\n";
          b += std::string("set ylabel ") + (row == 0 ? "\"PSNR (dB)\"" : "\"size (MiB)\"") + "\n";
          b += "plot " + series(std::to_string(3 + col) + ":" + (row == 0 ? "2" : "1")) + "\n";
        }
      b += "unset multiplot";
      draw("cost_" + ds + ".png", b, 500 * int(cols.size()), 450 * rows);
    }
  }
  // Bitstream breakdown per method: one stacked bar per run, in % of its size.
  for (size_t i = 0; i < g.methods.size(); ++i) {
    const auto& runs = g.by_method.at(g.methods[i]);
    std::string text = "run";
    for (int c = 0; c < kNumBitstreamCategories; ++c)
      text += std::string(" ") + category_name(static_cast<BitstreamCategory>(c));
    text += "\n";
    bool any = false;
    for (const auto* r : runs) {
      uint64_t total = 0;
      for (auto v : r->metrics.breakdown) total += v;
      if (total == 0) continue;
      any = true;
      std::string label = std::isfinite(r->rate) ? "λ=" + rate_text(*r)
                                                 : fmt("%.2fMiB", r->metrics.size_bytes / kMiB);
      text += gp_quote(label);
      for (auto v : r->metrics.breakdown) text += " " + std::to_string(100.0 * v / total);
      text += "\n";
    }
    if (!any) continue;
    const std::string f = p.data(ds + "_bd" + std::to_string(i) + ".dat", text);
    std::string b =
        "set title " + gp_quote("Bitstream breakdown: " + g.methods[i] + " on " + g.dataset) + "\n";
    b += "set style data histograms\nset style histogram rowstacked\n"
         "set style fill solid 0.85 border -1\nset boxwidth 0.7\nset yrange [0:100]\n"
         "set ylabel \"share of the bitstream (%)\"\nset key outside right top invert\n"
         "colors = \"#4e79a7 #f28e2b #76b7b2 #e15759 #59a14f #edc948 #b07aa1 #9c755f #bab0ac\"\n";
    b += "plot for [c=2:" + std::to_string(kNumBitstreamCategories + 1) + "] " + gp_quote(f) +
         " using c:xtic(1) title columnheader(c) lc rgb word(colors, c - 1)";
    draw("breakdown_" + breakdowns(g.dataset + "\n" + g.methods[i]) + ".png", b, 900, 600);
  }
}

/// What a curve is compared with: a re-encoded curve's own training method where the scene has
/// it (one model against models trained per λ), else the scene's first method.
const std::string& reference_method(const Group& g, const std::string& method) {
  const std::string& base = g.by_method.at(method).front()->metrics.base_method;
  const auto it = std::find(g.methods.begin(), g.methods.end(), base);
  return base.empty() || it == g.methods.end() ? g.methods[0] : *it;
}

/// The summary over scenes, as the paper's table: per scene and method the low- and high-rate
/// points (the smallest and the largest file) and the BD figures against the scene's first
/// method (the sweep's first config), then each method's mean BD over the scenes that have one.
Table summary_table(const std::vector<Group>& groups) {
  Table t = {{"scene", "method", "low rate: size (MiB)", "PSNR (dB)", "SSIM",
              "high rate: size (MiB)", "PSNR (dB)", "SSIM", "BD-rate (%)", "BD-PSNR (dB)",
              "BD over"}};
  std::vector<std::string> methods;  // first-seen order over all scenes
  std::map<std::string, std::vector<double>> rates, psnrs;
  for (const auto& g : groups) {
    for (const auto& method : g.methods) {
      const std::string& reference = reference_method(g, method);
      const auto& runs = g.by_method.at(method);
      const auto &lo = runs.front()->metrics, &hi = runs.back()->metrics;
      std::vector<std::string> row = {g.dataset,
                                      method,
                                      mib(lo.size_bytes),
                                      fmt("%.3f", lo.psnr_mean),
                                      fmt("%.4f", lo.ssim_mean),
                                      mib(hi.size_bytes),
                                      fmt("%.3f", hi.psnr_mean),
                                      fmt("%.4f", hi.ssim_mean)};
      if (method == reference) {
        row.insert(row.end(), {"anchor", "", ""});
      } else {
        if (std::find(methods.begin(), methods.end(), method) == methods.end())
          methods.push_back(method);
        const auto anchor = rd_points(g.by_method.at(reference));
        const auto test = rd_points(runs);
        const auto rate = bd_rate_figure(anchor, test);
        const auto psnr = bd_psnr_figure(anchor, test);
        if (rate) rates[method].push_back(rate->value);
        if (psnr) psnrs[method].push_back(psnr->value);
        row.push_back(rate ? fmt("%+.2f", rate->value) : "—");
        row.push_back(psnr ? fmt("%+.3f", psnr->value) : "—");
        row.push_back(rate ? std::to_string(rate->anchor_points) + "/" +
                                 std::to_string(rate->test_points) + " points, " +
                                 fmt("%.3f", rate->lo) + "–" + fmt("%.3f dB", rate->hi)
                           : front_text(anchor) + " / " + front_text(test));
        if (reference != g.methods[0]) row.back() += " (against " + reference + ")";
      }
      t.push_back(row);
    }
  }
  auto mean = [](const std::vector<double>& v) {
    double sum = 0;
    for (double x : v) sum += x;
    return v.empty() ? NAN : sum / double(v.size());
  };
  for (const auto& method : methods) {
    const auto &r = rates[method], &p = psnrs[method];
    t.push_back({"mean", method, "", "", "", "", "", "", fmt("%+.2f", mean(r)),
                 fmt("%+.3f", mean(p)),
                 std::to_string(r.size()) + (r.size() == 1 ? " scene" : " scenes")});
  }
  return t;
}

/// A CSV field: quoted when it holds a comma, a quote or a line break.
std::string csv_field(const std::string& s) {
  if (s.find_first_of(",\"\r\n") == std::string::npos) return s;
  std::string out = "\"";
  for (char c : s) out += c == '"' ? std::string("\"\"") : std::string(1, c);
  return out + "\"";
}

/// One scene's runs in the 3DGS compression survey's per-scene CSV layout. LPIPS is not computed
/// (it needs pretrained weights), so its column is empty, as the survey leaves unknown values.
std::string survey_csv(const Group& g) {
  std::string csv = "Submethod,PSNR,SSIM,LPIPS,Size [Bytes],#Gaussians\n";
  for (const auto& method : g.methods)
    for (const auto* r : g.by_method.at(method)) {
      const auto& m = r->metrics;
      const std::string name =
          method + (std::isfinite(r->rate) ? " lambda=" + rate_text(*r) : std::string());
      csv += csv_field(name) + "," + fmt("%.3f", m.psnr_mean) + "," + fmt("%.4f", m.ssim_mean) +
             ",," + std::to_string(m.size_bytes) + "," +
             (m.gaussians >= 0 ? std::to_string(m.gaussians) : std::string()) + "\n";
    }
  return csv;
}

// A run id as a relative path inside a records directory: no root, no "..", not empty.
bool safe_relative_id(const std::string& id) {
  const fs::path p(id);
  if (id.empty() || p.is_absolute() || p.has_root_name()) return false;
  for (const auto& part : p)
    if (part == ".." || part == ".") return false;
  return true;
}

// Runs of an earlier runs directory come first (its first method is the anchor of the BD
// figures), then by their index in their sweep.
constexpr int64_t kRunsPerDirectory = 1000000000;  // above any index run.json may hold

// Marks a report's records directory, so that a later report reading the runs directory that
// holds it does not take the old copies for runs.
constexpr const char* kRecordsMarker = ".crpgs-report-records";

// Copies each run's records into OUT/runs/<id>/ through a scratch directory swapped in at the
// end, so the directory holds exactly the runs of this report even when it was also an input.
Status write_records(const std::vector<ReportRun>& runs, const std::string& out_dir) {
  const fs::path final_dir = fs::path(out_dir) / "runs", scratch = final_dir.string() + ".new",
                 previous = final_dir.string() + ".old";
  std::error_code ec;
  fs::remove_all(scratch, ec);
  fs::remove_all(previous, ec);
  fs::create_directories(scratch, ec);
  if (!ec)
    CRPGS_RETURN_IF_ERROR(
        write_file_atomic((scratch / kRecordsMarker).string(), std::string_view()));
  for (size_t i = 0; i < runs.size(); ++i) {
    const fs::path dir =
        scratch / (safe_relative_id(runs[i].id) ? runs[i].id : "run-" + std::to_string(i));
    fs::create_directories(dir, ec);
    if (ec)
      return Status(StatusCode::kIoError, "cannot create " + dir.string() + ": " + ec.message());
    for (const char* name : {"metrics.json", "run.json", "config.yaml"}) {
      const std::string from = runs[i].dir + "/" + name;
      if (!fs::exists(from, ec)) continue;
      CRPGS_ASSIGN_OR_RETURN(auto bytes, read_file_bytes(from));
      CRPGS_RETURN_IF_ERROR(write_file_atomic((dir / name).string(), bytes));
    }
  }
  if (fs::exists(final_dir, ec)) fs::rename(final_dir, previous, ec);
  if (!ec) fs::rename(scratch, final_dir, ec);
  if (ec)
    return Status(StatusCode::kIoError,
                  "cannot move the run records into " + final_dir.string() + ": " + ec.message());
  fs::remove_all(previous, ec);
  return OkStatus();
}

}  // namespace

std::string base64_encode(const std::string& in) {
  static const char* kAlpha = "ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
  std::string out;
  out.reserve((in.size() + 2) / 3 * 4);
  size_t i = 0;
  for (; i + 2 < in.size(); i += 3) {
    const uint32_t v = (uint8_t(in[i]) << 16) | (uint8_t(in[i + 1]) << 8) | uint8_t(in[i + 2]);
    for (int s = 18; s >= 0; s -= 6) out += kAlpha[(v >> s) & 63];
  }
  if (i < in.size()) {
    uint32_t v = uint8_t(in[i]) << 16;
    if (i + 1 < in.size()) v |= uint8_t(in[i + 1]) << 8;
    out += kAlpha[(v >> 18) & 63];
    out += kAlpha[(v >> 12) & 63];
    out += i + 1 < in.size() ? kAlpha[(v >> 6) & 63] : '=';
    out += '=';
  }
  return out;
}

StatusOr<CollectedRuns> collect_runs(const std::vector<std::string>& runs_dirs,
                                     const std::string& exclude) {
  CollectedRuns out;
  std::error_code ec;
  const fs::path excluded = exclude.empty() ? fs::path() : fs::weakly_canonical(exclude, ec);
  for (size_t dir_index = 0; dir_index < runs_dirs.size(); ++dir_index) {
    const std::string& runs_dir = runs_dirs[dir_index];
    if (!fs::is_directory(runs_dir, ec))
      return Status(StatusCode::kNotFound, runs_dir + ": not a directory");
    std::vector<fs::path> dirs;
    for (auto it = fs::recursive_directory_iterator(runs_dir, ec);
         !ec && it != fs::recursive_directory_iterator(); it.increment(ec)) {
      std::error_code path_ec;
      if (it->is_directory(path_ec) &&
          ((!excluded.empty() && fs::weakly_canonical(it->path(), path_ec) == excluded) ||
           fs::exists(it->path() / kRecordsMarker, path_ec))) {
        it.disable_recursion_pending();  // this report's output, or an older report's records
        continue;
      }
      const auto name = it->path().filename();
      if (it->is_regular_file(path_ec) && (name == "metrics.json" || name == "run.json"))
        dirs.push_back(it->path().parent_path());
    }
    // A walk that stopped early would leave runs out of the tables without a word.
    if (ec) return Status(StatusCode::kIoError, "cannot read " + runs_dir + ": " + ec.message());
    std::sort(dirs.begin(), dirs.end());
    dirs.erase(std::unique(dirs.begin(), dirs.end()), dirs.end());
    for (const auto& d : dirs) {
      const std::string dir = d.string();
      ReportRun r;
      r.dir = dir;
      r.id = fs::relative(d, runs_dir, ec).string();
      r.order = int64_t(dir_index) * kRunsPerDirectory;
      auto m = read_run_metrics(dir + "/metrics.json");
      const bool finished = m.ok() && !run_marked_started(dir);
      if (finished) {
        // A re-encoded file (`crpgs encode --rate-scales`) after its runs directory's runs:
        // its curve never becomes a scene's first method, the BD anchor.
        if (std::isfinite(m->rate_scale)) r.order += kRunsPerDirectory - 1;
        r.metrics = std::move(m).value();
        r.method = r.metrics.method;
        r.dataset = r.metrics.dataset;
        r.rate = r.metrics.lambda;
      }
      if (fs::exists(d / "run.json", ec)) {
        auto info = io::read_json_file(dir + "/run.json");
        if (info.ok()) {
          const auto& j = info.value();
          if (auto* v = j.find("id"); v && v->is_string()) r.id = v->string;
          if (auto* v = j.find("method"); v && v->is_string()) r.method = v->string;
          if (auto* v = j.find("dataset"); v && v->is_string()) r.dataset = v->string;
          if (auto* v = j.find("rate"); v && v->is_number()) r.rate = v->number;
          if (auto* v = j.find("index"); v && v->is_number() && v->number >= 0 && v->number < 1e9)
            r.order = int64_t(dir_index) * kRunsPerDirectory + int64_t(v->number);
        }
      }
      // The same run seen before (an older record, or an unfinished copy): this one replaces
      // it, unless this one is unfinished and the earlier one finished.
      auto same = [&](const ReportRun& x) { return x.id == r.id; };
      if (!finished) {
        if (std::none_of(out.runs.begin(), out.runs.end(), same) &&
            std::find(out.unfinished.begin(), out.unfinished.end(), r.id) == out.unfinished.end())
          out.unfinished.push_back(r.id);
        continue;
      }
      out.runs.erase(std::remove_if(out.runs.begin(), out.runs.end(), same), out.runs.end());
      out.unfinished.erase(std::remove(out.unfinished.begin(), out.unfinished.end(), r.id),
                           out.unfinished.end());
      if (r.method.empty()) r.method = "unnamed";
      if (r.dataset.empty()) r.dataset = "unnamed";
      out.runs.push_back(std::move(r));
    }
  }
  std::stable_sort(out.runs.begin(), out.runs.end(),
                   [](const ReportRun& a, const ReportRun& b) { return a.order < b.order; });
  return out;
}

bool gnuplot_available(const std::string& gnuplot) {
  std::string out;
  return run_capture(shell_quote(gnuplot) + " --version", out) == 0;
}

StatusOr<ReportOutput> write_report(const std::vector<std::string>& runs_dirs,
                                    const ReportOptions& opt_in) {
  if (runs_dirs.empty()) return Status(StatusCode::kInvalidArgument, "no runs directory given");
  ReportOptions opt = opt_in;
  if (opt.out_dir.empty()) opt.out_dir = (fs::path(runs_dirs[0]) / "report").string();
  {
    // A report killed between write_records' two renames left its records only in runs.old.
    const fs::path records = fs::path(opt.out_dir) / "runs", previous = records.string() + ".old";
    std::error_code ec;
    if (!fs::exists(records, ec) && fs::is_directory(previous, ec))
      fs::rename(previous, records, ec);
  }
  CRPGS_ASSIGN_OR_RETURN(CollectedRuns collected, collect_runs(runs_dirs, opt.out_dir));
  if (collected.runs.empty() && collected.unfinished.empty())  // e.g. a level too deep or high
    return Status(StatusCode::kNotFound,
                  "no runs in " + join(runs_dirs) +
                      ": a runs directory holds a directory per run with its metrics.json or "
                      "run.json (as `crpgs sweep` writes them)");
  std::error_code ec;
  fs::create_directories(opt.out_dir, ec);
  if (ec)
    return Status(StatusCode::kInternal, "cannot create " + opt.out_dir + ": " + ec.message());

  // Datasets and methods in sweep order.
  std::vector<Group> groups;
  for (const auto& r : collected.runs) {
    auto g = std::find_if(groups.begin(), groups.end(),
                          [&](const Group& x) { return x.dataset == r.dataset; });
    if (g == groups.end()) {
      groups.push_back({r.dataset, {}, {}});
      g = groups.end() - 1;
    }
    if (!g->by_method.count(r.method)) g->methods.push_back(r.method);
    g->by_method[r.method].push_back(&r);
  }
  for (auto& g : groups)
    for (auto& [m, runs] : g.by_method)
      std::sort(runs.begin(), runs.end(), [](const ReportRun* a, const ReportRun* b) {
        return a->metrics.size_bytes < b->metrics.size_bytes;
      });

  ReportOutput result;
  bool plots = opt.plots && gnuplot_available(opt.gnuplot);
  if (opt.plots && !plots)
    result.notes.push_back("gnuplot not found (" + opt.gnuplot +
                           "): no plots; install the Debian package gnuplot-nox");
  std::string scratch;
  if (plots) {
    fs::path tmp = fs::temp_directory_path(ec);
    if (ec) tmp = "/tmp";  // TMPDIR names nothing usable
    std::string templ = (tmp / "crpgs-report-XXXXXX").string();
    if (mkdtemp(templ.data()))
      scratch = templ;
    else
      result.notes.push_back("no plots: cannot create " + templ + ": " + std::strerror(errno));
  }
  plots = plots && !scratch.empty();
  Plotter plotter(opt.gnuplot, opt.out_dir, scratch);

  std::string summary =
      std::string(runs_dirs.size() > 1 ? "Runs directories: " : "Runs directory: ") +
      join(runs_dirs) + "; " + std::to_string(collected.runs.size()) + " finished runs";
  if (!collected.unfinished.empty())
    summary += ", " + std::to_string(collected.unfinished.size()) + " unfinished (" + [&] {
      std::string s;
      for (size_t i = 0; i < collected.unfinished.size() && i < 10; ++i)
        s += (i ? ", " : "") + collected.unfinished[i];
      return s + (collected.unfinished.size() > 10 ? ", ..." : "");
    }() + ")";
  summary += ".";
  std::string md = "# Sweep report\n\n" + summary + "\n\n";
  std::string html_body = "<h1>Sweep report</h1>\n<p>" + html_escape(summary) + "</p>\n";
  const std::string bd_note =
      "BD-rate: average size change of *test* against *anchor* at equal PSNR (negative is "
      "smaller); BD-PSNR: average PSNR gain at equal size. Dominated points are removed, a PCHIP "
      "is fitted on log(size), and the difference is averaged over the common interval; — means "
      "no common interval (or fewer than 2 points); the fronts are the non-dominated points each "
      "curve keeps, with their PSNR range.\n\n";

  if (std::any_of(groups.begin(), groups.end(),
                  [](const Group& g) { return g.methods.size() > 1; })) {
    std::vector<Group> compared;
    for (const auto& g : groups)
      if (g.methods.size() > 1) compared.push_back(g);
    const Table t = summary_table(compared);
    const std::string note =
        "Low and high rate: each method's smallest and largest file on the scene. BD figures "
        "against the scene's first method (the sweep's first config; a one-model curve, "
        "re-encoded from one trained run at scaled steps, against its own method's per-λ "
        "curve), over the non-dominated points of both curves (anchor/test) and their common "
        "PSNR interval; the mean row "
        "averages the scenes that have a figure. Sizes in MiB (2^20 bytes, the field's \"MB\").";
    md += "## Summary over scenes\n\n" + note + "\n\n" + md_table(t);
    html_body += "<h2>Summary over scenes</h2>\n<p>" + html_escape(note) + "</p>\n" + html_table(t);
  }

  FileNames dataset_files, breakdown_files, csv_files;
  for (const auto& g : groups) {
    {
      const std::string csv = "scene_" + csv_files(g.dataset) + ".csv";
      CRPGS_RETURN_IF_ERROR(write_file_atomic(opt.out_dir + "/" + csv, survey_csv(g)));
      result.csvs.push_back(opt.out_dir + "/" + csv);
    }
    md += "## " + g.dataset + "\n\nIn the survey's CSV layout: [" + "scene_" +
          csv_files(g.dataset) + ".csv](scene_" + csv_files(g.dataset) +
          ".csv)\n\n### Rate–distortion points\n\n";
    html_body += "<h2>" + html_escape(g.dataset) + "</h2>\n<h3>Rate–distortion points</h3>\n";
    Table rd = {{"method", "λ", "size (B)", "size (MiB)", "PSNR (dB)", "SSIM", "anchors",
                 "Gaussians", "train (s)", "encode (s)", "decode (s)", "render (ms/view)",
                 "peak mem (MiB)", "run"}};
    for (const auto& method : g.methods)
      for (const auto* r : g.by_method.at(method)) {
        const auto& m = r->metrics;
        rd.push_back({method, rate_text(*r), std::to_string(m.size_bytes), mib(m.size_bytes),
                      fmt("%.3f", m.psnr_mean), fmt("%.4f", m.ssim_mean), count_text(m.anchors),
                      count_text(m.gaussians), train_time_text(m), fmt("%.3f", m.encode_seconds),
                      fmt("%.3f", m.decode_seconds), fmt("%.2f", m.render_seconds_per_view * 1e3),
                      m.peak_memory_bytes > 0 ? fmt("%.0f", m.peak_memory_bytes / kMiB) : "—",
                      r->id});
      }
    md += md_table(rd);
    html_body += html_table(rd);

    if (g.methods.size() >= 2) {
      Table bd = {{"anchor", "test", "BD-rate (%)", "over PSNR (dB)", "BD-PSNR (dB)",
                   "over size (MiB)", "anchor's front", "test's front"}};
      for (size_t a = 0; a < g.methods.size(); ++a)
        for (size_t t = a + 1; t < g.methods.size(); ++t) {
          const auto pa = rd_points(g.by_method.at(g.methods[a]));
          const auto pt = rd_points(g.by_method.at(g.methods[t]));
          const auto rate = bd_rate_figure(pa, pt);
          const auto psnr = bd_psnr_figure(pa, pt);
          bd.push_back({g.methods[a], g.methods[t], rate ? fmt("%+.2f", rate->value) : "—",
                        rate ? fmt("%.3f", rate->lo) + "–" + fmt("%.3f", rate->hi) : "—",
                        psnr ? fmt("%+.3f", psnr->value) : "—",
                        psnr ? mib(psnr->lo) + "–" + mib(psnr->hi) : "—", front_text(pa),
                        front_text(pt)});
        }
      md += "### BD-rate and BD-PSNR\n\n" + bd_note + md_table(bd);
      html_body +=
          "<h3>BD-rate and BD-PSNR</h3>\n<p>" + html_escape(bd_note) + "</p>\n" + html_table(bd);
    }

    // Every other method against the first (the sweep's first config) at the same rate weight:
    // needs no curve, so an ablation sweep with a single λ per row gets its table too.
    if (g.methods.size() >= 2) {
      const std::string& base = g.methods[0];
      Table same = {{"method", "λ", "size (MiB)", "size vs " + base + " (%)", "PSNR (dB)",
                     "ΔPSNR (dB)", "SSIM"}};
      for (size_t t = 1; t < g.methods.size(); ++t)
        for (const auto* r : g.by_method.at(g.methods[t])) {
          if (std::isfinite(r->metrics.rate_scale)) continue;  // one λ, many points
          const auto& by_base = g.by_method.at(base);
          const auto b = std::find_if(by_base.begin(), by_base.end(), [&](const ReportRun* x) {
            return std::abs(x->rate - r->rate) <= 1e-9 * std::max(std::abs(x->rate), 1e-30);
          });
          if (b == by_base.end()) continue;
          const auto &m = r->metrics, &mb = (*b)->metrics;
          same.push_back(
              {g.methods[t], rate_text(*r), mib(m.size_bytes),
               mb.size_bytes > 0
                   ? fmt("%+.2f", 100.0 * (double(m.size_bytes) / double(mb.size_bytes) - 1))
                   : "—",
               fmt("%.3f", m.psnr_mean), fmt("%+.3f", m.psnr_mean - mb.psnr_mean),
               fmt("%.4f", m.ssim_mean)});
        }
      if (same.size() > 1) {
        const std::string title = "Against " + base + " at the same λ";
        md += "### " + title + "\n\n" + md_table(same);
        html_body += "<h3>" + html_escape(title) + "</h3>\n" + html_table(same);
      }
    }

    // Between neighbouring points of a curve: what +0.1 dB costs in size and in time.
    Table cost = {{"method", "from λ", "to λ", "ΔPSNR (dB)", "size per +0.1 dB (KiB)",
                   "train per +0.1 dB (s)", "decode per +0.1 dB (s)",
                   "render per +0.1 dB (ms/view)"}};
    for (const auto& method : g.methods) {
      const auto& runs = g.by_method.at(method);
      for (size_t i = 1; i < runs.size(); ++i) {
        const auto &a = runs[i - 1]->metrics, &b = runs[i]->metrics;
        const double dp = b.psnr_mean - a.psnr_mean;
        if (!(dp > 0)) continue;  // a dominated step costs without gaining
        const double k = 0.1 / dp;
        cost.push_back(
            {method, rate_text(*runs[i - 1]), rate_text(*runs[i]), fmt("%+.3f", dp),
             fmt("%+.1f", k * (double(b.size_bytes) - double(a.size_bytes)) / 1024.0),
             a.provenance.device == b.provenance.device
                 ? fmt("%+.1f", k * (b.train_seconds - a.train_seconds))
                 : "— (" + a.provenance.device + " vs " + b.provenance.device + ")",
             fmt("%+.3f", k * (b.decode_seconds - a.decode_seconds)),
             fmt("%+.3f", k * 1e3 * (b.render_seconds_per_view - a.render_seconds_per_view))});
      }
    }
    if (cost.size() > 1) {
      md += "### What each +0.1 dB costs (between neighbouring RD points)\n\n" + md_table(cost);
      html_body +=
          "<h3>What each +0.1 dB costs (between neighbouring RD points)</h3>\n" + html_table(cost);
    }

    Table shares = {{"method"}};
    for (int c = 0; c < kNumBitstreamCategories; ++c)
      shares[0].push_back(category_name(static_cast<BitstreamCategory>(c)));
    for (const auto& method : g.methods) {
      std::vector<double> sum(kNumBitstreamCategories, 0.0);
      int n = 0;
      for (const auto* r : g.by_method.at(method)) {
        uint64_t total = 0;
        for (auto v : r->metrics.breakdown) total += v;
        if (total == 0) continue;
        ++n;
        for (int c = 0; c < kNumBitstreamCategories; ++c)
          sum[c] += 100.0 * r->metrics.breakdown[c] / total;
      }
      std::vector<std::string> row = {method};
      for (double s : sum) row.push_back(n ? fmt("%.1f", s / n) : "—");
      shares.push_back(row);
    }
    const std::string share_title = "### Bitstream breakdown (mean share over runs, %)\n\n";
    // Component sections are opaque to the codec: a context's or feature model's own MLP is
    // stored, and counted, with its grid.
    const std::string share_note =
        "hash_grids: the context and feature-model sections (binary hash tables with their own "
        "MLPs: HAC's mlp_grid, SFA's output layer); mlps: the neural Gaussians' MLPs.";
    md += share_title + md_table(shares) + share_note + "\n\n";
    html_body += "<h3>Bitstream breakdown (mean share over runs, %)</h3>\n" + html_table(shares) +
                 "<p>" + html_escape(share_note) + "</p>\n";

    if (plots) {
      std::vector<std::string> names;
      plots_for_group(plotter, g, dataset_files, breakdown_files, names, result.notes);
      if (!names.empty()) {
        md += "### Plots\n\n";
        html_body += "<h3>Plots</h3>\n";
      }
      for (const auto& n : names) {
        md += "![" + n + "](" + n + ")\n\n";
        auto bytes = read_file_bytes(opt.out_dir + "/" + n);
        if (bytes.ok())
          html_body += "<p><img alt=\"" + html_escape(n) + "\" src=\"data:image/png;base64," +
                       base64_encode(std::string(bytes->begin(), bytes->end())) + "\"></p>\n";
      }
    }
  }
  for (const auto& n : result.notes) {
    md += "> " + n + "\n\n";
    html_body += "<p><em>" + html_escape(n) + "</em></p>\n";
  }
  if (!scratch.empty()) fs::remove_all(scratch, ec);

  const std::string html =
      "<!DOCTYPE html>\n<html><head><meta charset=\"utf-8\"><title>crpgs sweep report</title>\n"
      "<style>body{font-family:sans-serif;max-width:1600px;margin:2em auto;padding:0 1em}"
      "table{border-collapse:collapse;margin:1em 0}td,th{border:1px solid #bbb;padding:3px 8px;"
      "text-align:right}td:first-child,th:first-child{text-align:left}img{max-width:100%}"
      "</style></head><body>\n" +
      html_body + "</body></html>\n";
  result.markdown = opt.out_dir + "/report.md";
  result.html = opt.out_dir + "/report.html";
  CRPGS_RETURN_IF_ERROR(write_file_atomic(result.markdown, md));
  CRPGS_RETURN_IF_ERROR(write_file_atomic(result.html, html));
  CRPGS_RETURN_IF_ERROR(write_records(collected.runs, opt.out_dir));
  result.records = opt.out_dir + "/runs";
  for (const auto& n : plotter.pngs) result.pngs.push_back(opt.out_dir + "/" + n);
  return result;
}

}  // namespace crpgs::experiments
