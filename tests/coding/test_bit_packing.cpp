/// @file test_bit_packing.cpp
/// @brief Fixed-width bit packing and the COHS link vector (docs/method.md §7.11).
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <numeric>
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

// --- Compact coding -----------------------------------------------------------------------------

/// n anchors, `leaves` of them linked one-to-one to distinct non-leaf roots, at random.
std::vector<int32_t> random_one_to_one(uint32_t n, uint32_t leaves, std::mt19937& rng) {
  std::vector<int32_t> perm(n), links(n, kNoRoot);
  std::iota(perm.begin(), perm.end(), 0);
  std::shuffle(perm.begin(), perm.end(), rng);
  for (uint32_t j = 0; j < leaves; ++j) links[size_t(perm[2 * j])] = perm[2 * j + 1];
  return links;
}

TEST(CompactLinks, RandomRoundTripNearTheInformationBound) {
  std::mt19937 rng(11);
  for (uint32_t n : {0u, 1u, 2u, 3u, 255u, 1000u, 70000u})
    for (double share : {0.0, 0.2, 0.5}) {
      const auto leaves = uint32_t(n * share);
      const auto links = random_one_to_one(n, leaves, rng);
      auto coded = encode_links_compact(links);
      ASSERT_TRUE(coded.ok()) << coded.status().message();
      auto back = decode_links_compact(coded.value());
      ASSERT_TRUE(back.ok()) << n << " " << share << ": " << back.status().message();
      EXPECT_EQ(back.value(), links) << n << " " << share;
      if (n < 1000) continue;
      // Information: the partition N·H(L/N) plus the matching log2(M!/(M-L)!) bits.
      const double p = double(leaves) / n, m = n - leaves;
      double bound = p > 0 ? -double(n) * (p * std::log2(p) + (1 - p) * std::log2(1 - p)) : 0;
      for (uint32_t k = 0; k < leaves; ++k) bound += std::log2(m - k);
      EXPECT_LE(8.0 * coded->size(), 1.01 * bound + 400) << n << " " << share;
      if (leaves > 0) {
        EXPECT_LT(coded->size(), pack_links(links)->size() / 2) << n;
      }
    }
}

TEST(CompactLinks, RootsAreTruncatedBinaryRanksAmongTheFreeRoots) {
  // Non-leaves 0, 1, 2; leaves 3, 4, 5. Leaf 3 -> 2: rank 2 of 3 -> "11"; leaf 4 -> 0: rank 0
  // of {0, 1} -> "0"; leaf 5 -> 1: the only root left, 0 bits. Roots stream: 110 00000.
  const std::vector<int32_t> links = {kNoRoot, kNoRoot, kNoRoot, 2, 0, 1};
  auto coded = encode_links_compact(links);
  ASSERT_TRUE(coded.ok()) << coded.status().message();
  EXPECT_EQ((*coded)[0], 6);                          // N
  EXPECT_EQ((*coded)[1], 3);                          // L
  EXPECT_EQ(size_t((*coded)[2]) + 4, coded->size());  // flags, then one byte of roots
  EXPECT_EQ(coded->back(), 0b11000000);
  auto back = decode_links_compact(coded.value());
  ASSERT_TRUE(back.ok()) << back.status().message();
  EXPECT_EQ(back.value(), links);
  // Leaf 3 -> 0 is rank 0 of 3 -> "0"; then leaf 4 -> 2 is rank 1 of {1, 2} -> "1".
  auto other = encode_links_compact({kNoRoot, kNoRoot, kNoRoot, 0, 2, 1});
  ASSERT_TRUE(other.ok());
  EXPECT_EQ(other->back(), 0b01000000);
}

TEST(CompactLinks, RefusesLinksThatAreNotOneHopOneToOne) {
  const auto code = [](const std::vector<int32_t>& l) {
    return encode_links_compact(l).status().code();
  };
  EXPECT_EQ(code({kNoRoot, 1}), StatusCode::kInvalidArgument);              // self
  EXPECT_EQ(code({2, kNoRoot}), StatusCode::kInvalidArgument);              // out of range
  EXPECT_EQ(code({-2, kNoRoot}), StatusCode::kInvalidArgument);             // not kNoRoot
  EXPECT_EQ(code({kNoRoot, 0, 1}), StatusCode::kInvalidArgument);           // chain 2 -> 1 -> 0
  EXPECT_EQ(code({kNoRoot, 0, 0, kNoRoot}), StatusCode::kInvalidArgument);  // two leaves, one root
  EXPECT_TRUE(encode_links_compact({}).ok());
}

TEST(CompactLinks, RefusesCorruptStreams) {
  std::mt19937 rng(5);
  const auto links = random_one_to_one(300, 100, rng);
  auto good = encode_links_compact(links);
  ASSERT_TRUE(good.ok());
  for (size_t len = 0; len < good->size(); ++len)
    EXPECT_EQ(decode_links_compact(ByteSpan(good->data(), len)).status().code(),
              StatusCode::kCorruptBitstream)
        << len;
  Bytes trailing = good.value();
  trailing.push_back(0);
  EXPECT_EQ(decode_links_compact(trailing).status().code(), StatusCode::kCorruptBitstream);
  // A leaf count that disagrees with the flags, and more leaves than roots.
  for (uint8_t leaves : {99, 101, 151, 200}) {
    Bytes bad = good.value();
    ASSERT_EQ(bad[2], 100);  // varint L: one byte here (N = 300 takes two)
    bad[2] = leaves;
    EXPECT_EQ(decode_links_compact(bad).status().code(), StatusCode::kCorruptBitstream)
        << int(leaves);
  }
  const Bytes absurd = {0xff, 0xff, 0xff, 0xff, 0x0f, 0x00, 0x00};
  EXPECT_EQ(decode_links_compact(absurd).status().code(), StatusCode::kCorruptBitstream);
}

}  // namespace
}  // namespace crpgs::coding
