/// @file grid_cuda.cu
/// @brief CUDA kernels of the binary hash grid (grid_cuda.h): one thread per (point, level),
/// the corner arithmetic of hash_grid_kernels.cpp's corners_block_dim in the same order. Built
/// with --fmad=false, so every product and sum rounds as on the CPU.
#include <cuda_runtime.h>

#include <cstdint>

#include "grid_cuda.h"

namespace crpgs::hash_grid::cuda_kernels {
namespace {

constexpr int kThreads = 256;
/// Features per level a thread accumulates in registers (HAC's layouts use 4).
constexpr int64_t kMaxFeatures = 16;

struct Levels {
  Level l[kMaxLevels];
};

/// The 2^dim corners of point `p` at level `lv`: normalised weights and table rows; false when
/// a coordinate the level reads lies outside [0, 1] (or is NaN).
template <int DIM, typename scalar_t>
__device__ bool corners(const Level& lv, const scalar_t* p, scalar_t (&w)[8], int32_t (&row)[8]) {
  const scalar_t scale = scalar_t(lv.res - 2);
  const int32_t last = lv.res - 1;
  const uint32_t hash_mask = uint32_t(lv.size - 1);
  scalar_t wd[DIM][2];
  uint32_t border_d[DIM][2], dense_d[DIM][2], hash_d[DIM][2];
  uint32_t inside = 1, stride = 1;
#pragma unroll
  for (int d = 0; d < DIM; ++d) {
    const scalar_t raw = p[lv.axes[d]];
    const uint32_t in = uint32_t(raw >= scalar_t(0)) & uint32_t(raw <= scalar_t(1));
    inside &= in;
    const scalar_t v = in ? raw : scalar_t(0);
    const scalar_t q = v * scale + scalar_t(0.5);
    const scalar_t fl = floor(q);
    const scalar_t frac = q - fl;
    const int32_t id0 = int32_t(fl);
    const int32_t id[2] = {id0, min(id0 + 1, last)};
    wd[d][0] = scalar_t(1) - frac;
    wd[d][1] = frac;
#pragma unroll
    for (int b = 0; b < 2; ++b) {
      border_d[d][b] = uint32_t(id[b] == 0) | uint32_t(id[b] == last);
      dense_d[d][b] = uint32_t(id[b]) * stride;
      hash_d[d][b] = uint32_t(id[b]) * (d == 0 ? kHashPrimeX : d == 1 ? kHashPrimeY : kHashPrimeZ);
    }
    stride *= uint32_t(lv.res);
  }
  scalar_t sum = 0;
#pragma unroll
  for (int c = 0; c < (1 << DIM); ++c) {
    scalar_t wc = 1;
    uint32_t border = 0, dense = 0, hash = 0;
#pragma unroll
    for (int d = 0; d < DIM; ++d) {
      const int b = (c >> d) & 1;
      wc = wc * wd[d][b];
      border |= border_d[d][b];
      dense += dense_d[d][b];
      hash ^= hash_d[d][b];
    }
    wc = border ? scalar_t(0) : wc;
    w[c] = wc;
    sum = sum + wc;
    row[c] = int32_t(lv.offset) + int32_t(lv.dense ? dense : (hash & hash_mask));
  }
  const scalar_t denom = sum == scalar_t(0) ? scalar_t(1e-9) : sum;
#pragma unroll
  for (int c = 0; c < (1 << DIM); ++c) w[c] = w[c] / denom;
  return inside != 0;
}

/// This thread's (point, level): its corners' weights and rows, and their count (0 for a point
/// outside the level's [0, 1] range); -1 past the last pair. `*slot`: the pair's first value in
/// an [n, n_levels * F] array.
template <typename scalar_t>
__device__ int thread_corners(const Levels& levels, int n_levels, int64_t F, const scalar_t* pos,
                              int64_t n, scalar_t (&w)[8], int32_t (&row)[8], int64_t* slot) {
  const int64_t t = int64_t(blockIdx.x) * blockDim.x + threadIdx.x;
  if (t >= n * n_levels) return -1;
  const int64_t i = t / n_levels;
  const int l = int(t % n_levels);
  *slot = t * F;  // = i * n_levels * F + l * F
  const Level& lv = levels.l[l];
  const bool ok =
      lv.dim == 3 ? corners<3>(lv, pos + i * 3, w, row) : corners<2>(lv, pos + i * 3, w, row);
  return ok ? 1 << lv.dim : 0;
}

template <typename scalar_t>
__global__ void forward_kernel(Levels levels, int n_levels, int64_t F, const scalar_t* pos,
                               const scalar_t* table, int64_t n, bool binarize, scalar_t* out) {
  scalar_t w[8];
  int32_t row[8];
  int64_t slot = 0;
  const int n_corners = thread_corners(levels, n_levels, F, pos, n, w, row, &slot);
  if (n_corners < 0) return;
  scalar_t acc[kMaxFeatures];
  for (int64_t f = 0; f < F; ++f) acc[f] = 0;
  for (int c = 0; c < n_corners; ++c) {
    const scalar_t* v = table + int64_t(row[c]) * F;
    for (int64_t f = 0; f < F; ++f) {
      const scalar_t x = binarize ? scalar_t(int(v[f] >= scalar_t(0)) * 2 - 1) : v[f];
      acc[f] = acc[f] + w[c] * x;
    }
  }
  for (int64_t f = 0; f < F; ++f) out[slot + f] = acc[f];
}

template <typename scalar_t>
__global__ void backward_kernel(Levels levels, int n_levels, int64_t F, const scalar_t* pos,
                                const scalar_t* grad_out, int64_t n, scalar_t* grad_table) {
  scalar_t w[8];
  int32_t row[8];
  int64_t slot = 0;
  const int n_corners = thread_corners(levels, n_levels, F, pos, n, w, row, &slot);
  const scalar_t* go = grad_out + slot;
  for (int c = 0; c < n_corners; ++c) {
    if (w[c] == scalar_t(0)) continue;
    scalar_t* g = grad_table + int64_t(row[c]) * F;
    for (int64_t f = 0; f < F; ++f) atomicAdd(g + f, w[c] * go[f]);
  }
}

template <typename scalar_t>
__global__ void straight_through_kernel(const scalar_t* table, int64_t count, scalar_t* grad) {
  const int64_t k = int64_t(blockIdx.x) * blockDim.x + threadIdx.x;
  if (k < count) grad[k] = grad[k] * scalar_t(fabs(table[k]) <= scalar_t(1));
}

const char* check_levels(int n_levels, int64_t F) {
  if (n_levels < 1 || n_levels > kMaxLevels) return "hash_grid (cuda): 1 to 64 levels";
  if (F < 1 || F > kMaxFeatures) return "hash_grid (cuda): 1 to 16 features per level";
  return nullptr;
}

const char* last_error() {
  const cudaError_t e = cudaGetLastError();
  return e == cudaSuccess ? nullptr : cudaGetErrorString(e);
}

unsigned blocks(int64_t work) {
  return unsigned((work + kThreads - 1) / kThreads);
}

template <typename scalar_t>
const char* forward_t(const Level* levels, int n_levels, int64_t F, const scalar_t* pos,
                      const scalar_t* table, int64_t n, bool binarize, scalar_t* out) {
  if (const char* e = check_levels(n_levels, F)) return e;
  if (n == 0) return nullptr;
  Levels ls{};
  for (int l = 0; l < n_levels; ++l) ls.l[l] = levels[l];
  forward_kernel<<<blocks(n * n_levels), kThreads>>>(ls, n_levels, F, pos, table, n, binarize, out);
  return last_error();
}

template <typename scalar_t>
const char* backward_t(const Level* levels, int n_levels, int64_t F, const scalar_t* pos,
                       const scalar_t* grad_out, const scalar_t* table, int64_t rows, int64_t n,
                       bool binarize, scalar_t* grad_table) {
  if (const char* e = check_levels(n_levels, F)) return e;
  Levels ls{};
  for (int l = 0; l < n_levels; ++l) ls.l[l] = levels[l];
  if (n > 0)
    backward_kernel<<<blocks(n * n_levels), kThreads>>>(ls, n_levels, F, pos, grad_out, n,
                                                        grad_table);
  if (binarize && rows > 0)
    straight_through_kernel<<<blocks(rows * F), kThreads>>>(table, rows * F, grad_table);
  return last_error();
}

}  // namespace

const char* forward(const Level* levels, int n_levels, int64_t n_features, const float* pos,
                    const float* table, int64_t n, bool binarize, float* out) {
  return forward_t(levels, n_levels, n_features, pos, table, n, binarize, out);
}
const char* forward(const Level* levels, int n_levels, int64_t n_features, const double* pos,
                    const double* table, int64_t n, bool binarize, double* out) {
  return forward_t(levels, n_levels, n_features, pos, table, n, binarize, out);
}
const char* backward(const Level* levels, int n_levels, int64_t n_features, const float* pos,
                     const float* grad_out, const float* table, int64_t rows, int64_t n,
                     bool binarize, float* grad_table) {
  return backward_t(levels, n_levels, n_features, pos, grad_out, table, rows, n, binarize,
                    grad_table);
}
const char* backward(const Level* levels, int n_levels, int64_t n_features, const double* pos,
                     const double* grad_out, const double* table, int64_t rows, int64_t n,
                     bool binarize, double* grad_table) {
  return backward_t(levels, n_levels, n_features, pos, grad_out, table, rows, n, binarize,
                    grad_table);
}

}  // namespace crpgs::hash_grid::cuda_kernels
