/// @file version.h
/// @brief SDK and plugin-ABI versions.
#pragma once

#define CRPGS_VERSION_MAJOR 0
#define CRPGS_VERSION_MINOR 1
#define CRPGS_VERSION_PATCH 0
#define CRPGS_VERSION_STRING "0.1.0"

// Plugin ABI history (bump on any change to plugin_abi.h or to a component interface header):
//   1: first version: crpgs_plugin_v1() descriptor, YAML schema, create/destroy with status.
//   2: ContextModel::forward_partial.
//   3: ContextModel::forward_portable.
#define CRPGS_PLUGIN_ABI_VERSION 3

namespace crpgs {
/// Compiled-in features and toolchain, e.g. for `crpgs --version`.
struct BuildInfo {
  const char* version;
  const char*
      git_commit;  ///< `git describe --always --dirty` of the sources; "unknown" outside git
  const char* compiler;
  const char* torch_version;
  bool cuda;
};
BuildInfo build_info();
}  // namespace crpgs
