/// @file entropy_params.h
/// @brief HAC's per-anchor entropy parameters (method.md §2.2): the grid context's output split
/// into means, scales and adaptive quantisation steps for features, scaling and offsets. One
/// function shared by training (rate term, quantised evaluation) and the codec, so the steps the
/// model is evaluated with are exactly the ones in the bitstream.
#pragma once

#include <torch/types.h>

#include "crpgs/context_model.h"
#include "crpgs/entropy_model.h"

namespace crpgs {

/// Initial quantisation steps Q0 (method.md §2.2).
struct QuantSteps {
  double feature = 1.0, scaling = 0.001, offset = 0.2;
};

struct EntropyParams {
  torch::Tensor mu_f, sigma_f;  ///< [N, Dc]
  torch::Tensor mu_s, sigma_s;  ///< [N, 6]
  torch::Tensor mu_o, sigma_o;  ///< [N, K*3]
  torch::Tensor q_f, q_s, q_o;  ///< [N, 1] adaptive steps Q0·(1 + tanh a), in (0, 2·Q0)
};

/// Splits a context output row ([N, layout.width()]) into EntropyParams. σ outputs are returned
/// raw (the entropy model clamps them).
EntropyParams split_entropy_params(const torch::Tensor& context_out,
                                   const EntropyParamLayout& layout, const QuantSteps& q0);

/// Evaluates `context` on positions01 in fixed chunks of `chunk` rows, in order, and splits.
/// The codec calls it with the same chunking on both sides, so GEMM shapes (and therefore
/// rounding) are identical in the encoder and the decoder.
EntropyParams predict_entropy_params(ContextModel& context, const torch::Tensor& positions01,
                                     const EntropyParamLayout& layout, const QuantSteps& q0,
                                     int64_t chunk = 3000);

}  // namespace crpgs
