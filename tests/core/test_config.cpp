/// @file test_config.cpp
/// @brief Schema parsing, config validation messages (file:line:col + YAML path), --set.
#include <gtest/gtest.h>

#include "crpgs/config.h"
#include "crpgs/plugin_abi.h"
#include "crpgs/registry.h"
#include "crpgs/version.h"

namespace crpgs {
namespace {

// A torch-free built-in descriptor so the config tests need no component code.
int fake_create(const char*, const crpgs_create_args*, void** out, char*, size_t) {
  static int dummy;
  *out = &dummy;
  return CRPGS_PLUGIN_OK;
}
void fake_destroy(void*) {}

const crpgs_plugin_descriptor* fake_descriptor(crpgs_kind kind, const char* type,
                                               const char* schema) {
  auto* d = new crpgs_plugin_descriptor{CRPGS_PLUGIN_ABI_VERSION,
                                        static_cast<uint32_t>(kind),
                                        "org.test.fake",
                                        type,
                                        1,
                                        0,
                                        host_build_info(),
                                        schema,
                                        &fake_create,
                                        &fake_destroy};
  return d;
}

ComponentRegistry test_registry() {
  ComponentRegistry r;
  EXPECT_TRUE(r.add_builtin(fake_descriptor(CRPGS_KIND_RASTERIZER, "cpu", "[]")).ok());
  EXPECT_TRUE(r.add_builtin(fake_descriptor(CRPGS_KIND_FEATURES, "identity", "[]")).ok());
  EXPECT_TRUE(r
                  .add_builtin(fake_descriptor(
                      CRPGS_KIND_FEATURES, "sfa",
                      "- {key: ratio, type: float, default: 0.4, min: 0, max: 1, doc: shared}\n"
                      "- {key: mode, type: choice, default: grid, choices: [grid, plane], doc: m}\n"
                      "- {key: levels, type: int_list, default: [1, 2], min: 1, doc: l}\n"))
                  .ok());
  return r;
}

Status resolve_text(const std::string& text, std::vector<std::string> sets = {}) {
  auto cfg = Config::from_string(text, "test.yaml");
  if (!cfg.ok()) return cfg.status();
  for (const auto& s : sets) CRPGS_RETURN_IF_ERROR(cfg->apply_override(s));
  return cfg->resolve(test_registry()).status();
}

TEST(Schema, ParsesAndRoundTrips) {
  auto s = Schema::parse(
      "- {key: a, type: float, default: 0.5, min: 0, max: 1, min_exclusive: true, doc: x}\n"
      "- {key: b, type: choice, default: u, choices: [u, v], doc: y}\n");
  ASSERT_TRUE(s.ok()) << s.status().to_string();
  EXPECT_EQ(s->params().size(), 2u);
  EXPECT_EQ(s->find("a")->expected(), "float in (0, 1]");
  EXPECT_EQ(s->find("b")->expected(), "one of {u, v}");
  auto again = Schema::parse(s->to_yaml());
  ASSERT_TRUE(again.ok());
  EXPECT_EQ(again->to_yaml(), s->to_yaml());
}

TEST(Schema, RejectsBrokenSchemas) {
  EXPECT_FALSE(Schema::parse("- {key: a, type: nosuchtype, default: 1}").ok());
  EXPECT_FALSE(Schema::parse("- {key: a, type: int}").ok());  // no default
  EXPECT_FALSE(
      Schema::parse("- {key: a, type: int, default: 5, max: 2}").ok());      // default out of range
  EXPECT_FALSE(Schema::parse("- {key: a, type: choice, default: x}").ok());  // no choices
  EXPECT_FALSE(Schema::parse("{not: a list}").ok());
  EXPECT_FALSE(Schema::parse("- [unclosed").ok());
}

TEST(Config, ResolvesDefaultsAndComponents) {
  auto cfg = Config::from_string("features: {type: sfa, ratio: 0.2}\n", "t.yaml");
  ASSERT_TRUE(cfg.ok());
  auto r = cfg->resolve(test_registry());
  ASSERT_TRUE(r.ok()) << r.status().to_string();
  EXPECT_DOUBLE_EQ(r->section("features")["ratio"].as<double>(), 0.2);
  EXPECT_EQ(r->section("features")["mode"].as<std::string>(), "grid");
  EXPECT_EQ(r->section("rasterizer")["type"].as<std::string>(), "cpu");  // default type filled
  EXPECT_EQ(r->section("dataset")["test_every"].as<int>(), 8);           // core default filled
  // Resolving a resolved config is the identity.
  auto again = Config::from_string(r->dump(), "again.yaml");
  ASSERT_TRUE(again.ok());
  auto r2 = again->resolve(test_registry());
  ASSERT_TRUE(r2.ok());
  EXPECT_EQ(r2->dump(), r->dump());
  EXPECT_EQ(r2->hash(), r->hash());
}

// Each kind of bad YAML names file:line:col, the YAML path and what was expected.
TEST(Config, UnknownKeyNamesLineAndValidKeys) {
  Status st = resolve_text("features:\n  type: sfa\n  ratoi: 0.3\n");
  ASSERT_FALSE(st.ok());
  EXPECT_NE(st.message().find("test.yaml:3:3"), std::string::npos) << st.message();
  EXPECT_NE(st.message().find("features.ratoi: unknown key"), std::string::npos) << st.message();
  EXPECT_NE(st.message().find("ratio"), std::string::npos) << st.message();
}

TEST(Config, WrongTypeAndOutOfRange) {
  Status st = resolve_text("features: {type: sfa, ratio: high}\n");
  ASSERT_FALSE(st.ok());
  EXPECT_NE(st.message().find("test.yaml:1:30"), std::string::npos) << st.message();
  EXPECT_NE(st.message().find("not a number; expected float in [0, 1]"), std::string::npos)
      << st.message();
  st = resolve_text("features: {type: sfa, ratio: 1.5}\n");
  EXPECT_NE(st.message().find("features.ratio: '1.5' is out of range"), std::string::npos)
      << st.message();
  st = resolve_text("features: {type: sfa, mode: cube}\n");
  EXPECT_NE(st.message().find("expected one of {grid, plane}"), std::string::npos) << st.message();
  st = resolve_text("features: {type: sfa, levels: [1, 0]}\n");
  EXPECT_NE(st.message().find("list element out of range"), std::string::npos) << st.message();
  st = resolve_text("dataset:\n  downscale: 2.5\n");
  EXPECT_NE(st.message().find("test.yaml:2:14: dataset.downscale: '2.5' is not an integer"),
            std::string::npos)
      << st.message();
}

TEST(Config, UnknownTypeListsAvailableAndSearchPath) {
  Status st = resolve_text("features:\n  type: sfx\n");
  ASSERT_FALSE(st.ok());
  EXPECT_NE(st.message().find("test.yaml:2:9: features.type: unknown features type 'sfx' "
                              "(available: identity, sfa; plugins searched in:"),
            std::string::npos)
      << st.message();
}

TEST(Config, UnknownSectionAndSyntaxError) {
  Status st = resolve_text("trian: {iterations: 3}\n");
  EXPECT_NE(st.message().find("test.yaml:1:1: trian: unknown section"), std::string::npos)
      << st.message();
  st = resolve_text("dataset: [1, 2\n");
  EXPECT_NE(st.message().find("YAML syntax error"), std::string::npos) << st.message();
  EXPECT_NE(st.message().find("test.yaml:2:"), std::string::npos) << st.message();
  st = resolve_text("- just\n- a list\n");
  EXPECT_NE(st.message().find("must be a YAML map"), std::string::npos) << st.message();
}

TEST(Config, SetOverridesAnyKeyAndReportsItsOrigin) {
  auto cfg = Config::from_string("features: {type: sfa}\n", "t.yaml");
  ASSERT_TRUE(cfg.ok());
  ASSERT_TRUE(cfg->apply_override("features.ratio=0.6").ok());
  ASSERT_TRUE(cfg->apply_override("dataset.path=/data/x").ok());  // creates the section
  auto r = cfg->resolve(test_registry());
  ASSERT_TRUE(r.ok()) << r.status().to_string();
  EXPECT_DOUBLE_EQ(r->section("features")["ratio"].as<double>(), 0.6);
  EXPECT_EQ(r->section("dataset")["path"].as<std::string>(), "/data/x");

  Status st = resolve_text("features: {type: sfa}\n", {"features.ratio=7"});
  EXPECT_NE(st.message().find("(--set): features.ratio: '7' is out of range"), std::string::npos)
      << st.message();
  auto bad = Config::from_string("{}", "t.yaml");
  EXPECT_FALSE(bad->apply_override("no_equals_sign").ok());
  EXPECT_FALSE(bad->apply_override("a..b=1").ok());
  ASSERT_TRUE(bad->apply_override("dataset.path=x").ok());
  EXPECT_FALSE(bad->apply_override("dataset.path.deeper=1").ok());  // path is a scalar
}

}  // namespace
}  // namespace crpgs
