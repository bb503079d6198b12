// The CLI's answer to a misspelt command or option: what does not exist, and the nearest that does.
#include <gtest/gtest.h>

#include <filesystem>
#include <string>

#include "cli_output.h"

namespace {

using crpgs::test::crpgs_output;

TEST(CliErrors, MisspeltCommandsAndOptionsGetTheNearestName) {
#ifndef CRPGS_CLI_PATH
  GTEST_SKIP() << "the crpgs executable is not part of this build (CRPGS_BUILD_APPS=OFF)";
#else
  int rc = 0;
  std::string out = crpgs_output("trian -c x.yaml", &rc);
  EXPECT_EQ(rc, 2);  // a usage error
  EXPECT_NE(out.find("unknown command 'trian' for 'crpgs', did you mean 'train'? (commands: "),
            std::string::npos)
      << out;
  EXPECT_EQ(out.find("subcommand is required"), std::string::npos) << out;  // it was given
  out = crpgs_output("", &rc);
  EXPECT_EQ(rc, 2);
  EXPECT_NE(out.find("A subcommand is required"), std::string::npos) << out;
  out = crpgs_output("train -o y", &rc);  // -c missing
  EXPECT_EQ(rc, 2);
  EXPECT_NE(out.find("--config is required"), std::string::npos) << out;
  // The value of a global option is not taken for a command.
  out = crpgs_output("--plugin-dir /nonexistent trian", &rc);
  EXPECT_NE(out.find("unknown command 'trian' for 'crpgs', did you"), std::string::npos) << out;
  EXPECT_EQ(out.find("'/nonexistent'"), std::string::npos) << out;
  out = crpgs_output("config chek x.yaml", &rc);
  EXPECT_NE(out.find("unknown command 'chek' for 'crpgs config', did you mean 'check'?"),
            std::string::npos)
      << out;
  out = crpgs_output("train -c x.yaml -o y --resme", &rc);
  EXPECT_EQ(rc, 2);
  EXPECT_NE(out.find("unknown option '--resme' for 'crpgs train', did you mean '--resume'?"),
            std::string::npos)
      << out;
  // Far from every name: said, without a guess.
  out = crpgs_output("train -c x.yaml -o y --bandwidth=3", &rc);
  EXPECT_NE(out.find("unknown option '--bandwidth' for 'crpgs train'\n"), std::string::npos) << out;
  // A good command line says nothing of the kind.
  out = crpgs_output("train --help", &rc);
  EXPECT_EQ(rc, 0);
  EXPECT_EQ(out.find("unknown"), std::string::npos) << out;
  // eval takes --set (e.g. dataset.path=DIR, as its missing-dataset message says).
  out = crpgs_output("eval /nonexistent_run --set dataset.path=x", &rc);
  EXPECT_NE(rc, 0);
  EXPECT_EQ(out.find("unknown option"), std::string::npos) << out;
  // So does encode.
  out = crpgs_output("encode /nonexistent_run -o x.crpgs --set dataset.path=x", &rc);
  EXPECT_NE(rc, 0);
  EXPECT_EQ(out.find("unknown option"), std::string::npos) << out;
  // A global option after the command is taken as well.
  out = crpgs_output("plugins --plugin-dir /nonexistent_plugins", &rc);
  EXPECT_EQ(rc, 0) << out;
  EXPECT_NE(out.find("/nonexistent_plugins"), std::string::npos) << out;
  // A path that holds no model is named as what it is not; a file that is not a bitstream is
  // named in the decoder's message, for eval and export alike.
  out = crpgs_output("eval /nonexistent_run", &rc);
  EXPECT_NE(rc, 0);
  EXPECT_NE(out.find("/nonexistent_run: no such file or directory; expected a .crpgs file"),
            std::string::npos)
      << out;
  EXPECT_EQ(out.find("config.yaml:"), std::string::npos) << out;
  const std::string not_bitstream = std::string(CRPGS_TEST_TMP_DIR) + "/cli_not_a_bitstream.crpgs";
  {
    FILE* f = std::fopen(not_bitstream.c_str(), "w");
    ASSERT_NE(f, nullptr);
    std::fputs("not a bitstream\n", f);
    std::fclose(f);
  }
  for (const std::string& cmd :
       {"eval " + not_bitstream, "export " + not_bitstream + " -o " + not_bitstream + ".ply"}) {
    out = crpgs_output(cmd, &rc);
    EXPECT_NE(rc, 0) << cmd;
    EXPECT_NE(out.find("crpgs: error: " + not_bitstream + ": "), std::string::npos) << cmd << out;
  }
  // A demo cut short by train.iterations ends before its link builds: the message says what to
  // set instead.
  out = crpgs_output(
      "demo -o " + std::string(CRPGS_TEST_TMP_DIR) + "/cli_demo_short --set train.iterations=60",
      &rc);
  EXPECT_NE(rc, 0);
  EXPECT_NE(out.find("lower train.fast_factor instead"), std::string::npos) << out;
  // A count that is not a count says so.
  out = crpgs_output("render x.crpgs -o r --threads -2", &rc);
  EXPECT_EQ(rc, 2);
  EXPECT_NE(out.find("--threads: Value -2 not in range 0 to 1024"), std::string::npos) << out;
#endif
}

// A --set dataset path is relative to the working directory and saved absolute, so a run's
// config.yaml (and the bitstream's config) still find the dataset from anywhere.
TEST(CliConfig, ASetDatasetPathIsMadeAbsolute) {
#ifndef CRPGS_CLI_PATH
  GTEST_SKIP() << "the crpgs executable is not part of this build (CRPGS_BUILD_APPS=OFF)";
#else
  int rc = 0;
  const std::string out = crpgs_output(std::string("config check '") + CRPGS_SOURCE_DIR +
                                           "/configs/fern.yaml' --set dataset.path=rel/fern",
                                       &rc);
  EXPECT_EQ(rc, 0) << out;
  const std::string want = (std::filesystem::current_path() / "rel/fern").string();
  EXPECT_NE(out.find("path: " + want + "\n"), std::string::npos) << want << "\n" << out;
#endif
}

}  // namespace
