/// @file progress_bar.cpp
#include "progress_bar.h"

#include <unistd.h>

#include <algorithm>
#include <cmath>

namespace crpgs::cli {

std::string format_duration(double s) {
  char buf[64];
  if (!std::isfinite(s) || s < 0) return "?";
  if (s < 60) {
    std::snprintf(buf, sizeof buf, "%.1fs", s);
  } else if (s < 3600) {
    std::snprintf(buf, sizeof buf, "%dm%02ds", int(s) / 60, int(s) % 60);
  } else {
    std::snprintf(buf, sizeof buf, "%dh%02dm", int(s) / 3600, (int(s) % 3600) / 60);
  }
  return buf;
}

ProgressBar::ProgressBar(std::string label, long total, long already_done, FILE* out)
    : label_(std::move(label)),
      total_(std::max(1L, total)),
      already_done_(std::clamp(already_done, 0L, total_)),
      out_(out),
      tty_(isatty(fileno(out)) != 0),
      start_(std::chrono::steady_clock::now()),
      last_draw_(start_ - std::chrono::hours(1)) {}

ProgressBar::~ProgressBar() {
  if (!finished_ && tty_) std::fputc('\n', out_);
}

void ProgressBar::update(long done, const std::string& extra) {
  const auto now = std::chrono::steady_clock::now();
  // A TTY redraws 10x per second; plain output prints a line every 5 seconds.
  const auto every = tty_ ? std::chrono::milliseconds(100) : std::chrono::milliseconds(5000);
  if (now - last_draw_ < every) return;
  last_draw_ = now;
  draw(done, extra, false);
}

void ProgressBar::finish(const std::string& extra) {
  if (finished_) return;
  draw(total_, extra, true);
  finished_ = true;
}

void ProgressBar::message(const std::string& line) {
  std::fprintf(out_, "%s%s\n", tty_ ? "\r\033[K" : "", line.c_str());
  last_draw_ = std::chrono::steady_clock::now() - std::chrono::hours(1);  // redraw next update
  std::fflush(out_);
}

void ProgressBar::draw(long done, const std::string& extra, bool final) {
  const double elapsed =
      std::chrono::duration<double>(std::chrono::steady_clock::now() - start_).count();
  const double rate = elapsed > 0 ? double(done - already_done_) / elapsed : 0;
  const double eta = rate > 0 ? (total_ - done) / rate : NAN;
  const double frac = std::clamp(double(done) / total_, 0.0, 1.0);
  char stats[160];
  std::snprintf(stats, sizeof stats, "%ld/%ld %.1f/s %s ETA %s", done, total_, rate,
                format_duration(elapsed).c_str(), final ? "0s" : format_duration(eta).c_str());
  if (tty_) {
    const int width = 28, fill = int(frac * width);
    std::string bar(size_t(fill), '#');
    bar.resize(size_t(width), '.');
    std::fprintf(out_, "\r\033[K%s [%s] %3.0f%% %s %s", label_.c_str(), bar.c_str(), frac * 100,
                 stats, extra.c_str());
    if (final) std::fputc('\n', out_);
  } else {
    std::fprintf(out_, "%s %3.0f%% %s %s\n", label_.c_str(), frac * 100, stats, extra.c_str());
  }
  std::fflush(out_);
}

}  // namespace crpgs::cli
