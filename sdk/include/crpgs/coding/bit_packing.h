/// @file bit_packing.h
/// @brief Fixed-width bit packing, and the COHS link vector in its two codings:
/// - paper (docs/method.md §7.11): one entry per active anchor, the active index of its root or
///   "no root", stored with w = ceil(log2(N_a + 1)) bits per entry and the sentinel 2^w - 1;
/// - compact: leaf flags plus each leaf's root as a rank among the roots still free (one-to-one
///   links only), 2.2-2.5x smaller on fern (bench/results/rd_fern.md).
/// Bits are packed LSB first: entry i occupies stream bits [i*w, (i+1)*w), bit k of the stream is
/// bit (k % 8) of byte k / 8; unused high bits of the last byte are zero.
#pragma once

#include <cstdint>
#include <vector>

#include "crpgs/coding/bitstream.h"
#include "crpgs/status.h"

namespace crpgs::coding {

/// Packs values with `width` bits each (0..32; width 0 packs nothing). kInvalidArgument if a
/// value does not fit the width.
StatusOr<Bytes> pack_bits(const std::vector<uint32_t>& values, int width);
/// Unpacks `count` values; kCorruptBitstream unless bytes has exactly ceil(count * width / 8)
/// bytes with the padding bits zero.
StatusOr<std::vector<uint32_t>> unpack_bits(ByteSpan bytes, size_t count, int width);

/// "No root" in the link vector's in-memory form (the paper's -1).
inline constexpr int32_t kNoRoot = -1;

/// w = ceil(log2(n_active + 1)): 0 for n_active = 0, 1 for 1, 2 for 2..3, 3 for 4..7, ...
int link_bit_width(uint32_t n_active);

/// The link vector has one entry per active anchor, so N_a = links.size(). Layout:
/// varint N_a | packed entries (w bits each, sentinel 2^w - 1). links[i] must be kNoRoot or an
/// active index in [0, N_a) other than i; anything else is refused (kInvalidArgument).
StatusOr<Bytes> pack_links(const std::vector<int32_t>& links);

/// Inverse of pack_links. kCorruptBitstream if the count does not match the bytes, an entry is
/// neither the sentinel nor a valid index, or an entry links to itself.
StatusOr<std::vector<int32_t>> unpack_links(ByteSpan bytes);

/// The compact link coding, for one-to-one one-hop links (every root has exactly one leaf).
/// Layout: varint N | varint L (leaves) | varint B | B bytes: encode_bernoulli of the N leaf
/// flags | the roots: for leaf k (k = 0..L-1, in index order), the rank of its root among the
/// M - k non-leaf anchors no earlier leaf took (M = N - L, ranks in index order), as a truncated
/// binary code over M - k values, MSB first, zero-padded to a byte. Costs about
/// N·H(L/N) + log2(M! / (M - L)!) bits, the information in the partition and the matching.
/// Roots are not spatially close to their leaves (feature similarity, not position, picks them),
/// so a rank codes them as well as any position-based prediction we measured.
/// kInvalidArgument for links that are out of range, chains or not one-to-one.
StatusOr<Bytes> encode_links_compact(const std::vector<int32_t>& links);

/// Inverse of encode_links_compact. kCorruptBitstream for counts the bytes cannot hold, a flag
/// count other than L, more leaves than non-leaves, truncation or trailing bytes.
StatusOr<std::vector<int32_t>> decode_links_compact(ByteSpan bytes);

}  // namespace crpgs::coding
