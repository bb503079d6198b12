/// @file hashing.h
/// @brief The project's one content hash: FNV-1a 64 (config hashes, prefix keys, build ids).
#pragma once

#include <cstdint>
#include <cstdio>
#include <string>
#include <string_view>

namespace crpgs {

inline constexpr uint64_t kFnv1a64Offset = 1469598103934665603ull;

/// FNV-1a 64 of `bytes`, continuing from `h` (pass a previous result to hash in pieces).
inline uint64_t fnv1a64(std::string_view bytes, uint64_t h = kFnv1a64Offset) {
  for (unsigned char c : bytes) h = (h ^ c) * 1099511628211ull;
  return h;
}

/// `v` as 16 lower-case hex digits, the form hashes are printed and stored in.
inline std::string hex64(uint64_t v) {
  char hex[17];
  std::snprintf(hex, sizeof hex, "%016llx", static_cast<unsigned long long>(v));
  return hex;
}

}  // namespace crpgs
