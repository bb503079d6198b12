/// @file cli_common.h
/// @brief What every `crpgs` subcommand shares: global options, the registry, config loading,
/// and plain-text tables.
#pragma once

#include <string>
#include <vector>

#include <CLI/CLI.hpp>

#include "crpgs/components.h"
#include "crpgs/config.h"
#include "crpgs/registry.h"

namespace crpgs::cli {

struct GlobalOptions {
  std::vector<std::string> plugin_dirs;  ///< --plugin-dir, searched first
  std::vector<std::string> sets;         ///< --set key.path=value overrides
};

/// Built-ins plus every plugin on the search path.
ComponentRegistry load_registry(const GlobalOptions& g);

/// Loads `path` (or `fallback_yaml` when path is empty), applies --set, resolves against the
/// registry. Errors are returned with file, line, column and YAML path.
StatusOr<Config> load_config(const std::string& path, const GlobalOptions& g,
                             const ComponentRegistry& registry, const std::string& fallback_yaml = "");

/// Prints rows as aligned columns (first row is the header).
void print_table(const std::vector<std::vector<std::string>>& rows, FILE* out = stdout);

/// Prints a Status to stderr as "crpgs: error: ..." and returns exit code 1.
int report_error(const Status& st);

/// Subcommand registration (each in its own .cpp).
void add_plugin_commands(CLI::App& app, GlobalOptions& g);
void add_config_commands(CLI::App& app, GlobalOptions& g);
void add_train_commands(CLI::App& app, GlobalOptions& g);
void add_codec_commands(CLI::App& app, GlobalOptions& g);
void add_sweep_commands(CLI::App& app, GlobalOptions& g);   // cmd_sweep.cpp
void add_report_commands(CLI::App& app, GlobalOptions& g);  // cmd_report.cpp

}  // namespace crpgs::cli
