/// @file progress_bar.h
/// @brief Terminal progress: a redrawn bar with rate and ETA on a TTY, plain throttled lines
/// otherwise (logs, CI). The SDK reports through callbacks; only the CLI prints.
#pragma once

#include <chrono>
#include <cmath>
#include <cstdio>
#include <optional>
#include <string>

namespace crpgs::cli {

class ProgressBar {
 public:
  /// `already_done` units were finished before this bar started (a resumed run): the rate and
  /// ETA count only what this process does.
  ProgressBar(std::string label, long total, long already_done = 0, FILE* out = stderr);
  ~ProgressBar();
  /// `done` units finished; `extra` is shown after the rate (loss, PSNR, ...).
  void update(long done, const std::string& extra = "");
  void finish(const std::string& extra = "");
  /// Prints a line of its own (warnings) without garbling the bar.
  void message(const std::string& line);

 private:
  void draw(long done, const std::string& extra, bool final);
  std::string label_;
  long total_;
  long already_done_;
  FILE* out_;
  bool tty_;
  bool finished_ = false;
  std::chrono::steady_clock::time_point start_, last_draw_;
};

/// "1m23s", "4.2s".
std::string format_duration(double seconds);

/// "0.73", "12.3", "415": three significant digits at most, two below 10 (a sweep's ETA
/// multiplies the rate by tens of thousands of iterations).
std::string format_rate(double per_second);

/// What one drawn bar says (read back from a log, e.g. by `crpgs sweep --status`).
struct ProgressLine {
  std::string label;
  long done = 0, total = 0;
  double rate = 0;  ///< units per second of the process that drew it
  std::string eta;  ///< as drawn ("2h10m", "?")
  /// `crpgs train`'s last held-out PSNR on the line ("test PSNR 26.16 dB"); NaN when absent.
  double test_psnr = std::nan("");
};
/// The last bar `label` drew in `log` (plain lines or TTY redraws); nullopt if none.
std::optional<ProgressLine> last_progress(const std::string& log, const std::string& label);

}  // namespace crpgs::cli
