/// @file hash_grid_kernels.h
/// @brief HAC's binary multi-resolution hash grid (docs/method.md §2.1): the level layout, fast CPU
/// forward/backward kernels and a pure-ATen reference of the same maths (used on CUDA tensors
/// and as the tests' oracle).
#pragma once

#include <cstdint>
#include <vector>

#include <ATen/ATen.h>

namespace crpgs::hash_grid {

/// One level of one grid. The xyz grid's levels come first, then the xy, xz and yz planes'.
struct GridLevel {
  int dim = 3;              ///< 3 (xyz) or 2 (a plane)
  int axes[3] = {0, 1, 2};  ///< which input coordinates the level reads
  int64_t res = 0;          ///< resolution; border vertices (0 and res-1) are discarded
  int64_t offset = 0;       ///< first table entry of the level
  int64_t size = 0;         ///< entries: min(2^log2, res^dim) rounded up to a multiple of 8
  bool dense = false;       ///< res^dim <= size: index g_x + g_y res + g_z res^2, else hashed
                            ///< (then size = 2^log2)
};

struct GridSpec {
  std::vector<GridLevel> levels;
  int64_t n_features = 4;  ///< per level
  int64_t n_entries = 0;   ///< table rows over all levels
  int64_t output_dim() const { return int64_t(levels.size()) * n_features; }
};

/// Most values (rows x features) a grid table may hold: 2^27, 512 MiB as float32.
inline constexpr int64_t kMaxTableValues = int64_t(1) << 27;

/// The xyz grid (resolutions res3, table 2^log2_3) then the xy, xz and yz planes (res2,
/// 2^log2_2 each). Throws std::invalid_argument for a resolution < 3, a log2 outside [3, 30] or
/// a table of more than kMaxTableValues values.
GridSpec make_grid_spec(const std::vector<int64_t>& res3, int log2_3,
                        const std::vector<int64_t>& res2, int log2_2, int64_t n_features);

/// Output [N, output_dim] of positions01 [N, 3] against table [n_entries, n_features] (same
/// floating dtype, CPU, contiguous). binarize: table values read as +1 (>= 0) or -1.
/// A level outputs 0 for a point with a coordinate outside [0, 1] (or NaN). Parallel over
/// points; the result does not depend on the thread count.
at::Tensor grid_forward(const GridSpec& spec, const at::Tensor& positions01,
                        const at::Tensor& table, bool binarize);
/// Gradient w.r.t. the table [n_entries, n_features] given grad_out [N, output_dim]; with
/// binarize, the straight-through mask |table| <= 1 is applied. Parallel over levels (disjoint
/// table ranges), points in order inside a level: deterministic for any thread count.
/// Positions get no gradient.
at::Tensor grid_backward(const GridSpec& spec, const at::Tensor& positions01,
                         const at::Tensor& table, const at::Tensor& grad_out, bool binarize);

/// The same maths in ATen ops, any device, differentiable w.r.t. table through autograd
/// (straight-through estimator included); positions are treated as constants. The levels of one
/// dimension go together (two passes, not one per level). What grid_lookup runs off the CPU.
at::Tensor grid_forward_reference(const GridSpec& spec, const at::Tensor& positions01,
                                  const at::Tensor& table, bool binarize);

/// Throws (c10::Error) unless positions01 is [N, 3] and table [n_entries, n_features].
void check_grid_inputs(const GridSpec& spec, const at::Tensor& positions01,
                       const at::Tensor& table);

/// The CUDA kernels (grid_cuda.cu) as an autograd function of the table, for CUDA tensors:
/// forward bit-equal to grid_forward, backward summed with atomics (order varies). Defined only
/// in plugins built with CRPGS_GRID_CUDA (a CUDA libtorch and nvcc; grid_cuda_glue.cpp).
at::Tensor grid_lookup_cuda(const GridSpec& spec, const at::Tensor& positions01,
                            const at::Tensor& table, bool binarize);
/// False when the environment sets CRPGS_GRID_CUDA=0: lookups on CUDA tensors then run
/// grid_forward_reference (ATen ops) instead, for A/B timings.
bool grid_cuda_kernels_enabled();

/// sign(x) with HAC's convention (+1 where x >= 0, else -1), forward value of the binarisation.
at::Tensor binarize_values(const at::Tensor& table);

}  // namespace crpgs::hash_grid
