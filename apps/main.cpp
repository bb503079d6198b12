/// @file main.cpp
/// @brief The `crpgs` command-line tool.
#include <cstdio>

#include "cli_common.h"
#include "crpgs/version.h"

int main(int argc, char** argv) {
  using namespace crpgs::cli;
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
