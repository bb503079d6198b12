/// @file bit_packing.cpp
/// @brief Fixed-width bit packing and the COHS link vector (paper and compact codings).
#include "crpgs/coding/bit_packing.h"

#include <string>

#include "crpgs/coding/range_coder.h"

namespace crpgs::coding {
namespace {
Status invalid(const std::string& m) {
  return Status(StatusCode::kInvalidArgument, m);
}

size_t lowest_bit(size_t i) {
  return i & (~i + 1);
}

/// Which of n ranked slots are still free: a Fenwick tree of 0/1 counts, so the rank of a slot
/// among the free ones and the slot of a rank both take O(log n).
class FreeSlots {
 public:
  explicit FreeSlots(size_t n) : tree_(n + 1, 0) {
    for (size_t i = 1; i <= n; ++i) {
      tree_[i] += 1;
      if (const size_t up = i + lowest_bit(i); up <= n) tree_[up] += tree_[i];
    }
  }
  /// Free slots before slot p.
  uint32_t rank(size_t p) const {
    uint32_t s = 0;
    for (size_t i = p; i > 0; i -= lowest_bit(i)) s += tree_[i];
    return s;
  }
  void take(size_t p) {
    for (size_t i = p + 1; i < tree_.size(); i += lowest_bit(i)) --tree_[i];
  }
  /// The free slot of rank r (r < the number of free slots).
  size_t slot(uint32_t r) const {
    size_t pos = 0, step = 1;
    while (step * 2 < tree_.size()) step *= 2;
    for (; step > 0; step /= 2)
      if (pos + step < tree_.size() && tree_[pos + step] <= r) {
        pos += step;
        r -= tree_[pos];
      }
    return pos;
  }

 private:
  std::vector<uint32_t> tree_;
};

int floor_log2(uint32_t m) {
  int k = 0;
  while ((uint64_t(2) << k) <= m) ++k;
  return k;
}

class MsbBitWriter {
 public:
  void put(uint32_t v, int width) {
    for (int k = width - 1; k >= 0; --k, ++bits_) {
      if (bits_ % 8 == 0) out_.push_back(0);
      if ((v >> k) & 1) out_.back() |= uint8_t(0x80u >> (bits_ % 8));
    }
  }
  /// v in [0, m), m >= 1: floor(log2 m) bits for the first 2^(k+1) - m values, one more after.
  void put_truncated(uint32_t v, uint32_t m) {
    const int k = floor_log2(m);
    const uint64_t u = (uint64_t(2) << k) - m;
    if (v < u)
      put(v, k);
    else
      put(uint32_t(v + u), k + 1);
  }
  Bytes take() { return std::move(out_); }

 private:
  Bytes out_;
  uint64_t bits_ = 0;
};

class MsbBitReader {
 public:
  explicit MsbBitReader(ByteSpan b) : b_(b) {}
  bool get(int width, uint32_t* v) {
    if (bits_ + uint64_t(width) > uint64_t(b_.size) * 8) return false;
    uint32_t x = 0;
    for (int k = 0; k < width; ++k, ++bits_)
      x = (x << 1) | ((b_.data[bits_ / 8] >> (7 - bits_ % 8)) & 1u);
    *v = x;
    return true;
  }
  bool get_truncated(uint32_t m, uint32_t* v) {
    const int k = floor_log2(m);
    const uint64_t u = (uint64_t(2) << k) - m;
    uint32_t x = 0, extra = 0;
    if (!get(k, &x)) return false;
    if (x >= u) {
      if (!get(1, &extra)) return false;
      x = uint32_t(((uint64_t(x) << 1) | extra) - u);
    }
    *v = x;
    return true;
  }
  /// All bytes used, the padding bits of the last one zero.
  bool at_clean_end() const {
    if ((bits_ + 7) / 8 != b_.size) return false;
    return bits_ % 8 == 0 || (b_.data[b_.size - 1] & (0xffu >> (bits_ % 8))) == 0;
  }

 private:
  ByteSpan b_;
  uint64_t bits_ = 0;
};

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

StatusOr<Bytes> encode_links_compact(const std::vector<int32_t>& links) {
  if (links.size() > 0xffffffffu) return invalid("too many links");
  const size_t n = links.size();
  std::vector<uint8_t> leaf(n, 0);
  for (size_t i = 0; i < n; ++i) {
    const int32_t l = links[i];
    if (l == kNoRoot) continue;
    if (l < 0 || size_t(l) >= n || size_t(l) == i)
      return invalid("link " + std::to_string(i) + " -> " + std::to_string(l) +
                     " is not kNoRoot or another index below " + std::to_string(n));
    leaf[i] = 1;
  }
  std::vector<uint32_t> slot(n, 0);  // a non-leaf anchor's rank among the non-leaves
  uint32_t m = 0;
  for (size_t i = 0; i < n; ++i)
    if (!leaf[i]) slot[i] = m++;
  FreeSlots free_roots(m);
  std::vector<uint8_t> taken(m, 0);
  MsbBitWriter roots;
  uint32_t k = 0;
  for (size_t i = 0; i < n; ++i) {
    if (!leaf[i]) continue;
    const auto r = size_t(links[i]);
    if (leaf[r])
      return invalid("link " + std::to_string(i) + " -> " + std::to_string(r) +
                     ": the root is itself a leaf");
    if (taken[slot[r]])
      return invalid("root " + std::to_string(r) + " has two leaves (links must be one-to-one)");
    taken[slot[r]] = 1;
    roots.put_truncated(free_roots.rank(slot[r]), m - k);
    free_roots.take(slot[r]);
    ++k;
  }
  CRPGS_ASSIGN_OR_RETURN(Bytes flags, encode_bernoulli(leaf));
  ByteWriter w;
  w.put_varint(n);
  w.put_varint(n - m);
  w.put_varint(flags.size());
  w.put_bytes(flags);
  w.put_bytes(roots.take());
  return w.take();
}

StatusOr<std::vector<int32_t>> decode_links_compact(ByteSpan bytes) {
  ByteReader r(bytes, "link vector");
  uint64_t n = 0, n_leaves = 0, flag_bytes = 0;
  CRPGS_RETURN_IF_ERROR(r.read_varint(&n));
  CRPGS_RETURN_IF_ERROR(r.read_varint(&n_leaves));
  CRPGS_RETURN_IF_ERROR(r.read_varint(&flag_bytes));
  if (n > 0xffffffffu) return r.error("absurd anchor count " + std::to_string(n));
  if (n_leaves > n || n_leaves > n - n_leaves)
    return r.error(std::to_string(n_leaves) + " leaves among " + std::to_string(n) +
                   " anchors cannot each have their own root");
  ByteSpan flag_span;
  CRPGS_RETURN_IF_ERROR(r.read_span(flag_bytes, &flag_span));
  auto flags = decode_bernoulli(flag_span, size_t(n));
  if (!flags.ok())
    return Status(StatusCode::kCorruptBitstream, "link vector: " + flags.status().message());
  const std::vector<uint8_t>& leaf = flags.value();
  std::vector<uint32_t> non_leaf;  // anchor index of each non-leaf rank
  non_leaf.reserve(size_t(n - n_leaves));
  for (size_t i = 0; i < leaf.size(); ++i)
    if (!leaf[i]) non_leaf.push_back(uint32_t(i));
  if (non_leaf.size() != n - n_leaves)
    return r.error("the flags mark " + std::to_string(n - non_leaf.size()) + " leaves, not " +
                   std::to_string(n_leaves));
  const auto m = uint32_t(non_leaf.size());
  FreeSlots free_roots(m);
  MsbBitReader roots(r.rest());
  std::vector<int32_t> links(size_t(n), kNoRoot);
  uint32_t k = 0;
  for (size_t i = 0; i < links.size(); ++i) {
    if (!leaf[i]) continue;
    uint32_t rank = 0;
    if (!roots.get_truncated(m - k, &rank)) return r.error("root codes truncated");
    const size_t s = free_roots.slot(rank);
    free_roots.take(s);
    links[i] = int32_t(non_leaf[s]);
    ++k;
  }
  if (!roots.at_clean_end()) return r.error("trailing bytes or non-zero padding after the roots");
  return links;
}

}  // namespace crpgs::coding
