/// @file config.h
/// @brief A YAML run configuration: loading with source positions, `--set` overrides, and
/// resolution of every section against its schema (core sections and component blocks).
#pragma once

#include <string>
#include <vector>

#include <yaml-cpp/yaml.h>

#include "crpgs/plugin_abi.h"
#include "crpgs/schema.h"
#include "crpgs/status.h"

namespace crpgs {

class ComponentRegistry;

/// A top-level section that holds a component: its YAML key, the kind it must be, and the
/// type used when the section is absent.
struct ComponentSection {
  const char* key;
  crpgs_kind kind;
  const char* default_type;
};
/// entropy, context, links, features, rasterizer.
const std::vector<ComponentSection>& component_sections();

/// A top-level section with a fixed schema owned by the core (dataset, scene, model, train, ...).
struct CoreSection {
  std::string key;
  Schema schema;
};
/// Registered by the SDK modules that own them (see core_sections.cpp).
const std::vector<CoreSection>& core_sections();

class Config {
 public:
  /// Reads a config file. A top-level `base: FILE` (or a list of files, later ones winning)
  /// inherits those configs: maps merge key by key, anything else in this file replaces the
  /// base's value, a component block naming another `type:` replaces the base's block, and
  /// `key: null` removes a section. A relative `dataset.path` is made
  /// absolute against the directory of the file that names it, so configs work from any
  /// directory and the resolved copy saved in a run directory stays valid. Messages about an
  /// inherited key name the base file and its line.
  static StatusOr<Config> load_file(const std::string& path);
  static StatusOr<Config> from_string(const std::string& yaml_text, const std::string& name);

  /// Applies "a.b.c=value" (value parsed as YAML). Creates missing maps.
  Status apply_override(const std::string& assignment);
  /// Sets the key "a.b.c" to `value` as it is (no YAML parsing). Creates missing maps.
  Status set(const std::string& dotted_key, const YAML::Node& value);

  /// Validates every section (unknown top-level keys are errors) and fills in defaults. Component
  /// types are looked up in `registry`; an unknown type lists the available types and where
  /// plugins were searched.
  StatusOr<Config> resolve(const ComponentRegistry& registry) const;

  const YAML::Node& root() const { return root_; }
  YAML::Node section(const std::string& key) const { return root_[key]; }
  const std::string& file() const { return src_.file; }
  const SourceRef& source() const { return src_; }
  /// The canonical text: hashed, and carried inside bitstreams. Floats keep yaml-cpp's 17
  /// significant digits (0.00020000000000000001), so that hashes, shared-prefix keys and
  /// bitstream bytes stay those of earlier builds.
  std::string dump() const;
  /// The text for people: dump() with each float in the shortest form that reads back as the
  /// same value (0.0002). What `config check` prints and save() writes; reading it back gives
  /// the same dump() and hash().
  std::string to_yaml() const;
  /// Writes to_yaml() atomically to `path`.
  Status save(const std::string& path) const;
  /// FNV-1a 64 of dump(): identifies a resolved config in bitstreams.
  uint64_t hash() const;

 private:
  YAML::Node root_;
  SourceRef src_;
};

/// Makes a relative dataset.path absolute against `base` (the working directory for a path given
/// with --set or a sweep file), so the copy saved in a run directory, and the config a bitstream
/// carries, stay valid from anywhere. Absent or absolute paths are left alone.
Status make_dataset_path_absolute(Config& cfg, const std::string& base);

}  // namespace crpgs
