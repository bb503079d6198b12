/// @file bitstream.h
/// @brief Byte-level I/O (little-endian ints, floats, varints; bounds-checked reads), CRC32 and
/// the versioned `.crpgs` container: magic, version, flags, config hash, then CRC-protected
/// sections, each tagged with a section id (4CC) and the writing component's id and version.
///
/// Container layout (all integers little-endian):
///   "CRPG" | u16 major | u16 minor | u32 flags | u64 config_hash | u32 n_sections | u32 header_crc
///   then n_sections times:
///     4 bytes section id (4CC, printable ASCII) | u8 len + component id (1..255 chars)
///     | u16 comp_major | u16 comp_minor | u64 payload_length | u32 crc | payload
/// header_crc is zlib's crc32 of the 24 bytes before it. A section's crc covers its own header
/// fields (id .. payload_length) and its payload, so a flipped bit anywhere is caught.
#pragma once

#include <cstddef>
#include <cstdint>
#include <string>
#include <vector>

#include "crpgs/status.h"

namespace crpgs::coding {

using Bytes = std::vector<uint8_t>;

/// A read-only view of bytes (C++17 has no std::span). Does not own the data.
struct ByteSpan {
  const uint8_t* data = nullptr;
  size_t size = 0;
  ByteSpan() = default;
  ByteSpan(const uint8_t* d, size_t n) : data(d), size(n) {}
  ByteSpan(const Bytes& b) : data(b.data()), size(b.size()) {}  // NOLINT(runtime/explicit)
  ByteSpan subspan(size_t offset, size_t n) const { return ByteSpan(data + offset, n); }
};

/// zlib's crc32 (polynomial 0xEDB88320); `crc` chains a previous value (0 to start).
uint32_t crc32(ByteSpan bytes, uint32_t crc = 0);

/// Appends little-endian values to a growing byte vector. Never fails.
class ByteWriter {
 public:
  void put_u8(uint8_t v) { bytes_.push_back(v); }
  void put_u16(uint16_t v);
  void put_u32(uint32_t v);
  void put_u64(uint64_t v);
  void put_i32(int32_t v) { put_u32(static_cast<uint32_t>(v)); }
  void put_i64(int64_t v) { put_u64(static_cast<uint64_t>(v)); }
  void put_f32(float v);  ///< IEEE-754 bits, little-endian.
  void put_f64(double v);
  void put_varint(uint64_t v);  ///< LEB128: 7 bits per byte, at most 10 bytes.
  void put_svarint(int64_t v);  ///< zigzag then LEB128.
  void put_bytes(ByteSpan b);
  /// varint length, then the characters.
  void put_string(const std::string& s);

  size_t size() const { return bytes_.size(); }
  const Bytes& bytes() const { return bytes_; }
  Bytes take() { return std::move(bytes_); }

 private:
  Bytes bytes_;
};

/// Reads little-endian values from a ByteSpan. Every read checks the remaining length and returns
/// kCorruptBitstream naming `what` (e.g. "section 'GEOM'") and the offset when it runs out;
/// on failure the output is left unchanged and the position does not move.
class ByteReader {
 public:
  explicit ByteReader(ByteSpan bytes, std::string what = "stream")
      : bytes_(bytes), what_(std::move(what)) {}

  Status read_u8(uint8_t* v);
  Status read_u16(uint16_t* v);
  Status read_u32(uint32_t* v);
  Status read_u64(uint64_t* v);
  Status read_i32(int32_t* v);
  Status read_i64(int64_t* v);
  Status read_f32(float* v);
  Status read_f64(double* v);
  /// Refuses encodings longer than 10 bytes or overflowing 64 bits.
  Status read_varint(uint64_t* v);
  Status read_svarint(int64_t* v);
  /// A view of the next n bytes (no copy); fails if fewer than n remain.
  Status read_span(size_t n, ByteSpan* out);
  Status read_bytes(size_t n, Bytes* out);
  /// varint length (at most max_len, and at most remaining()), then the characters.
  Status read_string(std::string* s, size_t max_len = 1 << 20);
  Status skip(size_t n);

  size_t position() const { return pos_; }
  size_t remaining() const { return bytes_.size - pos_; }
  bool at_end() const { return pos_ == bytes_.size; }
  /// The part not read yet.
  ByteSpan rest() const { return bytes_.subspan(pos_, remaining()); }
  /// kCorruptBitstream "<what>: <message> (at byte <pos>)", for callers' own checks.
  Status error(const std::string& message) const;
  const std::string& what() const { return what_; }

 private:
  Status need(size_t n, const char* reading);
  ByteSpan bytes_;
  size_t pos_ = 0;
  std::string what_;
};

// ---------------------------------------------------------------------------------------------
// Container

inline constexpr char kContainerMagic[4] = {'C', 'R', 'P', 'G'};
/// Format version this build writes. A reader accepts any minor of its own major and refuses
/// other majors with kUnsupportedVersion; new fields are gated on the minor version.
inline constexpr uint16_t kContainerMajorVersion = 1;
inline constexpr uint16_t kContainerMinorVersion = 0;
/// Fixed header size (magic .. header_crc).
inline constexpr size_t kContainerHeaderSize = 28;
/// Smallest possible section header (4CC, 1-char component id, versions, length, crc).
inline constexpr size_t kMinSectionHeaderSize = 4 + 2 + 4 + 8 + 4;
/// More sections than this is refused as absurd.
inline constexpr uint32_t kMaxSections = 1u << 16;

struct ContainerHeader {
  uint16_t major = kContainerMajorVersion;
  uint16_t minor = kContainerMinorVersion;
  uint32_t flags = 0;
  uint64_t config_hash = 0;
};

struct Section {
  std::string id;            ///< exactly 4 printable ASCII characters, e.g. "GEOM"
  std::string component_id;  ///< 1..255 characters, e.g. "crpgs.geometry.draco"
  uint16_t component_major = 0;
  uint16_t component_minor = 0;
  Bytes payload;
  /// Filled by the reader: where the section's header starts in the file, and its total size
  /// on disk (header + payload), for `crpgs info`.
  uint64_t file_offset = 0;
  uint64_t file_size = 0;
};

/// Builds a container in memory. Sections keep the order they were added in.
class ContainerWriter {
 public:
  explicit ContainerWriter(uint64_t config_hash = 0, uint32_t flags = 0);

  /// Refuses (kInvalidArgument) an id that is not 4 printable ASCII characters, an empty or
  /// over-long component id, or a duplicate (id, component_id) pair.
  Status add_section(Section section);
  Status add_section(const std::string& id, const std::string& component_id, uint16_t major,
                     uint16_t minor, Bytes payload);

  /// The complete container.
  Bytes finish() const;
  /// finish(), written atomically (temporary file + rename).
  Status write_file(const std::string& path) const;

  const std::vector<Section>& sections() const { return sections_; }

 private:
  ContainerHeader header_;
  std::vector<Section> sections_;
};

/// A parsed container: the header and the sections in file order (payloads copied).
struct Container {
  ContainerHeader header;
  std::vector<Section> sections;
  uint64_t file_size = 0;

  /// First section with this id (and component id, if not empty); nullptr if none.
  const Section* find(const std::string& id, const std::string& component_id = "") const;
};

class ContainerReader {
 public:
  /// Parses and checks everything. Errors: kCorruptBitstream for a wrong magic, bad header CRC,
  /// absurd section count, truncated or over-long section, bad section CRC, malformed id,
  /// duplicate section, trailing bytes; kUnsupportedVersion for another major version. Messages
  /// name the section (index and id) and the byte offset.
  static StatusOr<Container> parse(ByteSpan bytes);
  /// Reads the file, then parse(); kIoError if it cannot be read.
  static StatusOr<Container> read_file(const std::string& path);
};

/// True if `id` is 4 printable ASCII characters.
bool is_valid_section_id(const std::string& id);

}  // namespace crpgs::coding
