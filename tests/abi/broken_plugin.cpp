/// @file broken_plugin.cpp
/// @brief Deliberately broken plugins, one per BROKEN_* define, built by tests/abi/targets.cmake.
/// Each must be rejected (or fail to create) with its specific message, never crash the host.
#include <cstdio>

#include "crpgs/plugin.h"

#ifndef BROKEN_TYPE
#define BROKEN_TYPE "broken"
#endif

namespace {
[[maybe_unused]] int create_ok(const char*, const crpgs_create_args*, void** out, char*, size_t) {
  static int object;
  *out = &object;
  return CRPGS_PLUGIN_OK;
}
[[maybe_unused]] int create_fails(const char*, const crpgs_create_args*, void**, char* err,
                                  size_t len) {
  std::snprintf(err, len, "deliberate failure: the test plugin refuses to build");
  return CRPGS_PLUGIN_ERROR;
}
[[maybe_unused]] void destroy(void*) {}
}  // namespace

#ifdef BROKEN_NOT_A_PLUGIN
extern "C" __attribute__((visibility("default"))) int some_other_function() {
  return 42;
}
#else
extern "C" __attribute__((visibility("default"))) const crpgs_plugin_descriptor* crpgs_plugin_v1() {
  static crpgs_plugin_descriptor d = {CRPGS_PLUGIN_ABI_VERSION,
                                      CRPGS_KIND_FEATURES,
                                      "org.crpgs.test." BROKEN_TYPE,
                                      BROKEN_TYPE,
                                      1,
                                      0,
                                      CRPGS_THIS_BUILD_INFO,
                                      "[]",
                                      &create_ok,
                                      &destroy};
#ifdef BROKEN_WRONG_ABI
  d.abi_version = CRPGS_PLUGIN_ABI_VERSION + 41;
#endif
#ifdef BROKEN_BUILD_INFO
  d.build.torch_version = "0.4.1";
#endif
#ifdef BROKEN_CREATE_FAILS
  d.create = &create_fails;
#endif
#ifdef BROKEN_SCHEMA
  d.schema_yaml = "- {key: x, type: int, default: [unclosed";
#endif
  return &d;
}
#endif
