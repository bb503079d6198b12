/// @file time_text.h
/// @brief The local time as "YYYY-MM-DD HH:MM:SS", for logs and lock files.
#pragma once

#include <ctime>
#include <string>

namespace crpgs {

inline std::string local_time_text() {
  char buf[32];
  const std::time_t t = std::time(nullptr);
  std::tm tm{};
  localtime_r(&t, &tm);
  std::strftime(buf, sizeof buf, "%Y-%m-%d %H:%M:%S", &tm);
  return buf;
}

}  // namespace crpgs
