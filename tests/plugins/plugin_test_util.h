/// @file plugin_test_util.h
/// @brief Builds in-tree plugin components through the registry, as the pipeline does.
#pragma once

#include <memory>
#include <string>

#include <gtest/gtest.h>

#include "crpgs/components.h"
#include "crpgs/config.h"
#include "test_registry.h"

namespace crpgs::test {

inline const ComponentRegistry& plugin_registry() {
  return test_registry();
}

/// `section: {type: ..., extra}` resolved and built; fails the test on error.
template <typename T>
std::shared_ptr<T> make_plugin(const std::string& section, const std::string& block_yaml,
                               crpgs_create_args args = {50, 10, 0, 50, {0, 0, 0, 0}}) {
  auto cfg = Config::from_string(section + ": " + block_yaml + "\n", "test.yaml");
  EXPECT_TRUE(cfg.ok()) << cfg.status().to_string();
  if (!cfg.ok()) return nullptr;
  auto resolved = cfg->resolve(plugin_registry());
  EXPECT_TRUE(resolved.ok()) << resolved.status().to_string();
  if (!resolved.ok()) return nullptr;
  auto c = create_component<T>(plugin_registry(), resolved->section(section), args);
  EXPECT_TRUE(c.ok()) << c.status().to_string();
  return c.ok() ? c.value() : nullptr;
}

}  // namespace crpgs::test
