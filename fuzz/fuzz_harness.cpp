/// @file fuzz_harness.cpp
#include "fuzz_harness.h"

#include <cstring>

#include "crpgs/codec.h"
#include "crpgs/coding/bitstream.h"
#include "crpgs/trainer.h"

namespace crpgs::fuzz {
namespace {

uint64_t get_le(const std::vector<uint8_t>& b, size_t at, int n) {
  uint64_t v = 0;
  for (int i = n - 1; i >= 0; --i) v = (v << 8) | b[at + size_t(i)];
  return v;
}

void put_le32(std::vector<uint8_t>* b, size_t at, uint32_t v) {
  for (int i = 0; i < 4; ++i) (*b)[at + size_t(i)] = uint8_t(v >> (8 * i));
}

/// GEOM (Draco): u8 format | varint n | i32 min[3] | u32 crc32(rest) | Draco bytes.
void reseal_draco(std::vector<uint8_t>* b, size_t begin, size_t end) {
  size_t p = begin + 1;
  for (int i = 0; i < 10 && p < end; ++i)
    if (!((*b)[p++] & 0x80)) break;
  p += 12;
  if (p + 4 > end) return;
  const coding::ByteSpan rest(b->data() + p + 4, end - p - 4);
  put_le32(b, p, coding::crc32(rest));
}

}  // namespace

std::vector<uint8_t> reseal(const uint8_t* data, size_t size) {
  std::vector<uint8_t> b(data, data + size);
  if (size < coding::kContainerHeaderSize || std::memcmp(data, coding::kContainerMagic, 4) != 0)
    return b;
  const uint64_t n_sections = get_le(b, 20, 4);
  put_le32(&b, 24, coding::crc32(coding::ByteSpan(b.data(), 24)));
  size_t pos = coding::kContainerHeaderSize;
  for (uint64_t i = 0; i < n_sections && i < coding::kMaxSections; ++i) {
    if (pos + 5 > size) break;
    const size_t header_len = 4 + 1 + size_t(b[pos + 4]) + 2 + 2 + 8;
    if (header_len + 4 > size - pos) break;
    const uint64_t length = get_le(b, pos + header_len - 8, 8);
    const size_t payload = pos + header_len + 4;
    if (length > size - payload) break;
    const std::string id(reinterpret_cast<const char*>(b.data() + pos), 4);
    const std::string component(reinterpret_cast<const char*>(b.data() + pos + 5), b[pos + 4]);
    if (id == "GEOM" && component == "org.crpgs.geometry.draco")
      reseal_draco(&b, payload, payload + size_t(length));
    uint32_t crc = coding::crc32(coding::ByteSpan(b.data() + pos, header_len));
    crc = coding::crc32(coding::ByteSpan(b.data() + payload, size_t(length)), crc);
    put_le32(&b, pos + header_len, crc);
    pos = payload + size_t(length);
  }
  return b;
}

Outcome run_one(const uint8_t* data, size_t size, bool sealed, const ComponentRegistry& registry) {
  const std::vector<uint8_t> bytes =
      sealed ? reseal(data, size) : std::vector<uint8_t>(data, data + size);
  Outcome out;
  auto dec = decode_model(bytes, registry);
  if (!dec.ok()) {
    out.message = dec.status().to_string();
    return out;
  }
  auto options = model_options_from_config(dec->config);
  if (!options.ok()) {
    out.message = options.status().to_string();
    return out;
  }
  auto model = model_from_decoded(*dec, *options);
  if (!model.ok()) {
    out.message = model.status().to_string();
    return out;
  }
  out.decoded = true;
  return out;
}

}  // namespace crpgs::fuzz
