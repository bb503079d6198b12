/// @file test_geometry.cpp
/// @brief Draco anchor geometry (lossless, canonical Morton order on both sides), Morton order
/// itself, and the lossy raw 16-bit fallback.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <random>
#include <set>

#include "crpgs/coding/bit_packing.h"
#include "crpgs/coding/bitstream.h"
#include "crpgs/coding/geometry.h"

namespace crpgs::coding {
namespace {

std::vector<Voxel> random_unique(size_t n, int32_t lo, int32_t hi, uint32_t seed) {
  std::mt19937 rng(seed);
  std::uniform_int_distribution<int32_t> u(lo, hi);
  std::set<Voxel> seen;
  std::vector<Voxel> out;
  while (out.size() < n) {
    const Voxel v = {u(rng), u(rng), u(rng)};
    if (seen.insert(v).second) out.push_back(v);
  }
  return out;
}

std::vector<Voxel> in_morton_order(const std::vector<Voxel>& pts) {
  std::vector<Voxel> out;
  for (uint32_t i : morton_order(pts)) out.push_back(pts[i]);
  return out;
}

TEST(Morton, KnownOrder) {
  // z is the most significant bit of each triple, then y, then x.
  const std::vector<Voxel> expected = {{0, 0, 0}, {1, 0, 0}, {0, 1, 0}, {1, 1, 0},
                                       {0, 0, 1}, {1, 0, 1}, {0, 1, 1}, {1, 1, 1},
                                       {2, 0, 0}, {3, 0, 0}, {2, 1, 0}};
  std::vector<Voxel> shuffled = expected;
  std::mt19937 rng(3);
  std::shuffle(shuffled.begin(), shuffled.end(), rng);
  EXPECT_EQ(in_morton_order(shuffled), expected);
  // Negative coordinates come before non-negative ones on the same axis.
  EXPECT_TRUE(morton_less({-1, 0, 0}, {0, 0, 0}));
  EXPECT_TRUE(morton_less({0, 0, -5}, {0, 0, 3}));
  EXPECT_TRUE(morton_less({std::numeric_limits<int32_t>::min(), 0, 0}, {-1, 0, 0}));
  EXPECT_FALSE(morton_less({4, 4, 4}, {4, 4, 4}));
}

TEST(Morton, MatchesInterleavedKeys) {
  // Reference: 63-bit keys from explicit bit interleaving of 21-bit coordinates.
  const auto key = [](const Voxel& v) {
    uint64_t k = 0;
    for (int b = 0; b < 21; ++b)
      for (int d = 0; d < 3; ++d) k |= uint64_t((uint32_t(v[d]) >> b) & 1) << (3 * b + d);
    return k;
  };
  const std::vector<Voxel> pts = random_unique(3000, 0, (1 << 21) - 1, 5);
  const std::vector<Voxel> got = in_morton_order(pts);
  for (size_t i = 1; i < got.size(); ++i) ASSERT_LT(key(got[i - 1]), key(got[i]));
}

TEST(Geometry, LosslessOnRandomLatticeIncludingNegatives) {
  for (auto range : {std::pair<int32_t, int32_t>{-300, 300},
                     {-5000000, -4999000},
                     {0, 1 << 20},
                     {-(1 << 30), (1 << 30) - 1}}) {
    const std::vector<Voxel> pts = random_unique(4000, range.first, range.second, 17);
    auto enc = encode_positions(pts);
    ASSERT_TRUE(enc.ok()) << enc.status().message();
    auto dec = decode_positions(enc.value());
    ASSERT_TRUE(dec.ok()) << dec.status().message();
    // The decoder's canonical order equals the encoder's morton_order() of its own input.
    EXPECT_EQ(dec.value(), in_morton_order(pts)) << range.first << ".." << range.second;
  }
}

TEST(Geometry, CanonicalOrderIndependentOfInputOrder) {
  std::vector<Voxel> pts = random_unique(2000, -100, 100, 23);
  auto a = decode_positions(encode_positions(pts).value());
  std::mt19937 rng(1);
  std::shuffle(pts.begin(), pts.end(), rng);
  auto b = decode_positions(encode_positions(pts).value());
  ASSERT_TRUE(a.ok() && b.ok());
  EXPECT_EQ(a.value(), b.value());
  EXPECT_TRUE(std::is_sorted(a->begin(), a->end(), morton_less));
}

TEST(Geometry, CompressesSurfaceLikeClouds) {
  // A voxelised sphere shell of radius 200: about 12 bits/point per toolchain.md, far below raw
  // 3 x 32 bits.
  std::vector<Voxel> pts;
  for (int32_t x = -200; x <= 200; x += 2)
    for (int32_t y = -200; y <= 200; y += 2) {
      const double r2 = 200.0 * 200.0 - double(x) * x - double(y) * y;
      if (r2 < 0) continue;
      pts.push_back({x, y, int32_t(std::lround(std::sqrt(r2)))});
      pts.push_back({x, y, -int32_t(std::lround(std::sqrt(r2))) - 1});
    }
  auto enc = encode_positions(pts);
  ASSERT_TRUE(enc.ok()) << enc.status().message();
  EXPECT_LT(double(enc->size()) * 8 / double(pts.size()), 32.0);
  auto dec = decode_positions(enc.value());
  ASSERT_TRUE(dec.ok());
  EXPECT_EQ(dec.value(), in_morton_order(pts));
}

TEST(Geometry, EmptySinglePointAndTwoPoints) {
  for (const std::vector<Voxel>& pts : {std::vector<Voxel>{}, std::vector<Voxel>{{-7, 3, 123456}},
                                        std::vector<Voxel>{{5, 5, 5}, {-5, -5, -5}}}) {
    auto enc = encode_positions(pts);
    ASSERT_TRUE(enc.ok()) << enc.status().message();
    auto dec = decode_positions(enc.value());
    ASSERT_TRUE(dec.ok()) << dec.status().message();
    EXPECT_EQ(dec.value(), in_morton_order(pts));
  }
}

TEST(Geometry, RefusesDuplicatesAndHugeExtent) {
  auto dup = encode_positions({{1, 2, 3}, {4, 5, 6}, {1, 2, 3}});
  EXPECT_EQ(dup.status().code(), StatusCode::kInvalidArgument);
  EXPECT_NE(dup.status().message().find("(1, 2, 3)"), std::string::npos);
  auto wide = encode_positions(
      {{std::numeric_limits<int32_t>::min(), 0, 0}, {std::numeric_limits<int32_t>::max(), 0, 0}});
  EXPECT_EQ(wide.status().code(), StatusCode::kInvalidArgument);
}

TEST(Geometry, CorruptStreamsAreRefused) {
  const std::vector<Voxel> pts = random_unique(500, -50, 50, 29);
  const Bytes enc = encode_positions(pts).value();
  for (size_t len = 0; len < enc.size(); len += (len < 40 ? 1 : 37)) {
    auto r = decode_positions(ByteSpan(enc.data(), len));
    ASSERT_FALSE(r.ok()) << len;
    EXPECT_EQ(r.status().code(), StatusCode::kCorruptBitstream);
  }
  for (size_t off : {size_t(0), size_t(1), size_t(5), size_t(20), enc.size() / 2, enc.size() - 1}) {
    Bytes bad = enc;
    bad[off] ^= 0x20;
    auto r = decode_positions(bad);
    EXPECT_FALSE(r.ok() && r.value() == in_morton_order(pts)) << off;
    if (!r.ok()) {
      EXPECT_EQ(r.status().code(), StatusCode::kCorruptBitstream);
    }
  }
}

TEST(Raw16, QuantisesWithinHalfAStepAndKeepsOrder) {
  std::mt19937 rng(31);
  std::uniform_real_distribution<float> u(-3.f, 5.f);
  std::vector<std::array<float, 3>> xyz(1000);
  for (auto& p : xyz) p = {u(rng), u(rng) * 0.1f, u(rng) * 10.f};
  xyz.push_back(xyz[0]);  // duplicates are fine here
  const std::array<float, 3> lo = {-3.f, -0.3f, -30.f}, hi = {5.f, 0.5f, 50.f};
  auto q = quantize_raw16(xyz, lo, hi);
  ASSERT_TRUE(q.ok()) << q.status().message();
  const Bytes enc = encode_positions_raw16(q.value());
  EXPECT_EQ(enc.size(), 2 + 24 + xyz.size() * 6);  // varint(1001) + bounds + 3 x 16 bits
  auto dec = decode_positions_raw16(enc);
  ASSERT_TRUE(dec.ok()) << dec.status().message();
  EXPECT_EQ(dec->codes, q->codes);
  const auto back = dequantize_raw16(dec.value());
  ASSERT_EQ(back.size(), xyz.size());
  for (size_t i = 0; i < xyz.size(); ++i)
    for (int d = 0; d < 3; ++d) {
      const float half_step = (hi[d] - lo[d]) / 65535.f / 2;
      EXPECT_LE(std::abs(back[i][d] - xyz[i][d]), half_step * 1.01f) << i << "," << d;
    }
  EXPECT_EQ(back, dequantize_raw16(q.value()));  // encoder-side positions equal the decoder's
}

TEST(Raw16, RefusesBadInput) {
  EXPECT_FALSE(quantize_raw16({{0.f, 0.f, 0.f}}, {1.f, 0.f, 0.f}, {0.f, 1.f, 1.f}).ok());
  EXPECT_FALSE(quantize_raw16({{NAN, 0.f, 0.f}}, {0.f, 0.f, 0.f}, {1.f, 1.f, 1.f}).ok());
  auto q = quantize_raw16({{0.5f, 0.5f, 0.5f}, {2.f, -1.f, 0.f}}, {0.f, 0.f, 0.f}, {1.f, 1.f, 1.f});
  ASSERT_TRUE(q.ok());
  EXPECT_EQ(q->codes[1][0], 65535);  // clamped into the bounds
  EXPECT_EQ(q->codes[1][1], 0);
  Bytes enc = encode_positions_raw16(q.value());
  enc.pop_back();
  EXPECT_EQ(decode_positions_raw16(enc).status().code(), StatusCode::kCorruptBitstream);
  ByteWriter absurd;
  absurd.put_varint(uint64_t(1) << 62);
  for (int i = 0; i < 6; ++i) absurd.put_f32(0.f);
  EXPECT_EQ(decode_positions_raw16(absurd.bytes()).status().code(), StatusCode::kCorruptBitstream);
}

}  // namespace
}  // namespace crpgs::coding

namespace crpgs::coding {
namespace {

TEST(RawVoxels, LosslessWithTheNarrowestWidth) {
  for (auto range :
       {std::pair<int32_t, int32_t>{-300, 300}, {0, 65535}, {-(1 << 30), (1 << 30) - 1}}) {
    const auto pts = in_morton_order(random_unique(3000, range.first, range.second, 5));
    auto enc = encode_voxels_raw(pts);
    ASSERT_TRUE(enc.ok()) << enc.status().message();
    auto dec = decode_voxels_raw(enc.value());
    ASSERT_TRUE(dec.ok()) << dec.status().message();
    EXPECT_EQ(dec.value(), pts);
    // Header (u8 format, varint n, 3 x i32, u8 width) + one fixed width per coordinate.
    const int64_t extent = int64_t(range.second) - int64_t(range.first);
    int width = 1;
    while ((extent >> width) != 0) ++width;
    EXPECT_LE(enc->size(), 16 + (pts.size() * 3 * size_t(width) + 7) / 8) << width;
  }
  auto empty = encode_voxels_raw({});
  ASSERT_TRUE(empty.ok());
  auto dec = decode_voxels_raw(empty.value());
  ASSERT_TRUE(dec.ok()) << dec.status().message();
  EXPECT_TRUE(dec->empty());
}

TEST(RawVoxels, RefusesUnorderedInputAndCorruptStreams) {
  auto pts = in_morton_order(random_unique(200, -50, 50, 9));
  std::swap(pts[3], pts[4]);
  EXPECT_FALSE(encode_voxels_raw(pts).ok());
  std::swap(pts[3], pts[4]);
  auto enc = encode_voxels_raw(pts);
  ASSERT_TRUE(enc.ok());
  Bytes bytes = enc.value();
  for (size_t cut : {size_t(0), size_t(1), size_t(5), bytes.size() - 1}) {
    const Bytes part(bytes.begin(), bytes.begin() + std::ptrdiff_t(cut));
    EXPECT_FALSE(decode_voxels_raw(part).ok()) << "truncated at " << cut;
  }
  Bytes bad_width = bytes;
  bad_width[1 + 2 + 12] = 40;  // format, varint 200 (2 bytes), 3 x i32, then the width
  EXPECT_FALSE(decode_voxels_raw(bad_width).ok());
  // A well-formed stream whose points are out of order: (1,0,0) then (0,0,0).
  ByteWriter w;
  w.put_u8(1);
  w.put_varint(2);
  for (int a = 0; a < 3; ++a) w.put_i32(0);
  w.put_u8(2);
  auto packed = pack_bits({1, 0, 0, 0, 0, 0}, 2);
  ASSERT_TRUE(packed.ok());
  w.put_bytes(packed.value());
  auto d = decode_voxels_raw(w.take());
  ASSERT_FALSE(d.ok());
  EXPECT_NE(d.status().message().find("Morton"), std::string::npos) << d.status().message();
}

}  // namespace
}  // namespace crpgs::coding
