/// @file test_conformance.cpp
/// @brief One suite over every registered component (built-ins and the in-tree plugins): it builds
/// from defaults, and hyperparams() round-trips to an identical resolved config and object.
#include <gtest/gtest.h>

#include <ostream>

#include "crpgs/components.h"
#include "test_registry.h"

namespace crpgs {
namespace {

const ComponentRegistry& registry() {
  return test::test_registry();
}

struct ComponentCase {
  crpgs_kind kind;
  std::string type;
  friend std::ostream& operator<<(std::ostream& os, const ComponentCase& c) {
    return os << kind_name(c.kind) << "/" << c.type;
  }
};

std::vector<ComponentCase> all_components() {
  std::vector<ComponentCase> out;
  for (const auto& c : registry().components()) out.push_back({c.kind, c.type});
  return out;
}

const char* section_for(crpgs_kind kind) {
  for (const auto& s : component_sections())
    if (s.kind == kind) return s.key;
  return "";
}

StatusOr<std::shared_ptr<Component>> make(crpgs_kind kind, const YAML::Node& block) {
  const crpgs_create_args args{50, 10, 0, 50, {0, 0, 0, 0}};
  switch (kind) {
    case CRPGS_KIND_ENTROPY: {
      auto c = create_component<EntropyModel>(registry(), block, args);
      if (!c.ok()) return c.status();
      return std::shared_ptr<Component>(c.value());
    }
    case CRPGS_KIND_CONTEXT: {
      auto c = create_component<ContextModel>(registry(), block, args);
      if (!c.ok()) return c.status();
      return std::shared_ptr<Component>(c.value());
    }
    case CRPGS_KIND_FEATURES: {
      auto c = create_component<FeatureModel>(registry(), block, args);
      if (!c.ok()) return c.status();
      return std::shared_ptr<Component>(c.value());
    }
    case CRPGS_KIND_RASTERIZER: {
      auto c = create_component<Rasterizer>(registry(), block, args);
      if (!c.ok()) return c.status();
      return std::shared_ptr<Component>(c.value());
    }
  }
  return Status(StatusCode::kInternal, "bad kind");
}

std::string emit(const YAML::Node& n) {
  YAML::Emitter e;
  e << n;
  return e.c_str();
}

class Conformance : public ::testing::TestWithParam<ComponentCase> {};

TEST_P(Conformance, BuildsFromDefaultsAndHyperparamsRoundTrip) {
  const auto& c = GetParam();
  const std::string section = section_for(c.kind);
  auto cfg = Config::from_string(section + ": {type: " + c.type + "}\n", "conformance.yaml");
  ASSERT_TRUE(cfg.ok());
  auto resolved = cfg->resolve(registry());
  ASSERT_TRUE(resolved.ok()) << resolved.status().to_string();
  const YAML::Node block = resolved->section(section);

  auto obj = make(c.kind, block);
  ASSERT_TRUE(obj.ok()) << obj.status().to_string();
  EXPECT_EQ(obj.value()->type_name(), c.type);

  // hyperparams() is written from the object's members: it must resolve to the same block...
  const YAML::Node hp = obj.value()->hyperparams();
  YAML::Node root;
  root[section] = hp;
  auto again = Config::from_string(emit(root), "hyperparams.yaml");
  ASSERT_TRUE(again.ok());
  auto resolved_again = again->resolve(registry());
  ASSERT_TRUE(resolved_again.ok()) << resolved_again.status().to_string();
  EXPECT_EQ(emit(resolved_again->section(section)), emit(block));
  // ...list every key of the schema (nothing left to defaults by accident)...
  for (const auto& p : registry().find(c.kind, c.type)->schema.params())
    EXPECT_TRUE(hp[p.key].IsDefined()) << c.type << ": hyperparams() lacks '" << p.key << "'";
  // ...and an object built from it reports the same hyperparams.
  auto obj2 = make(c.kind, resolved_again->section(section));
  ASSERT_TRUE(obj2.ok()) << obj2.status().to_string();
  EXPECT_EQ(emit(obj2.value()->hyperparams()), emit(hp));
}

INSTANTIATE_TEST_SUITE_P(AllComponents, Conformance, ::testing::ValuesIn(all_components()),
                         [](const ::testing::TestParamInfo<ComponentCase>& info) {
                           return std::string(kind_name(info.param.kind)) + "_" + info.param.type;
                         });

TEST(ConformanceRegistry, HasTheBuiltinsAndInTreePlugins) {
  for (auto [kind, type] :
       std::vector<std::pair<crpgs_kind, std::string>>{{CRPGS_KIND_RASTERIZER, "cpu"},
                                                       {CRPGS_KIND_FEATURES, "identity"},
                                                       {CRPGS_KIND_ENTROPY, "gaussian"},
                                                       {CRPGS_KIND_CONTEXT, "link_none"}})
    EXPECT_NE(registry().find(kind, type), nullptr) << kind_name(kind) << "/" << type;
  EXPECT_TRUE(registry().rejected().empty())
      << registry().rejected()[0].path << ": " << registry().rejected()[0].reason;
}

TEST(ConformanceRegistry, CudaInACpuBuildIsAClearError) {
  if (registry().find(CRPGS_KIND_RASTERIZER, "cuda"))
    GTEST_SKIP() << "this build has the CUDA rasterizer";
  auto cfg = Config::from_string("rasterizer: {type: cuda}\n", "cuda.yaml");
  ASSERT_TRUE(cfg.ok());
  auto r = cfg->resolve(registry());
  ASSERT_FALSE(r.ok());
  EXPECT_NE(r.status().message().find("rasterizer 'cuda' is not compiled into this build"),
            std::string::npos)
      << r.status().message();
  EXPECT_NE(r.status().message().find("available: cpu"), std::string::npos);
}

}  // namespace
}  // namespace crpgs
