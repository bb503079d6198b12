/// @file chunked_mlp.cpp
/// @brief chunked_mlp: forward and backward of the two-layer MLPs, chunk by chunk.
#include "model/chunked_mlp.h"

#include <torch/torch.h>

#include <ATen/Parallel.h>

#include "crpgs/runtime.h"

namespace crpgs {
namespace {

using torch::autograd::AutogradContext;
using torch::autograd::variable_list;

// Rows per chunk: a chunk's input, hidden layer and output stay in a core's L2 cache.
constexpr int64_t kChunkRows = 1024;

int64_t chunk_count(int64_t rows) {
  return (rows + kChunkRows - 1) / kChunkRows;
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
  const at::Tensor w1t = w1.t(), w2t = w2.t();
  for_each_chunk(x.size(0), [&](int64_t, int64_t first, int64_t n) {
    at::Tensor hc = h.narrow(0, first, n);
    at::addmm_out(hc, b1, x.narrow(0, first, n), w1t);
    hc.clamp_min_(0);
    at::Tensor yc = y.narrow(0, first, n);
    at::addmm_out(yc, b2, hc, w2t);
  });
}

// Sums parts[0] + parts[1] + ... in that order (independent of the thread count).
at::Tensor sum_in_order(const at::Tensor& parts) {
  at::Tensor total = parts[0].clone();
  for (int64_t c = 1; c < parts.size(0); ++c) total.add_(parts[c]);
  return total;
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
      at::mm_out(part, dyc.t(), hc);
      part = db2[c];
      at::sum_out(part, dyc, 0);
      at::Tensor dh = at::mm(dyc, w2);
      dh.masked_fill_(hc.le(0), 0);  // ReLU: h is its output, > 0 exactly where it passed
      part = dw1[c];
      at::mm_out(part, dh.t(), xc);
      part = db1[c];
      at::sum_out(part, dh, 0);
      if (dx.defined()) {
        part = dx.narrow(0, first, n);
        at::mm_out(part, dh, w1);
      }
    });
    return {dx, sum_in_order(dw1), sum_in_order(db1), sum_in_order(dw2), sum_in_order(db2)};
  }
};

}  // namespace

torch::Tensor chunked_mlp(const torch::Tensor& x, const torch::Tensor& w1, const torch::Tensor& b1,
                          const torch::Tensor& w2, const torch::Tensor& b2) {
  TORCH_CHECK(x.dim() == 2 && w1.dim() == 2 && w2.dim() == 2 && x.size(1) == w1.size(1) &&
                  w2.size(1) == w1.size(0) && b1.numel() == w1.size(0) && b2.numel() == w2.size(0),
              "chunked_mlp: shapes do not chain (x ", x.sizes(), ", w1 ", w1.sizes(), ", w2 ",
              w2.sizes(), ")");
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
