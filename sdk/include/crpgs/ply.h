/// @file ply.h
/// @brief Standard 3DGS scenes as .ply files (the INRIA reference layout), torch-free.
///
/// A vertex is `x y z nx ny nz f_dc_0..2 f_rest_0..f_rest_{3(B-1)-1} opacity scale_0..2
/// rot_0..3`, all float32, binary little-endian, B = (degree+1)^2 SH coefficients per channel.
/// Stored values are pre-activation: opacity is a logit, scales are logs, the rotation is a
/// quaternion (w, x, y, z). f_rest is channel-major per vertex (every R coefficient 1..B-1, then
/// G, then B). Colour from direction d (Gaussian centre minus camera centre, normalised):
/// max(0.5 + Σ_b basis_b(d) · coeff_b, 0) per channel, with the 3DGS real SH basis (sh_basis).
#pragma once

#include <array>
#include <cstdint>
#include <string>
#include <vector>

#include "crpgs/status.h"

namespace crpgs {

/// SH coefficients per colour channel for a degree (0..3): (degree + 1)^2.
constexpr int sh_coeff_count(int degree) {
  return (degree + 1) * (degree + 1);
}

/// The 3DGS real SH basis at the unit direction (x, y, z): writes sh_coeff_count(degree) values
/// (constants and signs exactly as the reference rasterizer's eval_sh).
void sh_basis(int degree, float x, float y, float z, float* out);

/// The logit an infinite opacity is read as: sigmoid(±30) is 1 or 0 in float.
constexpr float kPlyReadSaturatedLogit = 30.f;

/// A 3DGS scene in the file's (pre-activation) parametrisation; arrays are row-major per vertex.
struct PlyGaussians {
  int sh_degree = 0;
  std::vector<float> means;       ///< [N*3]
  std::vector<float> sh_dc;       ///< [N*3] f_dc_0..2
  std::vector<float> sh_rest;     ///< [N * 3*(B-1)] f_rest, channel-major per vertex
  std::vector<float> opacity;     ///< [N] logit
  std::vector<float> log_scales;  ///< [N*3]
  std::vector<float> rotations;   ///< [N*4] (w, x, y, z)
  /// Vertices of the file left out because a value was NaN or infinite (read_ply).
  size_t dropped_non_finite = 0;

  size_t size() const { return opacity.size(); }
  /// Sizes every array for n Gaussians of sh_degree (new values 0; existing ones kept).
  void resize(size_t n);
  /// Checks that every array matches size() and the degree.
  Status check() const;
  /// Colour of Gaussian i seen from direction (x, y, z) (unit): max(0.5 + SH, 0) per channel.
  std::array<float, 3> color(size_t i, float x, float y, float z) const;
};

/// The largest opacity logit written: logit(254/255). Formats that store alpha in 8 bits (.spz,
/// .sog) round anything above 254.5/255 to 255, which reads back as an infinite logit.
constexpr float kPlyMaxOpacityLogit = 5.537334f;

/// The smallest log-scale written, relative to the file's median log-scale: e^-10 of a typical
/// Gaussian's size, far below a pixel. A flat Gaussian's thin axis (the export writes ln 1e-30
/// for a zero one) would otherwise stretch the range that formats with a 256-entry scale
/// codebook (.sog) spread their bins over, and the largest Gaussians lose their size there
/// (lego: 2.1 dB, bench/results/export.md).
constexpr float kPlyLogScaleFloorBelowMedian = 10.f;

/// The file's bytes (header + binary body; normals written as 0). What every consumer reads:
/// opacity logits clamped to ±kPlyMaxOpacityLogit (alpha 1/255..254/255), log-scales at least
/// the median log-scale − kPlyLogScaleFloorBelowMedian and rotations as unit quaternions (a
/// norm off 1 by more than float rounding is normalised; a zero one becomes the identity);
/// every other value as it is.
StatusOr<std::string> encode_ply(const PlyGaussians& g);
/// Writes encode_ply(g) atomically.
Status write_ply(const std::string& path, const PlyGaussians& g);

/// Parses a binary little-endian .ply with a `vertex` element holding the 3DGS properties (any
/// scalar type, converted to float); the SH degree follows from the number of f_rest_i (0, 9, 24
/// or 45). Other properties and elements after `vertex` are ignored. A vertex with a NaN, or an
/// infinite value other than its opacity, is left out and counted (dropped_non_finite); an
/// infinite opacity logit is alpha 1 or 0 (what an 8-bit alpha of 255 or 0 reads back as) and is
/// kept as ±kPlyReadSaturatedLogit. Refuses, with a message,
/// ascii or big-endian files, headers over 64 KiB, missing properties, list properties before
/// the vertex data, and counts the file is too short for (checked before allocating).
StatusOr<PlyGaussians> decode_ply(const uint8_t* data, size_t size, const std::string& name);
StatusOr<PlyGaussians> read_ply(const std::string& path);

}  // namespace crpgs
