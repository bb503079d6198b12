/// @file config.cpp
#include "crpgs/config.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <limits>
#include <map>
#include <sstream>
#include <utility>

#include "core/text_list.h"
#include "crpgs/atomic_file.h"
#include "crpgs/hashing.h"
#include "crpgs/registry.h"

namespace crpgs {
namespace {

// Aliases let a few lines stand for an exponential tree; no config comes near this.
constexpr size_t kMaxConfigNodes = 100000;
constexpr uintmax_t kMaxConfigBytes = 16u << 20;

// Every map key must be a plain scalar and appear once: the schemas, merging and messages read
// keys as text, and YAML parsers disagree on which of two equal keys wins.
Status check_keys(const YAML::Node& n, const std::string& name, size_t* visited) {
  if (++*visited > kMaxConfigNodes)
    return Status(StatusCode::kInvalidConfig,
                  name + ": more than " + std::to_string(kMaxConfigNodes) +
                      " values once its aliases are expanded; not a config");
  if (n.IsSequence())
    for (const auto& e : n) CRPGS_RETURN_IF_ERROR(check_keys(e, name, visited));
  if (!n.IsMap()) return OkStatus();
  std::map<std::string, int> first_line;
  for (const auto& kv : n) {
    if (!kv.first.IsScalar())
      return Status(StatusCode::kInvalidConfig,
                    SourceRef{name, {}}.describe(kv.first) + ": a key must be a plain name");
    const auto [it, fresh] = first_line.emplace(kv.first.Scalar(), kv.first.Mark().line + 1);
    if (!fresh)
      return Status(StatusCode::kInvalidConfig,
                    SourceRef{name, {}}.describe(kv.first) + ": " + kv.first.Scalar() +
                        ": key given twice (first at line " + std::to_string(it->second) + ")");
    CRPGS_RETURN_IF_ERROR(check_keys(kv.second, name, visited));
  }
  return OkStatus();
}

StatusOr<YAML::Node> parse_yaml(const std::string& text, const std::string& name) {
  try {
    const std::vector<YAML::Node> docs = YAML::LoadAll(text);
    for (size_t i = 1; i < docs.size(); ++i)
      if (!docs[i].IsNull())  // a trailing `---` (and comments) is harmless
        return Status(StatusCode::kInvalidConfig,
                      SourceRef{name, {}}.describe(docs[i]) +
                          ": a second YAML document (after `---`); a config is one document");
    YAML::Node root = docs.empty() ? YAML::Node() : docs[0];
    if (root.IsNull()) return YAML::Node(YAML::NodeType::Map);
    if (!root.IsMap())
      return Status(StatusCode::kInvalidConfig,
                    name + ":1:1: a config must be a YAML map of sections (dataset, train, ...)");
    size_t visited = 0;
    CRPGS_RETURN_IF_ERROR(check_keys(root, name, &visited));
    return root;
  } catch (const YAML::ParserException& e) {
    return Status(StatusCode::kInvalidConfig, name + ":" + std::to_string(e.mark.line + 1) + ":" +
                                                  std::to_string(e.mark.column + 1) +
                                                  ": YAML syntax error: " + e.msg);
  }
}

// Strips positions from an override value so messages attribute it to --set.
YAML::Node without_marks(const YAML::Node& n) {
  if (n.IsScalar()) return YAML::Node(n.Scalar());
  if (n.IsSequence()) {
    YAML::Node out(YAML::NodeType::Sequence);
    for (const auto& e : n) out.push_back(without_marks(e));
    out.SetStyle(YAML::EmitterStyle::Flow);
    return out;
  }
  if (n.IsMap()) {
    YAML::Node out(YAML::NodeType::Map);
    for (const auto& kv : n) out[kv.first.as<std::string>()] = without_marks(kv.second);
    return out;
  }
  return YAML::Node();
}

namespace fs = std::filesystem;

constexpr size_t kMaxBaseDepth = 8;  // levels of `base:` below the file loaded

// A component block's `type:`, or the section's default type where it names none.
std::string component_type(const YAML::Node& block, const std::string& section) {
  const YAML::Node t = block["type"];
  if (t.IsDefined() && t.IsScalar()) return t.Scalar();
  for (const auto& s : component_sections())
    if (section == s.key && s.default_type) return s.default_type;
  return {};
}

// Adds every key of `base` that `over` lacks to `over`, recursing where both hold maps. Nodes
// are shared, not copied, so they keep their positions and SourceRef can name their file. A
// top-level block that names another component type than the base's (or than the section's
// default, where the base names none) replaces it whole: the base's parameters belong to the
// other component.
void merge_base_into(YAML::Node over, const YAML::Node& base, bool top) {
  for (const auto& kv : base) {
    const std::string key = kv.first.as<std::string>();
    const YAML::Node mine = std::as_const(over)[key];
    if (!mine.IsDefined())
      over.force_insert(kv.first, kv.second);
    else if (mine.IsMap() && kv.second.IsMap() &&
             (!top || !mine["type"].IsDefined() ||
              component_type(mine, key) == component_type(kv.second, key)))
      merge_base_into(mine, kv.second, false);
  }
}

// Every node of a freshly parsed tree, keys included.
void collect_nodes(const YAML::Node& n, std::vector<YAML::Node>& out) {
  out.push_back(n);
  if (n.IsSequence())
    for (const auto& e : n) collect_nodes(e, out);
  if (n.IsMap())
    for (const auto& kv : n) {
      out.push_back(kv.first);
      collect_nodes(kv.second, out);
    }
}

struct LoadedTree {
  YAML::Node root;
  std::vector<YAML::Node> own;  // the nodes this file wrote, before merging its bases
  std::vector<std::pair<std::string, std::vector<YAML::Node>>> bases;  // as in SourceRef
};

// `chain`: the files being loaded, outermost first, to refuse a config that inherits itself.
StatusOr<LoadedTree> load_tree(const std::string& path, std::vector<std::string>& chain) {
  std::error_code ec;
  // A directory would read as an empty config (training on the defaults); pipes are fine
  // (`-c <(...)`), devices like /dev/zero end at the size limit.
  if (fs::is_directory(path, ec))
    return Status(StatusCode::kIoError, path + ": a directory, not a config file");
  std::ifstream in(path, std::ios::binary);
  if (!in) return Status(StatusCode::kIoError, "cannot open config file " + path);
  std::string text;
  char buf[65536];
  while (text.size() <= kMaxConfigBytes && in.read(buf, sizeof buf).gcount() > 0)
    text.append(buf, size_t(in.gcount()));
  if (in.bad()) return Status(StatusCode::kIoError, "cannot read config file " + path);
  if (text.size() > kMaxConfigBytes)
    return Status(StatusCode::kIoError, path + ": larger than 16 MiB; not a config");
  LoadedTree t;
  CRPGS_ASSIGN_OR_RETURN(t.root, parse_yaml(text, path));
  const fs::path dir = fs::absolute(path).parent_path();
  SourceRef src{path, {}};

  // Const lookups: a non-const operator[] would add the missing key and hide the base's.
  const YAML::Node dataset = std::as_const(t.root)["dataset"];
  YAML::Node path_node = dataset.IsDefined() && dataset.IsMap() ? dataset["path"] : YAML::Node();
  if (path_node.IsDefined() && path_node.IsScalar() && !path_node.Scalar().empty() &&
      fs::path(path_node.Scalar()).is_relative())
    path_node = (dir / path_node.Scalar()).lexically_normal().string();  // keeps its position

  collect_nodes(t.root, t.own);
  const YAML::Node base = std::as_const(t.root)["base"];
  if (!base.IsDefined()) return t;
  std::vector<YAML::Node> names;
  if (base.IsScalar()) names.push_back(base);
  if (base.IsSequence())
    for (const auto& e : base) names.push_back(e);
  if (names.empty() ||
      std::any_of(names.begin(), names.end(), [](const YAML::Node& n) { return !n.IsScalar(); }))
    return Status(StatusCode::kInvalidConfig,
                  src.describe(base) + ": base: expected a config file or a list of them");
  chain.push_back(fs::weakly_canonical(path, ec).string());
  if (ec) return Status(StatusCode::kIoError, path + ": " + ec.message());
  // Later bases win: merge the last one first, since merging only fills in missing keys.
  for (auto n = names.rbegin(); n != names.rend(); ++n) {
    const fs::path base_path =
        fs::path(n->Scalar()).is_absolute()
            ? fs::path(n->Scalar())
            : (fs::path(path).parent_path() / n->Scalar()).lexically_normal();
    const std::string canonical = fs::weakly_canonical(base_path, ec).string();
    if (ec)
      return Status(StatusCode::kIoError,
                    src.describe(*n) + ": base: '" + n->Scalar() + "': " + ec.message());
    if (std::find(chain.begin(), chain.end(), canonical) != chain.end())
      return Status(StatusCode::kInvalidConfig,
                    src.describe(*n) + ": base: '" + n->Scalar() + "' inherits itself");
    if (chain.size() > kMaxBaseDepth)
      return Status(StatusCode::kInvalidConfig, src.describe(*n) + ": base: more than " +
                                                    std::to_string(kMaxBaseDepth) +
                                                    " levels of inheritance");
    auto loaded = load_tree(base_path.string(), chain);
    if (!loaded.ok())
      return Status(loaded.status().code(),
                    src.describe(*n) + ": base: " + loaded.status().message());
    merge_base_into(t.root, loaded->root, true);
    t.bases.insert(t.bases.end(), loaded->bases.begin(), loaded->bases.end());
    t.bases.emplace_back(base_path.string(), std::move(loaded->own));
  }
  chain.pop_back();
  t.root.remove("base");
  return t;
}

}  // namespace

const std::vector<ComponentSection>& component_sections() {
  static const std::vector<ComponentSection> sections = {
      {"entropy", CRPGS_KIND_ENTROPY, nullptr},     {"context", CRPGS_KIND_CONTEXT, nullptr},
      {"links", CRPGS_KIND_CONTEXT, nullptr},       {"features", CRPGS_KIND_FEATURES, "identity"},
      {"rasterizer", CRPGS_KIND_RASTERIZER, "cpu"},
  };
  return sections;
}

StatusOr<Config> Config::from_string(const std::string& yaml_text, const std::string& name) {
  CRPGS_ASSIGN_OR_RETURN(YAML::Node root, parse_yaml(yaml_text, name));
  Config c;
  c.root_ = root;
  c.src_.file = name;
  return c;
}

StatusOr<Config> Config::load_file(const std::string& path) {
  std::vector<std::string> chain;
  CRPGS_ASSIGN_OR_RETURN(LoadedTree t, load_tree(path, chain));
  Config c;
  c.root_ = t.root;
  c.src_.file = path;
  c.src_.bases = std::move(t.bases);
  return c;
}

Status Config::apply_override(const std::string& assignment) {
  const auto eq = assignment.find('=');
  if (eq == std::string::npos || eq == 0)
    return Status(
        StatusCode::kInvalidArgument,
        "--set '" + assignment + "': expected key.path=value, e.g. train.iterations=1000");
  const std::string path = assignment.substr(0, eq), text = assignment.substr(eq + 1);
  YAML::Node value;
  try {
    value = without_marks(YAML::Load(text));
  } catch (const YAML::Exception& e) {
    return Status(StatusCode::kInvalidArgument,
                  "--set " + path + ": value does not parse: " + e.msg);
  }
  return set(path, value);
}

Status Config::set(const std::string& path, const YAML::Node& value) {
  std::vector<std::string> keys;
  std::stringstream ps(path);
  for (std::string k; std::getline(ps, k, '.');) {
    if (k.empty()) return Status(StatusCode::kInvalidArgument, "--set '" + path + "': empty key");
    keys.push_back(k);
  }
  if (path.empty() || path.back() == '.')  // getline drops the empty last part
    return Status(StatusCode::kInvalidArgument, "--set '" + path + "': empty key");
  // Walk/create maps; yaml-cpp nodes are handles, so assignment through `cur` edits root_.
  std::vector<YAML::Node> chain{root_};
  for (size_t i = 0; i + 1 < keys.size(); ++i) {
    YAML::Node next = chain.back()[keys[i]];
    if (next.IsDefined() && !next.IsNull() && !next.IsMap())
      return Status(StatusCode::kInvalidArgument,
                    "--set " + path + ": '" + keys[i] + "' is not a map in the config");
    if (!next.IsDefined() || next.IsNull()) {
      chain.back()[keys[i]] = YAML::Node(YAML::NodeType::Map);
      next = chain.back()[keys[i]];
    }
    chain.push_back(next);
  }
  chain.back()[keys.back()] = value;
  return OkStatus();
}

StatusOr<Config> Config::resolve(const ComponentRegistry& registry) const {
  auto err = [&](const YAML::Node& at, const std::string& msg) {
    return Status(StatusCode::kInvalidConfig, src_.describe(at) + ": " + msg);
  };
  Config out;
  out.src_ = src_;
  out.root_ = YAML::Node(YAML::NodeType::Map);

  std::vector<std::string> valid;
  for (const auto& s : core_sections()) valid.push_back(s.key);
  for (const auto& s : component_sections()) valid.push_back(s.key);
  for (const auto& kv : root_) {
    const std::string key = kv.first.as<std::string>();
    if (std::find(valid.begin(), valid.end(), key) == valid.end())
      return err(kv.first, key + ": unknown section" + did_you_mean(key, valid) +
                               " (valid sections: " + join(valid) + ")");
  }

  for (const auto& s : core_sections()) {
    CRPGS_ASSIGN_OR_RETURN(YAML::Node block, validate_block(root_[s.key], s.schema, s.key, src_));
    out.root_[s.key] = block;
  }

  for (const auto& s : component_sections()) {
    const YAML::Node block = root_[s.key];
    std::string type;
    if (!block.IsDefined() || block.IsNull()) {
      if (!s.default_type) continue;
      type = s.default_type;
    } else {
      if (!block.IsMap())
        return err(block, std::string(s.key) + ": expected a map with a `type:` key");
      const YAML::Node t = block["type"];
      if (!t.IsDefined()) {
        if (!s.default_type)
          return err(block, std::string(s.key) +
                                ".type: missing; available: " + join(registry.types(s.kind)));
        type = s.default_type;
      } else if (!t.IsScalar()) {
        return err(t, std::string(s.key) + ".type: expected a string");
      } else {
        type = t.Scalar();
      }
    }
    const ComponentInfo* info = registry.find(s.kind, type);
    if (!info && s.kind == CRPGS_KIND_RASTERIZER && type == "cuda") {
      return err(block["type"], std::string(s.key) +
                                    ".type: rasterizer 'cuda' is not compiled into this build "
                                    "(configure with CRPGS_WITH_CUDA=ON and a CUDA libtorch); "
                                    "available: " +
                                    join(registry.types(s.kind)));
    }
    if (!info) {
      std::string where = join(registry.searched_dirs());
      return err(block.IsDefined() && block["type"] ? block["type"] : block,
                 std::string(s.key) + ".type: unknown " + kind_name(s.kind) + " type '" + type +
                     "'" + did_you_mean(type, registry.types(s.kind)) +
                     " (available: " + join(registry.types(s.kind)) + "; plugins searched in: " +
                     (where.empty() ? std::string("no directories") : where) + ")");
    }
    CRPGS_ASSIGN_OR_RETURN(YAML::Node params,
                           validate_block(block, info->schema, s.key, src_, {"type"}));
    YAML::Node resolved(YAML::NodeType::Map);
    resolved["type"] = type;
    for (const auto& kv : params) resolved[kv.first.as<std::string>()] = kv.second;
    out.root_[s.key] = resolved;
  }
  return out;
}

std::string Config::dump() const {
  YAML::Emitter e;
  e << root_;
  return std::string(e.c_str()) + "\n";
}

namespace {

// A scalar as yaml-cpp writes a double (17 significant digits) in the shortest text that reads
// back as the same double; any other scalar, integers included, as it is.
std::string shortest_float_text(const std::string& s) {
  if (s.find_first_of(".eE") == std::string::npos) return s;
  char* end = nullptr;
  const double x = std::strtod(s.c_str(), &end);
  if (s.empty() || end != s.c_str() + s.size() || !std::isfinite(x)) return s;
  std::ostringstream as_written;  // yaml-cpp's convert<double>::encode
  as_written.precision(std::numeric_limits<double>::max_digits10);
  as_written << x;
  if (as_written.str() != s) return s;
  char buf[32];
  for (int digits = 1; digits <= std::numeric_limits<double>::max_digits10; ++digits) {
    std::snprintf(buf, sizeof buf, "%.*g", digits, x);
    if (std::strtod(buf, nullptr) == x) break;
  }
  return buf;
}

YAML::Node with_short_floats(const YAML::Node& n) {
  if (n.IsScalar()) return YAML::Node(shortest_float_text(n.Scalar()));
  YAML::Node out;
  if (n.IsSequence()) {
    out = YAML::Node(YAML::NodeType::Sequence);
    for (const auto& e : n) out.push_back(with_short_floats(e));
  } else if (n.IsMap()) {
    out = YAML::Node(YAML::NodeType::Map);
    for (const auto& kv : n) out[kv.first.Scalar()] = with_short_floats(kv.second);
  } else {
    return YAML::Clone(n);
  }
  out.SetStyle(n.Style());
  return out;
}

}  // namespace

std::string Config::to_yaml() const {
  YAML::Emitter e;
  e << with_short_floats(root_);
  return std::string(e.c_str()) + "\n";
}

Status make_dataset_path_absolute(Config& cfg, const std::string& base) {
  const YAML::Node ds = cfg.root()["dataset"];
  if (!ds || !ds.IsMap() || !ds["path"] || !ds["path"].IsScalar()) return OkStatus();
  const std::string p = ds["path"].Scalar();
  if (p.empty() || fs::path(p).is_absolute()) return OkStatus();
  // Set as a node, not as --set text: no YAML parsing, so "data #2" or "a: b" stay as they are.
  return cfg.set("dataset.path", YAML::Node((fs::path(base) / p).lexically_normal().string()));
}

Status Config::save(const std::string& path) const {
  return write_file_atomic(path, to_yaml());
}

uint64_t Config::hash() const {
  return fnv1a64(dump());
}

}  // namespace crpgs
