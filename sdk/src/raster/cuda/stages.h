/// @file stages.h
/// @brief The CUDA rasterizer's stages: stages.h's project -> intersect_tiles ->
/// rasterize_to_pixels with the same results structs, on float32 CUDA tensors. The glue between
/// libtorch and the kernels of kernels.h; it uses only device-generic ATen calls, so it compiles
/// against any libtorch (and fails at run time, with a message, where there is no CUDA device).
#pragma once

#include "raster/stages.h"

namespace crpgs::raster::cuda {

ProjectResult project_forward(const at::Tensor& means, const at::Tensor& scales,
                              const at::Tensor& rotations, const Camera& camera,
                              const RenderSettings& settings);

ProjectGrads project_backward(const at::Tensor& means, const at::Tensor& scales,
                              const at::Tensor& rotations, const Camera& camera,
                              const ProjectResult& fwd, const at::Tensor& v_means2d,
                              const at::Tensor& v_conics, const at::Tensor& v_depths);

/// The CPU's tile lists exactly: (depth, index) order per tile by a stable device radix sort on
/// (tile, depth) keys emitted in Gaussian order.
TileIntersections intersect_tiles(const at::Tensor& means2d, const at::Tensor& radii,
                                  const at::Tensor& depths, int width, int height,
                                  const at::Tensor& conics = {}, const at::Tensor& opacities = {});

RasterizeResult rasterize_forward(const at::Tensor& means2d, const at::Tensor& conics,
                                  const at::Tensor& opacities, const at::Tensor& colors,
                                  const at::Tensor& depths, const TileIntersections& isect,
                                  int width, int height, const std::array<float, 3>& background,
                                  bool render_depth);

RasterizeGrads rasterize_backward(const at::Tensor& means2d, const at::Tensor& conics,
                                  const at::Tensor& opacities, const at::Tensor& colors,
                                  const at::Tensor& depths, const TileIntersections& isect,
                                  const RasterizeResult& fwd, int width, int height,
                                  const std::array<float, 3>& background, bool render_depth,
                                  const at::Tensor& v_image, const at::Tensor& v_alpha,
                                  const at::Tensor& v_depth);

at::Tensor visible_anchors(const at::Tensor& positions, const at::Tensor& extents,
                           const Camera& camera, const RenderSettings& settings);

}  // namespace crpgs::raster::cuda
