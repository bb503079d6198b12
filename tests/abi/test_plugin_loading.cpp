/// @file test_plugin_loading.cpp
/// @brief Broken plugins are rejected with their specific reason and never crash the host.
#include <gtest/gtest.h>

#include <fstream>
#include <string>

#include "crpgs/registry.h"
#include "crpgs/version.h"

namespace crpgs {
namespace {

std::string plugin(const std::string& name) {
  return std::string(CRPGS_TEST_PLUGIN_DIR) + "/libcrpgs_test_" + name + ".so";
}

void expect_rejected(const std::string& name, StatusCode code, const std::string& text) {
  ComponentRegistry r;
  Status st = r.load_plugin_file(plugin(name));
  ASSERT_FALSE(st.ok()) << name;
  EXPECT_EQ(st.code(), code) << st.to_string();
  EXPECT_NE(st.message().find(text), std::string::npos) << st.message();
  EXPECT_NE(st.message().find(plugin(name)), std::string::npos) << "message names the file";
  ASSERT_EQ(r.rejected().size(), 1u);
  EXPECT_EQ(r.rejected()[0].path, plugin(name));
  EXPECT_TRUE(r.components().empty());
}

TEST(PluginLoading, MissingFile) {
  expect_rejected("does_not_exist", StatusCode::kPluginLoadFailed, "file not found");
}
TEST(PluginLoading, NotASharedLibrary) {
  expect_rejected("garbage", StatusCode::kPluginLoadFailed, "cannot load shared library");
}
TEST(PluginLoading, LibraryWithoutEntryPoint) {
  expect_rejected("not_a_plugin", StatusCode::kPluginLoadFailed,
                  "not a crpgs plugin (no symbol crpgs_plugin_v1)");
}
TEST(PluginLoading, WrongAbiVersion) {
  const std::string host = std::to_string(CRPGS_PLUGIN_ABI_VERSION);
  expect_rejected(
      "wrong_abi", StatusCode::kPluginAbiMismatch,
      "plugin ABI " + std::to_string(CRPGS_PLUGIN_ABI_VERSION + 41) + ", host expects " + host);
}
TEST(PluginLoading, MismatchedBuildInfo) {
  expect_rejected("bad_build_info", StatusCode::kPluginAbiMismatch,
                  "build info does not match the host: libtorch 0.4.1 vs host");
}
TEST(PluginLoading, SchemaThatDoesNotParse) {
  expect_rejected("bad_schema", StatusCode::kPluginLoadFailed, "schema: does not parse");
}

TEST(PluginLoading, DuplicateTypeKeepsFirstAndRejectsSecond) {
  ComponentRegistry r;
  ASSERT_TRUE(r.load_plugin_file(plugin("dup_a")).ok());
  Status st = r.load_plugin_file(plugin("dup_b"));
  ASSERT_FALSE(st.ok());
  EXPECT_NE(st.message().find("duplicate features type 'duplicated' (already provided by " +
                              plugin("dup_a")),
            std::string::npos)
      << st.message();
  EXPECT_EQ(r.components().size(), 1u);
}

TEST(PluginLoading, CreateFailureCarriesThePluginMessage) {
  ComponentRegistry r;
  ASSERT_TRUE(r.load_plugin_file(plugin("create_fails")).ok());
  YAML::Node block;
  block["type"] = "create_fails";
  auto obj = r.create_raw(CRPGS_KIND_FEATURES, block, crpgs_create_args{});
  ASSERT_FALSE(obj.ok());
  EXPECT_NE(obj.status().message().find("create failed: deliberate failure"), std::string::npos)
      << obj.status().message();
}

TEST(PluginLoading, DirectoryScanRecordsEveryRejection) {
  ComponentRegistry r;
  r.load_plugins({CRPGS_TEST_PLUGIN_DIR, CRPGS_TEST_PLUGIN_DIR, "/nonexistent/dir"});
  EXPECT_EQ(r.searched_dirs().size(), 2u);  // the repeated dir is searched once
  // Loaded: create_fails and dup_a; rejected: the 5 broken files + dup_b.
  EXPECT_EQ(r.components().size(), 2u);
  EXPECT_EQ(r.rejected().size(), 6u);
  for (const auto& x : r.rejected()) EXPECT_FALSE(x.reason.empty()) << x.path;
}

TEST(PluginLoading, ADirectoryThatCannotBeReadIsReported) {
  // Absent directories are normal (an install dir never installed to); one whose listing fails
  // hides plugins, so it is named. Tests often run as root, whom permissions do not stop: a path
  // through a regular file fails for everyone.
  const std::string file = std::string(CRPGS_TEST_PLUGIN_DIR) + "/../plugin_dir_is_a_file";
  { std::ofstream(file) << "x"; }
  ComponentRegistry r;
  r.load_plugins({file + "/plugins", "/nonexistent/dir"});
  ASSERT_EQ(r.rejected().size(), 1u);
  EXPECT_NE(r.rejected()[0].reason.find("cannot read the directory: Not a directory"),
            std::string::npos)
      << r.rejected()[0].reason;
}

TEST(PluginLoading, ObjectsKeepTheirLibraryAlive) {
  std::shared_ptr<void> obj;
  {
    ComponentRegistry r;
    ASSERT_TRUE(r.load_plugin_file(plugin("dup_a")).ok());
    YAML::Node block;
    block["type"] = "duplicated";
    auto made = r.create_raw(CRPGS_KIND_FEATURES, block, crpgs_create_args{});
    ASSERT_TRUE(made.ok()) << made.status().to_string();
    obj = made.value();
    EXPECT_GE(r.components()[0].library.use_count(), 2);  // registry + object deleter
  }
  obj.reset();  // the deleter runs plugin code after the registry is gone: must not crash
  SUCCEED();
}

}  // namespace
}  // namespace crpgs
