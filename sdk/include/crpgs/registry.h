/// @file registry.h
/// @brief The component registry: built-in components and plugins found on the search path,
/// keyed by (kind, type). Loading checks, in order: the file opens; it exports
/// crpgs_plugin_v1; the ABI version matches; the build info matches the host; the schema parses;
/// (kind, type) is unique. Each failure is recorded with its file and reason.
#pragma once

#include <memory>
#include <string>
#include <vector>

#include <yaml-cpp/yaml.h>

#include "crpgs/plugin_abi.h"
#include "crpgs/schema.h"
#include "crpgs/status.h"

namespace crpgs {

const char* kind_name(crpgs_kind kind);  ///< "entropy", "context", "features", "rasterizer"

/// An open plugin file. Kept alive by every object it created (dlopen'ed with RTLD_NODELETE
/// as well, since autograd nodes defined in a plugin may outlive their objects).
class PluginLibrary {
 public:
  ~PluginLibrary();
  static StatusOr<std::shared_ptr<PluginLibrary>> open(const std::string& path);
  void* symbol(const char* name) const;
  const std::string& path() const { return path_; }

 private:
  PluginLibrary() = default;
  void* handle_ = nullptr;
  std::string path_;
};

struct ComponentInfo {
  crpgs_kind kind;
  std::string type;
  std::string id;
  std::string path;  ///< plugin file, or "built-in"
  int version_major = 0, version_minor = 0;
  crpgs_build_info build{};
  Schema schema;
  const crpgs_plugin_descriptor* descriptor = nullptr;
  std::shared_ptr<PluginLibrary> library;  ///< null for built-ins
};

struct RejectedPlugin {
  std::string path;
  std::string reason;
};

/// The build info this host was compiled with; plugins must match it.
crpgs_build_info host_build_info();

class ComponentRegistry {
 public:
  /// Empty registry; call add_builtins() and/or load_plugins().
  ComponentRegistry() = default;

  /// Registers a built-in descriptor (the rasterizers, the identity feature model).
  Status add_builtin(const crpgs_plugin_descriptor* descriptor);

  /// Scans each directory (non-recursive, then one level of kind subfolders) for *.so files
  /// and loads the plugins in them. Missing directories are recorded as searched, not errors.
  void load_plugins(const std::vector<std::string>& dirs);
  /// Loads one file; the Status says why it was rejected (it is also recorded).
  Status load_plugin_file(const std::string& path);

  const std::vector<ComponentInfo>& components() const { return components_; }
  const std::vector<RejectedPlugin>& rejected() const { return rejected_; }
  const std::vector<std::string>& searched_dirs() const { return searched_; }

  const ComponentInfo* find(crpgs_kind kind, const std::string& type) const;
  std::vector<std::string> types(crpgs_kind kind) const;

  /// Builds a component from its resolved config block (as produced by Config::resolve).
  /// The returned object keeps its plugin library loaded.
  StatusOr<std::shared_ptr<void>> create_raw(crpgs_kind kind, const YAML::Node& resolved_block,
                                             const crpgs_create_args& args) const;

 private:
  Status add(ComponentInfo info);
  std::vector<ComponentInfo> components_;
  std::vector<RejectedPlugin> rejected_;
  std::vector<std::string> searched_;
};

/// The default search path: each --plugin-dir, then CRPGS_PLUGIN_PATH (':'-separated), then
/// the install dir (relative to the running executable, then the configured prefix).
std::vector<std::string> default_plugin_dirs(const std::vector<std::string>& plugin_dirs);

}  // namespace crpgs
