/// @file stages.h
/// @brief The CPU rasterizer as three stages (project -> intersect_tiles -> rasterize_to_pixels),
/// each with forward and backward on raw float32 buffers. Internal; the autograd wrapper in
/// cpu_rasterizer.cpp composes them and tests call them one by one.
///
/// Conventions (3DGS / gsplat): COLMAP/OpenCV camera (x right, y down, z forward); a point
/// projects to u = fx * x / z + cx, v = fy * y / z + cy, and pixel (i, j) has its centre at
/// (i + 0.5, j + 0.5), so cx = W / 2 is the image centre. Quaternions are (w, x, y, z) and are
/// normalised inside (a zero quaternion gives the identity rotation and zero gradient).
#pragma once

#include <array>
#include <cstdint>

#include <ATen/ATen.h>

#include "crpgs/camera.h"
#include "crpgs/rasterizer.h"
#include "raster/constants.h"
#include "raster/project_kernels.h"

namespace crpgs::raster {

/// Threads to use: `requested` > 0 as given, otherwise all available processors.
int resolve_threads(int requested);

/// The camera as the projection kernels take it (CPU and CUDA), in double; the tan limits clamp
/// x/z for the Jacobian as 3DGS and gsplat do.
kernels::ProjectCamera project_camera(const Camera& camera, const RenderSettings& settings);

struct ProjectResult {
  at::Tensor means2d;  // [N, 2] float32, pixels
  at::Tensor conics;   // [N, 3] float32, inverse 2D covariance (a, b, c) = [[a, b], [b, c]]
  at::Tensor depths;   // [N] float32, camera-space z
  at::Tensor radii;    // [N] int32, 0 where culled
};

struct ProjectGrads {
  at::Tensor v_means;      // [N, 3]
  at::Tensor v_scales;     // [N, 3]
  at::Tensor v_rotations;  // [N, 4]
};

/// means [N,3], scales [N,3], rotations [N,4]: float32, contiguous, CPU. A Gaussian is culled
/// (radius 0) outside near <= z <= far, when its 2D covariance is not positive definite, or
/// when its 3-sigma box touches no tile.
ProjectResult project_forward(const at::Tensor& means, const at::Tensor& scales,
                              const at::Tensor& rotations, const Camera& camera,
                              const RenderSettings& settings, int threads);

/// Gradients of the loss through the projection; culled Gaussians get zero.
ProjectGrads project_backward(const at::Tensor& means, const at::Tensor& scales,
                              const at::Tensor& rotations, const Camera& camera,
                              const ProjectResult& fwd, const at::Tensor& v_means2d,
                              const at::Tensor& v_conics, const at::Tensor& v_depths, int threads);

struct TileIntersections {
  int tiles_x = 0, tiles_y = 0;
  at::Tensor tile_offsets;  // [tiles_x * tiles_y + 1] int32, row-major tiles
  at::Tensor gaussian_ids;  // [M] int32, per tile sorted by (depth, index)
};

/// Tile rectangle of one Gaussian: tiles [x0, x1) x [y0, y1) (3DGS getRect).
struct TileRect {
  int x0, y0, x1, y1;
};
TileRect tile_rect(float mx, float my, int radius, int tiles_x, int tiles_y);

/// Every Gaussian with radius > 0 goes to the tiles of its tile_rect. Given its conic [N, 3] and
/// opacity [N] as well, only to those of them where its alpha can reach 1/255 (the pixel loops
/// would skip it in the others): the same image and gradients, fewer entries.
TileIntersections intersect_tiles(const at::Tensor& means2d, const at::Tensor& radii,
                                  const at::Tensor& depths, int width, int height, int threads,
                                  const at::Tensor& conics = {}, const at::Tensor& opacities = {});

struct RasterizeResult {
  at::Tensor image;         // [H, W, 3] colour including background
  at::Tensor alpha;         // [H, W, 1] 1 - final transmittance
  at::Tensor depth;         // [H, W, 1] sum of w_i * z_i (not normalised); undefined unless asked
  at::Tensor final_T;       // [H, W] transmittance after the last contribution
  at::Tensor last_contrib;  // [H, W] int32, entries of the tile list up to the last contributor
};

struct RasterizeGrads {
  at::Tensor v_means2d;    // [N, 2]
  at::Tensor v_conics;     // [N, 3]
  at::Tensor v_opacities;  // [N]
  at::Tensor v_colors;     // [N, 3]
  at::Tensor v_depths;     // [N]
};

/// Front-to-back compositing per 16x16 tile. `depths` is only read when render_depth.
RasterizeResult rasterize_forward(const at::Tensor& means2d, const at::Tensor& conics,
                                  const at::Tensor& opacities, const at::Tensor& colors,
                                  const at::Tensor& depths, const TileIntersections& isect,
                                  int width, int height, const std::array<float, 3>& background,
                                  bool render_depth, int threads);

/// v_image [H,W,3], v_alpha [H,W,1] and v_depth [H,W,1] (may be undefined = zero).
RasterizeGrads rasterize_backward(const at::Tensor& means2d, const at::Tensor& conics,
                                  const at::Tensor& opacities, const at::Tensor& colors,
                                  const at::Tensor& depths, const TileIntersections& isect,
                                  const RasterizeResult& fwd, int width, int height,
                                  const std::array<float, 3>& background, bool render_depth,
                                  const at::Tensor& v_image, const at::Tensor& v_alpha,
                                  const at::Tensor& v_depth, int threads);

/// [N,4] identity quaternions (w = 1) for the anchor prefilter of both back-ends.
at::Tensor identity_rotations(int64_t n, const at::TensorOptions& options);

/// Anchor prefilter: positions [N,3], extents [N,3] (scales, identity rotation) -> bool [N].
at::Tensor visible_anchors(const at::Tensor& positions, const at::Tensor& extents,
                           const Camera& camera, const RenderSettings& settings, int threads);

}  // namespace crpgs::raster
