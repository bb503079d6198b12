/// @file chunked_mlp.h
/// @brief Two-layer MLPs (Linear, ReLU, Linear) over row chunks in parallel: the neural-Gaussian
/// MLPs, and any plugin MLP run on every anchor (hash_grid's mlp_grid).
#pragma once

#include <torch/types.h>

namespace crpgs {

/// relu(x w1^T + b1) w2^T + b2 for x [N, C], w1 [H, C], w2 [O, H], with gradients for all five.
/// Rows go in fixed chunks, each chunk's GEMMs on one thread, chunks in parallel: the weight
/// gradients (a reduction over N into a small matrix) otherwise ran on one core, as BLAS splits
/// a GEMM only over its output. The weight gradients sum the chunks' partial sums in chunk
/// order, so results do not depend on the thread count. Tensors on another device take
/// chunked_mlp_reference.
torch::Tensor chunked_mlp(const torch::Tensor& x, const torch::Tensor& w1, const torch::Tensor& b1,
                          const torch::Tensor& w2, const torch::Tensor& b2);

/// The same MLP where only some of each row's outputs are wanted: w2 [K*O, H] holds K slots of
/// O outputs, and Gaussian g wants slot slot[g] of row row[g] (row non-decreasing). Returns
/// [G, O] = mlp(x)[row[g], slot[g]*O : slot[g]*O + O], computing only those outputs: colour and
/// covariance keep ~a quarter of the slots of the anchors they are computed for. Float tensors;
/// O <= 8. Tensors on another device take sparse_mlp_reference.
torch::Tensor sparse_mlp(const torch::Tensor& x, const torch::Tensor& w1, const torch::Tensor& b1,
                         const torch::Tensor& w2, const torch::Tensor& b2, const torch::Tensor& row,
                         const torch::Tensor& slot, int64_t outputs_per_slot);

/// The same two functions from libtorch operations (autograd), on any device.
torch::Tensor chunked_mlp_reference(const torch::Tensor& x, const torch::Tensor& w1,
                                    const torch::Tensor& b1, const torch::Tensor& w2,
                                    const torch::Tensor& b2);
torch::Tensor sparse_mlp_reference(const torch::Tensor& x, const torch::Tensor& w1,
                                   const torch::Tensor& b1, const torch::Tensor& w2,
                                   const torch::Tensor& b2, const torch::Tensor& row,
                                   const torch::Tensor& slot, int64_t outputs_per_slot);

}  // namespace crpgs
