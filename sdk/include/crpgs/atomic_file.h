/// @file atomic_file.h
/// @brief Every output (bitstreams, checkpoints, configs, reports, images) goes through here:
/// written to a temporary file in the same directory, flushed, then renamed over the target,
/// so a crash never leaves a half-written file under the final name.
#pragma once

#include <cstdint>
#include <string>
#include <string_view>
#include <vector>

#include "crpgs/status.h"

namespace crpgs {

Status write_file_atomic(const std::string& path, std::string_view bytes);
inline Status write_file_atomic(const std::string& path, const std::vector<uint8_t>& bytes) {
  return write_file_atomic(
      path, std::string_view(reinterpret_cast<const char*>(bytes.data()), bytes.size()));
}
StatusOr<std::vector<uint8_t>> read_file_bytes(const std::string& path);

/// Removes the temporary files that write_file_atomic left in `dir` when its process was killed
/// mid-write (a checkpoint's can be hundreds of MB). Only while nothing writes there, e.g. under
/// the directory's lock. Returns how many were removed.
int remove_stale_temp_files(const std::string& dir);

}  // namespace crpgs
