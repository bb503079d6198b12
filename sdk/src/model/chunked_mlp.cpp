/// @file chunked_mlp.cpp
/// @brief chunked_mlp: forward and backward of the two-layer MLPs, chunk by chunk.
#include "crpgs/chunked_mlp.h"

#include <torch/torch.h>

#include <ATen/Parallel.h>

#include <dlfcn.h>

#include <algorithm>
#include <type_traits>
#include <utility>
#include <vector>

#include "crpgs/runtime.h"
#include "model/sparse_head_kernels.h"

namespace crpgs {
namespace {

using torch::autograd::AutogradContext;
using torch::autograd::variable_list;

// Rows per chunk: a chunk's input, hidden layer and output stay in a core's L2 cache.
constexpr int64_t kChunkRows = 1024;

int64_t chunk_count(int64_t rows) {
  return (rows + kChunkRows - 1) / kChunkRows;
}

// The BLAS libtorch calls (Fortran interface, found at run time as runtime.cpp finds OpenBLAS);
// null where libtorch links its BLAS privately (then gemm goes through ATen).
template <typename T>
using FortranGemm = void (*)(const char*, const char*, const int*, const int*, const int*, const T*,
                             const T*, const int*, const T*, const int*, const T*, T*, const int*);
template <typename T>
FortranGemm<T> fortran_gemm() {
  static const auto f = reinterpret_cast<FortranGemm<T>>(
      dlsym(RTLD_DEFAULT, std::is_same_v<T, float> ? "sgemm_" : "dgemm_"));
  return f;
}

// c = a b, or c += a b with accumulate; each of a, b a row-major matrix or a .t() view of one,
// c row-major. The chunk loops make a few hundred of these per iteration: a direct BLAS call
// skips ATen's dispatch, views and checks (~4,000 of a rate-phase iteration's ~20,000 operators
// on fern, bench/results/train_fern.md). The BLAS call
// is the one at::mm makes for the same operands (row-major c as column-major c^T = b^T a^T).
void gemm(const at::Tensor& a, const at::Tensor& b, at::Tensor& c, bool accumulate) {
  const int64_t M = c.size(0), N = c.size(1), K = a.size(1);
  // A row-major matrix, or the transpose of one ('t'); a dimension of size 1 has any stride,
  // and BLAS wants a leading dimension of at least the stored row length.
  auto layout = [](const at::Tensor& t, char* trans, int* ld) {
    const int64_t r = t.size(0), c = t.size(1);
    if (t.stride(1) == 1 && (r == 1 || t.stride(0) >= c)) {
      *trans = 'n';
      *ld = int(std::max<int64_t>(1, r == 1 ? c : t.stride(0)));
      return true;
    }
    if (t.stride(0) == 1 && (c == 1 || t.stride(1) >= r)) {
      *trans = 't';
      *ld = int(std::max<int64_t>(1, c == 1 ? r : t.stride(1)));
      return true;
    }
    return false;
  };
  char ta = 0, tb = 0;
  int lda = 0, ldb = 0;
  const bool plain = c.stride(1) == 1 && c.stride(0) >= N && layout(a, &ta, &lda) &&
                     layout(b, &tb, &ldb) && M > 0 && N > 0 && K > 0;
  AT_DISPATCH_FLOATING_TYPES(c.scalar_type(), "chunked_mlp_gemm", [&] {
    const auto blas = fortran_gemm<scalar_t>();
    if (!plain || !blas) {
      if (accumulate) {
        c.addmm_(a, b);
      } else {
        at::mm_out(c, a, b);
      }
      return;
    }
    const int m = int(N), n = int(M), k = int(K), ldc = int(c.stride(0));
    const scalar_t one = 1, beta = accumulate ? 1 : 0;
    blas(&tb, &ta, &m, &n, &k, &one, b.data_ptr<scalar_t>(), &ldb, a.data_ptr<scalar_t>(), &lda,
         &beta, c.data_ptr<scalar_t>(), &ldc);
  });
}

// h = max(0, x w1^T + b1) for one chunk, into row-major h: the bias written first and the
// product added to it (as at::addmm_out does), the ReLU in place.
void first_layer_forward(const at::Tensor& x, const at::Tensor& w1t, const at::Tensor& b1,
                         at::Tensor& h) {
  AT_DISPATCH_FLOATING_TYPES(h.scalar_type(), "chunked_mlp_bias", [&] {
    const scalar_t* b = b1.data_ptr<scalar_t>();
    const int64_t H = h.size(1), ld = h.stride(0);
    scalar_t* out = h.data_ptr<scalar_t>();
    for (int64_t r = 0; r < h.size(0); ++r) std::copy(b, b + H, out + r * ld);
    gemm(x, w1t, h, true);
    for (int64_t r = 0; r < h.size(0); ++r)
      for (int64_t j = 0; j < H; ++j) out[r * ld + j] = std::max(out[r * ld + j], scalar_t(0));
  });
}

// f(chunk, first row, row count) for every chunk, in parallel, each GEMM on the calling thread.
template <typename F>
void for_each_chunk(int64_t rows, const F& f) {
  SingleThreadedBlas one_thread_per_gemm;
  at::parallel_for(0, chunk_count(rows), 1, [&](int64_t b, int64_t e) {
    for (int64_t c = b; c < e; ++c) {
      const int64_t first = c * kChunkRows;
      f(c, first, std::min(kChunkRows, rows - first));
    }
  });
}

// Forward into h (after the ReLU) and y; every input is detached (no autograd in the workers).
void forward_into(const at::Tensor& x, const at::Tensor& w1, const at::Tensor& b1,
                  const at::Tensor& w2, const at::Tensor& b2, at::Tensor& h, at::Tensor& y) {
  const at::Tensor w1t = w1.t(), w2t = w2.t(), b1c = b1.contiguous(), b2c = b2.contiguous();
  for_each_chunk(x.size(0), [&](int64_t, int64_t first, int64_t n) {
    at::Tensor hc = h.narrow(0, first, n);
    first_layer_forward(x.narrow(0, first, n), w1t, b1c, hc);
    at::Tensor yc = y.narrow(0, first, n);
    at::addmm_out(yc, b2c, hc, w2t);
  });
}

// Sums parts[0] + parts[1] + ... in that order (independent of the thread count).
at::Tensor sum_in_order(const at::Tensor& parts) {
  at::Tensor total = parts[0].clone();
  for (int64_t c = 1; c < parts.size(0); ++c) total.add_(parts[c]);
  return total;
}

// A chunk's backward through ReLU and the first layer, from dh (the gradient of the ReLU's
// output h, overwritten): its partial dw1 and db1, and its rows of dx where dx is defined.
void first_layer_backward(at::Tensor& dh, const at::Tensor& h, const at::Tensor& x,
                          const at::Tensor& w1, at::Tensor dw1, at::Tensor db1, at::Tensor dx) {
  // h > 0 exactly where the ReLU passed its input.
  TORCH_CHECK(dh.is_contiguous() && h.is_contiguous() && db1.is_contiguous(),
              "chunked_mlp: a chunk's buffers must be contiguous");
  AT_DISPATCH_FLOATING_TYPES(dh.scalar_type(), "relu_backward", [&] {
    sparse_head::relu_backward(h.data_ptr<scalar_t>(), dh.size(0), dh.size(1),
                               dh.data_ptr<scalar_t>(), db1.data_ptr<scalar_t>());
  });
  gemm(dh.t(), x, dw1, false);
  if (dx.defined()) gemm(dh, w1, dx, false);
}

struct ChunkedMlp : public torch::autograd::Function<ChunkedMlp> {
  static at::Tensor forward(AutogradContext* ctx, const at::Tensor& x, const at::Tensor& w1,
                            const at::Tensor& b1, const at::Tensor& w2, const at::Tensor& b2) {
    const at::Tensor xd = x.detach().contiguous();
    at::Tensor h = at::empty({xd.size(0), w1.size(0)}, xd.options());
    at::Tensor y = at::empty({xd.size(0), w2.size(0)}, xd.options());
    forward_into(xd, w1.detach(), b1.detach(), w2.detach(), b2.detach(), h, y);
    ctx->save_for_backward({xd, w1, w2, h});
    ctx->saved_data["x_grad"] = x.requires_grad();
    return y;
  }

  static variable_list backward(AutogradContext* ctx, variable_list grads) {
    const auto saved = ctx->get_saved_variables();
    const at::Tensor x = saved[0], w1 = saved[1].detach(), w2 = saved[2].detach(), h = saved[3];
    const at::Tensor dy = grads[0].contiguous();
    const int64_t rows = x.size(0), chunks = chunk_count(rows);
    const int64_t C = x.size(1), H = w1.size(0), O = w2.size(0);
    const auto opt = dy.options();
    if (chunks == 0)
      return {ctx->saved_data["x_grad"].toBool() ? at::zeros({0, C}, opt) : at::Tensor(),
              at::zeros({H, C}, opt), at::zeros({H}, opt), at::zeros({O, H}, opt),
              at::zeros({O}, opt)};
    at::Tensor dw2 = at::empty({chunks, O, H}, opt), db2 = at::empty({chunks, O}, opt);
    at::Tensor dw1 = at::empty({chunks, H, C}, opt), db1 = at::empty({chunks, H}, opt);
    at::Tensor dx = ctx->saved_data["x_grad"].toBool() ? at::empty({rows, C}, opt) : at::Tensor();
    for_each_chunk(rows, [&](int64_t c, int64_t first, int64_t n) {
      const at::Tensor dyc = dy.narrow(0, first, n), hc = h.narrow(0, first, n);
      const at::Tensor xc = x.narrow(0, first, n);
      at::Tensor part = dw2[c];
      gemm(dyc.t(), hc, part, false);
      part = db2[c];
      at::sum_out(part, dyc, 0);
      at::Tensor dh = at::empty({n, H}, opt);
      gemm(dyc, w2, dh, false);
      first_layer_backward(dh, hc, xc, w1, dw1[c], db1[c],
                           dx.defined() ? dx.narrow(0, first, n) : at::Tensor());
    });
    return {dx, sum_in_order(dw1), sum_in_order(db1), sum_in_order(dw2), sum_in_order(db2)};
  }
};

// Gaussians [g_first[c], g_first[c + 1]) belong to chunk c's rows (row is non-decreasing).
std::vector<int64_t> gaussians_by_chunk(const at::Tensor& row, int64_t rows) {
  const int64_t* r = row.data_ptr<int64_t>();
  const int64_t n = row.numel(), chunks = chunk_count(rows);
  std::vector<int64_t> first(size_t(chunks) + 1);
  for (int64_t c = 0; c <= chunks; ++c)
    first[size_t(c)] = std::lower_bound(r, r + n, std::min(rows, c * kChunkRows)) - r;
  return first;
}

// w2 [K*O, H] -> [K, H, kLanes]: slot s's outputs for hidden unit k in one zero-padded vector.
at::Tensor slot_lanes(const at::Tensor& w2, int64_t O) {
  const int64_t H = w2.size(1), K = w2.size(0) / O;
  return at::constant_pad_nd(w2.view({K, O, H}).permute({0, 2, 1}), {0, sparse_head::kLanes - O})
      .contiguous();
}

// The forward of sparse_mlp on detached tensors; returns h (after the ReLU) and y.
std::pair<at::Tensor, at::Tensor> sparse_forward(const at::Tensor& x, const at::Tensor& w1,
                                                 const at::Tensor& b1, const at::Tensor& w2,
                                                 const at::Tensor& b2, const at::Tensor& row,
                                                 const at::Tensor& slot, int64_t O) {
  const at::Tensor lanes = slot_lanes(w2, O), b2c = b2.contiguous();
  const int64_t rows = x.size(0), H = w1.size(0);
  at::Tensor h = at::empty({rows, H}, x.options());
  at::Tensor y = at::empty({row.numel(), O}, x.options());
  const std::vector<int64_t> g_first = gaussians_by_chunk(row, rows);
  const sparse_head::Layer layer{h.data_ptr<float>(),
                                 H,
                                 int(O),
                                 w2.data_ptr<float>(),
                                 lanes.data_ptr<float>(),
                                 b2c.data_ptr<float>(),
                                 row.data_ptr<int64_t>(),
                                 slot.data_ptr<int64_t>()};
  const at::Tensor w1t = w1.t(), b1c = b1.contiguous();
  for_each_chunk(rows, [&](int64_t c, int64_t first, int64_t n) {
    at::Tensor hc = h.narrow(0, first, n);
    first_layer_forward(x.narrow(0, first, n), w1t, b1c, hc);
    sparse_head::forward(layer, g_first[size_t(c)], g_first[size_t(c) + 1], y.data_ptr<float>());
  });
  return {h, y};
}

struct SparseMlp : public torch::autograd::Function<SparseMlp> {
  static at::Tensor forward(AutogradContext* ctx, const at::Tensor& x, const at::Tensor& w1,
                            const at::Tensor& b1, const at::Tensor& w2, const at::Tensor& b2,
                            const at::Tensor& row, const at::Tensor& slot, int64_t O) {
    const at::Tensor xd = x.detach().contiguous();
    auto [h, y] = sparse_forward(xd, w1.detach(), b1.detach(), w2.detach().contiguous(),
                                 b2.detach(), row, slot, O);
    ctx->save_for_backward({xd, w1, w2, h, row, slot});
    ctx->saved_data["x_grad"] = x.requires_grad();
    ctx->saved_data["outputs"] = O;
    return y;
  }

  static variable_list backward(AutogradContext* ctx, variable_list grads) {
    const auto saved = ctx->get_saved_variables();
    const at::Tensor x = saved[0], w1 = saved[1].detach(), h = saved[3];
    const at::Tensor w2 = saved[2].detach().contiguous(), row = saved[4], slot = saved[5];
    const int64_t O = ctx->saved_data["outputs"].toInt();
    const at::Tensor dy = grads[0].contiguous();
    const int64_t rows = x.size(0), chunks = chunk_count(rows);
    const int64_t C = x.size(1), H = w1.size(0), KO = w2.size(0);
    const auto opt = dy.options();
    const bool x_grad = ctx->saved_data["x_grad"].toBool();
    at::Tensor dw2 = at::zeros({std::max<int64_t>(chunks, 1), KO, H}, opt);
    at::Tensor db2 = at::zeros({std::max<int64_t>(chunks, 1), KO}, opt);
    at::Tensor dw1 = at::zeros({std::max<int64_t>(chunks, 1), H, C}, opt);
    at::Tensor db1 = at::zeros({std::max<int64_t>(chunks, 1), H}, opt);
    at::Tensor dx = x_grad ? at::empty({rows, C}, opt) : at::Tensor();
    const std::vector<int64_t> g_first = gaussians_by_chunk(row, rows);
    const sparse_head::Layer layer{h.data_ptr<float>(),
                                   H,
                                   int(O),
                                   w2.data_ptr<float>(),
                                   nullptr,
                                   nullptr,
                                   row.data_ptr<int64_t>(),
                                   slot.data_ptr<int64_t>()};
    for_each_chunk(rows, [&](int64_t c, int64_t first, int64_t n) {
      at::Tensor dh = at::zeros({n, H}, opt);
      sparse_head::backward(layer, g_first[size_t(c)], g_first[size_t(c) + 1], dy.data_ptr<float>(),
                            first, dh.data_ptr<float>(), dw2[c].data_ptr<float>(),
                            db2[c].data_ptr<float>());
      const at::Tensor hc = h.narrow(0, first, n), xc = x.narrow(0, first, n);
      first_layer_backward(dh, hc, xc, w1, dw1[c], db1[c],
                           x_grad ? dx.narrow(0, first, n) : at::Tensor());
    });
    return {
        dx,           sum_in_order(dw1), sum_in_order(db1), sum_in_order(dw2), sum_in_order(db2),
        at::Tensor(), at::Tensor(),      at::Tensor()};
  }
};

}  // namespace

torch::Tensor chunked_mlp_reference(const torch::Tensor& x, const torch::Tensor& w1,
                                    const torch::Tensor& b1, const torch::Tensor& w2,
                                    const torch::Tensor& b2) {
  return torch::addmm(b2, torch::relu(torch::addmm(b1, x, w1.t())), w2.t());
}

torch::Tensor sparse_mlp_reference(const torch::Tensor& x, const torch::Tensor& w1,
                                   const torch::Tensor& b1, const torch::Tensor& w2,
                                   const torch::Tensor& b2, const torch::Tensor& row,
                                   const torch::Tensor& slot, int64_t outputs_per_slot) {
  // Every slot's outputs, then each Gaussian's: K times the output layer's work, which a GPU
  // does in one GEMM sooner than it gathers per-Gaussian weights.
  const int64_t K = w2.size(0) / outputs_per_slot;
  const auto y = chunked_mlp_reference(x, w1, b1, w2, b2);  // [rows, K*O]
  return y.reshape({-1, outputs_per_slot}).index_select(0, row * K + slot);
}

torch::Tensor sparse_mlp(const torch::Tensor& x, const torch::Tensor& w1, const torch::Tensor& b1,
                         const torch::Tensor& w2, const torch::Tensor& b2, const torch::Tensor& row,
                         const torch::Tensor& slot, int64_t outputs_per_slot) {
  const int64_t O = outputs_per_slot;
  if (!x.device().is_cpu()) return sparse_mlp_reference(x, w1, b1, w2, b2, row, slot, O);
  for (const auto* t : {&x, &w1, &b1, &w2, &b2, &row, &slot})
    TORCH_CHECK(t->device().is_cpu(), "sparse_mlp: tensors on more than one device");
  TORCH_CHECK(x.scalar_type() == at::kFloat && w1.scalar_type() == at::kFloat &&
                  w2.scalar_type() == at::kFloat && b1.scalar_type() == at::kFloat &&
                  b2.scalar_type() == at::kFloat,
              "sparse_mlp: float tensors only");
  TORCH_CHECK(x.dim() == 2 && w1.dim() == 2 && w2.dim() == 2 && x.size(1) == w1.size(1) &&
                  w2.size(1) == w1.size(0) && b1.numel() == w1.size(0) &&
                  b2.numel() == w2.size(0) && O >= 1 && O <= sparse_head::kLanes &&
                  w2.size(0) % O == 0,
              "sparse_mlp: shapes do not chain (x ", x.sizes(), ", w1 ", w1.sizes(), ", w2 ",
              w2.sizes(), ", ", O, " outputs per slot)");
  TORCH_CHECK(row.dim() == 1 && slot.dim() == 1 && row.numel() == slot.numel() &&
                  row.scalar_type() == at::kLong && slot.scalar_type() == at::kLong &&
                  row.is_contiguous() && slot.is_contiguous(),
              "sparse_mlp: row and slot must be contiguous 1-D long tensors of one length");
  const int64_t n = row.numel();
  if (n > 0) {
    TORCH_CHECK(row.min().item<int64_t>() >= 0 && row.max().item<int64_t>() < x.size(0) &&
                    slot.min().item<int64_t>() >= 0 && slot.max().item<int64_t>() < w2.size(0) / O,
                "sparse_mlp: a row or slot is out of range");
    TORCH_CHECK(n < 2 || row.narrow(0, 1, n - 1).ge(row.narrow(0, 0, n - 1)).all().item<bool>(),
                "sparse_mlp: the rows decrease");
  }
  if (torch::GradMode::is_enabled() &&
      (x.requires_grad() || w1.requires_grad() || b1.requires_grad() || w2.requires_grad() ||
       b2.requires_grad()))
    return SparseMlp::apply(x, w1, b1, w2, b2, row, slot, O);
  // Detached: grad mode is per thread, and the pool's threads have it on.
  return sparse_forward(x.detach().contiguous(), w1.detach(), b1.detach(), w2.detach().contiguous(),
                        b2.detach(), row, slot, O)
      .second;
}

torch::Tensor chunked_mlp(const torch::Tensor& x, const torch::Tensor& w1, const torch::Tensor& b1,
                          const torch::Tensor& w2, const torch::Tensor& b2) {
  TORCH_CHECK(x.dim() == 2 && w1.dim() == 2 && w2.dim() == 2 && x.size(1) == w1.size(1) &&
                  w2.size(1) == w1.size(0) && b1.numel() == w1.size(0) && b2.numel() == w2.size(0),
              "chunked_mlp: shapes do not chain (x ", x.sizes(), ", w1 ", w1.sizes(), ", w2 ",
              w2.sizes(), ")");
  if (!x.device().is_cpu()) return chunked_mlp_reference(x, w1, b1, w2, b2);
  const bool grad = torch::GradMode::is_enabled() &&
                    (x.requires_grad() || w1.requires_grad() || b1.requires_grad() ||
                     w2.requires_grad() || b2.requires_grad());
  if (grad) return ChunkedMlp::apply(x, w1, b1, w2, b2);
  // Detached: grad mode is per thread, and the pool's threads have it on.
  const at::Tensor xd = x.detach().contiguous();
  at::Tensor h = at::empty({xd.size(0), w1.size(0)}, xd.options());
  at::Tensor y = at::empty({xd.size(0), w2.size(0)}, xd.options());
  forward_into(xd, w1.detach(), b1.detach(), w2.detach(), b2.detach(), h, y);
  return y;
}

}  // namespace crpgs
