/// @file cmd_plugins.cpp
/// @brief `crpgs plugins`, `crpgs plugins describe TYPE`, `crpgs config check FILE`.
#include <string>

#include "cli_common.h"
#include "core/text_list.h"

namespace crpgs::cli {
namespace {

std::string version_of(const ComponentInfo& c) {
  return std::to_string(c.version_major) + "." + std::to_string(c.version_minor);
}

int list_plugins(const GlobalOptions& g) {
  ComponentRegistry r = load_registry(g);
  std::vector<std::vector<std::string>> rows = {{"KIND", "TYPE", "VERSION", "ID", "PATH"}};
  for (const auto& c : r.components())
    rows.push_back({kind_name(c.kind), c.type, version_of(c), c.id, c.path});
  std::printf("Components (%zu):\n", r.components().size());
  print_table(rows);
  std::printf("\nSearched, in order:\n");
  for (const auto& d : r.searched_dirs()) std::printf("  %s\n", d.c_str());
  if (!r.rejected().empty()) {
    std::printf("\nRejected files (%zu):\n", r.rejected().size());
    for (const auto& x : r.rejected())
      std::printf("  %s\n    %s\n", x.path.c_str(), x.reason.c_str());
  }
  return 0;
}

int describe(const GlobalOptions& g, const std::string& type, const std::string& kind) {
  ComponentRegistry r = load_registry(g);
  int shown = 0;
  for (const auto& c : r.components()) {
    if (c.type != type || (!kind.empty() && kind != kind_name(c.kind))) continue;
    if (shown++) std::printf("\n");
    std::printf("%s '%s' %s (%s)\n  id: %s\n  built with: %s, libtorch %s, CUDA %s\n\n",
                kind_name(c.kind), c.type.c_str(), version_of(c).c_str(), c.path.c_str(),
                c.id.c_str(), c.build.compiler, c.build.torch_version, c.build.cuda ? "on" : "off");
    std::vector<std::vector<std::string>> rows = {{"KEY", "TYPE", "DEFAULT", "EXPECTED", "DOC"}};
    for (const auto& p : c.schema.params()) {
      YAML::Emitter e;
      e << YAML::Flow << p.default_value;
      rows.push_back({p.key, param_type_name(p.type), e.c_str(), p.expected(), p.doc});
    }
    if (rows.size() == 1) rows.push_back({"(no parameters)", "", "", "", ""});
    print_table(rows);
  }
  if (!shown) {
    std::vector<std::string> types;
    for (const auto& c : r.components()) {
      if (c.type == type)  // there, but of another kind than --kind asked for
        return report_error(Status(StatusCode::kNotFound, "'" + type + "' is of kind " +
                                                              kind_name(c.kind) + ", not " + kind));
      types.push_back(c.type);
    }
    return report_error(Status(StatusCode::kNotFound, "no component of type '" + type + "'" +
                                                          did_you_mean(type, types) +
                                                          " (available: " + join(types) + ")"));
  }
  return 0;
}

}  // namespace

void add_plugin_commands(CLI::App& app, GlobalOptions& g) {
  auto* plugins = app.add_subcommand("plugins",
                                     "List the components found (built-in and plugins), "
                                     "where plugins were searched, and why files were rejected");
  plugins->callback([&g, plugins] {
    if (plugins->get_subcommands().empty()) throw CLI::RuntimeError(list_plugins(g));
  });
  auto* desc = plugins->add_subcommand("describe", "Print the config schema of a component type");
  static std::string type, kind;
  desc->add_option("TYPE", type, "component type, e.g. cpu, identity, hash_grid")->required();
  desc->add_option("--kind", kind,
                   "entropy | context | features | rasterizer, when a type name exists in "
                   "several kinds (link strategies are of kind context)")
      ->check(CLI::IsMember({"entropy", "context", "features", "rasterizer"}));
  desc->callback([&g] { throw CLI::RuntimeError(describe(g, type, kind)); });
}

void add_config_commands(CLI::App& app, GlobalOptions& g) {
  auto* config = app.add_subcommand("config", "Work with YAML run configurations");
  config->require_subcommand(1);
  auto* check = config->add_subcommand(
      "check",
      "Validate a config against every schema (core sections and components) and print "
      "the fully resolved config");
  static std::string file;
  static bool quiet = false;
  check->add_option("FILE", file, "YAML config")->required();
  check->add_option("--set", g.sets, "override a key: --set train.iterations=1000 (repeatable)");
  check->add_flag("-q,--quiet", quiet, "only the verdict");
  check->callback([&g] {
    ComponentRegistry r = load_registry(g);
    auto cfg = load_config(file, g.sets, r);
    if (!cfg.ok()) throw CLI::RuntimeError(report_error(cfg.status()));
    if (!quiet) std::printf("%s", cfg->to_yaml().c_str());
    std::fprintf(stderr, "%s: ok\n", file.c_str());
  });
}

}  // namespace crpgs::cli
