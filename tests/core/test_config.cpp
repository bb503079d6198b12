/// @file test_config.cpp
/// @brief Schema parsing, config validation messages (file:line:col + YAML path), --set,
/// inheritance (`base:`).
#include <gtest/gtest.h>
#include <sys/stat.h>

#include <filesystem>
#include <fstream>
#include <thread>

#include "core/text_list.h"
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
  // A plugin's schema is data from a shared library: malformed fields are refused, never thrown.
  for (const char* bad :
       {"- {key: [a], type: int, default: 1}", "- {key: a, type: {x: 1}, default: 1}",
        "- {key: a, type: choice, default: x, choices: [[x]]}",
        "- {key: a, type: int, default: 1, doc: {x: 1}}",
        "- {key: a, type: int, default: 1, min_exclusive: maybe}",
        "- {key: a, type: int, default: 1, min: 3, max: 2}",
        "- {key: type, type: string, default: foo}"}) {
    auto s = Schema::parse(bad);
    ASSERT_FALSE(s.ok()) << bad;
    EXPECT_EQ(s.status().message().rfind("schema: ", 0), 0u) << s.status().message();
  }
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

// What people read (config check, RUN_DIR/config.yaml) has floats as written (0.0002, not
// 0.00020000000000000001); reading it back gives the canonical text and hash bitstreams carry.
TEST(Config, SavedTextHasShortFloatsAndReadsBackToTheSameHash) {
  auto cfg = Config::from_string(
      "features: {type: sfa, ratio: 0.2}\ntrain: {lambda_dssim: 0.1, iterations: 30}\n"
      "rate: {lambda: 2.0e-5}\n",
      "t.yaml");
  ASSERT_TRUE(cfg.ok());
  auto r = cfg->resolve(test_registry());
  ASSERT_TRUE(r.ok()) << r.status().to_string();
  const std::string text = r->to_yaml();
  EXPECT_NE(text.find("lambda_dssim: 0.1\n"), std::string::npos) << text;
  EXPECT_NE(text.find("ratio: 0.2\n"), std::string::npos) << text;
  EXPECT_NE(text.find("lambda: 2e-05\n"), std::string::npos) << text;
  EXPECT_NE(text.find("iterations: 30\n"), std::string::npos) << text;
  EXPECT_EQ(text.find("0000000"), std::string::npos) << text;
  EXPECT_NE(r->dump().find("0.10000000000000001"), std::string::npos);  // canonical: as before
  auto back = Config::from_string(text, "back.yaml");
  ASSERT_TRUE(back.ok());
  auto r2 = back->resolve(test_registry());
  ASSERT_TRUE(r2.ok()) << r2.status().to_string();
  EXPECT_EQ(r2->dump(), r->dump());
  EXPECT_EQ(r2->hash(), r->hash());
}

// Each kind of bad YAML names file:line:col, the YAML path and what was expected.
TEST(Config, UnknownKeyNamesLineAndValidKeys) {
  Status st = resolve_text("features:\n  type: sfa\n  ratoi: 0.3\n");
  ASSERT_FALSE(st.ok());
  EXPECT_NE(st.message().find("test.yaml:3:3"), std::string::npos) << st.message();
  EXPECT_NE(st.message().find("features.ratoi: unknown key, did you mean 'ratio'? (valid keys: "),
            std::string::npos)
      << st.message();
  // Nothing near enough: no guess, only the list.
  st = resolve_text("rate:\n  bandwidth: 3\n");
  EXPECT_NE(st.message().find("rate.bandwidth: unknown key (valid keys: "), std::string::npos)
      << st.message();
  st = resolve_text("rate:\n  lamda: 0.1\n");
  EXPECT_NE(st.message().find("did you mean 'lambda'?"), std::string::npos) << st.message();
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

TEST(Config, IntegersAreDecimalAndHugeOnesOutOfRange) {
  auto resolved = [](const std::string& text) {
    auto cfg = Config::from_string(text, "test.yaml");
    return cfg.ok() ? cfg->resolve(test_registry()) : StatusOr<Config>(cfg.status());
  };
  auto r = resolved("train: {iterations: 010}\n");
  ASSERT_TRUE(r.ok()) << r.status().to_string();
  EXPECT_EQ(r->section("train")["iterations"].as<int>(), 10);  // not octal 8
  EXPECT_NE(resolved("train: {iterations: 0x10}\n").status().message().find("not an integer"),
            std::string::npos);
  EXPECT_NE(resolved("train: {iterations: 99999999999999999999999}\n")
                .status()
                .message()
                .find("'99999999999999999999999' is out of range"),
            std::string::npos);
}

TEST(Config, KeysGivenTwiceAndSecondDocumentsAreRefused) {
  // yaml-cpp would keep the first section and the last key: neither is what a reader expects.
  Status st = resolve_text("train: {iterations: 5}\ndataset: {}\ntrain: {seed: 3}\n");
  EXPECT_NE(st.message().find("test.yaml:3:1: train: key given twice (first at line 1)"),
            std::string::npos)
      << st.message();
  st = resolve_text("train:\n  iterations: 5\n  iterations: 7\n");
  EXPECT_NE(st.message().find("test.yaml:3:3: iterations: key given twice (first at line 2)"),
            std::string::npos)
      << st.message();
  st = resolve_text("train: {seed: 1}\n---\ntrain: {seed: 2}\n");
  EXPECT_NE(st.message().find("a second YAML document"), std::string::npos) << st.message();
  // A trailing `---` (with a comment) holds nothing: fine.
  EXPECT_TRUE(resolve_text("train: {seed: 1}\n---\n# end\n").ok());
}

TEST(Config, AliasesThatExpandExponentiallyAreRefusedQuickly) {
  std::string text = "a0: &a0 [1, 2, 3, 4, 5, 6, 7, 8, 9, 10]\n";
  for (int i = 1; i <= 9; ++i) {
    text += "a" + std::to_string(i) + ": &a" + std::to_string(i) + " [";
    for (int k = 0; k < 10; ++k) text += (k ? ", *a" : "*a") + std::to_string(i - 1);
    text += "]\n";
  }
  Status st = Config::from_string(text, "bomb.yaml").status();  // 10^10 values if expanded
  EXPECT_NE(st.message().find("bomb.yaml: more than 100000 values once its aliases are expanded"),
            std::string::npos)
      << st.message();
  // A few aliases are fine.
  EXPECT_TRUE(resolve_text("train: &t {seed: 4}\n").ok());
}

TEST(Config, SetKeysEndingInADotAreRefused) {
  auto cfg = Config::from_string("train: {seed: 1}\n", "t.yaml");
  ASSERT_TRUE(cfg.ok());
  Status st = cfg->apply_override("train.=1");
  EXPECT_NE(st.message().find("--set 'train.': empty key"), std::string::npos) << st.message();
}

TEST(Config, UnknownTypeListsAvailableAndSearchPath) {
  Status st = resolve_text("features:\n  type: sfx\n");
  ASSERT_FALSE(st.ok());
  EXPECT_NE(st.message().find("test.yaml:2:9: features.type: unknown features type 'sfx', did "
                              "you mean 'sfa'? (available: identity, sfa; plugins searched in:"),
            std::string::npos)
      << st.message();
}

TEST(Config, UnknownSectionAndSyntaxError) {
  Status st = resolve_text("trian: {iterations: 3}\n");
  EXPECT_NE(st.message().find("test.yaml:1:1: trian: unknown section, did you mean 'train'?"),
            std::string::npos)
      << st.message();
  st = resolve_text("dataset: [1, 2\n");
  EXPECT_NE(st.message().find("YAML syntax error"), std::string::npos) << st.message();
  EXPECT_NE(st.message().find("test.yaml:2:"), std::string::npos) << st.message();
  st = resolve_text("- just\n- a list\n");
  EXPECT_NE(st.message().find("must be a YAML map"), std::string::npos) << st.message();
  st = resolve_text("train:\n  ? [a, b]\n  : 1\n");
  EXPECT_NE(st.message().find("test.yaml:2:5: a key must be a plain name"), std::string::npos)
      << st.message();
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

TEST(Config, RelativeDatasetPathsAreMadeAbsoluteAgainstTheGivenBase) {
  auto cfg = Config::from_string("dataset: {path: data/../data/fern}\n", "t.yaml");
  ASSERT_TRUE(cfg.ok());
  ASSERT_TRUE(make_dataset_path_absolute(cfg.value(), "/work/here").ok());
  EXPECT_EQ(cfg->section("dataset")["path"].as<std::string>(), "/work/here/data/fern");
  ASSERT_TRUE(make_dataset_path_absolute(cfg.value(), "/elsewhere").ok());  // absolute: kept
  EXPECT_EQ(cfg->section("dataset")["path"].as<std::string>(), "/work/here/data/fern");
  // The path is YAML-parsed again on the way in: '#' and ': ' must survive it.
  for (const std::string odd : {"data #2", "a: b", "it's \"here\""}) {
    auto c = Config::from_string("train: {seed: 1}\n", "t.yaml");
    YAML::Emitter quoted;
    quoted << YAML::DoubleQuoted << odd;
    ASSERT_TRUE(c->apply_override(std::string("dataset.path=") + quoted.c_str()).ok());
    ASSERT_TRUE(make_dataset_path_absolute(c.value(), "/run #3").ok());
    EXPECT_EQ(c->section("dataset")["path"].as<std::string>(), "/run #3/" + odd);
  }
  auto none = Config::from_string("train: {threads: 1}\n", "t.yaml");
  ASSERT_TRUE(make_dataset_path_absolute(none.value(), "/x").ok());
  EXPECT_FALSE(none->section("dataset").IsDefined());
}

// A directory of config files for one test: name -> text.
std::string write_configs(const std::string& test,
                          const std::vector<std::pair<std::string, std::string>>& files) {
  const std::string dir = testing::TempDir() + "crpgs_config_" + test + "/";
  std::filesystem::remove_all(dir);
  for (const auto& [name, text] : files) {
    std::filesystem::create_directories(std::filesystem::path(dir + name).parent_path());
    std::ofstream(dir + name) << text;
  }
  return dir;
}

TEST(ConfigBase, InheritsMergesOverridesAndRemoves) {
  const std::string dir = write_configs(
      "inherit", {{"full.yaml",
                   "dataset: {path: data/fern, format: colmap}\n"
                   "train: {iterations: 900, seed: 3}\n"
                   "features: {type: sfa, ratio: 0.4, mode: plane}\n"
                   "entropy: {type: sfa}\n"},
                  {"more.yaml", "train: {seed: 5}\n"},
                  {"identity.yaml", "base: full.yaml\nfeatures: {type: identity}\nentropy: null\n"},
                  {"ablations/x.yaml",
                   "base: [../full.yaml, ../more.yaml]\n"
                   "features: {ratio: 0.2}\n"
                   "entropy: null\n"}});
  auto cfg = Config::load_file(dir + "ablations/x.yaml");
  ASSERT_TRUE(cfg.ok()) << cfg.status().to_string();
  const YAML::Node& root = cfg->root();
  EXPECT_FALSE(root["base"].IsDefined());
  EXPECT_EQ(root["train"]["iterations"].as<int>(), 900);          // from full.yaml
  EXPECT_EQ(root["train"]["seed"].as<int>(), 5);                  // the later base wins
  EXPECT_DOUBLE_EQ(root["features"]["ratio"].as<double>(), 0.2);  // this file wins
  EXPECT_EQ(root["features"]["type"].as<std::string>(), "sfa");   // merged key by key
  EXPECT_EQ(root["features"]["mode"].as<std::string>(), "plane");
  EXPECT_TRUE(root["entropy"].IsNull());  // removed
  // The dataset path is relative to the file that names it, not to the one that inherits it.
  EXPECT_EQ(root["dataset"]["path"].as<std::string>(),
            (std::filesystem::absolute(dir) / "data/fern").lexically_normal().string());
  auto resolved = cfg->resolve(test_registry());
  ASSERT_TRUE(resolved.ok()) << resolved.status().to_string();
  EXPECT_FALSE(resolved->section("entropy").IsDefined());
  EXPECT_DOUBLE_EQ(resolved->section("features")["ratio"].as<double>(), 0.2);

  // Another component type replaces the base's block: sfa's ratio does not reach identity.
  auto other = Config::load_file(dir + "identity.yaml");
  ASSERT_TRUE(other.ok()) << other.status().to_string();
  EXPECT_FALSE(other->root()["features"]["ratio"].IsDefined());
  auto other_resolved = other->resolve(test_registry());
  ASSERT_TRUE(other_resolved.ok()) << other_resolved.status().to_string();
  EXPECT_EQ(other_resolved->section("features")["type"].as<std::string>(), "identity");
}

TEST(ConfigBase, MessagesNameTheFileAndLineOfTheKey) {
  const std::string dir =
      write_configs("messages", {{"base.yaml", "# comment\nfeatures:\n  type: sfa\n  ratoi: 1\n"},
                                 {"child.yaml", "base: base.yaml\nfeatures: {ratio: 9}\n"}});
  auto cfg = Config::load_file(dir + "child.yaml");
  ASSERT_TRUE(cfg.ok()) << cfg.status().to_string();
  Status st = cfg->resolve(test_registry()).status();
  ASSERT_FALSE(st.ok());
  // The first error in schema order is the child's ratio; the base's typo comes from base.yaml.
  EXPECT_NE(st.message().find(dir + "child.yaml:2:19: features.ratio: '9' is out of range"),
            std::string::npos)
      << st.message();
  ASSERT_TRUE(cfg->apply_override("features.ratio=0.5").ok());
  st = cfg->resolve(test_registry()).status();
  EXPECT_NE(st.message().find(dir + "base.yaml:4:3: features.ratoi: unknown key"),
            std::string::npos)
      << st.message();
}

// With several bases, each key's message names the base that wrote it, even where the merge
// put it into a block another base wrote.
TEST(ConfigBase, MessagesNameTheRightBaseOfSeveral) {
  const std::string dir =
      write_configs("several", {{"first.yaml", "train: {iteratons: 5}\n"},
                                {"second.yaml", "train: {seed: 2}\n"},
                                {"child.yaml", "base: [first.yaml, second.yaml]\n"}});
  auto cfg = Config::load_file(dir + "child.yaml");
  ASSERT_TRUE(cfg.ok()) << cfg.status().to_string();
  Status st = cfg->resolve(test_registry()).status();
  EXPECT_NE(st.message().find(dir + "first.yaml:1:9: train.iteratons: unknown key"),
            std::string::npos)
      << st.message();
}

// A block naming a type is compared with the section's default where the base names none.
TEST(ConfigBase, TheSectionsDefaultTypeCountsAsTheBasesType) {
  const std::string dir = write_configs("default_type", {{"base.yaml",
                                                          "features: {unknown_to_sfa: 1}\n"
                                                          "rasterizer: {threads: 3}\n"},
                                                         {"child.yaml",
                                                          "base: base.yaml\n"
                                                          "features: {type: sfa}\n"
                                                          "rasterizer: {type: cpu}\n"}});
  auto cfg = Config::load_file(dir + "child.yaml");
  ASSERT_TRUE(cfg.ok()) << cfg.status().to_string();
  EXPECT_FALSE(cfg->root()["features"]["unknown_to_sfa"].IsDefined());  // identity's block
  EXPECT_EQ(cfg->root()["rasterizer"]["threads"].as<int>(), 3);         // cpu is the default
}

TEST(ConfigBase, InheritanceDepthIsLimited) {
  std::vector<std::pair<std::string, std::string>> files;
  for (int i = 0; i < 10; ++i)
    files.emplace_back(
        "l" + std::to_string(i) + ".yaml",
        i < 9 ? "base: l" + std::to_string(i + 1) + ".yaml\n" : "train: {seed: 9}\n");
  const std::string dir = write_configs("depth", files);
  auto eight = Config::load_file(dir + "l1.yaml");  // 8 levels of base below l1
  ASSERT_TRUE(eight.ok()) << eight.status().to_string();
  EXPECT_EQ(eight->root()["train"]["seed"].as<int>(), 9);
  Status st = Config::load_file(dir + "l0.yaml").status();
  EXPECT_NE(st.message().find("more than 8 levels of inheritance"), std::string::npos)
      << st.message();
}

TEST(ConfigBase, RefusesCyclesMissingFilesAndBadValues) {
  const std::string dir =
      write_configs("refuse", {{"a.yaml", "base: b.yaml\n"},
                               {"b.yaml", "train: {seed: 1}\nbase: a.yaml\n"},
                               {"self.yaml", "base: ./self.yaml\n"},
                               {"missing.yaml", "train: {seed: 1}\nbase: nowhere.yaml\n"},
                               {"number.yaml", "base: {a: 1}\n"}});
  Status st = Config::load_file(dir + "a.yaml").status();
  EXPECT_NE(st.message().find("b.yaml:2:7: base: 'a.yaml' inherits itself"), std::string::npos)
      << st.message();
  st = Config::load_file(dir + "self.yaml").status();
  EXPECT_NE(st.message().find("self.yaml:1:7: base: './self.yaml' inherits itself"),
            std::string::npos)
      << st.message();
  st = Config::load_file(dir + "missing.yaml").status();
  EXPECT_NE(st.message().find("missing.yaml:2:7: base: cannot open config file"), std::string::npos)
      << st.message();
  EXPECT_NE(st.message().find("nowhere.yaml"), std::string::npos) << st.message();
  // Not a file: a directory read as an empty config would train on the defaults, /dev/zero
  // would never end.
  st = Config::load_file(dir).status();
  EXPECT_NE(st.message().find("a directory, not a config file"), std::string::npos) << st.message();
  st = Config::load_file("/dev/zero").status();
  EXPECT_NE(st.message().find("/dev/zero: larger than 16 MiB; not a config"), std::string::npos)
      << st.message();
  // A pipe is read like a file (`crpgs train -c <(...)`).
  const std::string fifo = dir + "pipe.yaml";
  ASSERT_EQ(::mkfifo(fifo.c_str(), 0600), 0);
  std::thread writer([&] { std::ofstream(fifo) << "train: {seed: 5}\n"; });
  auto piped = Config::load_file(fifo);
  writer.join();
  ASSERT_TRUE(piped.ok()) << piped.status().to_string();
  EXPECT_EQ(piped->root()["train"]["seed"].as<int>(), 5);
  st = Config::load_file(dir + "number.yaml").status();
  EXPECT_NE(st.message().find("number.yaml:1:7: base: expected a config file or a list"),
            std::string::npos)
      << st.message();
}

TEST(TextList, DidYouMeanGuessesOnlyANearUniqueName) {
  EXPECT_EQ(edit_distance("lamda", "lambda"), 1u);         // a letter left out
  EXPECT_EQ(edit_distance("hash_gird", "hash_grid"), 1u);  // two letters swapped
  EXPECT_EQ(edit_distance("", "abc"), 3u);
  EXPECT_EQ(did_you_mean("hash_gird", {"hash_grid", "link_cohs"}), ", did you mean 'hash_grid'?");
  EXPECT_EQ(did_you_mean("cohs", {"link_cohs", "link_none"}), "");  // 5 edits: too far to guess
  EXPECT_EQ(did_you_mean("bx", {"ax", "cx"}), "");                  // a tie: no guess
  EXPECT_EQ(did_you_mean("x", {}), "");
}

TEST(TextList, SplitUndoesJoin) {
  const std::vector<std::string> items = {"written by another build", "", "trained with a, b"};
  EXPECT_EQ(split(join(items, "; "), "; "), items);
  EXPECT_EQ(split("a, b"), (std::vector<std::string>{"a", "b"}));
  EXPECT_TRUE(split("", "; ").empty());
  EXPECT_EQ(split("one", "; "), std::vector<std::string>{"one"});
}

}  // namespace
}  // namespace crpgs
