/// @file npy.h
/// @brief Reader for NumPy .npy files holding a C-order little-endian float64/float32 array
/// (LLFF poses_bounds.npy). Internal.
#pragma once

#include <cstdint>
#include <string>
#include <vector>

#include "crpgs/status.h"

namespace crpgs::io {

struct NpyArray {
  std::vector<int64_t> shape;
  std::vector<double> data;  ///< row-major, converted to double
};

/// Parses .npy bytes (format versions 1-3, dtype '<f8' or '<f4', fortran_order False).
/// `path` is only used in error messages.
StatusOr<NpyArray> parse_npy(const std::string& bytes, const std::string& path);
StatusOr<NpyArray> read_npy(const std::string& path);

}  // namespace crpgs::io
