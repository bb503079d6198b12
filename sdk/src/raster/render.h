/// @file render.h
/// @brief The rasterizer components' common path: one libtorch autograd function over
/// project -> intersect_tiles -> rasterize_to_pixels whose backward runs the stages' backward
/// passes in reverse, on the stages of the device the Gaussians live on (CPU or CUDA).
#pragma once

#include "crpgs/rasterizer.h"

namespace crpgs::raster {

/// Checks the batch (float32, shapes, every tensor on `device`) and renders it; `threads` is
/// the CPU stages' worker count (ignored on CUDA).
RenderOutput render(const GaussianBatch& gaussians, const Camera& camera,
                    const RenderSettings& settings, torch::Device device, int threads);

/// render() on `device` for Gaussians that may live elsewhere: moves them there (differentiably)
/// and the outputs back to where the means are, so that a model kept on the CPU can use the
/// CUDA rasterizer (the `cuda` component does this).
RenderOutput render_bridged(const GaussianBatch& gaussians, const Camera& camera,
                            const RenderSettings& settings, torch::Device device, int threads);

}  // namespace crpgs::raster
