/// @file feature_model.h
/// @brief The feature-model family: what feature the Gaussian-generation MLPs see per anchor.
/// `identity` (built-in): the coded feature itself. `sfa`: a shared hash-grid feature f_s
/// concatenated with the coded individual feature f_i.
#pragma once

#include <torch/types.h>

#include "crpgs/component.h"

namespace crpgs {

class FeatureModel : public Component {
 public:
  /// Width of the per-anchor feature that is stored and entropy coded (D_i).
  virtual int64_t coded_dim() const = 0;
  /// Width of the feature the MLPs see (D_0).
  virtual int64_t feature_dim() const = 0;
  /// coded: [N, coded_dim()]; positions01: [N, 3] anchor positions normalised to [0,1] by the
  /// scene bounds. Returns [N, feature_dim()].
  virtual torch::Tensor forward(const torch::Tensor& coded, const torch::Tensor& positions01) = 0;
};

}  // namespace crpgs
