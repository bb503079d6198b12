/// @file schema.h
/// @brief Per-component parameter tables (key, type, default, range/choices, doc) and the
/// checker that validates a YAML block against one before the component is built.
#pragma once

#include <optional>
#include <string>
#include <utility>
#include <vector>

#include <yaml-cpp/yaml.h>

#include "crpgs/status.h"

namespace crpgs {

enum class ParamType { kInt, kFloat, kBool, kString, kChoice, kIntList, kFloatList };
const char* param_type_name(ParamType t);

struct ParamSpec {
  std::string key;
  ParamType type = ParamType::kFloat;
  YAML::Node default_value;          ///< always present: every key has a default
  std::optional<double> min, max;    ///< inclusive range for numbers and list elements
  bool min_exclusive = false;        ///< (min, ...] instead of [min, ...]
  std::vector<std::string> choices;  ///< for kChoice
  std::string doc;                   ///< one line
  /// "float in (0, 1]", "one of {a, b}", ...
  std::string expected() const;
};

class Schema {
 public:
  Schema() = default;
  explicit Schema(std::vector<ParamSpec> params) : params_(std::move(params)) {}
  /// Parses the YAML list form used by plugin descriptors:
  ///   - {key: ratio, type: float, default: 0.4, min: 0, max: 1, doc: "..."}
  static StatusOr<Schema> parse(const std::string& yaml_text);
  /// The inverse of parse(): what a plugin descriptor carries.
  std::string to_yaml() const;
  const std::vector<ParamSpec>& params() const { return params_; }
  const ParamSpec* find(const std::string& key) const;

 private:
  std::vector<ParamSpec> params_;
};

/// Where a YAML node came from, for messages: "configs/hac.yaml:14:9".
/// Nodes without a position (set by `--set`) are described as coming from the command line.
struct SourceRef {
  std::string file;
  /// Configs a file inherits (`base:`), each with the nodes it wrote itself (collected before
  /// any merge): such a node is described with that file's name instead of `file`.
  std::vector<std::pair<std::string, std::vector<YAML::Node>>> bases;
  std::string describe(const YAML::Node& node) const;
};

/// Checks `block` against `schema` and returns the resolved block: every key present, defaults
/// filled in, values normalised to their type. `path` is the YAML path of the block ("entropy")
/// and `allowed_extra` lists keys handled by the caller (e.g. "type"). Errors name the file,
/// line, column, YAML path, what was expected and, for unknown keys, the valid keys.
StatusOr<YAML::Node> validate_block(const YAML::Node& block, const Schema& schema,
                                    const std::string& path, const SourceRef& src,
                                    const std::vector<std::string>& allowed_extra = {});

}  // namespace crpgs
