/// @file json_writer.h
/// @brief A small JSON writer (the counterpart of json.h's reader), internal to crpgs_base.
/// Pretty-prints objects and arrays; short arrays of numbers can be kept on one line.
#pragma once

#include <cmath>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <string>
#include <vector>

namespace crpgs::io {

/// Quotes and escapes a string for JSON.
inline std::string json_quote(const std::string& s) {
  std::string out = "\"";
  for (unsigned char c : s) {
    switch (c) {
      case '"':
        out += "\\\"";
        break;
      case '\\':
        out += "\\\\";
        break;
      case '\n':
        out += "\\n";
        break;
      case '\r':
        out += "\\r";
        break;
      case '\t':
        out += "\\t";
        break;
      default:
        if (c < 0x20) {
          char buf[8];
          std::snprintf(buf, sizeof buf, "\\u%04x", c);
          out += buf;
        } else {
          out += static_cast<char>(c);
        }
    }
  }
  return out + "\"";
}

/// Shortest round-trip text of a double; NaN and infinities (not JSON) become null.
inline std::string json_number(double v) {
  if (!std::isfinite(v)) return "null";
  char buf[32];
  for (int prec = 6; prec <= 17; ++prec) {
    std::snprintf(buf, sizeof buf, "%.*g", prec, v);
    if (std::strtod(buf, nullptr) == v) break;
  }
  return buf;
}

/// Streaming writer: begin_object / key / value / end_object. The caller keeps the nesting
/// right; commas and indentation are handled here.
class JsonWriter {
 public:
  JsonWriter& begin_object() { return open('{'); }
  JsonWriter& end_object() { return close('}'); }
  JsonWriter& begin_array(bool inline_items = false) {
    open('[');
    inline_.back() = inline_items;
    return *this;
  }
  JsonWriter& end_array() { return close(']'); }
  JsonWriter& key(const std::string& k) {
    separator();
    out_ += json_quote(k) + ": ";
    after_key_ = true;
    return *this;
  }
  JsonWriter& value(const std::string& s) { return raw(json_quote(s)); }
  JsonWriter& value(const char* s) { return raw(json_quote(s)); }
  JsonWriter& value(double v) { return raw(json_number(v)); }
  JsonWriter& value(int v) { return raw(std::to_string(v)); }
  JsonWriter& value(int64_t v) { return raw(std::to_string(v)); }
  JsonWriter& value(uint64_t v) { return raw(std::to_string(v)); }
  JsonWriter& value(bool v) { return raw(v ? "true" : "false"); }
  JsonWriter& null() { return raw("null"); }
  /// Writes already-formatted JSON text as one value.
  JsonWriter& raw(const std::string& text) {
    separator();
    out_ += text;
    return *this;
  }
  /// The document, with a final newline.
  std::string str() const { return out_ + "\n"; }

 private:
  JsonWriter& open(char c) {
    separator();
    out_ += c;
    first_.push_back(true);
    inline_.push_back(false);
    return *this;
  }
  JsonWriter& close(char c) {
    const bool empty = first_.back(), in_line = inline_.back();
    first_.pop_back();
    inline_.pop_back();
    if (!empty && !in_line) newline();
    out_ += c;
    return *this;
  }
  void separator() {
    if (after_key_) {
      after_key_ = false;
      return;
    }
    if (first_.empty()) return;
    if (!first_.back()) out_ += inline_.back() ? ", " : ",";
    if (!inline_.back()) newline();
    first_.back() = false;
  }
  void newline() { out_ += "\n" + std::string(2 * first_.size(), ' '); }

  std::string out_;
  std::vector<bool> first_, inline_;
  bool after_key_ = false;
};

}  // namespace crpgs::io
