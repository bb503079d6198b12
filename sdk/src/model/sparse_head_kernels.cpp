/// @file sparse_head_kernels.cpp
/// @brief The per-Gaussian output layer, compiled for x86-64-v4, x86-64-v3 and baseline x86-64
/// (target_clones): a Gaussian's O outputs are one 8-lane vector accumulated over the hidden
/// units; the backward's loops over the hidden units (and the ReLU's) vectorise as they are.
#include "model/sparse_head_kernels.h"

#include "crpgs/target_clones.h"

namespace crpgs::sparse_head {
namespace {
typedef float vf __attribute__((vector_size(kLanes * sizeof(float))));

template <typename T>
inline __attribute__((always_inline)) void relu_backward_impl(const T* h, int64_t n, int64_t H,
                                                              T* dh, T* db1) {
  for (int64_t k = 0; k < H; ++k) db1[k] = T(0);
  for (int64_t r = 0; r < n; ++r) {
    const T* hr = h + r * H;
    T* d = dh + r * H;
    for (int64_t k = 0; k < H; ++k) {
      const T v = hr[k] > T(0) ? d[k] : T(0);
      d[k] = v;
      db1[k] += v;
    }
  }
}
}  // namespace

CRPGS_TARGET_CLONES
void forward(const Layer& l, int64_t g_begin, int64_t g_end, float* y) {
  const int64_t H = l.H;
  const int O = l.O;
  for (int64_t g = g_begin; g < g_end; ++g) {
    const int64_t s = l.slot[g];
    const float* h = l.h + l.row[g] * H;
    const float* w = l.w2_lanes + s * H * kLanes;
    // Four partial sums over the hidden units, so that four multiply-adds are in flight (one
    // chain of H dependent adds was the kernel's limit), summed in a fixed order.
    vf part[4] = {};
    auto add = [&](int64_t k, vf& a) {
      vf wk;
      __builtin_memcpy(&wk, w + k * kLanes, sizeof(vf));
      a += h[k] * wk;
    };
    int64_t k = 0;
    for (; k + 4 <= H; k += 4)
      for (int j = 0; j < 4; ++j) add(k + j, part[j]);
    for (; k < H; ++k) add(k, part[0]);
    const vf acc = (part[0] + part[1]) + (part[2] + part[3]);
    float* out = y + g * O;
    for (int o = 0; o < O; ++o) out[o] = acc[o] + l.b2[s * O + o];
  }
}

CRPGS_TARGET_CLONES
void backward(const Layer& l, int64_t g_begin, int64_t g_end, const float* dy, int64_t first_row,
              float* dh, float* dw2, float* db2) {
  const int64_t H = l.H;
  const int O = l.O;
  auto load = [](const float* p) {
    vf v;
    __builtin_memcpy(&v, p, sizeof(vf));
    return v;
  };
  auto store = [](float* p, vf v) { __builtin_memcpy(p, &v, sizeof(vf)); };
  for (int64_t g = g_begin; g < g_end; ++g) {
    const int64_t s = l.slot[g];
    const float* h = l.h + l.row[g] * H;
    float* dhr = dh + (l.row[g] - first_row) * H;
    const float* d = dy + g * O;
    const float* w = l.w2 + s * O * H;  // rows s*O + o, o < O
    float* dw = dw2 + s * O * H;
    // A block of hidden units at a time: dhr's block takes the O outputs in a register (the
    // same additions in the same order as one output at a time) and h's block is loaded once.
    int64_t k = 0;
    for (; k + kLanes <= H; k += kLanes) {
      vf acc = load(dhr + k);
      const vf hv = load(h + k);
      for (int o = 0; o < O; ++o) {
        acc += d[o] * load(w + o * H + k);
        store(dw + o * H + k, load(dw + o * H + k) + d[o] * hv);
      }
      store(dhr + k, acc);
    }
    for (; k < H; ++k) {
      for (int o = 0; o < O; ++o) {
        dhr[k] += d[o] * w[o * H + k];
        dw[o * H + k] += d[o] * h[k];
      }
    }
    for (int o = 0; o < O; ++o) db2[s * O + o] += d[o];
  }
}

CRPGS_TARGET_CLONES
void relu_backward(const float* h, int64_t n, int64_t H, float* dh, float* db1) {
  relu_backward_impl(h, n, H, dh, db1);
}

CRPGS_TARGET_CLONES
void relu_backward(const double* h, int64_t n, int64_t H, double* dh, double* db1) {
  relu_backward_impl(h, n, H, dh, db1);
}

}  // namespace crpgs::sparse_head
