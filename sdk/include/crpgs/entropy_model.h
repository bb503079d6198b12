/// @file entropy_model.h
/// @brief The entropy-model family (`gaussian`: HAC's conditional Gaussian): the training-time
/// rate of quantised values given predicted parameters.
#pragma once

#include <string>
#include <vector>

#include <torch/types.h>

#include "crpgs/component.h"

namespace crpgs {

/// How a grid context's output row splits (HAC mlp_grid): mu_f, sigma_f [Dc each], mu_s,
/// sigma_s [6 each], mu_o, sigma_o [3K each], then a_f, a_s, a_o (step refinements).
struct EntropyParamLayout {
  int64_t coded_dim = 50, n_offsets = 10;
  /// The last columns: the step adjustments a_f, a_s, a_o (Q = Q0·(1 + tanh a)).
  static constexpr int64_t kStepColumns = 3;
  int64_t width() const { return 2 * (coded_dim + 6 + 3 * n_offsets) + kStepColumns; }
};

class EntropyModel : public Component {
 public:
  /// Bits of each element of x (already quantised or noised) with step q under the model's
  /// distribution with parameters (mean, scale). All tensors broadcast to x's shape.
  virtual torch::Tensor bits(const torch::Tensor& x, const torch::Tensor& mean,
                             const torch::Tensor& scale, const torch::Tensor& q) = 0;

  /// Coding path. symbols: int32 [M] (k = round(x/q)); mean, scale, q: float32 [M] (the same
  /// tensors the decoder will recompute). Tables are built from (mean/q, scale/q) quantised onto
  /// a fixed grid so encoder and decoder derive identical integer CDFs on any machine; symbols
  /// outside a table's range are escape-coded. Both run single-threaded per call, in order.
  /// Models that only support training (rate estimates) keep the defaults, which refuse.
  virtual bool supports_coding() const { return false; }
  virtual std::vector<uint8_t> compress(const torch::Tensor& symbols, const torch::Tensor& mean,
                                        const torch::Tensor& scale, const torch::Tensor& q) {
    return {};
  }
  /// Inverse of compress(); refuses corrupt input with a message in *error (returns undefined).
  virtual torch::Tensor decompress(const std::vector<uint8_t>& bytes, const torch::Tensor& mean,
                                   const torch::Tensor& scale, const torch::Tensor& q,
                                   std::string* error) {
    if (error) *error = type_name() + ": this entropy model cannot code bitstreams";
    return {};
  }
};

}  // namespace crpgs
