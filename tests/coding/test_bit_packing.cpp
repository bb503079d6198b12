/// @file test_bit_packing.cpp
/// @brief Fixed-width bit packing and the COHS link vector (method.md §7.11).
#include <gtest/gtest.h>

#include <random>

#include "crpgs/coding/bit_packing.h"

namespace crpgs::coding {
namespace {

TEST(BitPacking, RoundTripEveryWidth) {
  std::mt19937 rng(5);
  for (int width = 0; width <= 32; ++width) {
    std::vector<uint32_t> v(1 + rng() % 300);
    for (auto& x : v) x = width == 0 ? 0 : uint32_t(rng()) >> (32 - width);
    auto packed = pack_bits(v, width);
    ASSERT_TRUE(packed.ok()) << width;
    EXPECT_EQ(packed->size(), (v.size() * width + 7) / 8);
    auto back = unpack_bits(packed.value(), v.size(), width);
    ASSERT_TRUE(back.ok()) << back.status().message();
    EXPECT_EQ(back.value(), v) << width;
  }
}

TEST(BitPacking, LsbFirstLayout) {
  auto packed = pack_bits({1, 2, 3, 0, 7}, 3);  // 001 010 011 000 111 -> LSB first
  ASSERT_TRUE(packed.ok());
  ASSERT_EQ(packed->size(), 2u);
  EXPECT_EQ((*packed)[0], 0b11010001);
  EXPECT_EQ((*packed)[1], 0b01110000);
}

TEST(BitPacking, RefusesBadInput) {
  EXPECT_EQ(pack_bits({8}, 3).status().code(), StatusCode::kInvalidArgument);
  EXPECT_FALSE(pack_bits({1}, 33).ok());
  const Bytes two = {0xff, 0x03};
  EXPECT_EQ(unpack_bits(two, 5, 4).status().code(), StatusCode::kCorruptBitstream);  // size
  EXPECT_EQ(unpack_bits(two, 3, 3).status().code(), StatusCode::kCorruptBitstream);  // padding
  EXPECT_TRUE(unpack_bits(two, 10, 1).ok());
  EXPECT_TRUE(unpack_bits(two, 4, 4).ok());
  EXPECT_EQ(unpack_bits(two, size_t(1) << 40, 1).status().code(), StatusCode::kCorruptBitstream);
}

TEST(LinkVector, BitWidth) {
  EXPECT_EQ(link_bit_width(0), 0);
  EXPECT_EQ(link_bit_width(1), 1);
  EXPECT_EQ(link_bit_width(2), 2);
  EXPECT_EQ(link_bit_width(3), 2);
  EXPECT_EQ(link_bit_width(4), 3);
  EXPECT_EQ(link_bit_width(7), 3);
  EXPECT_EQ(link_bit_width(8), 4);
  EXPECT_EQ(link_bit_width(0xffffffffu), 32);
}

TEST(LinkVector, SentinelIsAllOnes) {
  // N_a = 3 -> w = 2, sentinel 3: {-1, 0, 1} -> 11 00 01 -> byte 0b00010011.
  auto packed = pack_links({kNoRoot, 0, 1});
  ASSERT_TRUE(packed.ok());
  ASSERT_EQ(packed->size(), 2u);
  EXPECT_EQ((*packed)[0], 3);  // varint N_a
  EXPECT_EQ((*packed)[1], 0b00010011);
  auto back = unpack_links(packed.value());
  ASSERT_TRUE(back.ok()) << back.status().message();
  EXPECT_EQ(back.value(), (std::vector<int32_t>{kNoRoot, 0, 1}));
}

TEST(LinkVector, RandomRoundTrip) {
  std::mt19937 rng(8);
  for (uint32_t n : {0u, 1u, 2u, 255u, 256u, 1000u, 70000u}) {
    std::vector<int32_t> links(n, kNoRoot);
    for (uint32_t i = 0; i < n; ++i)
      if (n > 1 && rng() % 2) links[i] = int32_t((i + 1 + rng() % (n - 1)) % n);  // never i
    auto packed = pack_links(links);
    ASSERT_TRUE(packed.ok()) << packed.status().message();
    const int w = link_bit_width(n);
    EXPECT_LE(packed->size(), 5 + (size_t(n) * w + 7) / 8);
    auto back = unpack_links(packed.value());
    ASSERT_TRUE(back.ok()) << back.status().message();
    EXPECT_EQ(back.value(), links) << n;
  }
}

TEST(LinkVector, RefusesInvalidLinks) {
  EXPECT_EQ(pack_links({kNoRoot, 1}).status().code(), StatusCode::kInvalidArgument);  // self
  EXPECT_EQ(pack_links({2, kNoRoot}).status().code(), StatusCode::kInvalidArgument);  // range
  EXPECT_EQ(pack_links({-2, kNoRoot}).status().code(), StatusCode::kInvalidArgument);
  // N_a = 5 -> w = 3: value 6 is neither a root index nor the sentinel 7.
  auto bits = pack_bits({6, 7, 7, 7, 7}, 3);
  ASSERT_TRUE(bits.ok());
  Bytes bad = {5};
  bad.insert(bad.end(), bits->begin(), bits->end());
  EXPECT_EQ(unpack_links(bad).status().code(), StatusCode::kCorruptBitstream);
  // Self link in the stream.
  auto self = pack_bits({0, 7, 7, 7, 7}, 3);
  Bytes bad2 = {5};
  bad2.insert(bad2.end(), self->begin(), self->end());
  EXPECT_EQ(unpack_links(bad2).status().code(), StatusCode::kCorruptBitstream);
  // Count beyond the bytes, and truncation.
  auto good = pack_links({1, 0, kNoRoot, kNoRoot, 2});
  ASSERT_TRUE(good.ok());
  for (size_t len = 0; len < good->size(); ++len)
    EXPECT_FALSE(unpack_links(ByteSpan(good->data(), len)).ok()) << len;
  const Bytes absurd = {0xff, 0xff, 0xff, 0xff, 0x0f, 0x00};
  EXPECT_EQ(unpack_links(absurd).status().code(), StatusCode::kCorruptBitstream);
}

}  // namespace
}  // namespace crpgs::coding
