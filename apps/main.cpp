/// @file main.cpp
/// @brief The `crpgs` command-line tool.

#include <algorithm>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <string>
#include <vector>

#include "cli_common.h"
#include "core/text_list.h"
#include "crpgs/dir_lock.h"
#include "crpgs/runtime.h"
#include "crpgs/version.h"

namespace {

// The commands that compute restart once with the environment they run best under
// (bench/results/train_fern.md: idle threads that sleep, OpenBLAS kernels as wide as the CPU).
void restart_for_compute_commands(int argc, char** argv) {
  static const char* const kComputeCommands[] = {"train",  "eval",   "demo",   "encode",
                                                 "decode", "render", "export", "view"};
  for (int i = 1; i < argc; ++i)
    for (const char* c : kComputeCommands)
      if (std::strcmp(argv[i], c) == 0) return crpgs::restart_with_compute_environment(argv);
}

/// After a parse error: names the command or long option that does not exist and the nearest
/// one that does ("unknown command 'trian', did you mean 'train'?"); CLI11 alone says only that a
/// subcommand is required, or that an argument was not expected.
/// Returns true when it named an unknown command (CLI11's own message would then only say that a
/// subcommand is required, which misleads).
bool explain_unknown_names(const CLI::App& app, int argc, char** argv) {
  const CLI::App* cmd = &app;
  std::vector<std::string> chain;  // the commands that were recognised, e.g. {plugins}
  while (!cmd->get_subcommands().empty()) {
    cmd = cmd->get_subcommands().front();
    chain.push_back(cmd->get_name());
  }
  std::vector<std::string> commands;
  for (const CLI::App* sub : cmd->get_subcommands([](const CLI::App*) { return true; }))
    commands.push_back(sub->get_name());
  std::vector<std::string> options;
  for (const CLI::App* a = cmd; a; a = a->get_parent())
    for (const CLI::Option* o : a->get_options())
      for (const std::string& n : o->get_lnames()) options.push_back("--" + n);
  const std::string where = "crpgs" + (chain.empty() ? "" : " " + crpgs::join(chain, " "));
  size_t recognised = 0;
  for (int i = 1; i < argc; ++i) {
    const std::string arg = argv[i];
    if (arg.rfind("--", 0) == 0 && arg.size() > 2) {
      const std::string name = arg.substr(0, arg.find('='));
      if (std::find(options.begin(), options.end(), name) == options.end())
        std::fprintf(stderr, "crpgs: error: unknown option '%s' for '%s'%s\n", name.c_str(),
                     where.c_str(), crpgs::did_you_mean(name, options).c_str());
    } else if (recognised < chain.size() && arg == chain[recognised]) {
      ++recognised;
    } else if (!commands.empty() && !arg.empty() && arg[0] != '-' && argv[i - 1][0] != '-') {
      // A word where a command is expected (not an option's value).
      std::fprintf(stderr, "crpgs: error: unknown command '%s' for '%s'%s (commands: %s)\n",
                   arg.c_str(), where.c_str(), crpgs::did_you_mean(arg, commands).c_str(),
                   crpgs::join(commands).c_str());
      return true;
    }
  }
  return false;
}

}  // namespace

int main(int argc, char** argv) {
  using namespace crpgs::cli;
  restart_for_compute_commands(argc, argv);
  crpgs::take_handed_over_lock();            // before any thread starts: it edits the environment
  std::setvbuf(stdout, nullptr, _IOLBF, 0);  // logs show progress lines as they happen
  CLI::App app{
      "crpgs: compress 3D Gaussian Splatting scenes with CRP-GS (cross-representation "
      "priors) on the HAC / Scaffold-GS anchor representation"};
  app.require_subcommand(1);
  const auto bi = crpgs::build_info();
  app.set_version_flag("--version", std::string("crpgs ") + bi.version + " (commit " +
                                        bi.git_commit + ", " + bi.compiler + ", libtorch " +
                                        bi.torch_version + ", CUDA " + (bi.cuda ? "on" : "off") +
                                        ")");
  GlobalOptions g;
  app.add_option("--plugin-dir", g.plugin_dirs,
                 "extra plugin directory, searched before CRPGS_PLUGIN_PATH and the install dir "
                 "(repeatable)");
  app.fallthrough();  // `crpgs plugins --plugin-dir D` as well as `crpgs --plugin-dir D plugins`
  add_plugin_commands(app, g);
  add_config_commands(app, g);
  add_train_commands(app, g);
  add_codec_commands(app, g);
  add_render_commands(app, g);
  add_sweep_commands(app, g);
  add_report_commands(app, g);
  add_export_commands(app, g);
  add_view_commands(app, g);
  try {
    app.parse(argc, argv);
  } catch (const CLI::ParseError& e) {
    // --help/--version (0) and a command's own exit status (RuntimeError) pass through.
    if (e.get_exit_code() == 0 || dynamic_cast<const CLI::RuntimeError*>(&e)) return app.exit(e);
    // A usage error: exit status 2, as getopt-style tools and argparse use.
    if (!explain_unknown_names(app, argc, argv)) app.exit(e);
    return 2;
  } catch (const crpgs::StatusError& e) {
    return report_error(e.status);
  } catch (const std::exception& e) {
    std::fprintf(stderr, "crpgs: error: %s\n", e.what());
    return 1;
  }
  return 0;
}
