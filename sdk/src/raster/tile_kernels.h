/// @file tile_kernels.h
/// @brief The per-tile pixel loops of rasterize_to_pixels (forward and backward) on raw buffers.
/// Internal to stages.cpp; kept in their own translation unit so that they can be compiled for
/// several instruction sets (runtime dispatch) without touching the rest.
#pragma once

#include <cstdint>

namespace crpgs::raster::kernels {

/// What the pixel loops read of one Gaussian: one cache line.
struct alignas(64) Packed {
  float mx, my, a, b, c, op, r, g, bl, d;
  float ex, ey;  // half-extent of the region where alpha can reach 1/255; ex < 0: never does
  float q;       // that region is d^T K d <= q (K the conic)
  float pad[3];
};

/// m2 [2], con [3] (conic a, b, c), col [3].
Packed pack_one(const float* m2, const float* con, float op, const float* col, float depth);

/// Half-extent of a conic whose float a c − b² is not positive: unbounded, the radius box limits
/// it.
inline constexpr float kUnboundedExtent = 1e30f;

/// The half-extents ex, ey of Packed for a conic and opacity (ex < 0: alpha never reaches
/// 1/255; kUnboundedExtent: no bound but the radius box). A pixel x takes part only if
/// |x + 0.5 - mx| <= ex, and likewise in y. Returns Q = 2 ln(255 op), the bound on the conic's
/// quadratic form (Packed::q).
double alpha_extent(const float* con, float op, float& ex, float& ey);

/// Read-only inputs shared by every tile.
struct TileInputs {
  const Packed* gs;        // [N]
  const int32_t* offsets;  // [tiles + 1]
  const int32_t* ids;      // [M], per tile front to back
  int tiles_x, width, height;
  float bg[3];
  bool depth;  // render / differentiate the accumulated depth
};

struct ForwardOutputs {
  float* image;    // [H, W, 3]
  float* alpha;    // [H, W]
  float* depth;    // [H, W] or null when !depth
  float* final_T;  // [H, W]
  int32_t* last;   // [H, W]
};

struct BackwardInputs {
  const float* final_T;  // [H, W]
  const int32_t* last;   // [H, W]
  const float* v_image;  // [H, W, 3] or null (= zero)
  const float* v_alpha;  // [H, W] or null
  const float* v_depth;  // [H, W] or null
};

/// Per-entry gradient slots: mean2d (2), conic (3), opacity, colour (3), depth.
constexpr int kGradSlots = 10;

/// Front-to-back compositing of one 16x16 tile.
void forward_tile(int tile, const TileInputs& in, const ForwardOutputs& out);

/// Back-to-front gradients of one tile: writes kGradSlots floats for each of the tile's entries
/// (entry_grads is [M, kGradSlots], zero-initialised; entries without a contribution stay 0).
void backward_tile(int tile, const TileInputs& in, const BackwardInputs& bw, float* entry_grads);

}  // namespace crpgs::raster::kernels
