/// @file test_bitstream.cpp
/// @brief ByteWriter/ByteReader, CRC32 and the .crpgs container, including every corruption the
/// decoder must refuse.
#include <gtest/gtest.h>

#include <cmath>
#include <cstring>
#include <filesystem>
#include <limits>

#include "crpgs/coding/bitstream.h"

namespace crpgs::coding {
namespace {

TEST(ByteIo, RoundTripsEveryType) {
  ByteWriter w;
  w.put_u8(0xab);
  w.put_u16(0xbeef);
  w.put_u32(0xdeadbeef);
  w.put_u64(0x0123456789abcdefull);
  w.put_i32(-2);
  w.put_i64(std::numeric_limits<int64_t>::min());
  w.put_f32(-1.5f);
  w.put_f64(std::nan(""));
  for (uint64_t v : {uint64_t(0), uint64_t(127), uint64_t(128), ~uint64_t(0)}) w.put_varint(v);
  for (int64_t v : {int64_t(0), int64_t(-1), std::numeric_limits<int64_t>::min(),
                    std::numeric_limits<int64_t>::max()})
    w.put_svarint(v);
  w.put_string("hello");
  // Little-endian on the wire.
  EXPECT_EQ(w.bytes()[1], 0xef);
  EXPECT_EQ(w.bytes()[2], 0xbe);

  ByteReader r(w.bytes());
  uint8_t u8;
  uint16_t u16;
  uint32_t u32;
  uint64_t u64;
  int32_t i32;
  int64_t i64;
  float f32;
  double f64;
  std::string s;
  ASSERT_TRUE(r.read_u8(&u8).ok());
  ASSERT_TRUE(r.read_u16(&u16).ok());
  ASSERT_TRUE(r.read_u32(&u32).ok());
  ASSERT_TRUE(r.read_u64(&u64).ok());
  ASSERT_TRUE(r.read_i32(&i32).ok());
  ASSERT_TRUE(r.read_i64(&i64).ok());
  ASSERT_TRUE(r.read_f32(&f32).ok());
  ASSERT_TRUE(r.read_f64(&f64).ok());
  EXPECT_EQ(u8, 0xab);
  EXPECT_EQ(u16, 0xbeef);
  EXPECT_EQ(u32, 0xdeadbeefu);
  EXPECT_EQ(u64, 0x0123456789abcdefull);
  EXPECT_EQ(i32, -2);
  EXPECT_EQ(i64, std::numeric_limits<int64_t>::min());
  EXPECT_EQ(f32, -1.5f);
  EXPECT_TRUE(std::isnan(f64));
  for (uint64_t v : {uint64_t(0), uint64_t(127), uint64_t(128), ~uint64_t(0)}) {
    ASSERT_TRUE(r.read_varint(&u64).ok());
    EXPECT_EQ(u64, v);
  }
  for (int64_t v : {int64_t(0), int64_t(-1), std::numeric_limits<int64_t>::min(),
                    std::numeric_limits<int64_t>::max()}) {
    ASSERT_TRUE(r.read_svarint(&i64).ok());
    EXPECT_EQ(i64, v);
  }
  ASSERT_TRUE(r.read_string(&s).ok());
  EXPECT_EQ(s, "hello");
  EXPECT_TRUE(r.at_end());
}

TEST(ByteIo, ReadsPastTheEndFailWithoutMoving) {
  const Bytes b = {1, 2, 3};
  ByteReader r(b, "test blob");
  uint32_t v = 77;
  const Status st = r.read_u32(&v);
  EXPECT_EQ(st.code(), StatusCode::kCorruptBitstream);
  EXPECT_NE(st.message().find("test blob"), std::string::npos) << st.message();
  EXPECT_EQ(v, 77u);
  EXPECT_EQ(r.position(), 0u);
  uint16_t h;
  EXPECT_TRUE(r.read_u16(&h).ok());
  EXPECT_FALSE(r.skip(2).ok());
  ByteSpan span;
  EXPECT_FALSE(r.read_span(5, &span).ok());
}

TEST(ByteIo, RefusesMalformedVarintsAndStrings) {
  const Bytes overlong(11, 0x80);
  ByteReader r1(overlong);
  uint64_t v;
  EXPECT_FALSE(r1.read_varint(&v).ok());
  const Bytes overflow = {0xff, 0xff, 0xff, 0xff, 0xff, 0xff, 0xff, 0xff, 0xff, 0x02};
  ByteReader r2(overflow);
  EXPECT_FALSE(r2.read_varint(&v).ok());
  const Bytes unterminated = {0x80, 0x80};
  ByteReader r3(unterminated);
  EXPECT_FALSE(r3.read_varint(&v).ok());
  ByteWriter w;
  w.put_varint(1000);  // string length beyond the data
  w.put_u8('x');
  ByteReader r4(w.bytes());
  std::string s;
  EXPECT_FALSE(r4.read_string(&s).ok());
  EXPECT_EQ(r4.position(), 0u);
}

TEST(Crc32, MatchesZlibCheckValue) {
  const char* check = "123456789";
  EXPECT_EQ(crc32(ByteSpan(reinterpret_cast<const uint8_t*>(check), 9)), 0xCBF43926u);
  // Chaining equals one pass.
  const uint32_t part = crc32(ByteSpan(reinterpret_cast<const uint8_t*>(check), 4));
  EXPECT_EQ(crc32(ByteSpan(reinterpret_cast<const uint8_t*>(check) + 4, 5), part), 0xCBF43926u);
}

Bytes payload(size_t n, uint8_t seed) {
  Bytes b(n);
  for (size_t i = 0; i < n; ++i) b[i] = uint8_t(seed + i * 31);
  return b;
}

ContainerWriter sample_writer() {
  ContainerWriter w(0x1122334455667788ull, 5);
  EXPECT_TRUE(w.add_section("HEAD", "crpgs.core", 1, 0, payload(10, 1)).ok());
  EXPECT_TRUE(w.add_section("GEOM", "crpgs.geometry.draco", 1, 2, payload(40, 2)).ok());
  EXPECT_TRUE(w.add_section("MASK", "crpgs.mask", 0, 1, Bytes()).ok());
  return w;
}

TEST(Container, RoundTrip) {
  const Bytes file = sample_writer().finish();
  auto c = ContainerReader::parse(file);
  ASSERT_TRUE(c.ok()) << c.status().message();
  EXPECT_EQ(c->header.major, kContainerMajorVersion);
  EXPECT_EQ(c->header.minor, kContainerMinorVersion);
  EXPECT_EQ(c->header.flags, 5u);
  EXPECT_EQ(c->header.config_hash, 0x1122334455667788ull);
  ASSERT_EQ(c->sections.size(), 3u);
  EXPECT_EQ(c->sections[1].id, "GEOM");
  EXPECT_EQ(c->sections[1].component_id, "crpgs.geometry.draco");
  EXPECT_EQ(c->sections[1].component_major, 1);
  EXPECT_EQ(c->sections[1].component_minor, 2);
  EXPECT_EQ(c->sections[1].payload, payload(40, 2));
  EXPECT_TRUE(c->sections[2].payload.empty());
  ASSERT_NE(c->find("MASK"), nullptr);
  EXPECT_EQ(c->find("MASK", "other"), nullptr);
  EXPECT_EQ(c->find("NONE"), nullptr);
  // Per-section sizes add up to the file (for `crpgs info`).
  uint64_t sum = kContainerHeaderSize;
  for (const Section& s : c->sections) sum += s.file_size;
  EXPECT_EQ(sum, file.size());
  EXPECT_EQ(c->sections[0].file_offset, kContainerHeaderSize);
  EXPECT_EQ(c->file_size, file.size());
}

// Golden: the container layout is versioned; a change must bump kContainerMajorVersion.
TEST(Container, LayoutIsStable) {
  const Bytes file = sample_writer().finish();
  ASSERT_EQ(file.size(), 181u);
  EXPECT_EQ(std::string(file.begin(), file.begin() + 6), std::string("CRPG\x01\x00", 6));
  EXPECT_EQ(crc32(file), 2249644634u);
}

TEST(Container, WriterRefusesBadSections) {
  ContainerWriter w;
  EXPECT_EQ(w.add_section("GEO", "c", 1, 0, {}).code(), StatusCode::kInvalidArgument);
  EXPECT_EQ(w.add_section("GE\nO", "c", 1, 0, {}).code(), StatusCode::kInvalidArgument);
  EXPECT_EQ(w.add_section("GEOM", "", 1, 0, {}).code(), StatusCode::kInvalidArgument);
  EXPECT_EQ(w.add_section("GEOM", std::string(256, 'a'), 1, 0, {}).code(),
            StatusCode::kInvalidArgument);
  EXPECT_TRUE(w.add_section("GEOM", "c", 1, 0, {}).ok());
  EXPECT_EQ(w.add_section("GEOM", "c", 1, 0, {}).code(), StatusCode::kInvalidArgument);
  EXPECT_TRUE(w.add_section("GEOM", "d", 1, 0, {}).ok());
}

// Rewrites the header fields and fixes the header CRC, as a future writer would.
void set_version(Bytes* file, uint16_t major, uint16_t minor) {
  (*file)[4] = uint8_t(major);
  (*file)[5] = uint8_t(major >> 8);
  (*file)[6] = uint8_t(minor);
  (*file)[7] = uint8_t(minor >> 8);
  const uint32_t crc = crc32(ByteSpan(file->data(), 24));
  for (int i = 0; i < 4; ++i) (*file)[24 + i] = uint8_t(crc >> (8 * i));
}

TEST(Container, RefusesWrongMagic) {
  Bytes file = sample_writer().finish();
  file[0] = 'X';
  auto c = ContainerReader::parse(file);
  EXPECT_EQ(c.status().code(), StatusCode::kCorruptBitstream);
  EXPECT_NE(c.status().message().find("magic"), std::string::npos);
  EXPECT_FALSE(ContainerReader::parse(Bytes{'C', 'R'}).ok());
}

TEST(Container, RefusesFutureMajorAcceptsNewerMinor) {
  Bytes file = sample_writer().finish();
  set_version(&file, kContainerMajorVersion + 1, 0);
  auto c = ContainerReader::parse(file);
  EXPECT_EQ(c.status().code(), StatusCode::kUnsupportedVersion);
  EXPECT_NE(c.status().message().find("version 2.0"), std::string::npos) << c.status().message();
  set_version(&file, kContainerMajorVersion, kContainerMinorVersion + 3);
  auto ok = ContainerReader::parse(file);
  ASSERT_TRUE(ok.ok()) << ok.status().message();
  EXPECT_EQ(ok->header.minor, kContainerMinorVersion + 3);
}

TEST(Container, FlippedBitInEverySectionIsCaughtAndNamed) {
  const Bytes file = sample_writer().finish();
  auto c = ContainerReader::parse(file);
  ASSERT_TRUE(c.ok());
  for (const Section& s : c->sections) {
    for (uint64_t off = s.file_offset; off < s.file_offset + s.file_size; ++off) {
      Bytes bad = file;
      bad[off] ^= 0x04;
      auto r = ContainerReader::parse(bad);
      ASSERT_FALSE(r.ok()) << "flip at " << off << " in " << s.id;
      EXPECT_EQ(r.status().code(), StatusCode::kCorruptBitstream);
      EXPECT_NE(r.status().message().find("section"), std::string::npos) << r.status().message();
    }
    // A payload flip is reported as a CRC error of that very section.
    if (!s.payload.empty()) {
      Bytes bad = file;
      bad[s.file_offset + s.file_size - 1] ^= 0x80;
      auto r = ContainerReader::parse(bad);
      EXPECT_NE(r.status().message().find("'" + s.id + "'"), std::string::npos)
          << r.status().message();
      EXPECT_NE(r.status().message().find("CRC"), std::string::npos) << r.status().message();
    }
  }
  // Header flips (past the magic and version) break the header CRC.
  for (size_t off = 8; off < kContainerHeaderSize; ++off) {
    Bytes bad = file;
    bad[off] ^= 0x01;
    EXPECT_EQ(ContainerReader::parse(bad).status().code(), StatusCode::kCorruptBitstream) << off;
  }
}

TEST(Container, TruncationAtEveryOffsetIsRefused) {
  const Bytes file = sample_writer().finish();
  for (size_t len = 0; len < file.size(); ++len) {
    auto r = ContainerReader::parse(ByteSpan(file.data(), len));
    ASSERT_FALSE(r.ok()) << "truncated to " << len;
    EXPECT_EQ(r.status().code(), StatusCode::kCorruptBitstream);
  }
  Bytes longer = file;
  longer.push_back(0);
  EXPECT_NE(ContainerReader::parse(longer).status().message().find("trailing"), std::string::npos);
}

// A hand-built container whose single section claims `length` payload bytes (CRCs valid for
// what is there, so only the length check can refuse it).
Bytes container_with_length(uint64_t length, uint32_t n_sections = 1) {
  ByteWriter w;
  w.put_bytes(ByteSpan(reinterpret_cast<const uint8_t*>("CRPG"), 4));
  w.put_u16(kContainerMajorVersion);
  w.put_u16(kContainerMinorVersion);
  w.put_u32(0);
  w.put_u64(0);
  w.put_u32(n_sections);
  w.put_u32(crc32(ByteSpan(w.bytes().data(), w.size())));
  const size_t start = w.size();
  w.put_bytes(ByteSpan(reinterpret_cast<const uint8_t*>("FEAT"), 4));
  w.put_u8(1);
  w.put_u8('x');
  w.put_u16(1);
  w.put_u16(0);
  w.put_u64(length);
  const Bytes body = payload(16, 9);
  w.put_u32(crc32(body, crc32(ByteSpan(w.bytes().data() + start, w.size() - start))));
  w.put_bytes(body);
  return w.take();
}

TEST(Container, SectionLengthBeyondFileIsRefused) {
  ASSERT_TRUE(ContainerReader::parse(container_with_length(16)).ok());
  for (uint64_t len : {uint64_t(17), uint64_t(1) << 32, ~uint64_t(0)}) {
    auto r = ContainerReader::parse(container_with_length(len));
    EXPECT_EQ(r.status().code(), StatusCode::kCorruptBitstream);
    EXPECT_NE(r.status().message().find("'FEAT'"), std::string::npos) << r.status().message();
    EXPECT_NE(r.status().message().find("exceeds"), std::string::npos) << r.status().message();
  }
}

TEST(Container, AbsurdSectionCountIsRefused) {
  for (uint32_t n : {2u, 1000u, 0xffffffffu}) {
    auto r = ContainerReader::parse(container_with_length(16, n));
    EXPECT_EQ(r.status().code(), StatusCode::kCorruptBitstream) << n;
  }
}

TEST(Container, WritesFilesAtomically) {
  namespace fs = std::filesystem;
  const fs::path dir = fs::path(CRPGS_TEST_TMP_DIR) / "coding_container";
  fs::remove_all(dir);
  const std::string path = (dir / "scene.crpgs").string();
  const ContainerWriter w = sample_writer();
  ASSERT_TRUE(w.write_file(path).ok());
  auto c = ContainerReader::read_file(path);
  ASSERT_TRUE(c.ok()) << c.status().message();
  EXPECT_EQ(c->sections.size(), 3u);
  EXPECT_EQ(fs::file_size(path), w.finish().size());
  size_t files = 0;
  for (const auto& e : fs::directory_iterator(dir)) files += e.is_regular_file();
  EXPECT_EQ(files, 1u);  // no temporary left behind
  EXPECT_EQ(ContainerReader::read_file((dir / "missing.crpgs").string()).status().code(),
            StatusCode::kIoError);
}

}  // namespace
}  // namespace crpgs::coding
