/// @file test_range_coder.cpp
/// @brief rANS table coder: tables, round trips on random and adversarial tables, escapes,
/// chunking (independence, thread-count independence), Bernoulli streams, corrupt input.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <limits>
#include <random>

#include "crpgs/coding/range_coder.h"

namespace crpgs::coding {
namespace {

constexpr int32_t kI32Min = std::numeric_limits<int32_t>::min();
constexpr int32_t kI32Max = std::numeric_limits<int32_t>::max();

CdfTableSet make_set(std::vector<CdfTable> tables, int precision = kDefaultPrecision) {
  auto set = CdfTableSet::create(std::move(tables), precision);
  EXPECT_TRUE(set.ok()) << set.status().message();
  return std::move(set).value();
}

CdfTable table_from_pmf(const std::vector<double>& pmf, int32_t offset,
                        int precision = kDefaultPrecision) {
  auto t = make_cdf_table(pmf, offset, precision);
  EXPECT_TRUE(t.ok()) << t.status().message();
  return std::move(t).value();
}

// Discretised Gaussian over [-c, c], c = ceil(6 * scale), as an entropy model would build.
CdfTable gaussian_table(double scale, int precision = kDefaultPrecision) {
  const int c = int(std::ceil(6 * scale));
  std::vector<double> pmf;
  for (int v = -c; v <= c; ++v)
    pmf.push_back(0.5 * (std::erfc(-(v + 0.5) / (scale * std::sqrt(2.0))) -
                         std::erfc(-(v - 0.5) / (scale * std::sqrt(2.0)))));
  return table_from_pmf(pmf, -c, precision);
}

void expect_round_trip(const std::vector<int32_t>& symbols, const std::vector<uint32_t>& idx,
                       const CdfTableSet& set) {
  auto enc = encode_symbols(symbols, idx, set);
  ASSERT_TRUE(enc.ok()) << enc.status().message();
  auto dec = decode_symbols(enc.value(), idx, set);
  ASSERT_TRUE(dec.ok()) << dec.status().message();
  EXPECT_EQ(dec.value(), symbols);
}

// Draws values mostly from the table's pmf, sometimes far outside it.
std::vector<int32_t> sample(const std::vector<uint32_t>& idx, const CdfTableSet& set,
                            std::mt19937& rng, double outside_rate) {
  std::vector<int32_t> out(idx.size());
  std::uniform_real_distribution<double> u(0, 1);
  for (size_t i = 0; i < idx.size(); ++i) {
    const CdfTable& t = set.table(idx[i]);
    if (u(rng) < outside_rate) {
      out[i] = int32_t(rng());  // any int32, almost always escaped
      continue;
    }
    const uint32_t slot = rng() & ((1u << set.precision()) - 1);
    size_t s = 0;
    while (t.cdf[s + 1] <= slot) ++s;
    out[i] = int32_t(int64_t(t.offset) + int64_t(s));  // s == n gives offset + n: an escape
  }
  return out;
}

TEST(QuantizePmf, EverySymbolGetsACountAndTheTotalIsExact) {
  for (int precision : {12, 16, 24}) {
    const std::vector<double> pmf = {0.0, 1e-30, 0.5, 0.25, 0.0, 0.25 - 1e-9, 1e-9};
    auto cdf = quantize_pmf(pmf, precision);
    ASSERT_TRUE(cdf.ok()) << cdf.status().message();
    ASSERT_EQ(cdf->size(), pmf.size() + 1);
    EXPECT_EQ(cdf->front(), 0u);
    EXPECT_EQ(cdf->back(), 1u << precision);
    for (size_t i = 0; i < pmf.size(); ++i) EXPECT_GE((*cdf)[i + 1] - (*cdf)[i], 1u);
    EXPECT_TRUE(validate_cdf(cdf.value(), precision).ok());
    // The big symbol keeps about half the mass.
    EXPECT_NEAR(double((*cdf)[3] - (*cdf)[2]) / (1 << precision), 0.5, 1e-3);
  }
}

TEST(QuantizePmf, MaxSizeTableHasOneCountPerSymbol) {
  std::vector<double> pmf(1 << 12, 1.0);
  auto cdf = quantize_pmf(pmf, 12);
  ASSERT_TRUE(cdf.ok()) << cdf.status().message();
  for (size_t i = 0; i < pmf.size(); ++i) EXPECT_EQ((*cdf)[i + 1] - (*cdf)[i], 1u);
  pmf.push_back(1.0);  // one symbol too many
  EXPECT_EQ(quantize_pmf(pmf, 12).status().code(), StatusCode::kInvalidArgument);
}

TEST(QuantizePmf, RefusesBadInput) {
  const double nan = std::numeric_limits<double>::quiet_NaN();
  const double inf = std::numeric_limits<double>::infinity();
  EXPECT_FALSE(quantize_pmf({}).ok());
  EXPECT_FALSE(quantize_pmf({0.5, -0.1}).ok());
  EXPECT_FALSE(quantize_pmf({0.5, nan}).ok());
  EXPECT_FALSE(quantize_pmf({0.5, inf}).ok());
  EXPECT_FALSE(quantize_pmf({0.0, 0.0}).ok());
  EXPECT_FALSE(quantize_pmf({0.5, 0.5}, 11).ok());
  EXPECT_FALSE(quantize_pmf({0.5, 0.5}, 25).ok());
}

TEST(ValidateCdf, FindsEachDefect) {
  EXPECT_TRUE(validate_cdf({0, 100, 65536}).ok());
  EXPECT_FALSE(validate_cdf({0}).ok());
  EXPECT_FALSE(validate_cdf({1, 100, 65536}).ok());       // does not start at 0
  EXPECT_FALSE(validate_cdf({0, 100, 100, 65536}).ok());  // zero-count symbol
  EXPECT_FALSE(validate_cdf({0, 200, 100, 65536}).ok());  // decreasing
  EXPECT_FALSE(validate_cdf({0, 100, 65535}).ok());       // does not end at 2^16
  const Status st = validate_cdf({0, 5, 5, 65536});
  EXPECT_NE(st.message().find("entry 2"), std::string::npos) << st.message();
}

TEST(CdfTableSet, RefusesBadTablesNamingThem) {
  CdfTable good = table_from_pmf({0.5, 0.5}, 0);
  CdfTable bad;
  bad.cdf = {0, 10, 10, 65536};
  auto set = CdfTableSet::create({good, bad});
  ASSERT_FALSE(set.ok());
  EXPECT_EQ(set.status().code(), StatusCode::kInvalidArgument);
  EXPECT_NE(set.status().message().find("table 1"), std::string::npos);
  CdfTable only_escape;
  only_escape.cdf = {0, 65536};
  EXPECT_FALSE(CdfTableSet::create({only_escape}).ok());
  CdfTable overflow = good;
  overflow.offset = kI32Max;  // offset + 1 does not fit int32
  EXPECT_FALSE(CdfTableSet::create({overflow}).ok());
  EXPECT_FALSE(CdfTableSet::create({good}, 16).value().size() != 1);
  EXPECT_FALSE(CdfTableSet::create({good}, 12).ok());  // table was built at 16 bits
}

TEST(RangeCoder, RoundTripRandomTables) {
  std::mt19937 rng(1234);
  for (int precision : {12, 16, 20, 24}) {
    std::vector<CdfTable> tables;
    for (int t = 0; t < 20; ++t) {
      const size_t n = 1 + rng() % 300;
      std::vector<double> pmf(n);
      for (auto& p : pmf) p = (rng() % 4 == 0) ? 0.0 : std::exp(-double(rng() % 2000) / 100.0);
      tables.push_back(table_from_pmf(pmf, int32_t(rng() % 1000) - 500, precision));
    }
    const CdfTableSet set = make_set(tables, precision);
    std::vector<uint32_t> idx(50000);
    for (auto& i : idx) i = rng() % set.size();
    expect_round_trip(sample(idx, set, rng, 0.01), idx, set);
  }
}

TEST(RangeCoder, AdversarialTables) {
  std::mt19937 rng(7);
  // One symbol with almost all the mass; the rare symbols still round-trip.
  std::vector<double> peaked(50, 1e-15);
  peaked[25] = 1.0 - 49e-15;
  // Uniform, tiny (1 symbol + escape, 2 symbols + escape), and the largest possible table
  // (2^16 - 1 symbols + escape, one count each).
  const std::vector<double> uniform(257, 1.0 / 257);
  const std::vector<double> tiny1 = {1.0};
  const std::vector<double> tiny2 = {0.3, 0.7};
  const std::vector<double> max_size((1 << 16) - 1, 1.0);
  const CdfTableSet set =
      make_set({table_from_pmf(peaked, -25), table_from_pmf(uniform, 0), table_from_pmf(tiny1, 3),
                table_from_pmf(tiny2, -1), table_from_pmf(max_size, -30000)});
  EXPECT_EQ(set.table(4).cdf.size(), size_t(1) << 16 | 1);
  for (uint32_t t = 0; t < set.size(); ++t) {
    std::vector<uint32_t> idx(20000, t);
    // Uniform over the table range and a bit beyond, so rare symbols and escapes all occur.
    const CdfTable& tab = set.table(t);
    std::vector<int32_t> sym(idx.size());
    for (auto& s : sym) s = tab.offset - 2 + int32_t(rng() % (tab.num_symbols() + 4));
    expect_round_trip(sym, idx, set);
    // Mostly the probable symbols, as real data would be.
    expect_round_trip(sample(idx, set, rng, 0.0), idx, set);
  }
}

TEST(RangeCoder, PeakedTableCostsAlmostNothing) {
  std::vector<double> peaked(11, 1e-12);
  peaked[5] = 1.0;
  const CdfTableSet set = make_set({table_from_pmf(peaked, -5)});
  const std::vector<int32_t> sym(100000, 0);
  const std::vector<uint32_t> idx(sym.size(), 0);
  auto enc = encode_symbols(sym, idx, set);
  ASSERT_TRUE(enc.ok());
  // 11 counts of 65536 go to the other symbols: ~0.00024 bits each, ~3 bytes in all.
  EXPECT_LT(enc->size(), 40u);
  expect_round_trip(sym, idx, set);
}

TEST(RangeCoder, EscapesCarryAnyInt32) {
  const CdfTableSet set = make_set({gaussian_table(2.0), table_from_pmf({0.5, 0.5}, kI32Min),
                                    table_from_pmf({0.5, 0.5}, kI32Max - 1)});
  const std::vector<int32_t> values = {kI32Min, kI32Min + 1, -1000000007, -13, -12, 12, 13,
                                       1 << 30, kI32Max - 1, kI32Max,     0,   -1,  1};
  for (uint32_t t = 0; t < set.size(); ++t) {
    const std::vector<uint32_t> idx(values.size(), t);
    expect_round_trip(values, idx, set);
  }
  // Escapes cost bits: an in-range value is cheaper than a huge one.
  const std::vector<uint32_t> idx1(1000, 0);
  auto small = encode_symbols(std::vector<int32_t>(1000, 0), idx1, set);
  auto huge = encode_symbols(std::vector<int32_t>(1000, kI32Max), idx1, set);
  ASSERT_TRUE(small.ok() && huge.ok());
  EXPECT_GT(huge->size(), small->size() + 1000 * 4);
}

TEST(RangeCoder, RefusesBadArguments) {
  const CdfTableSet set = make_set({gaussian_table(1.0)});
  EXPECT_EQ(encode_symbols({1, 2}, {0}, set).status().code(), StatusCode::kInvalidArgument);
  EXPECT_EQ(encode_symbols({1, 2}, {0, 1}, set).status().code(), StatusCode::kInvalidArgument);
  auto enc = encode_symbols({1, 2}, {0, 0}, set);
  ASSERT_TRUE(enc.ok());
  EXPECT_EQ(decode_symbols(enc.value(), {0, 5}, set).status().code(), StatusCode::kInvalidArgument);
}

TEST(RangeCoder, PlainStreamMustBeConsumedExactly) {
  const CdfTableSet set = make_set({gaussian_table(3.0)});
  std::vector<int32_t> sym(5000);
  for (size_t i = 0; i < sym.size(); ++i) sym[i] = int32_t(i % 9) - 4;
  const std::vector<uint32_t> idx(sym.size(), 0);
  auto enc = encode_symbols(sym, idx, set);
  ASSERT_TRUE(enc.ok());
  Bytes longer = enc.value();
  longer.insert(longer.end(), {0, 0, 0, 0});  // one extra word
  EXPECT_EQ(decode_symbols(longer, idx, set).status().code(), StatusCode::kCorruptBitstream);
  longer.push_back(0);  // not 8 + 4k bytes
  EXPECT_EQ(decode_symbols(longer, idx, set).status().code(), StatusCode::kCorruptBitstream);
  for (size_t len : {size_t(0), size_t(7), enc->size() - 4})
    EXPECT_EQ(decode_symbols(ByteSpan(enc->data(), len), idx, set).status().code(),
              StatusCode::kCorruptBitstream)
        << len;
  // Fewer symbols than coded leaves words unread.
  const std::vector<uint32_t> fewer(idx.begin(), idx.end() - 100);
  EXPECT_FALSE(decode_symbols(enc.value(), fewer, set).ok());
}

TEST(RangeCoder, EmptySequence) {
  const CdfTableSet set = make_set({gaussian_table(1.0)});
  expect_round_trip({}, {}, set);
  auto enc = ChunkedEncoder().encode({}, {}, set);
  ASSERT_TRUE(enc.ok());
  auto dec = ChunkedDecoder::decode(enc.value(), {}, set, 4);
  ASSERT_TRUE(dec.ok()) << dec.status().message();
  EXPECT_TRUE(dec->empty());
}

TEST(RangeCoder, FuzzedChunkedRoundTrips) {
  std::mt19937 rng(20240611);
  for (int iter = 0; iter < 150; ++iter) {
    const int precision = kMinPrecision + int(rng() % (kMaxPrecision - kMinPrecision + 1));
    std::vector<CdfTable> tables;
    const int n_tables = 1 + int(rng() % 8);
    for (int t = 0; t < n_tables; ++t) {
      const size_t n = 1 + rng() % std::min<size_t>(600, (size_t(1) << precision) - 1);
      std::vector<double> pmf(n);
      for (auto& p : pmf) p = double(rng() % 1000) * (rng() % 3 ? 1.0 : 1e-9);
      pmf[rng() % n] += 1.0;
      tables.push_back(table_from_pmf(pmf, int32_t(rng()) / 4, precision));
    }
    const CdfTableSet set = make_set(tables, precision);
    std::vector<uint32_t> idx(rng() % 5000);
    for (auto& i : idx) i = rng() % set.size();
    const std::vector<int32_t> sym = sample(idx, set, rng, 0.02);
    const uint32_t chunk = 1 + rng() % 1500;
    auto enc = ChunkedEncoder(chunk).encode(sym, idx, set);
    ASSERT_TRUE(enc.ok()) << enc.status().message();
    auto dec = ChunkedDecoder::decode(enc.value(), idx, set, 1 + int(rng() % 4));
    ASSERT_TRUE(dec.ok()) << "iter " << iter << ": " << dec.status().message();
    ASSERT_EQ(dec.value(), sym) << "iter " << iter;
  }
}

struct ChunkFixture {
  CdfTableSet set;
  std::vector<uint32_t> idx;
  std::vector<int32_t> sym;
};

ChunkFixture realistic(size_t n, uint32_t seed) {
  std::mt19937 rng(seed);
  std::vector<CdfTable> tables;
  for (int t = 0; t < 16; ++t) tables.push_back(gaussian_table(0.5 * std::pow(1.27, t)));
  ChunkFixture f{make_set(tables), std::vector<uint32_t>(n), {}};
  for (auto& i : f.idx) i = rng() % f.set.size();
  f.sym = sample(f.idx, f.set, rng, 0.001);
  return f;
}

TEST(ChunkedCoder, ChunksDecodeAlone) {
  const ChunkFixture f = realistic(35000, 1);
  auto enc = ChunkedEncoder(10000).encode(f.sym, f.idx, f.set);
  ASSERT_TRUE(enc.ok());
  auto info = ChunkedDecoder::parse(enc.value());
  ASSERT_TRUE(info.ok()) << info.status().message();
  ASSERT_EQ(info->chunks.size(), 4u);
  EXPECT_EQ(info->chunk_symbols(3), 5000u);
  for (size_t k : {2u, 0u, 3u}) {
    const size_t begin = k * 10000, len = info->chunk_symbols(k);
    const std::vector<uint32_t> idx(f.idx.begin() + begin, f.idx.begin() + begin + len);
    auto dec = ChunkedDecoder::decode_chunk(info.value(), k, idx, f.set);
    ASSERT_TRUE(dec.ok()) << dec.status().message();
    EXPECT_TRUE(std::equal(dec->begin(), dec->end(), f.sym.begin() + begin)) << "chunk " << k;
  }
  // Wrong index count or chunk number is refused.
  EXPECT_FALSE(ChunkedDecoder::decode_chunk(info.value(), 4, {}, f.set).ok());
  EXPECT_FALSE(ChunkedDecoder::decode_chunk(info.value(), 0, {0, 1}, f.set).ok());
}

TEST(ChunkedCoder, ResultDoesNotDependOnThreadCount) {
  const ChunkFixture f = realistic(53001, 2);
  auto enc1 = ChunkedEncoder(5000, 1).encode(f.sym, f.idx, f.set);
  auto enc3 = ChunkedEncoder(5000, 3).encode(f.sym, f.idx, f.set);
  ASSERT_TRUE(enc1.ok() && enc3.ok());
  EXPECT_EQ(enc1.value(), enc3.value());
  for (int threads : {1, 2, 3, 7, 0}) {
    auto dec = ChunkedDecoder::decode(enc1.value(), f.idx, f.set, threads);
    ASSERT_TRUE(dec.ok()) << dec.status().message();
    EXPECT_EQ(dec.value(), f.sym) << threads << " threads";
  }
}

TEST(ChunkedCoder, HeaderMismatchesAreRefused) {
  const ChunkFixture f = realistic(1000, 3);
  auto enc = ChunkedEncoder(300).encode(f.sym, f.idx, f.set);
  ASSERT_TRUE(enc.ok());
  std::vector<uint32_t> fewer(f.idx.begin(), f.idx.end() - 1);
  EXPECT_EQ(ChunkedDecoder::decode(enc.value(), fewer, f.set).status().code(),
            StatusCode::kCorruptBitstream);
  const CdfTableSet other = make_set({gaussian_table(1.0, 20)}, 20);
  const std::vector<uint32_t> zeros(f.idx.size(), 0);
  EXPECT_EQ(ChunkedDecoder::decode(enc.value(), zeros, other).status().code(),
            StatusCode::kCorruptBitstream);
}

TEST(ChunkedCoder, AbsurdCountsAreRefusedBeforeAllocating) {
  // Header claiming 2^60 symbols in chunks of 1: 2^60 chunk lengths cannot fit 20 bytes.
  ByteWriter w;
  w.put_u8(16);
  w.put_varint(uint64_t(1) << 60);
  w.put_varint(1);
  for (int i = 0; i < 20; ++i) w.put_u8(9);
  auto info = ChunkedDecoder::parse(w.bytes());
  EXPECT_EQ(info.status().code(), StatusCode::kCorruptBitstream);
  // Zero chunk size.
  ByteWriter z;
  z.put_u8(16);
  z.put_varint(10);
  z.put_varint(0);
  EXPECT_EQ(ChunkedDecoder::parse(z.bytes()).status().code(), StatusCode::kCorruptBitstream);
}

TEST(ChunkedCoder, TruncationAtEveryOffsetIsRefused) {
  const ChunkFixture f = realistic(700, 4);
  auto enc = ChunkedEncoder(200).encode(f.sym, f.idx, f.set);
  ASSERT_TRUE(enc.ok());
  for (size_t len = 0; len < enc->size(); ++len) {
    const ByteSpan cut(enc->data(), len);
    auto dec = ChunkedDecoder::decode(cut, f.idx, f.set, 2);
    ASSERT_FALSE(dec.ok()) << "truncated to " << len;
    EXPECT_EQ(dec.status().code(), StatusCode::kCorruptBitstream);
  }
}

TEST(ChunkedCoder, FlippedBitsAreDetected) {
  const ChunkFixture f = realistic(500, 5);
  auto enc = ChunkedEncoder(200).encode(f.sym, f.idx, f.set);
  ASSERT_TRUE(enc.ok());
  size_t detected = 0, total = 0;
  for (size_t byte = 0; byte < enc->size(); ++byte)
    for (int bit = 0; bit < 8; ++bit) {
      Bytes bad = enc.value();
      bad[byte] ^= uint8_t(1u << bit);
      auto dec = ChunkedDecoder::decode(bad, f.idx, f.set, 1);
      ++total;
      if (!dec.ok()) {
        EXPECT_EQ(dec.status().code(), StatusCode::kCorruptBitstream);
        ++detected;
      } else {
        // A stream that passes every check decodes to other symbols (rANS is a bijection).
        EXPECT_NE(dec.value(), f.sym) << "byte " << byte << " bit " << bit;
      }
    }
  // The final-state and length checks catch essentially every flip.
  EXPECT_GE(double(detected), 0.99 * double(total));
}

TEST(ChunkedCoder, RandomGarbageNeverCrashes) {
  const ChunkFixture f = realistic(3000, 6);
  std::mt19937 rng(99);
  int refused = 0;
  for (int iter = 0; iter < 300; ++iter) {
    Bytes junk(rng() % 200);
    for (auto& b : junk) b = uint8_t(rng());
    if (iter % 2 && junk.size() > 4) {  // a plausible header in front of the junk
      junk[0] = 16;
      junk[1] = uint8_t(f.idx.size() & 0x7f) | 0x80;
      junk[2] = uint8_t(f.idx.size() >> 7);
    }
    auto dec = ChunkedDecoder::decode(junk, f.idx, f.set, 2);
    if (!dec.ok()) {
      EXPECT_EQ(dec.status().code(), StatusCode::kCorruptBitstream);
      ++refused;
    }
    // Plain streams too.
    auto plain = decode_symbols(junk, f.idx, f.set);
    if (!plain.ok()) {
      EXPECT_EQ(plain.status().code(), StatusCode::kCorruptBitstream);
    }
  }
  EXPECT_EQ(refused, 300);
}

TEST(Bernoulli, RoundTripsAndCompresses) {
  std::mt19937 rng(11);
  for (double p : {0.0, 0.01, 0.3, 0.5, 0.97, 1.0}) {
    std::bernoulli_distribution b(p);
    std::vector<uint8_t> bits(100000);
    for (auto& x : bits) x = b(rng);
    auto enc = encode_bernoulli(bits);
    ASSERT_TRUE(enc.ok());
    auto dec = decode_bernoulli(enc.value(), bits.size());
    ASSERT_TRUE(dec.ok()) << dec.status().message();
    EXPECT_EQ(dec.value(), bits) << "p=" << p;
    // Within 1% + 64 bytes of the empirical entropy.
    const double q =
        std::clamp(double(std::count(bits.begin(), bits.end(), 1)) / bits.size(), 1e-5, 1 - 1e-5);
    const double h = -(q * std::log2(q) + (1 - q) * std::log2(1 - q)) * bits.size() / 8;
    EXPECT_LT(double(enc->size()), 1.01 * h + 64) << "p=" << p;
  }
}

TEST(Bernoulli, EdgeCasesAndCorruption) {
  auto empty = encode_bernoulli({});
  ASSERT_TRUE(empty.ok());
  auto dec = decode_bernoulli(empty.value(), 0);
  ASSERT_TRUE(dec.ok());
  EXPECT_TRUE(dec->empty());
  EXPECT_EQ(encode_bernoulli({0, 1, 2}).status().code(), StatusCode::kInvalidArgument);

  std::vector<uint8_t> bits(5000);
  for (size_t i = 0; i < bits.size(); ++i) bits[i] = (i * 7919) % 13 == 0;
  auto enc = encode_bernoulli(bits);
  ASSERT_TRUE(enc.ok());
  EXPECT_EQ(decode_bernoulli(enc.value(), 4999).status().code(), StatusCode::kCorruptBitstream);
  for (size_t len = 0; len < enc->size(); ++len)
    EXPECT_FALSE(decode_bernoulli(ByteSpan(enc->data(), len), bits.size()).ok()) << len;
  Bytes bad = enc.value();
  bad[bad.size() / 2] ^= 0x10;
  EXPECT_FALSE(decode_bernoulli(bad, bits.size()).ok());
}

}  // namespace
}  // namespace crpgs::coding

namespace crpgs::coding {
namespace {

// Golden: the stream format and the integer tables are part of the bitstream version. A change
// here means old files no longer decode: bump the container version instead of the constant.
// Inputs use only IEEE-exact arithmetic and raw mt19937 output (both fully specified).
TEST(RangeCoderGolden, ChunkedAndBernoulliStreamsAreStable) {
  std::vector<CdfTable> tables;
  for (int t = 0; t < 4; ++t) {
    std::vector<double> pmf(9 + 4 * t);
    for (size_t i = 0; i < pmf.size(); ++i) {
      const double d = double(i) - double(pmf.size() / 2);
      pmf[i] = 1.0 / (1.0 + d * d * (t + 1));
    }
    double sum = 0;
    for (double p : pmf) sum += p;
    for (double& p : pmf) p *= 0.999 / sum;
    tables.push_back(make_cdf_table(pmf, -int32_t(pmf.size() / 2)).value());
  }
  const CdfTableSet set = CdfTableSet::create(tables).value();
  std::mt19937 rng(2024);
  std::vector<uint32_t> idx(25000);
  std::vector<int32_t> sym(idx.size());
  for (size_t i = 0; i < idx.size(); ++i) {
    idx[i] = rng() % 4;
    sym[i] = int32_t(rng() % 11) - 5;
    if (i % 997 == 0) sym[i] = int32_t(rng());  // escapes
  }
  auto enc = ChunkedEncoder(10000).encode(sym, idx, set);
  ASSERT_TRUE(enc.ok());
  EXPECT_EQ(enc->size(), 16560u);
  EXPECT_EQ(crc32(enc.value()), 2948501301u);
  std::vector<uint8_t> bits(10000);
  for (auto& b : bits) b = rng() % 7 == 0;
  auto bern = encode_bernoulli(bits);
  ASSERT_TRUE(bern.ok());
  EXPECT_EQ(bern->size(), 726u);
  EXPECT_EQ(crc32(bern.value()), 661291671u);
}

}  // namespace
}  // namespace crpgs::coding
