/// @file bit_packing.h
/// @brief Fixed-width bit packing, and the COHS link vector on top of it (method.md §7.11):
/// one entry per active anchor, the active index of its root or "no root", stored with
/// w = ceil(log2(N_a + 1)) bits per entry and the sentinel 2^w - 1 for "no root".
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

}  // namespace crpgs::coding
