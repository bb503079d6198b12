/// @file schema.cpp
#include "crpgs/schema.h"

#include <algorithm>
#include <cmath>
#include <sstream>

#include "core/text_list.h"

namespace crpgs {
namespace {

struct TypeName {
  ParamType type;
  const char* name;
};
constexpr TypeName kTypeNames[] = {
    {ParamType::kInt, "int"},
    {ParamType::kFloat, "float"},
    {ParamType::kBool, "bool"},
    {ParamType::kString, "string"},
    {ParamType::kChoice, "choice"},
    {ParamType::kIntList, "int_list"},
    {ParamType::kFloatList, "float_list"},
};

std::string fmt_number(double v) {
  std::ostringstream os;
  os << v;
  return os.str();
}

/// Decimal only: "010" is ten, not octal eight. `*overflow`: a valid integer beyond long long.
bool parse_int(const YAML::Node& n, long long* out, bool* overflow = nullptr) {
  if (!n.IsScalar()) return false;
  const std::string s = n.Scalar();
  try {
    size_t pos = 0;
    *out = std::stoll(s, &pos, 10);
    return pos == s.size();
  } catch (const std::out_of_range&) {
    if (overflow) *overflow = s.find_first_not_of("+-0123456789") == std::string::npos;
    return false;
  } catch (...) {
    return false;
  }
}

bool parse_float(const YAML::Node& n, double* out) {
  if (!n.IsScalar()) return false;
  try {
    const std::string s = n.Scalar();
    size_t pos = 0;
    *out = std::stod(s, &pos);
    return pos == s.size() && std::isfinite(*out);
  } catch (...) {
    return false;
  }
}

bool parse_bool(const YAML::Node& n, bool* out) {
  if (!n.IsScalar()) return false;
  const std::string& s = n.Scalar();
  if (s == "true" || s == "True" || s == "yes" || s == "on") return *out = true, true;
  if (s == "false" || s == "False" || s == "no" || s == "off") return *out = false, true;
  return false;
}

bool in_range(const ParamSpec& p, double v) {
  if (p.min && (p.min_exclusive ? v <= *p.min : v < *p.min)) return false;
  if (p.max && v > *p.max) return false;
  return true;
}

// Checks one value and returns its normalised form; `why` gets the mismatch description.
bool check_value(const ParamSpec& p, const YAML::Node& v, YAML::Node* out, std::string* why) {
  auto scalar_number = [&](const YAML::Node& n, bool integer, YAML::Node* o) {
    if (integer) {
      long long x;
      bool overflow = false;
      if (!parse_int(n, &x, &overflow))
        return *why = overflow ? "out of range" : "not an integer", false;
      if (!in_range(p, double(x))) return *why = "out of range", false;
      *o = YAML::Node(x);
    } else {
      double x;
      if (!parse_float(n, &x)) return *why = "not a number", false;
      if (!in_range(p, x)) return *why = "out of range", false;
      *o = YAML::Node(x);
    }
    return true;
  };
  switch (p.type) {
    case ParamType::kInt:
      return scalar_number(v, true, out);
    case ParamType::kFloat:
      return scalar_number(v, false, out);
    case ParamType::kBool: {
      bool b;
      if (!parse_bool(v, &b)) return *why = "not a boolean", false;
      *out = YAML::Node(b);
      return true;
    }
    case ParamType::kString:
      if (!v.IsScalar()) return *why = "not a string", false;
      *out = YAML::Node(v.Scalar());
      return true;
    case ParamType::kChoice:
      if (!v.IsScalar()) return *why = "not a string", false;
      for (const auto& c : p.choices)
        if (c == v.Scalar()) return *out = YAML::Node(c), true;
      *why = "not a valid choice";
      return false;
    case ParamType::kIntList:
    case ParamType::kFloatList: {
      if (!v.IsSequence()) return *why = "not a list", false;
      YAML::Node list(YAML::NodeType::Sequence);
      for (const auto& e : v) {
        YAML::Node o;
        if (!scalar_number(e, p.type == ParamType::kIntList, &o)) {
          *why = "list element " + *why;
          return false;
        }
        list.push_back(o);
      }
      list.SetStyle(YAML::EmitterStyle::Flow);
      *out = list;
      return true;
    }
  }
  return false;
}

std::string mark_of(const YAML::Node& node, const SourceRef& src) {
  return src.describe(node);
}

}  // namespace

const char* param_type_name(ParamType t) {
  for (const auto& tn : kTypeNames)
    if (tn.type == t) return tn.name;
  return "?";
}

std::string ParamSpec::expected() const {
  std::string s = param_type_name(type);
  if (type == ParamType::kChoice) {
    return "one of {" + join(choices) + "}";
  }
  if (type == ParamType::kIntList) s = "list of int";
  if (type == ParamType::kFloatList) s = "list of float";
  if (min || max) {
    s += " in ";
    s += min ? (min_exclusive ? "(" : "[") + fmt_number(*min) : std::string("(-inf");
    s += ", ";
    s += max ? fmt_number(*max) + "]" : std::string("inf)");
  }
  return s;
}

const ParamSpec* Schema::find(const std::string& key) const {
  for (const auto& p : params_)
    if (p.key == key) return &p;
  return nullptr;
}

StatusOr<Schema> Schema::parse(const std::string& yaml_text) {
  auto bad = [](const std::string& msg) {
    return Status(StatusCode::kInvalidConfig, "schema: " + msg);
  };
  YAML::Node root;
  try {
    root = YAML::Load(yaml_text);
  } catch (const YAML::Exception& e) {
    return bad(std::string("does not parse: ") + e.what());
  }
  if (root.IsNull()) return Schema();
  if (!root.IsSequence()) return bad("must be a YAML list of parameter maps");
  std::vector<ParamSpec> params;
  // A plugin's text: every field read as what it must be, never trusted to convert.
  auto text = [](const YAML::Node& n, std::string* out) {
    if (!n.IsScalar()) return false;
    *out = n.Scalar();
    return true;
  };
  for (const auto& e : root) {
    if (!e.IsMap() || !e["key"] || !e["type"]) return bad("each entry needs `key` and `type`");
    ParamSpec p;
    std::string tn;
    if (!text(e["key"], &p.key) || p.key.empty()) return bad("a parameter's `key` must be a name");
    if (p.key == "type")
      return bad("parameter 'type': reserved (the `type:` of the component block)");
    if (!text(e["type"], &tn)) return bad("parameter '" + p.key + "': `type` must be a name");
    bool known = false;
    for (const auto& t : kTypeNames)
      if (tn == t.name) p.type = t.type, known = true;
    if (!known) return bad("parameter '" + p.key + "': unknown type '" + tn + "'");
    double d;
    if (e["min"]) {
      if (!parse_float(e["min"], &d)) return bad("parameter '" + p.key + "': bad min");
      p.min = d;
    }
    if (e["max"]) {
      if (!parse_float(e["max"], &d)) return bad("parameter '" + p.key + "': bad max");
      p.max = d;
    }
    if (p.min && p.max && *p.min > *p.max) return bad("parameter '" + p.key + "': min > max");
    if (e["min_exclusive"] && !YAML::convert<bool>::decode(e["min_exclusive"], p.min_exclusive))
      return bad("parameter '" + p.key + "': min_exclusive must be true or false");
    if (e["choices"]) {
      if (!e["choices"].IsSequence())
        return bad("parameter '" + p.key + "': choices must be a list");
      for (const auto& c : e["choices"]) {
        std::string choice;
        if (!text(c, &choice)) return bad("parameter '" + p.key + "': a choice must be a name");
        p.choices.push_back(choice);
      }
    }
    if (p.type == ParamType::kChoice && p.choices.empty())
      return bad("parameter '" + p.key + "': choice without choices");
    if (e["doc"] && !e["doc"].IsNull() && !text(e["doc"], &p.doc))
      return bad("parameter '" + p.key + "': doc must be text");
    if (!e["default"]) return bad("parameter '" + p.key + "': missing default");
    std::string why;
    if (!check_value(p, e["default"], &p.default_value, &why))
      return bad("parameter '" + p.key + "': default " + why + " (expected " + p.expected() + ")");
    if (params.end() != std::find_if(params.begin(), params.end(),
                                     [&](const ParamSpec& q) { return q.key == p.key; }))
      return bad("parameter '" + p.key + "' listed twice");
    params.push_back(std::move(p));
  }
  return Schema(std::move(params));
}

std::string Schema::to_yaml() const {
  YAML::Emitter out;
  out << YAML::BeginSeq;
  for (const auto& p : params_) {
    out << YAML::Flow << YAML::BeginMap;
    out << YAML::Key << "key" << YAML::Value << p.key;
    out << YAML::Key << "type" << YAML::Value << param_type_name(p.type);
    out << YAML::Key << "default" << YAML::Value << p.default_value;
    if (p.min) out << YAML::Key << "min" << YAML::Value << *p.min;
    if (p.min_exclusive) out << YAML::Key << "min_exclusive" << YAML::Value << true;
    if (p.max) out << YAML::Key << "max" << YAML::Value << *p.max;
    if (!p.choices.empty()) out << YAML::Key << "choices" << YAML::Value << p.choices;
    out << YAML::Key << "doc" << YAML::Value << p.doc;
    out << YAML::EndMap;
  }
  out << YAML::EndSeq;
  return out.c_str();
}

std::string SourceRef::describe(const YAML::Node& node) const {
  std::string s = file.empty() ? "<config>" : file;
  if (!node.IsDefined() || node.Mark().line < 0) return s + " (--set)";
  for (const auto& [base_file, nodes] : bases)
    if (std::any_of(nodes.begin(), nodes.end(), [&](const YAML::Node& n) { return n.is(node); })) {
      s = base_file;
      break;
    }
  return s + ":" + std::to_string(node.Mark().line + 1) + ":" +
         std::to_string(node.Mark().column + 1);
}

StatusOr<YAML::Node> validate_block(const YAML::Node& block, const Schema& schema,
                                    const std::string& path, const SourceRef& src,
                                    const std::vector<std::string>& allowed_extra) {
  auto err = [&](const YAML::Node& at, const std::string& msg) {
    return Status(StatusCode::kInvalidConfig, mark_of(at, src) + ": " + msg);
  };
  const bool present = block.IsDefined() && !block.IsNull();
  if (present && !block.IsMap()) return err(block, path + ": expected a map of parameters");
  YAML::Node resolved(YAML::NodeType::Map);
  if (present) {
    for (const auto& kv : block) {
      const std::string key = kv.first.as<std::string>();
      if (std::find(allowed_extra.begin(), allowed_extra.end(), key) != allowed_extra.end())
        continue;
      const ParamSpec* p = schema.find(key);
      if (!p) {
        std::vector<std::string> keys;
        for (const auto& q : schema.params()) keys.push_back(q.key);
        return err(kv.first,
                   path + "." + key + ": unknown key" + did_you_mean(key, keys) +
                       " (valid keys: " + (keys.empty() ? std::string("none") : join(keys)) + ")");
      }
      YAML::Node value;
      std::string why;
      if (!check_value(*p, kv.second, &value, &why)) {
        std::string shown = kv.second.IsScalar() ? "'" + kv.second.Scalar() + "'" : "this value";
        return err(kv.second,
                   path + "." + key + ": " + shown + " is " + why + "; expected " + p->expected());
      }
      resolved[key] = value;
    }
  }
  for (const auto& p : schema.params())
    if (!resolved[p.key]) resolved[p.key] = YAML::Clone(p.default_value);
  // Keep schema order for stable dumps and hashes.
  YAML::Node ordered(YAML::NodeType::Map);
  for (const auto& p : schema.params()) ordered[p.key] = resolved[p.key];
  return ordered;
}

}  // namespace crpgs
