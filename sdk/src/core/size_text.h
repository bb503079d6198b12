/// @file size_text.h
/// @brief A size as users write it ("1.5MiB", "800KB", "2000000") in bytes.
#pragma once

#include <cmath>
#include <cstdint>
#include <cstdlib>
#include <string>

#include "crpgs/status.h"

namespace crpgs {

/// A number with an optional unit: B; KiB, MiB, GiB (2^10, 2^20, 2^30 bytes: the field's "MB");
/// KB, MB, GB (10^3, 10^6, 10^9). Units are case-sensitive, as they differ by case elsewhere.
inline StatusOr<uint64_t> parse_byte_size(const std::string& text) {
  const char* begin = text.c_str();
  char* end = nullptr;
  const double value = std::strtod(begin, &end);
  std::string unit(end == begin ? "" : end);
  while (!unit.empty() && unit.front() == ' ') unit.erase(0, 1);
  struct Unit {
    const char* name;
    double bytes;
  };
  static const Unit kUnits[] = {
      {"", 1},     {"B", 1},    {"KiB", 1024.0}, {"MiB", 1048576.0}, {"GiB", 1073741824.0},
      {"KB", 1e3}, {"MB", 1e6}, {"GB", 1e9}};
  if (end != begin && std::isfinite(value) && value > 0)
    for (const Unit& u : kUnits)
      if (unit == u.name && value * u.bytes < 1.8e19)
        return static_cast<uint64_t>(std::floor(value * u.bytes));
  return Status(StatusCode::kInvalidArgument,
                "'" + text +
                    "' is not a size: a positive number with an optional unit B, KiB, MiB, GiB "
                    "(2^10, 2^20, 2^30 bytes) or KB, MB, GB (10^3, 10^6, 10^9 bytes)");
}

}  // namespace crpgs
