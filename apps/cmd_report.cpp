/// @file cmd_report.cpp
/// @brief `crpgs report`: tables, BD-rate and plots from a runs directory.
#include "cli_common.h"
#include "crpgs/experiments/report.h"

namespace crpgs::cli {

void add_report_commands(CLI::App& app, GlobalOptions& /*g*/) {
  static std::string runs_dir;
  static experiments::ReportOptions opt;
  static bool no_plots = false;
  auto* cmd = app.add_subcommand(
      "report",
      "Summarise a runs directory (from `crpgs sweep`): RD points per method, BD-rate and "
      "BD-PSNR for each pair of methods, RD curves, PSNR vs training time, size/PSNR vs "
      "encode/decode/render time and bitstream breakdowns, as report.md, PNGs (gnuplot) and a "
      "self-contained report.html");
  cmd->add_option("RUNS_DIR", runs_dir, "directory with the runs' metrics.json files")
      ->required()
      ->check(CLI::ExistingDirectory);
  cmd->add_option("-o,--output", opt.out_dir, "output directory (default: RUNS_DIR/report)");
  cmd->add_flag("--no-plots", no_plots, "tables only");
  cmd->callback([] {
    opt.plots = !no_plots;
    auto out = experiments::write_report(runs_dir, opt);
    if (!out.ok()) throw CLI::RuntimeError(report_error(out.status()));
    for (const auto& n : out->notes) std::fprintf(stderr, "crpgs: note: %s\n", n.c_str());
    std::printf("report: %s\n        %s\n", out->markdown.c_str(), out->html.c_str());
    for (const auto& p : out->pngs) std::printf("plot:   %s\n", p.c_str());
  });
}

}  // namespace crpgs::cli
