/// @file sorted_gather.cpp
/// @brief gather_sorted_rows: the neural Gaussians' row gathers (anchor -> visible anchor ->
/// Gaussian), whose backward as index_select's was a large share of a late fern iteration.
#include "model/sorted_gather.h"

#include <torch/torch.h>

#include <ATen/Parallel.h>

#include <algorithm>
#include <limits>

namespace crpgs {
namespace {

using torch::autograd::AutogradContext;
using torch::autograd::variable_list;

constexpr int64_t kGrain = 2048;

/// first[r] = the first position of the sorted `idx` holding a value >= r, for r in [0, rows]:
/// position j fills the r in (idx[j-1], idx[j]], so each entry is written once.
at::Tensor run_starts(const at::Tensor& idx, int64_t rows) {
  const int64_t* p = idx.data_ptr<int64_t>();
  const int64_t n = idx.numel();
  at::Tensor first = at::empty({rows + 1}, at::kLong);
  int64_t* f = first.data_ptr<int64_t>();
  at::parallel_for(0, n + 1, kGrain, [&](int64_t b, int64_t e) {
    for (int64_t j = b; j < e; ++j) {
      const int64_t lo = j == 0 ? -1 : p[j - 1], hi = j == n ? rows : p[j];
      for (int64_t r = lo + 1; r <= hi; ++r) f[r] = j;
    }
  });
  return first;
}

/// out[idx[j]] = grad[j] and every other row of out = 0, for a strictly increasing idx: position
/// j writes the rows (idx[j-1], idx[j]] (a run of consecutive positions, their rows together), so
/// each row is written once.
void scatter_unique_rows(const at::Tensor& idx, const at::Tensor& grad, at::Tensor& out) {
  const int64_t* p = idx.data_ptr<int64_t>();
  const int64_t n = idx.numel(), rows = out.size(0), width = rows > 0 ? out.numel() / rows : 0;
  AT_DISPATCH_FLOATING_TYPES(grad.scalar_type(), "gather_sorted_rows_scatter", [&] {
    const scalar_t* g = grad.data_ptr<scalar_t>();
    scalar_t* o = out.data_ptr<scalar_t>();
    at::parallel_for(0, n + 1, kGrain, [&](int64_t b, int64_t e) {
      for (int64_t j = b; j < e;) {
        const int64_t lo = j == 0 ? -1 : p[j - 1], hi = j == n ? rows : p[j];
        std::fill(o + (lo + 1) * width, o + hi * width, scalar_t(0));
        if (j == n) break;
        // Consecutive rows in one copy (nonzero() indices come in long runs).
        int64_t end = j + 1;
        while (end < e && end < n && p[end] == p[end - 1] + 1) ++end;
        std::copy(g + j * width, g + end * width, o + hi * width);
        j = end;
      }
    });
  });
}

struct GatherSortedRows : public torch::autograd::Function<GatherSortedRows> {
  static at::Tensor forward(AutogradContext* ctx, const at::Tensor& src, const at::Tensor& index) {
    const at::Tensor idx = index.contiguous();
    const int64_t n = idx.numel(), rows = src.size(0);
    const int64_t* p = idx.data_ptr<int64_t>();
    bool strict = true;  // no row taken twice: the backward is a copy, not a sum
    for (int64_t j = 1; j < n; ++j) {
      TORCH_CHECK(p[j] >= p[j - 1], "gather_sorted_rows: the index decreases at position ", j);
      strict = strict && p[j] > p[j - 1];
    }
    if (n > 0)
      TORCH_CHECK(p[0] >= 0 && p[n - 1] < rows, "gather_sorted_rows: index values ", p[0], "..",
                  p[n - 1], " are out of range for ", rows, " rows");
    ctx->save_for_backward({idx});
    ctx->saved_data["sizes"] = src.sizes().vec();
    ctx->saved_data["strict"] = strict;
    return src.index_select(0, idx);
  }

  static variable_list backward(AutogradContext* ctx, variable_list grads) {
    const auto sizes = ctx->saved_data["sizes"].toIntVector();
    const at::Tensor idx = ctx->get_saved_variables()[0];
    const at::Tensor grad = grads[0].contiguous();
    at::Tensor out = at::empty(sizes, grad.options());
    const int64_t rows = sizes[0], width = rows > 0 ? out.numel() / rows : 0;
    if (ctx->saved_data["strict"].toBool()) {
      scatter_unique_rows(idx, grad, out);
      return {out, at::Tensor()};
    }
    const at::Tensor first = run_starts(idx, rows);
    const int64_t* f = first.data_ptr<int64_t>();
    AT_DISPATCH_FLOATING_TYPES(grad.scalar_type(), "gather_sorted_rows_backward", [&] {
      const scalar_t* g = grad.data_ptr<scalar_t>();
      scalar_t* o = out.data_ptr<scalar_t>();
      at::parallel_for(0, rows, kGrain, [&](int64_t b, int64_t e) {
        for (int64_t r = b; r < e; ++r) {
          scalar_t* dst = o + r * width;
          std::fill(dst, dst + width, scalar_t(0));
          for (int64_t j = f[r]; j < f[r + 1]; ++j) {
            const scalar_t* src = g + j * width;
            for (int64_t c = 0; c < width; ++c) dst[c] += src[c];
          }
        }
      });
    });
    return {out, at::Tensor()};
  }
};

}  // namespace

torch::Tensor gather_sorted_rows(const torch::Tensor& src, const torch::Tensor& index) {
  TORCH_CHECK(src.dim() >= 1 && index.dim() == 1 && index.scalar_type() == at::kLong,
              "gather_sorted_rows: expected rows of a tensor and a 1-D long index");
  // Off the CPU index_select's own backward (a parallel scatter-add there).
  if (!src.requires_grad() || !torch::GradMode::is_enabled() || !src.device().is_cpu())
    return src.index_select(0, index);
  return GatherSortedRows::apply(src, index);
}

torch::Tensor max_rows_into(const torch::Tensor& src, const torch::Tensor& cell, int64_t rows) {
  TORCH_CHECK(src.dim() == 2 && cell.dim() == 1 && cell.size(0) == src.size(0) &&
                  src.scalar_type() == at::kFloat && cell.scalar_type() == at::kLong,
              "max_rows_into: expected float rows [S, D] and a long cell index [S]");
  if (!src.device().is_cpu()) return max_rows_into_reference(src, cell, rows);
  // A plain loop: scatter_reduce is "beta" in libtorch 1.13 and logs a warning on the CPU.
  const int64_t D = src.size(1);
  auto out = torch::full({rows, D}, -std::numeric_limits<float>::infinity(), src.options());
  const auto pf = src.detach().contiguous();
  const auto inv = cell.contiguous();
  const float* s = pf.data_ptr<float>();
  const int64_t* c = inv.data_ptr<int64_t>();
  float* dst = out.data_ptr<float>();
  for (int64_t r = 0; r < pf.size(0); ++r) {
    TORCH_CHECK(c[r] >= 0 && c[r] < rows, "max_rows_into: cell ", c[r], " is out of range");
    for (int64_t k = 0; k < D; ++k) dst[c[r] * D + k] = std::max(dst[c[r] * D + k], s[r * D + k]);
  }
  return out;
}

torch::Tensor max_rows_into_reference(const torch::Tensor& src, const torch::Tensor& cell,
                                      int64_t rows) {
  auto out =
      torch::full({rows, src.size(1)}, -std::numeric_limits<float>::infinity(), src.options());
  return out.scatter_reduce_(0, cell.unsqueeze(1).expand_as(src), src.detach(), "amax", true);
}

}  // namespace crpgs
