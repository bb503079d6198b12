// The CLI's progress bar: a resumed run's rate and ETA count only this process's units.
#include <fcntl.h>
#include <gtest/gtest.h>
#include <sys/ioctl.h>
#include <unistd.h>

#include <chrono>
#include <cmath>
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

// On a terminal each redraw fits in one row: a line that wraps leaves its first row behind on
// every redraw (the trainer's extras make the line ~150 characters).
TEST(ProgressBar, ATerminalLineFitsItsWidth) {
  const int master = posix_openpt(O_RDWR | O_NOCTTY);
  ASSERT_GE(master, 0);
  ASSERT_EQ(grantpt(master), 0);
  ASSERT_EQ(unlockpt(master), 0);
  const int slave = open(ptsname(master), O_RDWR | O_NOCTTY);
  ASSERT_GE(slave, 0);
  winsize ws{};
  ws.ws_col = 80;
  ws.ws_row = 24;
  ASSERT_EQ(ioctl(slave, TIOCSWINSZ, &ws), 0);
  FILE* out = fdopen(slave, "w");
  ASSERT_NE(out, nullptr);
  const std::string extra(120, 'x');
  {
    ProgressBar bar("train", 40000, 0, out);
    bar.update(139, extra);
    std::this_thread::sleep_for(std::chrono::milliseconds(120));
    bar.update(140, extra);
    bar.finish(extra);
  }
  std::fclose(out);
  std::string text;
  char buf[4096];
  for (ssize_t n; (n = read(master, buf, sizeof buf)) > 0;) {
    text.append(buf, size_t(n));
    if (text.find("40000/40000") != std::string::npos && text.find('\n') != std::string::npos)
      break;
  }
  close(master);
  // Split at every redraw ("\r\033[K") and line end: no drawn row is wider than 79 columns.
  int rows = 0;
  size_t start = 0;
  while (start < text.size()) {
    size_t end = text.find_first_of("\r\n", start);
    if (end == std::string::npos) end = text.size();
    std::string row = text.substr(start, end - start);
    if (row.rfind("\033[K", 0) == 0) row.erase(0, 3);
    if (!row.empty()) {
      ++rows;
      EXPECT_LE(row.size(), 79u) << row;
      EXPECT_EQ(row.rfind("train [", 0), 0u) << row;
    }
    start = end + 1;
  }
  EXPECT_EQ(rows, 3);
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

// `crpgs sweep --status` reads a run's progress back from its log.
TEST(ProgressBar, LastProgressReadsBackWhatTheBarDrew) {
  const std::string text = bar_output(30000, 12000, 13030);
  auto p = last_progress(text, "train");
  ASSERT_TRUE(p.has_value()) << text;
  EXPECT_EQ(p->done, 13030);
  EXPECT_EQ(p->total, 30000);
  EXPECT_GT(p->rate, 0);
  EXPECT_FALSE(p->eta.empty());
  // The last of several lines, TTY redraws included; other labels and cut-off lines are skipped.
  const std::string log =
      "train  10% 3000/30000 2.0/s 25m00s ETA 3h45m\n"
      "\r\033[Ktrain [###.....] 11% 3300/30000 2.1/s 26m10s ETA 3h31m loss 0.1"
      "\r\033[Ktrain [###.....] 11% 3310/30000 2.1/s 26m15s ETA 3h30m loss 0.1\n"
      "decode 50% 1/2 1.0/s 1.0s ETA 1.0s\n"
      "train  11% 33";
  p = last_progress(log, "train");
  ASSERT_TRUE(p.has_value());
  EXPECT_EQ(p->done, 3310);
  EXPECT_EQ(p->eta, "3h30m");
  EXPECT_DOUBLE_EQ(p->rate, 2.1);
  EXPECT_TRUE(std::isnan(p->test_psnr));  // this line shows none
  EXPECT_FALSE(last_progress("no bar here\n", "train").has_value());
  // `crpgs train`'s extras: the held-out PSNR it last measured ("-" before the first).
  p = last_progress(
      "train  72% 28644/40000 0.43/s 27m03s ETA 7h22m loss 0.0175  test PSNR "
      "26.16 dB  anchors 69386  gaussians 195210\n",
      "train");
  ASSERT_TRUE(p.has_value());
  EXPECT_DOUBLE_EQ(p->test_psnr, 26.16);
  p = last_progress("train   0% 5/40000 1.2/s 4s ETA 9h loss 0.2  test PSNR -  anchors 9\n",
                    "train");
  ASSERT_TRUE(p.has_value());
  EXPECT_TRUE(std::isnan(p->test_psnr));
}

}  // namespace

}  // namespace crpgs::cli
