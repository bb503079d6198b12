// The CLI's progress bar: a resumed run's rate and ETA count only this process's units.
#include <gtest/gtest.h>

#include <chrono>
#include <cstdio>
#include <string>
#include <thread>

#include "../../apps/progress_bar.h"

namespace crpgs::cli {
namespace {

/// Everything the bar wrote to a temporary (non-TTY) file.
std::string bar_output(long total, long already_done, long done) {
  FILE* f = std::tmpfile();
  EXPECT_NE(f, nullptr);
  {
    ProgressBar bar("train", total, already_done, f);
    std::this_thread::sleep_for(std::chrono::milliseconds(50));
    bar.update(done);
  }
  std::rewind(f);
  std::string text;
  char buf[256];
  while (std::fgets(buf, sizeof buf, f)) text += buf;
  std::fclose(f);
  return text;
}

/// The "N.N/s" figure of the first line.
double rate_of(const std::string& line) {
  const size_t slash = line.find("/s ");
  EXPECT_NE(slash, std::string::npos) << line;
  const size_t start = line.rfind(' ', slash) + 1;
  return std::stod(line.substr(start, slash - start));
}

TEST(ProgressBar, AResumedRunCountsOnlyItsOwnUnits) {
  // 10 units in >= 50 ms: at most 200/s. Counting the 999,990 done before the resume would
  // report millions per second and an ETA near zero.
  const std::string line = bar_output(1000000, 999990, 1000000);
  EXPECT_NE(line.find("1000000/1000000"), std::string::npos) << line;
  EXPECT_LE(rate_of(line), 200.0) << line;
  EXPECT_GT(rate_of(line), 0.0) << line;
}

TEST(ProgressBar, AFreshRunCountsFromZero) {
  // 20 of 40 units: the ETA is about the time taken so far, not "?" and not 0.
  const std::string line = bar_output(40, 0, 20);
  EXPECT_NE(line.find("20/40"), std::string::npos) << line;
  EXPECT_GT(rate_of(line), 0.0) << line;
  EXPECT_EQ(line.find("ETA ?"), std::string::npos) << line;
}

}  // namespace
}  // namespace crpgs::cli
