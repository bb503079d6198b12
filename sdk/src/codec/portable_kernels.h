/// @file portable_kernels.h
/// @brief Raw-pointer kernels behind crpgs/portable_math.h (kept out of the torch TUs).
#pragma once

#include <cstdint>

namespace crpgs::portable {

/// Rows [first, last) of y [N, O] = x [N, I] wt [I, O] + b [O], summed as portable_linear says.
void linear_rows(const float* x, const float* wt, const float* b, int64_t first, int64_t last,
                 int64_t in, int64_t out, float* y);

/// y[i] = tanh(x[i]) for i in [first, last).
void tanh_range(const float* x, int64_t first, int64_t last, float* y);

/// y[i] = 1 + tanh(x[i]) = 2 / (1 + exp(−2 x[i])) for i in [first, last).
void one_plus_tanh_range(const float* x, int64_t first, int64_t last, float* y);

}  // namespace crpgs::portable
