/// @file bit_packing.cpp
/// @brief Fixed-width bit packing and the COHS link vector.
#include "crpgs/coding/bit_packing.h"

#include <string>

namespace crpgs::coding {
namespace {
Status invalid(const std::string& m) {
  return Status(StatusCode::kInvalidArgument, m);
}
}  // namespace

StatusOr<Bytes> pack_bits(const std::vector<uint32_t>& values, int width) {
  if (width < 0 || width > 32) return invalid("bit width " + std::to_string(width));
  const uint64_t limit = width == 32 ? ~uint64_t(0) : (uint64_t(1) << width) - 1;
  Bytes out((uint64_t(values.size()) * width + 7) / 8, 0);
  uint64_t bit = 0;
  for (size_t i = 0; i < values.size(); ++i, bit += width) {
    if (values[i] > limit)
      return invalid("value " + std::to_string(values[i]) + " at " + std::to_string(i) +
                     " does not fit " + std::to_string(width) + " bits");
    for (int k = 0; k < width; ++k)
      if ((values[i] >> k) & 1) out[(bit + k) >> 3] |= uint8_t(1u << ((bit + k) & 7));
  }
  return out;
}

StatusOr<std::vector<uint32_t>> unpack_bits(ByteSpan bytes, size_t count, int width) {
  ByteReader r(bytes, "packed bits");
  if (width < 0 || width > 32) return invalid("bit width " + std::to_string(width));
  // Check the size first, so a huge count never allocates.
  if (width > 0 && count > bytes.size * 8 / size_t(width))
    return r.error(std::to_string(count) + " entries of " + std::to_string(width) +
                   " bits need more than the " + std::to_string(bytes.size) + " bytes present");
  const uint64_t n_bits = uint64_t(count) * width;
  if ((n_bits + 7) / 8 != bytes.size)
    return r.error("expected " + std::to_string((n_bits + 7) / 8) + " bytes, got " +
                   std::to_string(bytes.size));
  if (n_bits % 8 && (bytes.data[bytes.size - 1] >> (n_bits % 8)) != 0)
    return r.error("non-zero padding bits");
  std::vector<uint32_t> out(count, 0);
  uint64_t bit = 0;
  for (size_t i = 0; i < count; ++i, bit += width) {
    uint32_t v = 0;
    for (int k = 0; k < width; ++k)
      v |= uint32_t((bytes.data[(bit + k) >> 3] >> ((bit + k) & 7)) & 1) << k;
    out[i] = v;
  }
  return out;
}

int link_bit_width(uint32_t n_active) {
  int w = 0;
  while ((uint64_t(1) << w) < uint64_t(n_active) + 1) ++w;
  return w;
}

StatusOr<Bytes> pack_links(const std::vector<int32_t>& links) {
  if (links.size() > 0xffffffffu) return invalid("too many links");
  const uint32_t n_active = uint32_t(links.size());
  const int w = link_bit_width(n_active);
  const uint32_t sentinel = uint32_t((uint64_t(1) << w) - 1);
  std::vector<uint32_t> values(links.size());
  for (size_t i = 0; i < links.size(); ++i) {
    const int32_t l = links[i];
    if (l == kNoRoot) {
      values[i] = sentinel;
    } else if (l < 0 || uint32_t(l) >= n_active || size_t(l) == i) {
      return invalid("link " + std::to_string(i) + " -> " + std::to_string(l) +
                     " is not kNoRoot or another active index below " + std::to_string(n_active));
    } else {
      values[i] = uint32_t(l);
    }
  }
  ByteWriter wr;
  wr.put_varint(n_active);
  CRPGS_ASSIGN_OR_RETURN(Bytes packed, pack_bits(values, w));
  wr.put_bytes(packed);
  return wr.take();
}

StatusOr<std::vector<int32_t>> unpack_links(ByteSpan bytes) {
  ByteReader r(bytes, "link vector");
  uint64_t n = 0;
  CRPGS_RETURN_IF_ERROR(r.read_varint(&n));
  if (n > 0xffffffffu) return r.error("absurd active-anchor count " + std::to_string(n));
  const int w = link_bit_width(uint32_t(n));
  // Size check before allocating (w >= 1 whenever n >= 1).
  if (n > r.remaining() * 8 / uint64_t(w ? w : 1))
    return r.error(std::to_string(n) + " entries of " + std::to_string(w) +
                   " bits do not fit the " + std::to_string(r.remaining()) + " bytes present");
  auto values = unpack_bits(r.rest(), size_t(n), w);
  if (!values.ok())
    return Status(StatusCode::kCorruptBitstream, "link vector: " + values.status().message());
  const uint32_t sentinel = uint32_t((uint64_t(1) << w) - 1);
  std::vector<int32_t> links(static_cast<size_t>(n));
  for (size_t i = 0; i < links.size(); ++i) {
    const uint32_t v = values.value()[i];
    if (v == sentinel) {
      links[i] = kNoRoot;
    } else if (v >= n || v == i) {
      return r.error("entry " + std::to_string(i) + " = " + std::to_string(v) +
                     " is not a valid root");
    } else {
      links[i] = int32_t(v);
    }
  }
  return links;
}

}  // namespace crpgs::coding
