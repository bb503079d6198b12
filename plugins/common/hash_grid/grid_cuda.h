/// @file grid_cuda.h
/// @brief The binary hash grid's forward and backward as CUDA kernels, behind plain launchers on
/// raw device pointers: no libtorch and no CUDA header, so the glue (grid_cuda_glue.cpp) compiles
/// with any libtorch and the kernels (grid_cuda.cu) with nvcc alone. Every launcher runs on the
/// legacy default stream (libtorch's unless a caller sets another) and returns null, or the CUDA
/// error's text.
///
/// The maths is the CPU kernel's (hash_grid_kernels.cpp) operation for operation, without FMA
/// contraction, so forward values are bit-equal to it. The backward sums into the table with
/// atomics: the order, hence the last bits, varies from run to run (training on a GPU is not
/// bit-reproducible; the bitstream is coded on the CPU).
#pragma once

#include <cstdint>

namespace crpgs::hash_grid::cuda_kernels {

/// One level (GridLevel in a form nvcc needs no libtorch for).
struct Level {
  int32_t dim;      ///< 3 or 2
  int32_t axes[3];  ///< input coordinates read
  int32_t res;
  int32_t dense;   ///< 1: index g_x + g_y res + g_z res^2; 0: hashed, size a power of two
  int64_t offset;  ///< first table row
  int64_t size;    ///< rows
};

/// HAC's hash primes of the x, y and z grid coordinates (the CPU kernel's too).
inline constexpr uint32_t kHashPrimeX = 1u, kHashPrimeY = 2654435761u, kHashPrimeZ = 805459861u;

/// Most levels one launch takes (HAC's default grid has 12 + 3 x 4).
inline constexpr int kMaxLevels = 64;

/// out [n, n_levels * n_features] (fully written) from pos [n, 3] and table [rows, n_features].
const char* forward(const Level* levels, int n_levels, int64_t n_features, const float* pos,
                    const float* table, int64_t n, bool binarize, float* out);
const char* forward(const Level* levels, int n_levels, int64_t n_features, const double* pos,
                    const double* table, int64_t n, bool binarize, double* out);

/// grad_table [rows, n_features] (pre-zeroed) += the lookups' weights x grad_out [n, width]; with
/// binarize, then x [|table| <= 1] (straight through).
const char* backward(const Level* levels, int n_levels, int64_t n_features, const float* pos,
                     const float* grad_out, const float* table, int64_t rows, int64_t n,
                     bool binarize, float* grad_table);
const char* backward(const Level* levels, int n_levels, int64_t n_features, const double* pos,
                     const double* grad_out, const double* table, int64_t rows, int64_t n,
                     bool binarize, double* grad_table);

}  // namespace crpgs::hash_grid::cuda_kernels
