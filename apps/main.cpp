/// @file main.cpp
/// @brief The `crpgs` command-line tool.
#include <unistd.h>

#include <cstdio>
#include <cstdlib>
#include <cstring>

#include "cli_common.h"
#include "crpgs/version.h"

namespace {

// libgomp and OpenBLAS each keep their idle threads spinning, and read how long when they load,
// before main(). With both pools spinning on 2 cores each steals the other's core: fern's steady
// phase ran 1.2x faster with idle threads that sleep (bench/results/train_fern.md). The commands
// that compute therefore restart once with that setting, unless the user chose one.
void restart_with_idle_threads_that_sleep(int argc, char** argv) {
  static const char* const kComputeCommands[] = {"train",  "eval",   "demo",  "encode",
                                                 "decode", "render", "export"};
  bool compute = false;
  for (int i = 1; i < argc && !compute; ++i)
    for (const char* c : kComputeCommands) compute = compute || std::strcmp(argv[i], c) == 0;
  if (!compute) return;
  bool changed = false;
  for (const auto& [name, value] :
       {std::pair{"OMP_WAIT_POLICY", "PASSIVE"}, std::pair{"OPENBLAS_THREAD_TIMEOUT", "4"}})
    if (!std::getenv(name)) changed = setenv(name, value, 0) == 0 || changed;
  if (changed) execv("/proc/self/exe", argv);  // if it fails, run on as we are
}

}  // namespace

int main(int argc, char** argv) {
  using namespace crpgs::cli;
  restart_with_idle_threads_that_sleep(argc, argv);
  std::setvbuf(stdout, nullptr, _IOLBF, 0);  // logs show progress lines as they happen
  CLI::App app{
      "crpgs: compress 3D Gaussian Splatting scenes with CRP-GS (cross-representation "
      "priors) on the HAC / Scaffold-GS anchor representation"};
  app.require_subcommand(1);
  const auto bi = crpgs::build_info();
  app.set_version_flag("--version", std::string("crpgs ") + bi.version + " (" + bi.compiler +
                                        ", libtorch " + bi.torch_version + ", CUDA " +
                                        (bi.cuda ? "on" : "off") + ")");
  GlobalOptions g;
  app.add_option("--plugin-dir", g.plugin_dirs,
                 "extra plugin directory, searched before CRPGS_PLUGIN_PATH and the install dir "
                 "(repeatable)");
  add_plugin_commands(app, g);
  add_config_commands(app, g);
  add_train_commands(app, g);
  add_codec_commands(app, g);
  add_render_commands(app, g);
  add_sweep_commands(app, g);
  add_report_commands(app, g);
  add_export_commands(app, g);
  try {
    app.parse(argc, argv);
  } catch (const CLI::ParseError& e) {
    return app.exit(e);
  } catch (const crpgs::StatusError& e) {
    return report_error(e.status);
  } catch (const std::exception& e) {
    std::fprintf(stderr, "crpgs: error: %s\n", e.what());
    return 1;
  }
  return 0;
}
