/// @file bitstream.cpp
/// @brief ByteWriter/ByteReader, CRC32 (zlib) and the `.crpgs` container.
#include "crpgs/coding/bitstream.h"

#include <zlib.h>

#include <cstring>
#include <set>
#include <utility>

#include "crpgs/atomic_file.h"

namespace crpgs::coding {

uint32_t crc32(ByteSpan bytes, uint32_t crc) {
  // zlib takes uInt lengths; feed large buffers in pieces.
  uLong c = crc;
  size_t done = 0;
  while (done < bytes.size) {
    const size_t n = std::min<size_t>(bytes.size - done, 1u << 30);
    c = ::crc32(c, bytes.data + done, static_cast<uInt>(n));
    done += n;
  }
  return static_cast<uint32_t>(c);
}

// --- ByteWriter ------------------------------------------------------------------------------

void ByteWriter::put_u16(uint16_t v) {
  put_u8(uint8_t(v));
  put_u8(uint8_t(v >> 8));
}
void ByteWriter::put_u32(uint32_t v) {
  for (int i = 0; i < 4; ++i) put_u8(uint8_t(v >> (8 * i)));
}
void ByteWriter::put_u64(uint64_t v) {
  for (int i = 0; i < 8; ++i) put_u8(uint8_t(v >> (8 * i)));
}
void ByteWriter::put_f32(float v) {
  uint32_t u;
  std::memcpy(&u, &v, 4);
  put_u32(u);
}
void ByteWriter::put_f64(double v) {
  uint64_t u;
  std::memcpy(&u, &v, 8);
  put_u64(u);
}
void ByteWriter::put_varint(uint64_t v) {
  while (v >= 0x80) {
    put_u8(uint8_t(v | 0x80));
    v >>= 7;
  }
  put_u8(uint8_t(v));
}
void ByteWriter::put_svarint(int64_t v) {
  put_varint((static_cast<uint64_t>(v) << 1) ^ static_cast<uint64_t>(v >> 63));
}
void ByteWriter::put_bytes(ByteSpan b) {
  if (b.size) bytes_.insert(bytes_.end(), b.data, b.data + b.size);
}
void ByteWriter::put_string(const std::string& s) {
  put_varint(s.size());
  put_bytes(ByteSpan(reinterpret_cast<const uint8_t*>(s.data()), s.size()));
}

// --- ByteReader ------------------------------------------------------------------------------

Status ByteReader::error(const std::string& message) const {
  return Status(StatusCode::kCorruptBitstream,
                what_ + ": " + message + " (at byte " + std::to_string(pos_) + ")");
}

Status ByteReader::need(size_t n, const char* reading) {
  if (remaining() >= n) return OkStatus();
  return error(std::string("truncated: needs ") + std::to_string(n) + " bytes for " + reading +
               ", " + std::to_string(remaining()) + " left");
}

namespace {
template <typename T>
T load_le(const uint8_t* p) {
  T v = 0;
  for (size_t i = 0; i < sizeof(T); ++i) v |= T(p[i]) << (8 * i);
  return v;
}
}  // namespace

Status ByteReader::read_u8(uint8_t* v) {
  CRPGS_RETURN_IF_ERROR(need(1, "u8"));
  *v = bytes_.data[pos_++];
  return OkStatus();
}
Status ByteReader::read_u16(uint16_t* v) {
  CRPGS_RETURN_IF_ERROR(need(2, "u16"));
  *v = load_le<uint16_t>(bytes_.data + pos_);
  pos_ += 2;
  return OkStatus();
}
Status ByteReader::read_u32(uint32_t* v) {
  CRPGS_RETURN_IF_ERROR(need(4, "u32"));
  *v = load_le<uint32_t>(bytes_.data + pos_);
  pos_ += 4;
  return OkStatus();
}
Status ByteReader::read_u64(uint64_t* v) {
  CRPGS_RETURN_IF_ERROR(need(8, "u64"));
  *v = load_le<uint64_t>(bytes_.data + pos_);
  pos_ += 8;
  return OkStatus();
}
Status ByteReader::read_i32(int32_t* v) {
  uint32_t u;
  CRPGS_RETURN_IF_ERROR(read_u32(&u));
  *v = static_cast<int32_t>(u);
  return OkStatus();
}
Status ByteReader::read_i64(int64_t* v) {
  uint64_t u;
  CRPGS_RETURN_IF_ERROR(read_u64(&u));
  *v = static_cast<int64_t>(u);
  return OkStatus();
}
Status ByteReader::read_f32(float* v) {
  uint32_t u;
  CRPGS_RETURN_IF_ERROR(read_u32(&u));
  std::memcpy(v, &u, 4);
  return OkStatus();
}
Status ByteReader::read_f64(double* v) {
  uint64_t u;
  CRPGS_RETURN_IF_ERROR(read_u64(&u));
  std::memcpy(v, &u, 8);
  return OkStatus();
}
Status ByteReader::read_varint(uint64_t* v) {
  uint64_t out = 0;
  for (size_t i = 0; i < 10; ++i) {
    if (pos_ + i >= bytes_.size) return error("truncated varint");
    const uint8_t b = bytes_.data[pos_ + i];
    if (i == 9 && b > 1) return error("varint overflows 64 bits");
    out |= uint64_t(b & 0x7f) << (7 * i);
    if (!(b & 0x80)) {
      pos_ += i + 1;
      *v = out;
      return OkStatus();
    }
  }
  return error("varint longer than 10 bytes");
}
Status ByteReader::read_svarint(int64_t* v) {
  uint64_t u;
  CRPGS_RETURN_IF_ERROR(read_varint(&u));
  *v = static_cast<int64_t>((u >> 1) ^ (~(u & 1) + 1));
  return OkStatus();
}
Status ByteReader::read_span(size_t n, ByteSpan* out) {
  CRPGS_RETURN_IF_ERROR(need(n, "a byte block"));
  *out = bytes_.subspan(pos_, n);
  pos_ += n;
  return OkStatus();
}
Status ByteReader::read_bytes(size_t n, Bytes* out) {
  ByteSpan s;
  CRPGS_RETURN_IF_ERROR(read_span(n, &s));
  out->assign(s.data, s.data + s.size);
  return OkStatus();
}
Status ByteReader::read_string(std::string* s, size_t max_len) {
  const size_t start = pos_;
  uint64_t n;
  CRPGS_RETURN_IF_ERROR(read_varint(&n));
  if (n > max_len || n > remaining()) {
    const Status st = error("string length " + std::to_string(n) + " exceeds " +
                            (n > max_len ? "the limit" : "the remaining bytes"));
    pos_ = start;
    return st;
  }
  s->assign(reinterpret_cast<const char*>(bytes_.data + pos_), size_t(n));
  pos_ += size_t(n);
  return OkStatus();
}
Status ByteReader::skip(size_t n) {
  CRPGS_RETURN_IF_ERROR(need(n, "skip"));
  pos_ += n;
  return OkStatus();
}

// --- Container -------------------------------------------------------------------------------

bool is_valid_section_id(const std::string& id) {
  if (id.size() != 4) return false;
  for (char c : id)
    if (c < 0x21 || c > 0x7e) return false;
  return true;
}

ContainerWriter::ContainerWriter(uint64_t config_hash, uint32_t flags) {
  header_.config_hash = config_hash;
  header_.flags = flags;
}

Status ContainerWriter::add_section(Section s) {
  if (!is_valid_section_id(s.id))
    return Status(StatusCode::kInvalidArgument,
                  "section id '" + s.id + "' is not 4 printable ASCII characters");
  if (s.component_id.empty() || s.component_id.size() > 255)
    return Status(StatusCode::kInvalidArgument,
                  "section '" + s.id + "': component id must have 1..255 characters");
  for (const Section& o : sections_)
    if (o.id == s.id && o.component_id == s.component_id)
      return Status(StatusCode::kInvalidArgument,
                    "duplicate section '" + s.id + "' from component '" + s.component_id + "'");
  sections_.push_back(std::move(s));
  return OkStatus();
}

Status ContainerWriter::add_section(const std::string& id, const std::string& component_id,
                                    uint16_t major, uint16_t minor, Bytes payload) {
  Section s;
  s.id = id;
  s.component_id = component_id;
  s.component_major = major;
  s.component_minor = minor;
  s.payload = std::move(payload);
  return add_section(std::move(s));
}

namespace {
void put_section_header(ByteWriter& w, const Section& s) {
  w.put_bytes(ByteSpan(reinterpret_cast<const uint8_t*>(s.id.data()), 4));
  w.put_u8(uint8_t(s.component_id.size()));
  w.put_bytes(
      ByteSpan(reinterpret_cast<const uint8_t*>(s.component_id.data()), s.component_id.size()));
  w.put_u16(s.component_major);
  w.put_u16(s.component_minor);
  w.put_u64(s.payload.size());
}
}  // namespace

Bytes ContainerWriter::finish() const {
  ByteWriter w;
  w.put_bytes(ByteSpan(reinterpret_cast<const uint8_t*>(kContainerMagic), 4));
  w.put_u16(header_.major);
  w.put_u16(header_.minor);
  w.put_u32(header_.flags);
  w.put_u64(header_.config_hash);
  w.put_u32(uint32_t(sections_.size()));
  w.put_u32(crc32(ByteSpan(w.bytes().data(), w.size())));
  for (const Section& s : sections_) {
    const size_t start = w.size();
    put_section_header(w, s);
    uint32_t crc = crc32(ByteSpan(w.bytes().data() + start, w.size() - start));
    crc = crc32(s.payload, crc);
    w.put_u32(crc);
    w.put_bytes(s.payload);
  }
  return w.take();
}

Status ContainerWriter::write_file(const std::string& path) const {
  return write_file_atomic(path, finish());
}

const Section* Container::find(const std::string& id, const std::string& component_id) const {
  for (const Section& s : sections)
    if (s.id == id && (component_id.empty() || s.component_id == component_id)) return &s;
  return nullptr;
}

StatusOr<Container> ContainerReader::parse(ByteSpan bytes) {
  ByteReader r(bytes, "container header");
  Container c;
  c.file_size = bytes.size;
  if (bytes.size < 4 || std::memcmp(bytes.data, kContainerMagic, 4) != 0)
    return Status(StatusCode::kCorruptBitstream, "not a crpgs bitstream (magic is not 'CRPG')");
  if (bytes.size < kContainerHeaderSize)
    return r.error("truncated: file has " + std::to_string(bytes.size) + " bytes, header needs " +
                   std::to_string(kContainerHeaderSize));
  CRPGS_RETURN_IF_ERROR(r.skip(4));
  uint32_t n_sections = 0, header_crc = 0;
  CRPGS_RETURN_IF_ERROR(r.read_u16(&c.header.major));
  CRPGS_RETURN_IF_ERROR(r.read_u16(&c.header.minor));
  // Version before CRC: a future major may lay its header out differently.
  if (c.header.major != kContainerMajorVersion)
    return Status(StatusCode::kUnsupportedVersion,
                  "bitstream format version " + std::to_string(c.header.major) + "." +
                      std::to_string(c.header.minor) + " is not supported (this build reads " +
                      std::to_string(kContainerMajorVersion) + ".x)");
  CRPGS_RETURN_IF_ERROR(r.read_u32(&c.header.flags));
  CRPGS_RETURN_IF_ERROR(r.read_u64(&c.header.config_hash));
  CRPGS_RETURN_IF_ERROR(r.read_u32(&n_sections));
  const uint32_t expect_crc = crc32(ByteSpan(bytes.data, r.position()));
  CRPGS_RETURN_IF_ERROR(r.read_u32(&header_crc));
  if (header_crc != expect_crc) return r.error("header CRC mismatch");
  if (n_sections > kMaxSections || uint64_t(n_sections) * kMinSectionHeaderSize > r.remaining())
    return r.error("absurd section count " + std::to_string(n_sections) + " for " +
                   std::to_string(r.remaining()) + " remaining bytes");
  c.sections.reserve(n_sections);
  std::set<std::pair<std::string, std::string>> seen;
  for (uint32_t i = 0; i < n_sections; ++i) {
    const size_t start = r.position();
    ByteReader sr(bytes.subspan(start, bytes.size - start),
                  "section " + std::to_string(i) + " (at byte " + std::to_string(start) + ")");
    Section s;
    ByteSpan id;
    CRPGS_RETURN_IF_ERROR(sr.read_span(4, &id));
    s.id.assign(reinterpret_cast<const char*>(id.data), 4);
    if (!is_valid_section_id(s.id)) return sr.error("section id is not 4 printable characters");
    ByteReader hr(bytes.subspan(start, bytes.size - start), "section '" + s.id + "' (index " +
                                                                std::to_string(i) + ", at byte " +
                                                                std::to_string(start) + ")");
    CRPGS_RETURN_IF_ERROR(hr.skip(4));
    uint8_t id_len = 0;
    CRPGS_RETURN_IF_ERROR(hr.read_u8(&id_len));
    if (id_len == 0) return hr.error("empty component id");
    ByteSpan comp;
    CRPGS_RETURN_IF_ERROR(hr.read_span(id_len, &comp));
    s.component_id.assign(reinterpret_cast<const char*>(comp.data), comp.size);
    uint64_t length = 0;
    uint32_t crc = 0;
    CRPGS_RETURN_IF_ERROR(hr.read_u16(&s.component_major));
    CRPGS_RETURN_IF_ERROR(hr.read_u16(&s.component_minor));
    CRPGS_RETURN_IF_ERROR(hr.read_u64(&length));
    const size_t header_len = hr.position();
    CRPGS_RETURN_IF_ERROR(hr.read_u32(&crc));
    if (length > hr.remaining())
      return hr.error("payload length " + std::to_string(length) + " exceeds the " +
                      std::to_string(hr.remaining()) + " bytes left in the file");
    ByteSpan payload;
    CRPGS_RETURN_IF_ERROR(hr.read_span(size_t(length), &payload));
    const uint32_t expect = crc32(payload, crc32(bytes.subspan(start, header_len)));
    if (crc != expect) return hr.error("CRC mismatch (section is corrupt)");
    if (!seen.insert({s.id, s.component_id}).second)
      return hr.error("duplicate section from component '" + s.component_id + "'");
    s.payload.assign(payload.data, payload.data + payload.size);
    s.file_offset = start;
    s.file_size = hr.position();
    CRPGS_RETURN_IF_ERROR(r.skip(hr.position()));
    c.sections.push_back(std::move(s));
  }
  if (!r.at_end())
    return r.error(std::to_string(r.remaining()) + " trailing bytes after the last section");
  return c;
}

StatusOr<Container> ContainerReader::read_file(const std::string& path) {
  CRPGS_ASSIGN_OR_RETURN(Bytes bytes, read_file_bytes(path));
  auto c = parse(bytes);
  if (!c.ok()) return Status(c.status().code(), path + ": " + c.status().message());
  return c;
}

}  // namespace crpgs::coding
