/// @file adam_kernel.h
/// @brief The element loop of one Adam update, in a TU of its own compiled to vectorise.
#pragma once

#include <cstdint>

namespace crpgs {

struct AdamScalars {
  float beta1, beta2;
  float one_minus_beta1, one_minus_beta2;  ///< from double: 1 - 0.999f is 5e-5 off 0.001
  float inv_sqrt_bias_correction2;         ///< 1 / sqrt(1 - beta2^t)
  float eps;
  float step_size;  ///< lr / (1 - beta1^t)
};

/// m = b1 m + (1 - b1) g; v = b2 v + (1 - b2) g^2; p -= step_size m / (sqrt(v) / sqrt(bc2) + eps)
/// for the elements [begin, end).
void adam_kernel(float* param, float* m, float* v, const float* grad, int64_t begin, int64_t end,
                 const AdamScalars& s);

}  // namespace crpgs
