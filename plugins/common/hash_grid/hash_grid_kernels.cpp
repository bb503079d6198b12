/// @file hash_grid_kernels.cpp
/// @brief CPU kernels and the ATen reference of the binary hash grid. Built with
/// -ffp-contract=off so kernel and reference round identically.
#include "hash_grid_kernels.h"

#include <ATen/Parallel.h>

#include <algorithm>
#include <cmath>
#include <stdexcept>
#include <string>
#include <vector>

#include "crpgs/target_clones.h"
#include "grid_cuda.h"

namespace crpgs::hash_grid {
namespace {

constexpr uint32_t kPrimes[3] = {cuda_kernels::kHashPrimeX, cuda_kernels::kHashPrimeY,
                                 cuda_kernels::kHashPrimeZ};

/// Points whose corners are computed together: one vector of lanes per corner term.
constexpr int kLanes = 16;

/// The 2^dim corners of up to kLanes points at one level: normalised weights and table rows,
/// corner-major so that the lanes are contiguous. ok = 0 for a point outside [0, 1] on an axis
/// the level reads (its weights are then meaningless).
template <typename scalar_t>
struct CornerBlock {
  alignas(64) scalar_t w[8][kLanes];
  alignas(64) int32_t row[8][kLanes];
  alignas(64) uint32_t ok[kLanes];
};

// Rows fit int32: a table holds at most kMaxTableValues values.
static_assert(kMaxTableValues <= int64_t(INT32_MAX));

/// Each axis's two candidate weights, border flags, dense and hash terms are computed once and
/// combined per corner in the same order as the reference, so the results are bit-identical to
/// it. Lanes run independently (no early exit, out-of-range coordinates replaced by 0, indices in
/// wrapping uint32), so the loop over them vectorises.
template <int DIM, typename scalar_t>
[[gnu::always_inline]] inline void corners_block_dim(const GridLevel& lv, const scalar_t* pos,
                                                     int64_t n, CornerBlock<scalar_t>& cb) {
  scalar_t u[DIM][kLanes];
  for (int d = 0; d < DIM; ++d) {
    std::fill(u[d], u[d] + kLanes, scalar_t(0));
    for (int64_t i = 0; i < n; ++i) u[d][i] = pos[i * 3 + lv.axes[d]];
  }
  const scalar_t scale = scalar_t(lv.res - 2);
  const int32_t last = int32_t(lv.res - 1);
  const uint32_t res = uint32_t(lv.res);
  const int32_t offset = int32_t(lv.offset);
  // A dense index is below res^dim <= size; a hashed level's size is a power of two, so the
  // modulo is a mask.
  const uint32_t hash_mask = uint32_t(lv.size - 1);
  const uint32_t dense_sel = lv.dense ? ~uint32_t(0) : 0;  // a select the lanes share
  for (int i = 0; i < kLanes; ++i) {
    scalar_t wd[DIM][2];
    uint32_t border_d[DIM][2];
    uint32_t dense_d[DIM][2];
    uint32_t hash_d[DIM][2];
    uint32_t inside = 1;
    uint32_t stride = 1;
#pragma GCC unroll 3
    for (int d = 0; d < DIM; ++d) {
      const scalar_t raw = u[d][i];
      // Bitwise & and |, not && and ||: no branch per lane.
      const uint32_t in = uint32_t(raw >= scalar_t(0)) & uint32_t(raw <= scalar_t(1));
      inside &= in;
      const scalar_t v = in ? raw : scalar_t(0);
      const scalar_t p = v * scale + scalar_t(0.5);
      const scalar_t fl = std::floor(p);
      const scalar_t frac = p - fl;
      const int32_t id0 = int32_t(fl);
      const int32_t id[2] = {id0, std::min(id0 + 1, last)};
      wd[d][0] = scalar_t(1) - frac;
      wd[d][1] = frac;
      for (int b = 0; b < 2; ++b) {
        border_d[d][b] = uint32_t(id[b] == 0) | uint32_t(id[b] == last);
        dense_d[d][b] = uint32_t(id[b]) * stride;  // wraps only on hashed levels, unused there
        hash_d[d][b] = uint32_t(id[b]) * kPrimes[d];
      }
      stride *= res;
    }
    scalar_t sum = 0;
#pragma GCC unroll 8
    for (int c = 0; c < (1 << DIM); ++c) {
      scalar_t wc = 1;
      uint32_t border = 0;
      uint32_t dense = 0, hash = 0;
      for (int d = 0; d < DIM; ++d) {
        const int b = (c >> d) & 1;
        wc = wc * wd[d][b];
        border |= border_d[d][b];
        dense += dense_d[d][b];
        hash ^= hash_d[d][b];
      }
      wc = border ? scalar_t(0) : wc;
      cb.w[c][i] = wc;
      sum = sum + wc;
      cb.row[c][i] = offset + int32_t((dense & dense_sel) | (hash & hash_mask & ~dense_sel));
    }
    const scalar_t denom = sum == scalar_t(0) ? scalar_t(1e-9) : sum;
#pragma GCC unroll 8
    for (int c = 0; c < (1 << DIM); ++c) cb.w[c][i] = cb.w[c][i] / denom;
    cb.ok[i] = inside;
  }
}

template <typename scalar_t>
[[gnu::always_inline]] inline void corners_block_impl(const GridLevel& lv, const scalar_t* pos,
                                                      int64_t n, CornerBlock<scalar_t>& cb) {
  if (lv.dim == 3)
    corners_block_dim<3>(lv, pos, n, cb);
  else
    corners_block_dim<2>(lv, pos, n, cb);
}

// float (training) gets a vector clone per ISA; every clone rounds alike (IEEE operations, no
// contraction), so encoder and decoder agree whichever one a machine picks.
CRPGS_TARGET_CLONES
void corners_block(const GridLevel& lv, const float* pos, int64_t n, CornerBlock<float>& cb) {
  corners_block_impl(lv, pos, n, cb);
}

void corners_block(const GridLevel& lv, const double* pos, int64_t n, CornerBlock<double>& cb) {
  corners_block_impl(lv, pos, n, cb);
}

/// Sign bits of a binarised table, one byte per row (bit f = value f >= 0, HAC's convention):
/// HAC's table is 28 MB of floats read at random, its signs 1.7 MB, so the forward's lookups hit
/// the cache instead of memory (forward 1.9x faster, bench/results/hash_grid.md).
template <typename scalar_t>
std::vector<uint8_t> pack_signs(const scalar_t* table, int64_t rows, int64_t F) {
  std::vector<uint8_t> signs(size_t(rows), 0);
  at::parallel_for(0, rows, 1 << 16, [&](int64_t begin, int64_t end) {
    for (int64_t r = begin; r < end; ++r) {
      uint8_t bits = 0;
      for (int64_t f = 0; f < F; ++f) bits |= uint8_t(table[r * F + f] >= scalar_t(0)) << f;
      signs[size_t(r)] = bits;
    }
  });
  return signs;
}

constexpr int64_t kMaxPackedFeatures = 8;

/// kF > 0: the feature count as a compile-time constant (HAC's layouts use 4), so the per-corner
/// feature loop unrolls; kF = 0 reads it from the spec.
template <int kF, typename scalar_t>
void forward_impl_f(const GridSpec& spec, const scalar_t* pos, const scalar_t* table, int64_t n,
                    bool binarize, scalar_t* out) {
  const int64_t F = kF > 0 ? kF : spec.n_features, width = spec.output_dim();
  const bool packed = binarize && F <= kMaxPackedFeatures;
  const std::vector<uint8_t> signs =
      packed ? pack_signs(table, spec.n_entries, F) : std::vector<uint8_t>();
  at::parallel_for(0, n, 4096, [&](int64_t begin, int64_t end) {
    CornerBlock<scalar_t> cb;
    // Level-outer inside blocks of 1024 points: one level's table and the block's output rows
    // stay in cache.
    for (int64_t b0 = begin; b0 < end; b0 += 1024) {
      const int64_t b1 = std::min(end, b0 + 1024);
      // One fill per block: zeroing F values per point and level compiled to a memset call each.
      std::fill(out + b0 * width, out + b1 * width, scalar_t(0));
      for (size_t l = 0; l < spec.levels.size(); ++l) {
        const GridLevel& lv = spec.levels[l];
        for (int64_t s0 = b0; s0 < b1; s0 += kLanes) {
          const int64_t m = std::min<int64_t>(kLanes, b1 - s0);
          corners_block(lv, pos + s0 * 3, m, cb);
          for (int64_t i = 0; i < m; ++i) {
            if (!cb.ok[i]) continue;
            scalar_t* o = out + (s0 + i) * width + int64_t(l) * F;
            for (int c = 0; c < (1 << lv.dim); ++c) {
              const scalar_t w = cb.w[c][i];
              if (packed) {
                const unsigned bits = signs[size_t(cb.row[c][i])];
                // Branch-free sign: random signs would mispredict a branch half the time.
                for (int64_t f = 0; f < F; ++f)
                  o[f] = o[f] + w * scalar_t(int((bits >> f) & 1u) * 2 - 1);
                continue;
              }
              const scalar_t* t = table + int64_t(cb.row[c][i]) * F;
              for (int64_t f = 0; f < F; ++f) {
                const scalar_t v = binarize ? scalar_t(int(t[f] >= scalar_t(0)) * 2 - 1) : t[f];
                o[f] = o[f] + w * v;
              }
            }
          }
        }
      }
    }
  });
}

template <typename scalar_t>
void forward_impl(const GridSpec& spec, const scalar_t* pos, const scalar_t* table, int64_t n,
                  bool binarize, scalar_t* out) {
  if (spec.n_features == 4)
    forward_impl_f<4>(spec, pos, table, n, binarize, out);
  else
    forward_impl_f<0>(spec, pos, table, n, binarize, out);
}

template <typename scalar_t>
void backward_impl(const GridSpec& spec, const scalar_t* pos, const scalar_t* grad_out, int64_t n,
                   scalar_t* grad_table) {
  const int64_t F = spec.n_features, width = spec.output_dim();
  const int64_t n_levels = int64_t(spec.levels.size());
  // Levels write disjoint table rows, so threads split them. The 3D levels (8 corners) come
  // first and cost about twice the 2D ones (4 corners): taking levels in the order 0, n−1, 1,
  // n−2, ... gives each contiguous share of the range a mix of both.
  std::vector<int64_t> order(static_cast<size_t>(n_levels));
  for (int64_t i = 0; i < n_levels; ++i)
    order[size_t(i)] = i % 2 == 0 ? i / 2 : n_levels - 1 - i / 2;
  at::parallel_for(0, n_levels, 1, [&](int64_t lbegin, int64_t lend) {
    CornerBlock<scalar_t> cb;
    for (int64_t k = lbegin; k < lend; ++k) {
      const int64_t l = order[size_t(k)];
      const GridLevel& lv = spec.levels[size_t(l)];
      for (int64_t s0 = 0; s0 < n; s0 += kLanes) {
        const int64_t m = std::min<int64_t>(kLanes, n - s0);
        corners_block(lv, pos + s0 * 3, m, cb);
        for (int64_t i = 0; i < m; ++i) {
          if (!cb.ok[i]) continue;
          const scalar_t* go = grad_out + (s0 + i) * width + l * F;
          for (int c = 0; c < (1 << lv.dim); ++c) {
            const scalar_t w = cb.w[c][i];
            if (w == scalar_t(0)) continue;
            scalar_t* gt = grad_table + int64_t(cb.row[c][i]) * F;
            for (int64_t f = 0; f < F; ++f) gt[f] = gt[f] + w * go[f];
          }
        }
      }
    }
  });
}

}  // namespace

void check_grid_inputs(const GridSpec& spec, const at::Tensor& positions01,
                       const at::Tensor& table) {
  TORCH_CHECK(positions01.dim() == 2 && positions01.size(1) == 3,
              "hash_grid: positions must be [N, 3], got ", positions01.sizes());
  TORCH_CHECK(
      table.dim() == 2 && table.size(0) == spec.n_entries && table.size(1) == spec.n_features,
      "hash_grid: table must be [", spec.n_entries, ", ", spec.n_features, "], got ",
      table.sizes());
}

GridSpec make_grid_spec(const std::vector<int64_t>& res3, int log2_3,
                        const std::vector<int64_t>& res2, int log2_2, int64_t n_features) {
  if (log2_3 < 3 || log2_3 > 30 || log2_2 < 3 || log2_2 > 30)
    throw std::invalid_argument("hash_grid: log2 table sizes must lie in [3, 30]");
  if (n_features < 1) throw std::invalid_argument("hash_grid: n_features_per_level must be >= 1");
  GridSpec spec;
  spec.n_features = n_features;
  auto add = [&](int dim, int a0, int a1, int a2, int64_t res, int log2) {
    if (res < 3 || res > 65536)
      throw std::invalid_argument("hash_grid: resolution " + std::to_string(res) +
                                  " outside [3, 65536]");
    GridLevel lv;
    lv.dim = dim;
    lv.axes[0] = a0;
    lv.axes[1] = a1;
    lv.axes[2] = a2;
    lv.res = res;
    int64_t full = 1;
    for (int d = 0; d < dim; ++d) full *= res;
    const int64_t cap = int64_t(1) << log2;
    lv.size = (std::min(cap, full) + 7) / 8 * 8;
    lv.dense = full <= lv.size;
    // Hashed: full > size, so size = 2^log2 (>= 8); the kernels mask instead of dividing.
    if (!lv.dense && (lv.size & (lv.size - 1)) != 0)
      throw std::logic_error("hash_grid: hashed level of non-power-of-two size");
    lv.offset = spec.n_entries;
    spec.n_entries += lv.size;
    spec.levels.push_back(lv);
  };
  for (int64_t r : res3) add(3, 0, 1, 2, r, log2_3);
  for (int plane = 0; plane < 3; ++plane) {
    const int axes[3][2] = {{0, 1}, {0, 2}, {1, 2}};  // xy, xz, yz
    for (int64_t r : res2) add(2, axes[plane][0], axes[plane][1], 0, r, log2_2);
  }
  // A decoder builds the grid from the bitstream's config before reading any table bytes, so a
  // few config bytes must not be able to ask for gigabytes (HAC's default grid has 2^21 values).
  if (spec.n_entries > kMaxTableValues / n_features)
    throw std::invalid_argument("hash_grid: the table would hold " +
                                std::to_string(spec.n_entries) + " x " +
                                std::to_string(n_features) + " values, more than the limit of " +
                                std::to_string(kMaxTableValues));
  return spec;
}

at::Tensor grid_forward(const GridSpec& spec, const at::Tensor& positions01,
                        const at::Tensor& table, bool binarize) {
  check_grid_inputs(spec, positions01, table);
  TORCH_CHECK(table.device().is_cpu() && positions01.device().is_cpu(),
              "hash_grid: CPU kernel called on non-CPU tensors");
  const auto pos = positions01.to(table.scalar_type()).contiguous();
  const auto tab = table.contiguous();
  auto out = at::empty({pos.size(0), spec.output_dim()}, tab.options());
  AT_DISPATCH_FLOATING_TYPES(tab.scalar_type(), "hash_grid_forward", [&] {
    forward_impl<scalar_t>(spec, pos.data_ptr<scalar_t>(), tab.data_ptr<scalar_t>(), pos.size(0),
                           binarize, out.data_ptr<scalar_t>());
  });
  return out;
}

at::Tensor grid_backward(const GridSpec& spec, const at::Tensor& positions01,
                         const at::Tensor& table, const at::Tensor& grad_out, bool binarize) {
  check_grid_inputs(spec, positions01, table);
  TORCH_CHECK(grad_out.dim() == 2 && grad_out.size(0) == positions01.size(0) &&
                  grad_out.size(1) == spec.output_dim(),
              "hash_grid: grad_out must be [N, ", spec.output_dim(), "]");
  const auto pos = positions01.to(table.scalar_type()).contiguous();
  const auto go = grad_out.to(table.scalar_type()).contiguous();
  auto grad = at::zeros_like(table, at::MemoryFormat::Contiguous);
  AT_DISPATCH_FLOATING_TYPES(table.scalar_type(), "hash_grid_backward", [&] {
    backward_impl<scalar_t>(spec, pos.data_ptr<scalar_t>(), go.data_ptr<scalar_t>(), pos.size(0),
                            grad.data_ptr<scalar_t>());
  });
  if (binarize) {
    // Straight through where |t| <= 1, in one pass (the ATen expression made four).
    AT_DISPATCH_FLOATING_TYPES(table.scalar_type(), "hash_grid_ste", [&] {
      const auto tab = table.contiguous();
      const scalar_t* t = tab.data_ptr<scalar_t>();
      scalar_t* g = grad.data_ptr<scalar_t>();
      at::parallel_for(0, grad.numel(), 1 << 16, [&](int64_t begin, int64_t end) {
        for (int64_t i = begin; i < end; ++i) g[i] = g[i] * scalar_t(std::abs(t[i]) <= scalar_t(1));
      });
    });
  }
  return grad;
}

at::Tensor binarize_values(const at::Tensor& table) {
  return at::where(table.ge(0), at::ones_like(table), -at::ones_like(table));
}

namespace {
// The values a lookup reads: the table, or with binarize exactly ±1 forward and the gradient
// where |table| <= 1 backward (straight through).
at::Tensor lookup_values(const at::Tensor& table, bool binarize) {
  if (!binarize) return table;
  const auto mask = table.detach().abs().le(1).to(table.scalar_type());
  return binarize_values(table.detach()) + (table - table.detach()) * mask;
}
}  // namespace

at::Tensor grid_forward_reference(const GridSpec& spec, const at::Tensor& positions01,
                                  const at::Tensor& table, bool binarize) {
  check_grid_inputs(spec, positions01, table);
  const at::Tensor values = lookup_values(table, binarize);
  const auto pos = positions01.detach().to(table.scalar_type());
  const int64_t n = pos.size(0), F = spec.n_features, L = int64_t(spec.levels.size());
  if (L == 0) return at::zeros({n, 0}, values.options());
  const auto iopt = at::TensorOptions().dtype(at::kLong).device(pos.device());
  std::vector<at::Tensor> groups;  // [G, n, F] per dimension, levels in spec order inside
  std::vector<int64_t> order;      // the levels in the order of `groups`
  for (int dim : {3, 2}) {
    std::vector<int64_t> ids, axes, res, offset, size, dense;
    for (int64_t l = 0; l < L; ++l) {
      const GridLevel& lv = spec.levels[size_t(l)];
      if (lv.dim != dim) continue;
      ids.push_back(l);
      axes.insert(axes.end(), lv.axes, lv.axes + dim);
      res.push_back(lv.res);
      offset.push_back(lv.offset);
      size.push_back(lv.size);
      dense.push_back(lv.dense);
    }
    if (ids.empty()) continue;
    const int64_t G = int64_t(ids.size());
    auto level_col = [&](const std::vector<int64_t>& v) {
      return at::tensor(v, iopt).view({G, 1});
    };
    const auto res_l = level_col(res), offset_l = level_col(offset), size_l = level_col(size);
    const auto dense_l = level_col(dense).ne(0);
    const auto res_m2 = (res_l - 2).to(pos.scalar_type()).unsqueeze(2);  // [G, 1, 1]
    // u [G, n, dim]: each level's coordinates.
    auto u = pos.t().index_select(0, at::tensor(axes, iopt)).view({G, dim, n}).permute({0, 2, 1});
    const auto inside = u.ge(0).logical_and(u.le(1)).all(2);  // [G, n]; NaN compares false
    u = at::where(inside.unsqueeze(2), u, at::zeros_like(u));
    const auto p = u * res_m2 + 0.5;
    const auto fl = at::floor(p);
    const auto frac = p - fl;
    const auto g = fl.to(at::kLong);
    // Per corner the kernel's operations in its order (so the same values bit for bit), on all
    // levels of this dimension at once: a GPU is bound by the number of ATen calls here, and one
    // level at a time made 12x more.
    std::vector<at::Tensor> ws, rows;
    auto sum = at::zeros({G, n}, pos.options());
    for (int c = 0; c < (1 << dim); ++c) {
      auto w = at::ones({G, n}, pos.options());
      auto border = at::zeros({G, n}, pos.options().dtype(at::kBool));
      auto dense_idx = at::zeros({G, n}, iopt);
      auto hash = at::zeros({G, n}, iopt);
      auto stride = at::ones({G, 1}, iopt);
      for (int d = 0; d < dim; ++d) {
        auto id = g.select(2, d);
        if (c & (1 << d)) {
          w = w * frac.select(2, d);
          id = at::minimum(id + 1, res_l - 1);
        } else {
          w = w * (1 - frac.select(2, d));
        }
        border = border.logical_or(id.eq(0)).logical_or(id.eq(res_l - 1));
        dense_idx = dense_idx + id * stride;
        stride = stride * res_l;
        hash = at::bitwise_xor(hash, (id * int64_t(kPrimes[d])).bitwise_and(int64_t(0xFFFFFFFF)));
      }
      w = at::where(border, at::zeros_like(w), w);
      sum = sum + w;
      ws.push_back(w);
      rows.push_back(at::where(dense_l, dense_idx, hash).remainder(size_l) + offset_l);
    }
    const auto denom = at::where(sum.eq(0), at::full_like(sum, 1e-9), sum);
    auto out = at::zeros({G, n, F}, values.options());
    for (size_t c = 0; c < ws.size(); ++c)
      out = out + (ws[c] / denom).unsqueeze(2) *
                      values.index_select(0, rows[c].reshape({-1})).view({G, n, F});
    groups.push_back(at::where(inside.unsqueeze(2), out, at::zeros_like(out)));
    order.insert(order.end(), ids.begin(), ids.end());
  }
  std::vector<int64_t> slot(size_t(L), 0);  // level l is groups' row slot[l]
  for (size_t i = 0; i < order.size(); ++i) slot[size_t(order[i])] = int64_t(i);
  const auto levels = at::cat(groups, 0).index_select(0, at::tensor(slot, iopt));  // [L, n, F]
  return levels.permute({1, 0, 2}).reshape({n, L * F});
}

}  // namespace crpgs::hash_grid
