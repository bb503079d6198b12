/// @file kernels.h
/// @brief The CUDA rasterizer's kernels behind plain launchers on raw device pointers: no
/// libtorch and no CUDA header, so the glue (cuda_stages.cpp) compiles with any libtorch and the
/// kernels (kernels.cu) with nvcc alone. Every launcher runs on the legacy default stream (the
/// one libtorch uses unless a caller sets another) and returns null, or the CUDA error's text.
///
/// The maths is the CPU rasterizer's, operation for operation: the projection in double
/// (project_kernels.cpp), the pixel loops in float with the same exp and no FMA contraction
/// (tile_kernels.cpp), so that forward images match the CPU's to the last bit wherever both
/// evaluate the same pixels. Gradients are summed with atomics (order varies, ~1e-7 relative).
#pragma once

#include <cstddef>
#include <cstdint>

#include "raster/project_kernels.h"

namespace crpgs::raster::cuda_kernels {

/// Culls and projects: outputs pre-zeroed, written only for Gaussians that draw (stages.h).
const char* project_forward(const kernels::ProjectCamera& cam, int64_t n, const float* means,
                            const float* scales, const float* quats, int tiles_x, int tiles_y,
                            float* means2d, float* conics, float* depths, int32_t* radii);

/// Gradients of means, scales and quaternions (outputs pre-zeroed; culled Gaussians stay 0).
const char* project_backward(const kernels::ProjectCamera& cam, int64_t n, const float* means,
                             const float* scales, const float* quats, const int32_t* radii,
                             const float* v_means2d, const float* v_conics, const float* v_depths,
                             float* v_means, float* v_scales, float* v_quats);

/// Tile rectangles ([x0, y0, x1, y1] per Gaussian, int32 [n, 4]) as intersect_tiles clips them
/// (conics and opacities may be null: the radius box alone) and the number of tiles of each.
const char* tile_rects(int64_t n, const float* means2d, const int32_t* radii, const float* conics,
                       const float* opacities, int tiles_x, int tiles_y, int32_t* rects,
                       int64_t* counts);

/// Inclusive prefix sum of counts [n] into cumulative [n]; temp null asks for temp_bytes.
const char* inclusive_sum(void* temp, size_t& temp_bytes, const int64_t* counts,
                          int64_t* cumulative, int64_t n);

/// One (tile << 32 | depth order) key and Gaussian id per intersection, in Gaussian order.
const char* emit_intersections(int64_t n, const int32_t* rects, const int64_t* cumulative,
                               const float* depths, int tiles_x, int64_t* keys, int32_t* ids);

/// Stable radix sort of (key, id) pairs on key bits [0, end_bit); temp null asks for temp_bytes.
const char* sort_intersections(void* temp, size_t& temp_bytes, const int64_t* keys_in,
                               int64_t* keys_out, const int32_t* ids_in, int32_t* ids_out,
                               int64_t m, int end_bit);

/// offsets [n_tiles + 1]: where each tile's entries start in the sorted keys [m].
const char* tile_offsets(const int64_t* sorted_keys, int64_t m, int n_tiles, int32_t* offsets);

struct TileBuffers {
  const float *means2d, *conics, *opacities, *colors, *depths;  // per Gaussian
  const int32_t *offsets, *ids;                                 // tile lists
  int width, height, tiles_x, tiles_y;
  float bg[3];
  bool depth;  // render (and differentiate) the accumulated depth
};

/// Front-to-back compositing, one 16x16 block per tile.
const char* rasterize_forward(const TileBuffers& in, float* image, float* alpha, float* depth,
                              float* final_T, int32_t* last);

/// Back-to-front gradients into per-Gaussian outputs (pre-zeroed); v_* inputs may be null.
const char* rasterize_backward(const TileBuffers& in, const float* final_T, const int32_t* last,
                               const float* v_image, const float* v_alpha, const float* v_depth,
                               float* v_means2d, float* v_conics, float* v_opacities,
                               float* v_colors, float* v_depths);

}  // namespace crpgs::raster::cuda_kernels
