/// @file plugin.h
/// @brief What a plugin (or a built-in component) writes to describe itself:
///
///   CRPGS_PLUGIN(CRPGS_KIND_FEATURES, crpgs::FeatureModel, MyFeatures,
///                "org.example.features.mine", "mine", 1, 0, kMySchemaYaml)
///
/// defines the exported entry point crpgs_plugin_v1(). `MyFeatures` needs a constructor
/// `MyFeatures(const YAML::Node& resolved_config, const crpgs_create_args& args)`; it may throw,
/// the generated create() turns any exception into a status and message.
#pragma once

#include <cstdio>
#include <exception>
#include <string>

#include <torch/version.h>
#include <yaml-cpp/yaml.h>

#include "crpgs/plugin_abi.h"
#include "crpgs/version.h"

#define CRPGS_STRINGIFY_INNER(x) #x
#define CRPGS_STRINGIFY(x) CRPGS_STRINGIFY_INNER(x)

#if defined(__clang__)
#define CRPGS_COMPILER_STRING "Clang " __clang_version__
#elif defined(__GNUC__)
#define CRPGS_COMPILER_STRING "GCC " CRPGS_STRINGIFY(__GNUC__) "." CRPGS_STRINGIFY(__GNUC_MINOR__)
#else
#define CRPGS_COMPILER_STRING "unknown"
#endif

#if defined(_GLIBCXX_USE_CXX11_ABI) && _GLIBCXX_USE_CXX11_ABI == 0
#define CRPGS_CXX_ABI_STRING "old"
#else
#define CRPGS_CXX_ABI_STRING "cxx11"
#endif

#ifndef CRPGS_BUILT_WITH_CUDA
#define CRPGS_BUILT_WITH_CUDA 0
#endif

/// The build info of the translation unit that expands it.
#define CRPGS_THIS_BUILD_INFO                                                         \
  crpgs_build_info {                                                                  \
    CRPGS_COMPILER_STRING, TORCH_VERSION, CRPGS_CXX_ABI_STRING, CRPGS_BUILT_WITH_CUDA \
  }

namespace crpgs::detail {

inline void write_error(char* err, size_t err_len, const char* msg) {
  if (err && err_len > 0) std::snprintf(err, err_len, "%s", msg);
}

template <typename Interface, typename Impl>
int create_component(const char* config_yaml, const crpgs_create_args* args, void** out, char* err,
                     size_t err_len) noexcept {
  try {
    if (!args || !out) {
      write_error(err, err_len, "create() called with null arguments");
      return CRPGS_PLUGIN_ERROR;
    }
    YAML::Node node = YAML::Load(config_yaml ? config_yaml : "{}");
    Interface* obj = new Impl(node, *args);
    *out = static_cast<void*>(obj);
    return CRPGS_PLUGIN_OK;
  } catch (const std::exception& e) {
    write_error(err, err_len, e.what());
  } catch (...) {
    write_error(err, err_len, "unknown exception in create()");
  }
  return CRPGS_PLUGIN_ERROR;
}

template <typename Interface>
void destroy_component(void* obj) noexcept {
  delete static_cast<Interface*>(obj);
}

}  // namespace crpgs::detail

/// Defines a static descriptor and a function `fn` returning it (for built-ins).
#define CRPGS_DESCRIPTOR_FUNCTION(fn, KIND, Interface, Impl, ID, TYPE, VMAJ, VMIN, SCHEMA)         \
  const crpgs_plugin_descriptor* fn() {                                                            \
    static const crpgs_plugin_descriptor d = {CRPGS_PLUGIN_ABI_VERSION,                            \
                                              static_cast<uint32_t>(KIND),                         \
                                              ID,                                                  \
                                              TYPE,                                                \
                                              VMAJ,                                                \
                                              VMIN,                                                \
                                              CRPGS_THIS_BUILD_INFO,                               \
                                              SCHEMA,                                              \
                                              &::crpgs::detail::create_component<Interface, Impl>, \
                                              &::crpgs::detail::destroy_component<Interface>};     \
    return &d;                                                                                     \
  }

/// Defines the exported entry point of a plugin library.
#define CRPGS_PLUGIN(KIND, Interface, Impl, ID, TYPE, VMAJ, VMIN, SCHEMA) \
  extern "C" __attribute__((visibility("default")))                       \
  CRPGS_DESCRIPTOR_FUNCTION(crpgs_plugin_v1, KIND, Interface, Impl, ID, TYPE, VMAJ, VMIN, SCHEMA)
