/// @file json.cpp
#include "io/json.h"

#include <cmath>
#include <cstdlib>
#include <cstring>
#include <fstream>
#include <sstream>

namespace crpgs::io {
namespace {

class Parser {
 public:
  explicit Parser(const std::string& s) : s_(s) {}

  Status parse(JsonValue& out) {
    CRPGS_RETURN_IF_ERROR(value(out, 0));
    skip_ws();
    if (pos_ != s_.size()) return error("trailing characters after the document");
    return OkStatus();
  }

 private:
  // Four hex digits at pos_ (advanced past them).
  bool hex4(unsigned* out) {
    if (pos_ + 4 > s_.size()) return false;
    unsigned v = 0;
    for (int i = 0; i < 4; ++i) {
      const char c = s_[pos_ + size_t(i)];
      const int d = c >= '0' && c <= '9'   ? c - '0'
                    : c >= 'a' && c <= 'f' ? c - 'a' + 10
                    : c >= 'A' && c <= 'F' ? c - 'A' + 10
                                           : -1;
      if (d < 0) return false;
      v = v * 16 + unsigned(d);
    }
    pos_ += 4;
    *out = v;
    return true;
  }

  static void append_utf8(unsigned cp, std::string& out) {
    if (cp < 0x80) {
      out += char(cp);
    } else if (cp < 0x800) {
      out += char(0xC0 | (cp >> 6));
      out += char(0x80 | (cp & 0x3F));
    } else if (cp < 0x10000) {
      out += char(0xE0 | (cp >> 12));
      out += char(0x80 | ((cp >> 6) & 0x3F));
      out += char(0x80 | (cp & 0x3F));
    } else {
      out += char(0xF0 | (cp >> 18));
      out += char(0x80 | ((cp >> 12) & 0x3F));
      out += char(0x80 | ((cp >> 6) & 0x3F));
      out += char(0x80 | (cp & 0x3F));
    }
  }

  Status error(const std::string& what) const {
    int line = 1, col = 1;
    for (size_t i = 0; i < pos_ && i < s_.size(); ++i) {
      if (s_[i] == '\n')
        ++line, col = 1;
      else
        ++col;
    }
    return Status(StatusCode::kInvalidArgument, "JSON line " + std::to_string(line) + " column " +
                                                    std::to_string(col) + ": " + what);
  }
  void skip_ws() {
    while (pos_ < s_.size() &&
           (s_[pos_] == ' ' || s_[pos_] == '\t' || s_[pos_] == '\n' || s_[pos_] == '\r'))
      ++pos_;
  }
  bool literal(const char* word) {
    const std::string w(word);
    if (s_.compare(pos_, w.size(), w) != 0) return false;
    pos_ += w.size();
    return true;
  }

  Status value(JsonValue& out, int depth) {
    if (depth > 200) return error("nesting too deep");
    skip_ws();
    if (pos_ >= s_.size()) return error("unexpected end of input");
    const char ch = s_[pos_];
    if (ch == '{') return object(out, depth);
    if (ch == '[') return array(out, depth);
    if (ch == '"') {
      out.type = JsonValue::Type::kString;
      return string(out.string);
    }
    if (literal("true")) {
      out.type = JsonValue::Type::kBool;
      out.boolean = true;
      return OkStatus();
    }
    if (literal("false")) {
      out.type = JsonValue::Type::kBool;
      return OkStatus();
    }
    if (literal("null")) return OkStatus();
    if (ch == '-' || (ch >= '0' && ch <= '9')) {
      const char* begin = s_.c_str() + pos_;
      // JSON's grammar only (strtod also takes inf, nan and hex), and a finite value.
      const char* p = begin + (ch == '-' ? 1 : 0);
      if (!(*p >= '0' && *p <= '9')) return error("bad number");
      for (const char* q = p; *q && !std::strchr(",]}\t\n\r ", *q); ++q)
        if (!std::strchr("0123456789.eE+-", *q)) return error("bad number");
      char* end = nullptr;
      out.number = std::strtod(begin, &end);
      if (end == begin) return error("bad number");
      if (!std::isfinite(out.number)) return error("number out of range");
      out.type = JsonValue::Type::kNumber;
      pos_ += size_t(end - begin);
      return OkStatus();
    }
    return error(std::string("unexpected character '") + ch + "'");
  }

  Status string(std::string& out) {
    ++pos_;  // opening quote
    while (pos_ < s_.size()) {
      const char ch = s_[pos_++];
      if (ch == '"') return OkStatus();
      if (ch != '\\') {
        out += ch;
        continue;
      }
      if (pos_ >= s_.size()) break;
      const char e = s_[pos_++];
      switch (e) {
        case '"':
          out += '"';
          break;
        case '\\':
          out += '\\';
          break;
        case '/':
          out += '/';
          break;
        case 'b':
          out += '\b';
          break;
        case 'f':
          out += '\f';
          break;
        case 'n':
          out += '\n';
          break;
        case 'r':
          out += '\r';
          break;
        case 't':
          out += '\t';
          break;
        case 'u': {
          unsigned cp = 0;
          if (!hex4(&cp)) return error("bad \\u escape (expected 4 hex digits)");
          // UTF-16 surrogates: a high one must pair with a low one into one code point.
          if (cp >= 0xDC00 && cp <= 0xDFFF) return error("unpaired low surrogate in \\u escape");
          if (cp >= 0xD800 && cp <= 0xDBFF) {
            unsigned low = 0;
            if (s_.compare(pos_, 2, "\\u") != 0 || (pos_ += 2, !hex4(&low)) || low < 0xDC00 ||
                low > 0xDFFF)
              return error("unpaired high surrogate in \\u escape");
            cp = 0x10000 + ((cp - 0xD800) << 10) + (low - 0xDC00);
          }
          append_utf8(cp, out);
          break;
        }
        default:
          return error("bad escape");
      }
    }
    return error("unterminated string");
  }

  Status array(JsonValue& out, int depth) {
    out.type = JsonValue::Type::kArray;
    ++pos_;
    skip_ws();
    if (pos_ < s_.size() && s_[pos_] == ']') return ++pos_, OkStatus();
    while (true) {
      out.array.emplace_back();
      CRPGS_RETURN_IF_ERROR(value(out.array.back(), depth + 1));
      skip_ws();
      if (pos_ < s_.size() && s_[pos_] == ',') {
        ++pos_;
        continue;
      }
      if (pos_ < s_.size() && s_[pos_] == ']') return ++pos_, OkStatus();
      return error("expected ',' or ']'");
    }
  }

  Status object(JsonValue& out, int depth) {
    out.type = JsonValue::Type::kObject;
    ++pos_;
    skip_ws();
    if (pos_ < s_.size() && s_[pos_] == '}') return ++pos_, OkStatus();
    while (true) {
      skip_ws();
      if (pos_ >= s_.size() || s_[pos_] != '"') return error("expected a key string");
      std::string key;
      CRPGS_RETURN_IF_ERROR(string(key));
      skip_ws();
      if (pos_ >= s_.size() || s_[pos_] != ':') return error("expected ':'");
      ++pos_;
      CRPGS_RETURN_IF_ERROR(value(out.object[key], depth + 1));
      skip_ws();
      if (pos_ < s_.size() && s_[pos_] == ',') {
        ++pos_;
        continue;
      }
      if (pos_ < s_.size() && s_[pos_] == '}') return ++pos_, OkStatus();
      return error("expected ',' or '}'");
    }
  }

  const std::string& s_;
  size_t pos_ = 0;
};

}  // namespace

const JsonValue* JsonValue::find(const std::string& key) const {
  if (type != Type::kObject) return nullptr;
  auto it = object.find(key);
  return it == object.end() ? nullptr : &it->second;
}

StatusOr<JsonValue> parse_json(const std::string& text) {
  JsonValue v;
  CRPGS_RETURN_IF_ERROR(Parser(text).parse(v));
  return v;
}

StatusOr<JsonValue> read_json_file(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) return Status(StatusCode::kNotFound, "cannot open " + path);
  std::stringstream ss;
  ss << in.rdbuf();
  auto v = parse_json(ss.str());
  if (!v.ok()) return Status(v.status().code(), path + ": " + v.status().message());
  return v;
}

}  // namespace crpgs::io
