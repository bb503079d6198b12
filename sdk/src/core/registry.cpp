/// @file registry.cpp
#include "crpgs/registry.h"

#include <dlfcn.h>
#include <unistd.h>

#include <algorithm>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <sstream>

#include "core/text_list.h"
#include "crpgs/plugin.h"
#include "crpgs_git_commit.h"

namespace crpgs {
namespace fs = std::filesystem;

const char* kind_name(crpgs_kind kind) {
  switch (kind) {
    case CRPGS_KIND_ENTROPY:
      return "entropy";
    case CRPGS_KIND_CONTEXT:
      return "context";
    case CRPGS_KIND_FEATURES:
      return "features";
    case CRPGS_KIND_RASTERIZER:
      return "rasterizer";
  }
  return "unknown";
}

crpgs_build_info host_build_info() {
  return CRPGS_THIS_BUILD_INFO;
}

PluginLibrary::~PluginLibrary() {
  // RTLD_NODELETE keeps the code mapped anyway: autograd nodes defined in a plugin may outlive
  // every object it created, and unmapping them crashes on backward.
  if (handle_) dlclose(handle_);
}

StatusOr<std::shared_ptr<PluginLibrary>> PluginLibrary::open(const std::string& path) {
  if (!fs::exists(path)) return Status(StatusCode::kPluginLoadFailed, path + ": file not found");
  dlerror();
  void* h = dlopen(path.c_str(), RTLD_NOW | RTLD_LOCAL | RTLD_NODELETE);
  if (!h) {
    const char* e = dlerror();
    return Status(StatusCode::kPluginLoadFailed,
                  path + ": cannot load shared library: " + (e ? e : "unknown dlopen error"));
  }
  std::shared_ptr<PluginLibrary> lib(new PluginLibrary());
  lib->handle_ = h;
  lib->path_ = path;
  return lib;
}

void* PluginLibrary::symbol(const char* name) const {
  return dlsym(handle_, name);
}

namespace {

std::string str_or(const char* s) {
  return s ? s : "(null)";
}

// Validates the descriptor fields; `who` prefixes each message.
Status check_descriptor(const crpgs_plugin_descriptor* d, const std::string& who,
                        ComponentInfo* info) {
  auto fail = [&](StatusCode c, const std::string& m) { return Status(c, who + ": " + m); };
  if (!d) return fail(StatusCode::kPluginLoadFailed, "crpgs_plugin_v1() returned null");
  if (d->abi_version != CRPGS_PLUGIN_ABI_VERSION)
    return fail(StatusCode::kPluginAbiMismatch,
                "plugin ABI " + std::to_string(d->abi_version) + ", host expects " +
                    std::to_string(CRPGS_PLUGIN_ABI_VERSION) + "; rebuild it against crpgs " +
                    CRPGS_VERSION_STRING);
  const crpgs_build_info host = host_build_info();
  auto same = [](const char* a, const char* b) { return a && b && std::strcmp(a, b) == 0; };
  std::string diff;
  if (!same(d->build.compiler, host.compiler))
    diff += " compiler '" + str_or(d->build.compiler) + "' vs host '" + host.compiler + "';";
  if (!same(d->build.torch_version, host.torch_version))
    diff += " libtorch " + str_or(d->build.torch_version) + " vs host " + host.torch_version + ";";
  if (!same(d->build.cxx_abi, host.cxx_abi))
    diff += " C++ ABI " + str_or(d->build.cxx_abi) + " vs host " + host.cxx_abi + ";";
  if (d->build.cuda != host.cuda)
    diff += std::string(" CUDA ") + (d->build.cuda ? "on" : "off") + " vs host " +
            (host.cuda ? "on" : "off") + ";";
  if (!diff.empty()) {
    diff.pop_back();
    return fail(StatusCode::kPluginAbiMismatch,
                "build info does not match the host:" + diff +
                    " (torch::Tensor crosses the boundary, so "
                    "plugins must be built with the host's toolchain)");
  }
  if (d->kind < CRPGS_KIND_ENTROPY || d->kind > CRPGS_KIND_RASTERIZER)
    return fail(StatusCode::kPluginLoadFailed, "unknown component kind " + std::to_string(d->kind));
  if (!d->type_name || !*d->type_name || !d->id || !*d->id)
    return fail(StatusCode::kPluginLoadFailed, "descriptor has an empty type name or id");
  if (!d->create || !d->destroy)
    return fail(StatusCode::kPluginLoadFailed, "descriptor has no create/destroy function");
  auto schema = Schema::parse(d->schema_yaml ? d->schema_yaml : "");
  if (!schema.ok())
    return fail(StatusCode::kPluginLoadFailed,
                std::string(d->type_name) + ": " + schema.status().message());
  info->kind = static_cast<crpgs_kind>(d->kind);
  info->type = d->type_name;
  info->id = d->id;
  info->version_major = int(d->version_major);
  info->version_minor = int(d->version_minor);
  info->build = d->build;
  info->schema = std::move(schema).value();
  info->descriptor = d;
  return OkStatus();
}

std::string lower(std::string s) {
  for (auto& c : s) c = char(std::tolower(static_cast<unsigned char>(c)));
  return s;
}

}  // namespace

Status ComponentRegistry::add(ComponentInfo info) {
  for (const auto& c : components_) {
    if (c.kind == info.kind && lower(c.type) == lower(info.type))
      return Status(StatusCode::kPluginLoadFailed,
                    info.path + ": duplicate " + kind_name(info.kind) + " type '" + info.type +
                        "' (already provided by " + c.path + ")");
  }
  components_.push_back(std::move(info));
  return OkStatus();
}

Status ComponentRegistry::add_builtin(const crpgs_plugin_descriptor* descriptor) {
  ComponentInfo info;
  CRPGS_RETURN_IF_ERROR(check_descriptor(descriptor, "built-in", &info));
  info.path = "built-in";
  return add(std::move(info));
}

Status ComponentRegistry::load_plugin_file(const std::string& path) {
  auto reject = [&](const Status& s) {
    rejected_.push_back({path, s.message()});
    return s;
  };
  auto lib = PluginLibrary::open(path);
  if (!lib.ok()) return reject(lib.status());
  auto entry =
      reinterpret_cast<crpgs_plugin_entry_fn>(lib.value()->symbol(CRPGS_PLUGIN_ENTRY_SYMBOL));
  if (!entry)
    return reject(Status(StatusCode::kPluginLoadFailed,
                         path + ": not a crpgs plugin (no symbol " CRPGS_PLUGIN_ENTRY_SYMBOL ")"));
  ComponentInfo info;
  Status st = check_descriptor(entry(), path, &info);
  if (!st.ok()) return reject(st);
  info.path = path;
  info.library = lib.value();
  st = add(std::move(info));
  if (!st.ok()) return reject(st);
  return OkStatus();
}

void ComponentRegistry::load_plugins(const std::vector<std::string>& dirs) {
  std::vector<std::string> seen_files;
  for (const auto& dir : dirs) {
    std::error_code ec;
    const std::string canon = fs::weakly_canonical(dir, ec).string();
    if (std::find(searched_.begin(), searched_.end(), canon) != searched_.end()) continue;
    searched_.push_back(canon);
    if (!fs::is_directory(canon, ec)) {
      // An absent directory is normal (the install dir of a build that was not installed); one
      // that is there but cannot be read hides its plugins, so it is reported.
      if (ec && ec != std::errc::no_such_file_or_directory)
        rejected_.push_back({canon, "cannot read the directory: " + ec.message()});
      continue;
    }
    std::vector<std::string> files, subdirs;
    // Lists `d`: its .so files, and (for the top level) its subdirectories.
    auto list = [&](const fs::path& d, std::vector<std::string>* dirs_out) {
      std::error_code list_ec;
      for (fs::directory_iterator it(d, list_ec), end; !list_ec && it != end;
           it.increment(list_ec)) {
        std::error_code type_ec;
        if (it->is_regular_file(type_ec) && it->path().extension() == ".so")
          files.push_back(it->path().string());
        else if (dirs_out && it->is_directory(type_ec))
          dirs_out->push_back(it->path().string());
      }
      if (list_ec)
        rejected_.push_back({d.string(), "cannot read the directory: " + list_ec.message()});
    };
    list(canon, &subdirs);
    for (const auto& d : subdirs) list(d, nullptr);
    std::sort(files.begin(), files.end());
    for (const auto& f : files) {
      const std::string cf = fs::weakly_canonical(f, ec).string();
      if (std::find(seen_files.begin(), seen_files.end(), cf) != seen_files.end()) continue;
      seen_files.push_back(cf);
      (void)load_plugin_file(f);  // rejections are recorded
    }
  }
}

const ComponentInfo* ComponentRegistry::find(crpgs_kind kind, const std::string& type) const {
  for (const auto& c : components_)
    if (c.kind == kind && lower(c.type) == lower(type)) return &c;
  return nullptr;
}

std::vector<std::string> ComponentRegistry::types(crpgs_kind kind) const {
  std::vector<std::string> out;
  for (const auto& c : components_)
    if (c.kind == kind) out.push_back(c.type);
  std::sort(out.begin(), out.end());
  return out;
}

StatusOr<std::shared_ptr<void>> ComponentRegistry::create_raw(crpgs_kind kind,
                                                              const YAML::Node& resolved_block,
                                                              const crpgs_create_args& args) const {
  const std::string type = resolved_block["type"] ? resolved_block["type"].as<std::string>() : "";
  const ComponentInfo* info = find(kind, type);
  if (!info) {
    return Status(StatusCode::kNotFound, std::string("unknown ") + kind_name(kind) + " type '" +
                                             type + "'" + did_you_mean(type, types(kind)) +
                                             " (available: " + join(types(kind)) + ")");
  }
  YAML::Emitter e;
  e << resolved_block;
  char err[2048] = {0};
  void* obj = nullptr;
  const int rc = info->descriptor->create(e.c_str(), &args, &obj, err, sizeof(err));
  err[sizeof(err) - 1] = 0;  // a plugin that filled the buffer without terminating it
  if (rc != CRPGS_PLUGIN_OK || !obj) {
    return Status(StatusCode::kInvalidConfig,
                  std::string(kind_name(kind)) + " '" + type + "' (" + info->path +
                      "): create failed: " + (err[0] ? err : "no message"));
  }
  auto destroy = info->descriptor->destroy;
  auto lib = info->library;  // keeps the plugin loaded while the object lives
  return std::shared_ptr<void>(obj, [destroy, lib](void* p) { destroy(p); });
}

std::vector<std::string> default_plugin_dirs(const std::vector<std::string>& plugin_dirs) {
  std::vector<std::string> dirs = plugin_dirs;
  if (const char* env = std::getenv("CRPGS_PLUGIN_PATH")) {
    std::stringstream ss(env);
    for (std::string d; std::getline(ss, d, ':');)
      if (!d.empty()) dirs.push_back(d);
  }
  std::error_code ec;
  const fs::path exe = fs::read_symlink("/proc/self/exe", ec);
  if (!ec) dirs.push_back((exe.parent_path().parent_path() / CRPGS_PLUGIN_SUBDIR).string());
  dirs.push_back(CRPGS_INSTALL_PLUGIN_DIR);
  return dirs;
}

}  // namespace crpgs

namespace crpgs {
BuildInfo build_info() {
  const crpgs_build_info b = host_build_info();
  // The release as its package names it, where the build found one (sdk/CMakeLists.txt).
  const char* torch = CRPGS_TORCH_RELEASE[0] != '\0' ? CRPGS_TORCH_RELEASE : b.torch_version;
  return BuildInfo{CRPGS_VERSION_STRING, CRPGS_GIT_COMMIT, b.compiler, torch, b.cuda != 0};
}
}  // namespace crpgs
