/// @file geometry.h
/// @brief Anchor geometry: lossless coding of unique integer voxel coordinates with Draco's
/// kd-tree coder, the canonical (Morton) anchor order both sides derive from the decoded
/// positions, and HAC's lossy raw 16-bit fallback for the ablation config.
#pragma once

#include <array>
#include <cstdint>
#include <vector>

#include "crpgs/coding/bitstream.h"
#include "crpgs/status.h"

namespace crpgs::coding {

using Voxel = std::array<int32_t, 3>;

/// Canonical order: true if a comes before b in Morton (Z-order) of the integer coordinates.
/// Coordinates are mapped order-preservingly to uint32 (sign bit flipped), bits interleaved
/// with z the most significant of each (x, y, z) triple. Total order on distinct points.
bool morton_less(const Voxel& a, const Voxel& b);

/// The permutation that sorts points into canonical order: points[perm[0]], points[perm[1]],
/// ... are in Morton order (stable for equal points).
std::vector<uint32_t> morton_order(const std::vector<Voxel>& points);

/// Sorts in place into canonical order.
void sort_morton(std::vector<Voxel>* points);

/// Lossless: Draco kd-tree coder on DT_INT32 positions (no quantisation) after subtracting the
/// per-axis minimum, which is stored. Layout: u8 format (1) | varint n | i32 min x, y, z |
/// u32 crc32 of the Draco bytes | Draco bytes (absent when n = 0). Refuses (kInvalidArgument)
/// duplicate voxels (the caller guarantees unique voxels; merge them first), a per-axis extent
/// of 2^31 or more, or more than 2^31 - 1 points.
StatusOr<Bytes> encode_positions(const std::vector<Voxel>& points);

/// The decoded voxels in canonical Morton order (Draco returns points in its own order, so the
/// encoder must order every per-anchor attribute with morton_order() too). kCorruptBitstream on a
/// malformed header, a CRC mismatch, a Draco failure, a wrong point count or duplicates. Before
/// Draco runs (it sizes buffers from its own header), the Draco header must be the one
/// encode_positions() writes, with the same point count, and the count must fit the bytes (at
/// most 64 points per byte; the kd-tree coder needs about a bit per point even when densest).
StatusOr<std::vector<Voxel>> decode_positions(ByteSpan bytes);

/// Lossless without a point-cloud codec (the ablation "no anchor-position coding"): the voxels,
/// already in canonical Morton order, minus the per-axis minimum, stored raw with one fixed
/// width w for every coordinate: the narrowest that holds the extent (at most 16 bits, HAC's
/// raw width, for a scene under 65536 voxels across). Refuses duplicates or points not in Morton
/// order (kInvalidArgument). Layout: u8 format (1) | varint n | i32 min[3] | u8 w | packed bits.
StatusOr<Bytes> encode_voxels_raw(const std::vector<Voxel>& points);
/// kCorruptBitstream on a bad header or width, a wrong byte count, or points that are not
/// strictly increasing in Morton order.
StatusOr<std::vector<Voxel>> decode_voxels_raw(ByteSpan bytes);

/// HAC's fallback (docs/method.md §7.1): each coordinate quantised uniformly to 16 bits inside the
/// bounds [lo, hi] and stored raw (N * 3 * 16 bits). Lossy: the error is up to half a step,
/// (hi - lo) / 65535 / 2 per axis; positions outside the bounds are clamped. The input order is
/// kept (no reordering, duplicates allowed). Layout: varint n | f32 lo[3] | f32 hi[3] |
/// u16 codes, point-major.
struct Raw16Positions {
  std::array<float, 3> lo{};
  std::array<float, 3> hi{};
  std::vector<std::array<uint16_t, 3>> codes;
};

/// Quantises positions to 16-bit codes. kInvalidArgument for non-finite values or bounds with
/// hi < lo on an axis.
StatusOr<Raw16Positions> quantize_raw16(const std::vector<std::array<float, 3>>& xyz,
                                        const std::array<float, 3>& lo,
                                        const std::array<float, 3>& hi);
/// The decoded positions lo + code * (hi - lo) / 65535, in float32, the same on both sides.
std::vector<std::array<float, 3>> dequantize_raw16(const Raw16Positions& q);
Bytes encode_positions_raw16(const Raw16Positions& q);
/// kCorruptBitstream if the byte count does not match the point count or the bounds are bad.
StatusOr<Raw16Positions> decode_positions_raw16(ByteSpan bytes);

}  // namespace crpgs::coding
