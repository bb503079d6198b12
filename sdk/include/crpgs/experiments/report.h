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
  int64_t order = 0;  ///< runs directory, then run.json index (sweep order): a stable method order
  RunMetrics metrics;
};

struct CollectedRuns {
  std::vector<ReportRun> runs;          ///< finished runs
  std::vector<std::string> unfinished;  ///< run dirs (with run.json) without usable metrics
};

/// Walks each of `runs_dirs` recursively for metrics.json (and run.json) files, skipping the
/// directory `exclude` (a report's own output) and any other report's records found inside.
/// A run id seen again replaces the earlier run (a later directory wins, so new runs can be
/// reported together with an older report's records), except that an unfinished copy does not
/// replace a finished run.
StatusOr<CollectedRuns> collect_runs(const std::vector<std::string>& runs_dirs,
                                     const std::string& exclude = "");

struct ReportOptions {
  std::string out_dir;              ///< default: the first runs directory's report/
  std::string gnuplot = "gnuplot";  ///< executable; plots are skipped (with a note) if missing
  bool plots = true;
};

struct ReportOutput {
  std::string markdown;  ///< path of report.md
  std::string html;      ///< path of report.html
  std::string records;   ///< the directory of the runs' records
  std::vector<std::string> pngs;
  std::vector<std::string> csvs;   ///< per scene, the 3DGS compression survey's CSV layout
  std::vector<std::string> notes;  ///< e.g. "gnuplot not found: no plots"
};

/// True if `gnuplot --version` runs.
bool gnuplot_available(const std::string& gnuplot = "gnuplot");

/// Writes report.md, report.html and the PNGs into opt.out_dir, all atomically, and the records
/// of every finished run it reports (metrics.json, run.json, config.yaml: a few KB each) into
/// opt.out_dir/runs/<run id>/, so the report can be rebuilt, or extended with new runs, from the
/// output directory alone: `crpgs report OUT/runs NEW_RUNS -o OUT`.
StatusOr<ReportOutput> write_report(const std::vector<std::string>& runs_dirs,
                                    const ReportOptions& opt);

/// RFC 4648 base64 (for the data URIs of the HTML page).
std::string base64_encode(const std::string& bytes);

}  // namespace crpgs::experiments
