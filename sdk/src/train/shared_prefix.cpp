/// @file shared_prefix.cpp
#include "crpgs/shared_prefix.h"

#include <cstdio>

namespace crpgs {

std::string shared_prefix_key(const Config& resolved) {
  if (!resolved.section("context")) return "";
  auto blanked = Config::from_string(resolved.dump(), "<prefix key>");
  if (!blanked.ok()) return "";
  for (const char* key : {"rate.lambda=0", "rate.mask_lambda=0"})
    if (!blanked->apply_override(key).ok()) return "";
  char hex[17];
  std::snprintf(hex, sizeof hex, "%016llx", static_cast<unsigned long long>(blanked->hash()));
  return hex;
}

}  // namespace crpgs
