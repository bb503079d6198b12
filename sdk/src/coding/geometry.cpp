/// @file geometry.cpp
/// @brief Draco kd-tree coding of integer anchor voxels, Morton order, raw 16-bit fallback.
#include "crpgs/coding/geometry.h"

#include "crpgs/coding/bit_packing.h"

#include <draco/compression/decode.h>
#include <draco/compression/encode.h>
#include <draco/point_cloud/point_cloud_builder.h>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <limits>
#include <numeric>
#include <string>

namespace crpgs::coding {
namespace {

constexpr uint8_t kDracoFormat = 1;
constexpr int kDracoSpeed = 5;  // kd-tree at the default speed (toolchain.md §3)

// Draco sizes its attribute buffers from counts in its own header before it decodes anything,
// so decode_positions() checks that header against what encode_positions() writes first:
// "DRACO" | u8 major (2) | u8 minor | u8 point cloud (0) | u8 kd-tree (1) | u16 flags (0: no
// metadata) | i32 n | 1 attribute decoder, 1 attribute: POSITION, DT_INT32, 3 components, not
// normalised, id 0 | u8 level | u32 bit length | u32 n.
constexpr uint8_t kDracoAttributes[7] = {1, 1, 0, 5, 3, 0, 0};
constexpr size_t kDracoHeaderSize = 31;
// The kd-tree coder spends about a bit per point even on a completely filled cube (1.01 bits at
// 64^3, 1.03 at 100^3 with kDracoSpeed), so more than 64 points per byte (8x that) is refused.
constexpr uint64_t kMaxPointsPerDracoByte = 64;

Status invalid(const std::string& m) {
  return Status(StatusCode::kInvalidArgument, m);
}
Status corrupt(const std::string& m) {
  return Status(StatusCode::kCorruptBitstream, m);
}

inline uint32_t morton_key(int32_t v) {
  return uint32_t(v) ^ 0x80000000u;
}

// True if the highest set bit of a is below that of b.
inline bool less_msb(uint32_t a, uint32_t b) {
  return a < b && a < (a ^ b);
}

std::string voxel_str(const Voxel& v) {
  return "(" + std::to_string(v[0]) + ", " + std::to_string(v[1]) + ", " + std::to_string(v[2]) +
         ")";
}

}  // namespace

bool morton_less(const Voxel& a, const Voxel& b) {
  // Compare on the axis whose differing bit is highest; z wins ties (most significant of a
  // triple), then y, then x.
  int best = 2;
  uint32_t best_xor = morton_key(a[2]) ^ morton_key(b[2]);
  for (int d = 1; d >= 0; --d) {
    const uint32_t x = morton_key(a[d]) ^ morton_key(b[d]);
    if (less_msb(best_xor, x)) {
      best = d;
      best_xor = x;
    }
  }
  return morton_key(a[best]) < morton_key(b[best]);
}

std::vector<uint32_t> morton_order(const std::vector<Voxel>& points) {
  std::vector<uint32_t> perm(points.size());
  std::iota(perm.begin(), perm.end(), 0u);
  std::stable_sort(perm.begin(), perm.end(),
                   [&](uint32_t a, uint32_t b) { return morton_less(points[a], points[b]); });
  return perm;
}

void sort_morton(std::vector<Voxel>* points) {
  std::stable_sort(points->begin(), points->end(), morton_less);
}

StatusOr<Bytes> encode_positions(const std::vector<Voxel>& points) {
  const size_t n = points.size();
  if (n > size_t(std::numeric_limits<int32_t>::max()))
    return invalid("too many points for Draco: " + std::to_string(n));
  ByteWriter w;
  w.put_u8(kDracoFormat);
  w.put_varint(n);
  if (n == 0) return w.take();
  // Duplicates would make the canonical order ambiguous: refuse them.
  {
    std::vector<Voxel> sorted(points);
    std::sort(sorted.begin(), sorted.end());
    const auto dup = std::adjacent_find(sorted.begin(), sorted.end());
    if (dup != sorted.end())
      return invalid("duplicate voxel " + voxel_str(*dup) + ": anchors must be unique voxels");
  }
  Voxel lo = points[0], hi = points[0];
  for (const Voxel& p : points)
    for (int d = 0; d < 3; ++d) {
      lo[d] = std::min(lo[d], p[d]);
      hi[d] = std::max(hi[d], p[d]);
    }
  for (int d = 0; d < 3; ++d)
    if (int64_t(hi[d]) - lo[d] > int64_t(std::numeric_limits<int32_t>::max()))
      return invalid("voxel extent on axis " + std::to_string(d) + " is 2^31 or more");
  for (int d = 0; d < 3; ++d) w.put_i32(lo[d]);

  draco::PointCloudBuilder builder;
  builder.Start(static_cast<draco::PointIndex::ValueType>(n));
  const int att = builder.AddAttribute(draco::GeometryAttribute::POSITION, 3, draco::DT_INT32);
  for (size_t i = 0; i < n; ++i) {
    const int32_t v[3] = {int32_t(int64_t(points[i][0]) - lo[0]),
                          int32_t(int64_t(points[i][1]) - lo[1]),
                          int32_t(int64_t(points[i][2]) - lo[2])};
    builder.SetAttributeValueForPoint(att, draco::PointIndex(static_cast<uint32_t>(i)), v);
  }
  std::unique_ptr<draco::PointCloud> pc = builder.Finalize(false);
  if (!pc) return Status(StatusCode::kInternal, "Draco point cloud builder failed");
  draco::Encoder enc;
  enc.SetEncodingMethod(draco::POINT_CLOUD_KD_TREE_ENCODING);
  enc.SetSpeedOptions(kDracoSpeed, kDracoSpeed);
  draco::EncoderBuffer buf;
  const draco::Status st = enc.EncodePointCloudToBuffer(*pc, &buf);
  if (!st.ok()) return Status(StatusCode::kInternal, std::string("Draco: ") + st.error_msg());
  const ByteSpan draco_bytes(reinterpret_cast<const uint8_t*>(buf.data()), buf.size());
  w.put_u32(crc32(draco_bytes));
  w.put_bytes(draco_bytes);
  return w.take();
}

StatusOr<std::vector<Voxel>> decode_positions(ByteSpan bytes) {
  ByteReader r(bytes, "anchor geometry");
  uint8_t format = 0;
  uint64_t n = 0;
  CRPGS_RETURN_IF_ERROR(r.read_u8(&format));
  if (format != kDracoFormat) return r.error("unknown geometry format " + std::to_string(format));
  CRPGS_RETURN_IF_ERROR(r.read_varint(&n));
  if (n == 0) {
    if (!r.at_end()) return r.error("trailing bytes after an empty point set");
    return std::vector<Voxel>();
  }
  if (n > uint64_t(std::numeric_limits<int32_t>::max())) return r.error("absurd point count");
  Voxel lo;
  for (int d = 0; d < 3; ++d) CRPGS_RETURN_IF_ERROR(r.read_i32(&lo[d]));
  uint32_t crc = 0;
  CRPGS_RETURN_IF_ERROR(r.read_u32(&crc));
  const ByteSpan draco_bytes = r.rest();
  if (crc32(draco_bytes) != crc) return r.error("CRC mismatch in the Draco payload");
  if (n > kMaxPointsPerDracoByte * draco_bytes.size)
    return r.error(std::to_string(n) + " points cannot be coded in " +
                   std::to_string(draco_bytes.size) + " Draco bytes");
  const uint8_t* d = draco_bytes.data;
  auto le32 = [&](size_t at) {
    return uint32_t(d[at]) | uint32_t(d[at + 1]) << 8 | uint32_t(d[at + 2]) << 16 |
           uint32_t(d[at + 3]) << 24;
  };
  if (draco_bytes.size < kDracoHeaderSize || std::memcmp(d, "DRACO", 5) != 0 || d[5] != 2 ||
      d[7] != 0 || d[8] != 1 || d[9] != 0 || d[10] != 0 ||
      std::memcmp(d + 15, kDracoAttributes, sizeof(kDracoAttributes)) != 0)
    return r.error("the Draco payload is not a kd-tree coded int32 point cloud");
  if (le32(11) != n || le32(27) != n)
    return r.error("the Draco header claims " + std::to_string(le32(11)) + " and " +
                   std::to_string(le32(27)) + " points, ours " + std::to_string(n));

  draco::DecoderBuffer buf;
  buf.Init(reinterpret_cast<const char*>(draco_bytes.data), draco_bytes.size);
  draco::Decoder dec;
  auto decoded = dec.DecodePointCloudFromBuffer(&buf);
  if (!decoded.ok())
    return corrupt(std::string("anchor geometry: Draco: ") + decoded.status().error_msg());
  const std::unique_ptr<draco::PointCloud> pc = std::move(decoded).value();
  if (!pc || pc->num_points() != n)
    return corrupt("anchor geometry: Draco returned " + std::to_string(pc ? pc->num_points() : 0) +
                   " points, header says " + std::to_string(n));
  const draco::PointAttribute* att = pc->GetNamedAttribute(draco::GeometryAttribute::POSITION);
  if (!att || att->num_components() != 3 || att->data_type() != draco::DT_INT32)
    return corrupt("anchor geometry: no 3-component int32 position attribute");
  std::vector<Voxel> out(static_cast<size_t>(n));
  for (size_t i = 0; i < out.size(); ++i) {
    int32_t v[3];
    if (!att->ConvertValue<int32_t>(att->mapped_index(draco::PointIndex(uint32_t(i))), 3, v))
      return corrupt("anchor geometry: cannot read point " + std::to_string(i));
    for (int d = 0; d < 3; ++d) {
      const int64_t c = int64_t(v[d]) + lo[d];
      if (v[d] < 0 || c > std::numeric_limits<int32_t>::max())
        return corrupt("anchor geometry: coordinate out of range at point " + std::to_string(i));
      out[i][d] = int32_t(c);
    }
  }
  sort_morton(&out);
  for (size_t i = 1; i < out.size(); ++i)
    if (out[i] == out[i - 1]) return corrupt("anchor geometry: duplicate voxel after decoding");
  return out;
}

// --- Raw 16-bit fallback ---------------------------------------------------------------------

StatusOr<Bytes> encode_voxels_raw(const std::vector<Voxel>& points) {
  if (points.size() > size_t(std::numeric_limits<int32_t>::max()))
    return invalid("raw geometry: too many points");
  Voxel lo{0, 0, 0};
  int64_t extent = 0;
  for (size_t i = 0; i < points.size(); ++i) {
    if (i > 0 && !morton_less(points[i - 1], points[i]))
      return invalid("raw geometry: points must be unique and in Morton order");
    for (int a = 0; a < 3; ++a)
      lo[size_t(a)] = i == 0 ? points[i][size_t(a)] : std::min(lo[size_t(a)], points[i][size_t(a)]);
  }
  for (const auto& p : points)
    for (int a = 0; a < 3; ++a)
      extent = std::max(extent, int64_t(p[size_t(a)]) - int64_t(lo[size_t(a)]));
  int width = 1;
  while (width < 32 && (extent >> width) != 0) ++width;
  std::vector<uint32_t> values;
  values.reserve(points.size() * 3);
  for (const auto& p : points)
    for (int a = 0; a < 3; ++a)
      values.push_back(uint32_t(int64_t(p[size_t(a)]) - int64_t(lo[size_t(a)])));
  CRPGS_ASSIGN_OR_RETURN(Bytes packed, pack_bits(values, width));
  ByteWriter w;
  w.put_u8(1);
  w.put_varint(points.size());
  for (int32_t v : lo) w.put_i32(v);
  w.put_u8(uint8_t(width));
  w.put_bytes(packed);
  return w.take();
}

StatusOr<std::vector<Voxel>> decode_voxels_raw(ByteSpan bytes) {
  ByteReader r(bytes, "raw geometry");
  uint8_t format = 0, width = 0;
  uint64_t n = 0;
  CRPGS_RETURN_IF_ERROR(r.read_u8(&format));
  if (format != 1) return corrupt("raw geometry: unknown format " + std::to_string(format));
  CRPGS_RETURN_IF_ERROR(r.read_varint(&n));
  Voxel lo{};
  for (int32_t& v : lo) CRPGS_RETURN_IF_ERROR(r.read_i32(&v));
  CRPGS_RETURN_IF_ERROR(r.read_u8(&width));
  if (width < 1 || width > 32) return corrupt("raw geometry: width " + std::to_string(width));
  if (n > r.remaining() * 8 / (3 * uint64_t(width)))
    return corrupt("raw geometry: " + std::to_string(n) + " points do not fit the section");
  ByteSpan rest;
  CRPGS_RETURN_IF_ERROR(r.read_span(r.remaining(), &rest));
  CRPGS_ASSIGN_OR_RETURN(std::vector<uint32_t> values, unpack_bits(rest, size_t(n) * 3, width));
  std::vector<Voxel> points(static_cast<size_t>(n));
  for (size_t i = 0; i < points.size(); ++i) {
    for (int a = 0; a < 3; ++a) {
      const int64_t v = int64_t(lo[size_t(a)]) + int64_t(values[3 * i + size_t(a)]);
      if (v > std::numeric_limits<int32_t>::max()) return corrupt("raw geometry: out of range");
      points[i][size_t(a)] = int32_t(v);
    }
    if (i > 0 && !morton_less(points[i - 1], points[i]))
      return corrupt("raw geometry: points not strictly in Morton order");
  }
  return points;
}

StatusOr<Raw16Positions> quantize_raw16(const std::vector<std::array<float, 3>>& xyz,
                                        const std::array<float, 3>& lo,
                                        const std::array<float, 3>& hi) {
  for (int d = 0; d < 3; ++d)
    if (!std::isfinite(lo[d]) || !std::isfinite(hi[d]) || hi[d] < lo[d])
      return invalid("raw16: bad bounds on axis " + std::to_string(d));
  Raw16Positions q;
  q.lo = lo;
  q.hi = hi;
  q.codes.resize(xyz.size());
  for (size_t i = 0; i < xyz.size(); ++i)
    for (int d = 0; d < 3; ++d) {
      if (!std::isfinite(xyz[i][d]))
        return invalid("raw16: non-finite coordinate at point " + std::to_string(i));
      const float range = hi[d] - lo[d];
      const float t = range > 0 ? (xyz[i][d] - lo[d]) / range : 0.f;
      const float c = std::nearbyint(std::clamp(t, 0.f, 1.f) * 65535.f);
      q.codes[i][d] = uint16_t(c);
    }
  return q;
}

std::vector<std::array<float, 3>> dequantize_raw16(const Raw16Positions& q) {
  std::vector<std::array<float, 3>> out(q.codes.size());
  for (int d = 0; d < 3; ++d) {
    const float step = (q.hi[d] - q.lo[d]) / 65535.f;
    for (size_t i = 0; i < out.size(); ++i) out[i][d] = q.lo[d] + float(q.codes[i][d]) * step;
  }
  return out;
}

Bytes encode_positions_raw16(const Raw16Positions& q) {
  ByteWriter w;
  w.put_varint(q.codes.size());
  for (int d = 0; d < 3; ++d) w.put_f32(q.lo[d]);
  for (int d = 0; d < 3; ++d) w.put_f32(q.hi[d]);
  for (const auto& c : q.codes)
    for (int d = 0; d < 3; ++d) w.put_u16(c[d]);
  return w.take();
}

StatusOr<Raw16Positions> decode_positions_raw16(ByteSpan bytes) {
  ByteReader r(bytes, "raw16 anchor positions");
  uint64_t n = 0;
  CRPGS_RETURN_IF_ERROR(r.read_varint(&n));
  Raw16Positions q;
  for (int d = 0; d < 3; ++d) CRPGS_RETURN_IF_ERROR(r.read_f32(&q.lo[d]));
  for (int d = 0; d < 3; ++d) CRPGS_RETURN_IF_ERROR(r.read_f32(&q.hi[d]));
  for (int d = 0; d < 3; ++d)
    if (!std::isfinite(q.lo[d]) || !std::isfinite(q.hi[d]) || q.hi[d] < q.lo[d])
      return r.error("bad bounds on axis " + std::to_string(d));
  if (n > r.remaining() / 6 || n * 6 != r.remaining())
    return r.error(std::to_string(n) + " points need " + std::to_string(n * 6) + " bytes, " +
                   std::to_string(r.remaining()) + " present");
  q.codes.resize(size_t(n));
  for (auto& c : q.codes)
    for (int d = 0; d < 3; ++d) CRPGS_RETURN_IF_ERROR(r.read_u16(&c[d]));
  return q;
}

}  // namespace crpgs::coding
