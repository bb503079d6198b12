/// @file adam.h
/// @brief One Adam update of a parameter tensor (torch.optim.Adam: betas 0.9/0.999, eps 1e-15,
/// no weight decay), fused into one parallel pass when every tensor is contiguous float32.
#pragma once

#include <torch/types.h>

#include <cstdint>

namespace crpgs {

/// `step` is the 1-based count of updates this parameter has had, this one included.
void adam_update(torch::Tensor& param, const torch::Tensor& grad, torch::Tensor& m,
                 torch::Tensor& v, double lr, int64_t step);

}  // namespace crpgs
