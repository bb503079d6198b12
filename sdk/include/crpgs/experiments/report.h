/// @file report.h
/// @brief `crpgs report`: collects the metrics.json of a runs directory and writes Markdown
/// tables (RD points per method, BD-rate / BD-PSNR for each pair of methods, bitstream
/// shares), PNG plots drawn by gnuplot (RD curves, PSNR vs training time, size/PSNR vs encode,
/// decode and render time, a bitstream breakdown per method) and one self-contained HTML page.
#pragma once

#include <string>
#include <vector>

#include "crpgs/experiments/run_metrics.h"
#include "crpgs/status.h"

namespace crpgs::experiments {

struct ReportRun {
  std::string id;  ///< run.json id, else the directory relative to the runs directory
  std::string dir;
  std::string method;   ///< run.json method, else metrics.method
  std::string dataset;  ///< run.json dataset, else metrics.dataset
  double rate = NAN;    ///< run.json rate, else metrics.lambda
  int order = 0;        ///< run.json index (sweep order), for a stable method order
  RunMetrics metrics;
};

struct CollectedRuns {
  std::vector<ReportRun> runs;          ///< finished runs
  std::vector<std::string> unfinished;  ///< run dirs (with run.json) without usable metrics
};

/// Walks `runs_dir` recursively for metrics.json (and run.json) files.
StatusOr<CollectedRuns> collect_runs(const std::string& runs_dir);

struct ReportOptions {
  std::string out_dir;              ///< default: RUNS_DIR/report
  std::string gnuplot = "gnuplot";  ///< executable; plots are skipped (with a note) if missing
  bool plots = true;
};

struct ReportOutput {
  std::string markdown;  ///< path of report.md
  std::string html;      ///< path of report.html
  std::vector<std::string> pngs;
  std::vector<std::string> notes;  ///< e.g. "gnuplot not found: no plots"
};

/// True if `gnuplot --version` runs.
bool gnuplot_available(const std::string& gnuplot = "gnuplot");

/// Writes report.md, report.html and the PNGs into opt.out_dir, all atomically.
StatusOr<ReportOutput> write_report(const std::string& runs_dir, const ReportOptions& opt);

/// RFC 4648 base64 (for the data URIs of the HTML page).
std::string base64_encode(const std::string& bytes);

}  // namespace crpgs::experiments
