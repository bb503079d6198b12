/// @file adam_kernel.cpp
/// @brief adam_kernel. Built with -fno-math-errno (see sources.cmake): sqrtf may then be a
/// vector instruction, and the loop vectorises.
#include "model/adam_kernel.h"

#include <cmath>

namespace crpgs {

void adam_kernel(float* __restrict param, float* __restrict m, float* __restrict v,
                 const float* __restrict grad, int64_t begin, int64_t end, const AdamScalars& s) {
  const float b1 = s.beta1, b2 = s.beta2, c1 = s.one_minus_beta1, c2 = s.one_minus_beta2;
  const float inv = s.inv_sqrt_bias_correction2, eps = s.eps, step = s.step_size;
  for (int64_t i = begin; i < end; ++i) {
    const float g = grad[i];
    const float mi = b1 * m[i] + c1 * g;
    const float vi = b2 * v[i] + c2 * g * g;
    m[i] = mi;
    v[i] = vi;
    param[i] -= step * mi / (std::sqrt(vi) * inv + eps);
  }
}

}  // namespace crpgs
