/// @file sparse_head_kernels.h
/// @brief Per-Gaussian output layer of the colour and covariance MLPs (see sparse_mlp) and the
/// hidden ReLU's backward of every chunked MLP, on raw float arrays; no libtorch header.
#pragma once

#include <cstdint>

namespace crpgs::sparse_head {

/// Output lanes per Gaussian in the forward (O <= kLanes).
constexpr int kLanes = 8;

/// What one chunk of anchors sees. h: [rows, H] after the ReLU (row r = anchor r of the call);
/// row[g], slot[g]: the Gaussians' anchors (non-decreasing) and slots, for g in [g_begin, g_end).
struct Layer {
  const float* h = nullptr;
  int64_t H = 0;
  int O = 0;                        ///< outputs per Gaussian
  const float* w2 = nullptr;        ///< [K*O, H], row s*O + o
  const float* w2_lanes = nullptr;  ///< [K, H, kLanes]: w2 by slot, transposed, zero-padded
  const float* b2 = nullptr;        ///< [K*O]
  const int64_t* row = nullptr;
  const int64_t* slot = nullptr;
};

/// y[g, o] = b2[s*O + o] + sum_k h[row[g], k] w2[s*O + o, k] with s = slot[g]; y is [G, O].
void forward(const Layer& l, int64_t g_begin, int64_t g_end, float* y);

/// For dy [G, O]: dh[row[g] - first_row, :] += sum_o dy[g, o] w2[s*O + o, :] (dh: [., H],
/// zeroed by the caller) and the chunk's partial weight and bias gradients, dw2 += dy[g, o]
/// h[row[g], :] and db2 += dy[g, o] (both zeroed by the caller), Gaussians in order.
void backward(const Layer& l, int64_t g_begin, int64_t g_end, const float* dy, int64_t first_row,
              float* dh, float* dw2, float* db2);

/// The hidden ReLU's backward for rows [0, n) of [n, H] arrays, in place: dh[r, k] = 0 where
/// h[r, k] <= 0 (h is the ReLU's output), and db1[k] = sum_r dh[r, k] (overwritten), rows in
/// order. One pass where the ATen ops (le, masked_fill_, sum) took three.
void relu_backward(const float* h, int64_t n, int64_t H, float* dh, float* db1);
void relu_backward(const double* h, int64_t n, int64_t H, double* dh, double* db1);

}  // namespace crpgs::sparse_head
