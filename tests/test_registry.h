/// @file test_registry.h
/// @brief The registry tests build components from: the built-ins plus every plugin of this build
/// tree (CRPGS_PLUGIN_BUILD_DIR), loaded once per test process.
#pragma once

#include "crpgs/components.h"

namespace crpgs::test {

inline const ComponentRegistry& test_registry() {
  static const ComponentRegistry r = [] {
    ComponentRegistry reg = builtin_registry();
    reg.load_plugins({CRPGS_PLUGIN_BUILD_DIR});
    return reg;
  }();
  return r;
}

}  // namespace crpgs::test
