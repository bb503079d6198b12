/// @file progress_bar.cpp
#include "progress_bar.h"

#include <sys/ioctl.h>
#include <unistd.h>

#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <sstream>
#include <utility>

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

std::string format_rate(double per_second) {
  char buf[64];
  const double r = std::isfinite(per_second) ? per_second : 0;
  std::snprintf(buf, sizeof buf, r < 10 ? "%.2f" : r < 100 ? "%.1f" : "%.0f", r);
  return buf;
}

namespace {

/// The terminal's width: its window size, else $COLUMNS, else 80.
size_t terminal_columns(FILE* out) {
  winsize ws{};
  if (ioctl(fileno(out), TIOCGWINSZ, &ws) == 0 && ws.ws_col > 0) return ws.ws_col;
  if (const char* c = std::getenv("COLUMNS"); c && std::atoi(c) > 0) return size_t(std::atoi(c));
  return 80;
}

}  // namespace

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
  std::snprintf(stats, sizeof stats, "%ld/%ld %s/s %s ETA %s", done, total_,
                format_rate(rate).c_str(), format_duration(elapsed).c_str(),
                final ? "0s" : format_duration(eta).c_str());
  if (tty_) {
    const int width = 28, fill = int(frac * width);
    std::string bar(size_t(fill), '#');
    bar.resize(size_t(width), '.');
    char pct[16];
    std::snprintf(pct, sizeof pct, "%3.0f%%", frac * 100);
    std::string line = label_ + " [" + bar + "] " + pct + " " + stats + " " + extra;
    // A line that wraps leaves its first row behind: "\r\033[K" clears only the row it is on.
    const size_t columns = terminal_columns(out_);
    if (line.size() >= columns) line.resize(columns - 1);
    std::fprintf(out_, "\r\033[K%s", line.c_str());
    if (final) std::fputc('\n', out_);
  } else {
    std::fprintf(out_, "%s %3.0f%% %s %s\n", label_.c_str(), frac * 100, stats, extra.c_str());
  }
  std::fflush(out_);
}

std::optional<ProgressLine> last_progress(const std::string& log, const std::string& label) {
  // draw() writes "LABEL [bar] PCT% DONE/TOTAL RATE/s ELAPSED ETA ETA ..." on a TTY (after
  // "\r\033[K") and the same without the bar in plain lines.
  size_t end = log.size();
  while (end > 0) {
    const size_t cut = log.find_last_of("\r\n", end - 1);
    const size_t begin = cut == std::string::npos ? 0 : cut + 1;
    std::string line = log.substr(begin, end - begin);
    end = cut == std::string::npos ? 0 : cut;
    if (line.rfind("\033[K", 0) == 0) line.erase(0, 3);
    std::istringstream in(line);
    std::string word, fraction, rate, elapsed, eta_word, eta;
    if (!(in >> word) || word != label) continue;
    if (!(in >> word)) continue;
    if (word.front() == '[' && !(in >> word)) continue;  // the TTY bar, then the percentage
    if (!(in >> fraction >> rate >> elapsed >> eta_word >> eta) || eta_word != "ETA") continue;
    const size_t slash = fraction.find('/');
    if (slash == std::string::npos || rate.size() < 3 || rate.substr(rate.size() - 2) != "/s")
      continue;
    try {
      ProgressLine p;
      p.label = label;
      p.done = std::stol(fraction.substr(0, slash));
      p.total = std::stol(fraction.substr(slash + 1));
      p.rate = std::stod(rate.substr(0, rate.size() - 2));
      p.eta = eta;
      // The trainer's extras follow the ETA: "loss L  test PSNR X dB  ...".
      std::string two_back, one_back;
      while (in >> word) {
        if (two_back == "test" && one_back == "PSNR") {
          if (word != "-") p.test_psnr = std::stod(word);
          break;
        }
        two_back = std::exchange(one_back, word);
      }
      return p;
    } catch (const std::exception&) {
      continue;  // a garbled line (e.g. cut off by a kill)
    }
  }
  return std::nullopt;
}

}  // namespace crpgs::cli
