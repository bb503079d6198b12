/// @file constants.h
/// @brief Constants of the CPU rasterizer, shared by the stages and the pixel kernels (which
/// include no libtorch header).
#pragma once

namespace crpgs::raster {

constexpr int kTileSize = 16;
/// Tiles that cover `pixels` pixels along one axis.
constexpr int tile_count(int pixels) {
  return (pixels + kTileSize - 1) / kTileSize;
}
constexpr double kCovDilation = 0.3;        // added to the 2D covariance diagonal (low-pass)
constexpr float kMaxAlpha = 0.99f;          // alpha = min(0.99, opacity * G)
constexpr float kMinAlpha = 1.f / 255.f;    // contributions below are skipped
constexpr float kMinTransmittance = 1e-4f;  // a pixel stops when T would drop to this or below
constexpr double kQuatEps = 1e-12;          // q / max(|q|, eps)
constexpr double kMaxRadius = 1 << 24;      // radii are clamped so extreme scales stay finite

}  // namespace crpgs::raster
