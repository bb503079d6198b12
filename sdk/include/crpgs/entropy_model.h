/// @file entropy_model.h
/// @brief The entropy-model family (`gaussian`: HAC's conditional Gaussian): the training-time
/// rate of quantised values given predicted parameters.
#pragma once

#include <torch/types.h>

#include "crpgs/component.h"

namespace crpgs {

class EntropyModel : public Component {
 public:
  /// Bits of each element of x (already quantised or noised) with step q under the model's
  /// distribution with parameters (mean, scale). All tensors broadcast to x's shape.
  virtual torch::Tensor bits(const torch::Tensor& x, const torch::Tensor& mean,
                             const torch::Tensor& scale, const torch::Tensor& q) = 0;
};

}  // namespace crpgs
