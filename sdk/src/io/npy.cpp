/// @file npy.cpp
/// @brief .npy: magic "\x93NUMPY", version (2 bytes), header length (u16 for v1, u32 for v2/3),
/// a Python dict literal {'descr': ..., 'fortran_order': ..., 'shape': (...), }, then the data.
#include "io/npy.h"

#include <cstring>
#include <fstream>
#include <limits>
#include <sstream>

namespace crpgs::io {
namespace {

Status bad(const std::string& path, const std::string& why) {
  return Status(StatusCode::kIoError, path + ": not a supported .npy file (" + why + ")");
}

// Value text after 'key': in the header dict (up to the next ',' at depth 0 or '}').
bool dict_value(const std::string& header, const std::string& key, std::string& out) {
  size_t p = header.find("'" + key + "'");
  if (p == std::string::npos) p = header.find("\"" + key + "\"");
  if (p == std::string::npos) return false;
  p = header.find(':', p);
  if (p == std::string::npos) return false;
  ++p;
  int depth = 0;
  size_t e = p;
  for (; e < header.size(); ++e) {
    const char c = header[e];
    if (c == '(' || c == '[') ++depth;
    if (c == ')' || c == ']') --depth;
    if (depth == 0 && (c == ',' || c == '}')) break;
  }
  out = header.substr(p, e - p);
  const size_t b = out.find_first_not_of(" \t"), l = out.find_last_not_of(" \t");
  out = b == std::string::npos ? "" : out.substr(b, l - b + 1);
  return true;
}

}  // namespace

StatusOr<NpyArray> parse_npy(const std::string& bytes, const std::string& path) {
  if (bytes.size() < 10 || std::memcmp(bytes.data(), "\x93NUMPY", 6) != 0)
    return bad(path, "bad magic");
  const int major = static_cast<unsigned char>(bytes[6]);
  size_t header_len = 0, offset = 0;
  if (major == 1) {
    header_len = size_t(static_cast<unsigned char>(bytes[8])) |
                 size_t(static_cast<unsigned char>(bytes[9])) << 8;
    offset = 10;
  } else if (major == 2 || major == 3) {
    if (bytes.size() < 12) return bad(path, "truncated header");
    for (int i = 0; i < 4; ++i)
      header_len |= size_t(static_cast<unsigned char>(bytes[size_t(8 + i)])) << (8 * i);
    offset = 12;
  } else {
    return bad(path, "format version " + std::to_string(major));
  }
  if (offset + header_len > bytes.size()) return bad(path, "truncated header");
  const std::string header = bytes.substr(offset, header_len);
  offset += header_len;
  std::string descr, fortran, shape;
  if (!dict_value(header, "descr", descr) || !dict_value(header, "fortran_order", fortran) ||
      !dict_value(header, "shape", shape))
    return bad(path, "header lacks descr/fortran_order/shape: " + header);
  size_t item = 0;
  if (descr == "'<f8'" || descr == "\"<f8\"") {
    item = 8;
  } else if (descr == "'<f4'" || descr == "\"<f4\"") {
    item = 4;
  } else {
    return bad(path, "dtype " + descr + ", expected '<f8' or '<f4'");
  }
  if (fortran != "False") return bad(path, "fortran_order " + fortran);
  NpyArray a;
  if (shape.size() < 2 || shape.front() != '(' || shape.back() != ')')
    return bad(path, "shape " + shape);
  std::istringstream ss(shape.substr(1, shape.size() - 2));
  std::string dim;
  size_t count = 1;
  while (std::getline(ss, dim, ',')) {
    if (dim.find_first_not_of(" ") == std::string::npos) continue;
    const long long d = std::atoll(dim.c_str());
    if (d < 0) return bad(path, "shape " + shape);
    a.shape.push_back(d);
    // More data than any file holds, checked before count * item can overflow.
    if (d > 0 && count > std::numeric_limits<size_t>::max() / item / size_t(d))
      return bad(path, "shape " + shape + " is too large");
    count *= size_t(d);
  }
  if (bytes.size() - offset < count * item)
    return bad(path, "truncated data: " + std::to_string(bytes.size() - offset) + " bytes for " +
                         std::to_string(count) + " values of " + std::to_string(item) + " bytes");
  a.data.resize(count);
  for (size_t i = 0; i < count; ++i) {
    if (item == 8) {
      std::memcpy(&a.data[i], bytes.data() + offset + i * 8, 8);
    } else {
      float f;
      std::memcpy(&f, bytes.data() + offset + i * 4, 4);
      a.data[i] = f;
    }
  }
  return a;
}

StatusOr<NpyArray> read_npy(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) return Status(StatusCode::kNotFound, "cannot open " + path);
  std::stringstream ss;
  ss << in.rdbuf();
  return parse_npy(ss.str(), path);
}

}  // namespace crpgs::io
