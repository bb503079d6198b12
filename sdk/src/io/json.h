/// @file json.h
/// @brief A minimal JSON reader for transforms.json files (no third-party JSON library in the
/// dependency set). Internal to crpgs_base.
#pragma once

#include <map>
#include <memory>
#include <string>
#include <vector>

#include "crpgs/status.h"

namespace crpgs::io {

struct JsonValue {
  enum class Type { kNull, kBool, kNumber, kString, kArray, kObject };
  Type type = Type::kNull;
  bool boolean = false;
  double number = 0;
  std::string string;
  std::vector<JsonValue> array;
  std::map<std::string, JsonValue> object;

  bool is_number() const { return type == Type::kNumber; }
  bool is_string() const { return type == Type::kString; }
  bool is_array() const { return type == Type::kArray; }
  bool is_object() const { return type == Type::kObject; }
  /// Member lookup; nullptr if absent or this is not an object.
  const JsonValue* find(const std::string& key) const;
};

/// Parses a whole document; errors give the line and column.
StatusOr<JsonValue> parse_json(const std::string& text);
/// Reads and parses a file; errors name the path.
StatusOr<JsonValue> read_json_file(const std::string& path);

}  // namespace crpgs::io
