/// @file test_hostile_coding.cpp
/// @brief Hostile counts at the coding layer (issue #9): a stream that claims far more elements
/// than its bytes can hold is refused with a message before anything is sized from the claim,
/// and the most skewed legitimate streams still decode.
#include <gtest/gtest.h>

#include <limits>

#include "crpgs/coding/bit_packing.h"
#include "crpgs/coding/bitstream.h"
#include "crpgs/coding/geometry.h"
#include "crpgs/coding/range_coder.h"

namespace crpgs::coding {
namespace {

constexpr uint64_t k2To32 = uint64_t(1) << 32;

/// A 1 KB Bernoulli stream claiming `n` bits with p(1) = f1 / 2^16: a valid initial rANS state
/// followed by zero words.
Bytes bernoulli_claiming(uint64_t n, uint32_t f1) {
  ByteWriter w;
  w.put_varint(n);
  w.put_u32(f1);
  w.put_u64(uint64_t(1) << 40);
  while (w.size() < 1024) w.put_u32(0);
  return w.take();
}

TEST(HostileCoding, BernoulliCountBeyondWhatItsBytesCanCodeIsRefused) {
  for (uint32_t f1 : {1u, 32768u, 65535u}) {
    const Bytes b = bernoulli_claiming(k2To32, f1);
    auto r = decode_bernoulli(b, size_t(k2To32));
    ASSERT_FALSE(r.ok()) << "f1 " << f1;
    EXPECT_EQ(r.status().code(), StatusCode::kCorruptBitstream);
    // Refused by the count check, which comes before the output is allocated.
    EXPECT_NE(r.status().message().find("code at most"), std::string::npos) << r.status().message();
  }
  // An even split costs a full bit of state per bit: 1 KB cannot hold 10^5 of them.
  auto r = decode_bernoulli(bernoulli_claiming(100000, 32768), 100000);
  ASSERT_FALSE(r.ok());
  EXPECT_NE(r.status().message().find("code at most"), std::string::npos);
}

TEST(HostileCoding, BernoulliStreamsOfOnlyTheLikelierBitStillDecode) {
  // The most compressible legitimate streams: the bound must never refuse what the encoder wrote.
  for (uint8_t bit : {uint8_t(0), uint8_t(1)}) {
    const std::vector<uint8_t> bits(size_t(1) << 22, bit);
    auto enc = encode_bernoulli(bits);
    ASSERT_TRUE(enc.ok()) << enc.status().to_string();
    auto dec = decode_bernoulli(*enc, bits.size());
    ASSERT_TRUE(dec.ok()) << dec.status().to_string();
    EXPECT_EQ(*dec, bits);
  }
  std::vector<uint8_t> sparse(size_t(1) << 20, 0);
  for (size_t i = 0; i < sparse.size(); i += 4099) sparse[i] = 1;
  auto enc = encode_bernoulli(sparse);
  ASSERT_TRUE(enc.ok());
  auto dec = decode_bernoulli(*enc, sparse.size());
  ASSERT_TRUE(dec.ok()) << dec.status().to_string();
  EXPECT_EQ(*dec, sparse);
}

TEST(HostileCoding, LinkVectorClaiming2To32EntriesIsRefused) {
  ByteWriter w;
  w.put_varint(k2To32);
  while (w.size() < 1024) w.put_u8(0xff);
  auto r = unpack_links(w.bytes());
  ASSERT_FALSE(r.ok());
  EXPECT_FALSE(r.status().message().empty());
}

TEST(HostileCoding, RawGeometryClaiming2To31PointsIsRefused) {
  ByteWriter w;
  w.put_u8(1);
  w.put_varint(uint64_t(1) << 31);
  for (int a = 0; a < 3; ++a) w.put_i32(0);
  w.put_u8(1);
  while (w.size() < 1024) w.put_u8(0x55);
  auto r = decode_voxels_raw(w.bytes());
  ASSERT_FALSE(r.ok());
  EXPECT_FALSE(r.status().message().empty());
}

TEST(HostileCoding, DracoGeometryClaimingMorePointsThanItHoldsIsRefused) {
  auto good = encode_positions({{0, 0, 0}, {1, 0, 0}, {0, 1, 0}, {5, 5, 5}});
  ASSERT_TRUE(good.ok());
  // Same Draco payload, our header claiming 2^31 - 1 points.
  ByteReader r(*good);
  uint8_t format = 0;
  uint64_t n = 0;
  ASSERT_TRUE(r.read_u8(&format).ok());
  ASSERT_TRUE(r.read_varint(&n).ok());
  ByteWriter w;
  w.put_u8(format);
  w.put_varint(uint64_t(std::numeric_limits<int32_t>::max()));
  w.put_bytes(r.rest());
  auto dec = decode_positions(w.bytes());
  ASSERT_FALSE(dec.ok());
  EXPECT_NE(dec.status().message().find("points"), std::string::npos) << dec.status().message();
}

TEST(HostileCoding, ChunkedStreamClaiming2To40SymbolsIsRefused) {
  for (uint64_t chunk : {uint64_t(1), uint64_t(10000)}) {
    ByteWriter w;
    w.put_u8(16);
    w.put_varint(uint64_t(1) << 40);
    w.put_varint(chunk);
    while (w.size() < 1024) w.put_u8(4);
    auto r = ChunkedDecoder::parse(w.bytes());
    ASSERT_FALSE(r.ok()) << "chunk size " << chunk;
    EXPECT_FALSE(r.status().message().empty());
  }
}

}  // namespace
}  // namespace crpgs::coding
