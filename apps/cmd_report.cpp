/// @file cmd_report.cpp
/// @brief `crpgs report`: tables, BD-rate and plots from a runs directory.
#include "cli_common.h"
#include "crpgs/experiments/report.h"

namespace crpgs::cli {

void add_report_commands(CLI::App& app, GlobalOptions& /*g*/) {
  static std::vector<std::string> runs_dirs;
  static experiments::ReportOptions opt;
  static bool no_plots = false;
  auto* cmd = app.add_subcommand(
      "report",
      "Summarise runs directories (from `crpgs sweep`): RD points per method, BD-rate and "
      "BD-PSNR for each pair of methods, RD curves, PSNR vs training time, size/PSNR vs "
      "encode/decode/render time and bitstream breakdowns, as report.md, PNGs (gnuplot) and a "
      "self-contained report.html");
  cmd->add_option("RUNS_DIR", runs_dirs,
                  "directories with the runs' metrics.json files; a run id found again in a "
                  "later one replaces the earlier run, unless it is unfinished (e.g. OUT/runs, the "
                  "records of an earlier report, then a directory of new runs)")
      ->required()
      ->check(CLI::ExistingDirectory);
  cmd->add_option("-o,--output", opt.out_dir,
                  "output directory (default: the first RUNS_DIR/report); it also receives "
                  "OUT/runs/, each reported run's metrics.json, run.json and config.yaml, from "
                  "which the report can be rebuilt");
  cmd->add_flag("--no-plots", no_plots, "tables only");
  cmd->callback([] {
    opt.plots = !no_plots;
    auto out = experiments::write_report(runs_dirs, opt);
    if (!out.ok()) throw CLI::RuntimeError(report_error(out.status()));
    for (const auto& n : out->notes) std::fprintf(stderr, "crpgs: note: %s\n", n.c_str());
    std::printf("report: %s\n        %s\nruns:   %s\n", out->markdown.c_str(), out->html.c_str(),
                out->records.c_str());
    for (const auto& p : out->pngs) std::printf("plot:   %s\n", p.c_str());
  });
}

}  // namespace crpgs::cli
