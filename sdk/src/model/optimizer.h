/// @file optimizer.h
/// @brief What the anchor model's optimiser and export's refinement share: one Adam update, the
/// log-linear learning-rate schedule, and 3DGS's spatial scale for the position rates.
#pragma once

#include <torch/types.h>

#include <Eigen/Core>
#include <cstdint>
#include <vector>

namespace crpgs {

/// One Adam update of `param` (torch.optim.Adam: betas 0.9/0.999, eps 1e-15, no weight decay),
/// fused into one parallel pass when every tensor is contiguous float32. `step` is the 1-based
/// count of updates this parameter has had, this one included.
void adam_update(torch::Tensor& param, const torch::Tensor& grad, torch::Tensor& m,
                 torch::Tensor& v, double lr, int64_t step);

/// a at it = 0 to b at it = max_steps, linear in log space, clamped outside; a when either is
/// not positive (no decay to or from 0).
double log_lerp(double a, double b, int it, int max_steps);

/// 3DGS's cameras_extent (getNerfppNorm): 1.1 x the largest distance of a camera centre from
/// their mean; 1 when the cameras do not span a distance (one camera).
double cameras_extent(const std::vector<Eigen::Vector3d>& centers);

}  // namespace crpgs
