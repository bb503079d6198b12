/// @file ply.cpp
/// @brief 3DGS .ply reading and writing (see ply.h).
#include "crpgs/ply.h"

#include <algorithm>
#include <cmath>
#include <cstring>
#include <limits>
#include <map>
#include <sstream>
#include <vector>

#include "crpgs/atomic_file.h"

namespace crpgs {
namespace {

constexpr size_t kMaxHeader = 64 * 1024;
constexpr size_t kMaxProperties = 4096;

// The 3DGS reference constants (sh_utils.py / forward.cu).
constexpr float kC0 = 0.28209479177387814f;
constexpr float kC1 = 0.4886025119029199f;
constexpr float kC2[5] = {1.0925484305920792f, -1.0925484305920792f, 0.31539156525252005f,
                          -1.0925484305920792f, 0.5462742152960396f};
constexpr float kC3[7] = {-0.5900435899266435f, 2.890611442640554f,   -0.4570457994644658f,
                          0.3731763325901154f,  -0.4570457994644658f, 1.445305721320277f,
                          -0.5900435899266435f};

Status bad(const std::string& name, const std::string& what) {
  return Status(StatusCode::kCorruptBitstream, name + ": " + what);
}

enum class Scalar { kI8, kU8, kI16, kU16, kI32, kU32, kF32, kF64, kBad };

Scalar scalar_type(const std::string& t) {
  static const std::map<std::string, Scalar> m = {
      {"char", Scalar::kI8},    {"int8", Scalar::kI8},     {"uchar", Scalar::kU8},
      {"uint8", Scalar::kU8},   {"short", Scalar::kI16},   {"int16", Scalar::kI16},
      {"ushort", Scalar::kU16}, {"uint16", Scalar::kU16},  {"int", Scalar::kI32},
      {"int32", Scalar::kI32},  {"uint", Scalar::kU32},    {"uint32", Scalar::kU32},
      {"float", Scalar::kF32},  {"float32", Scalar::kF32}, {"double", Scalar::kF64},
      {"float64", Scalar::kF64}};
  auto it = m.find(t);
  return it == m.end() ? Scalar::kBad : it->second;
}

size_t scalar_size(Scalar s) {
  switch (s) {
    case Scalar::kI8:
    case Scalar::kU8:
      return 1;
    case Scalar::kI16:
    case Scalar::kU16:
      return 2;
    case Scalar::kI32:
    case Scalar::kU32:
    case Scalar::kF32:
      return 4;
    case Scalar::kF64:
      return 8;
    default:
      return 0;
  }
}

template <typename T>
T load(const uint8_t* p) {  // the file is little-endian, as is every host we build for
  T v;
  std::memcpy(&v, p, sizeof v);
  return v;
}

float read_scalar(Scalar s, const uint8_t* p) {
  switch (s) {
    case Scalar::kI8:
      return float(load<int8_t>(p));
    case Scalar::kU8:
      return float(load<uint8_t>(p));
    case Scalar::kI16:
      return float(load<int16_t>(p));
    case Scalar::kU16:
      return float(load<uint16_t>(p));
    case Scalar::kI32:
      return float(load<int32_t>(p));
    case Scalar::kU32:
      return float(load<uint32_t>(p));
    case Scalar::kF32:
      return load<float>(p);
    case Scalar::kF64:
      return float(load<double>(p));
    default:
      return 0.f;
  }
}

struct Property {
  std::string name;
  Scalar type = Scalar::kBad;
  size_t offset = 0;
};

struct Element {
  std::string name;
  uint64_t count = 0;
  std::vector<Property> props;
  size_t stride = 0;
  bool has_list = false;
};

std::vector<std::string> rest_names(int degree) {
  std::vector<std::string> n;
  for (int i = 0; i < 3 * (sh_coeff_count(degree) - 1); ++i)
    n.push_back("f_rest_" + std::to_string(i));
  return n;
}

std::vector<std::string> property_names(int degree) {
  std::vector<std::string> n = {"x", "y", "z", "nx", "ny", "nz", "f_dc_0", "f_dc_1", "f_dc_2"};
  for (auto& r : rest_names(degree)) n.push_back(r);
  for (const char* s :
       {"opacity", "scale_0", "scale_1", "scale_2", "rot_0", "rot_1", "rot_2", "rot_3"})
    n.push_back(s);
  return n;
}

}  // namespace

void sh_basis(int degree, float x, float y, float z, float* out) {
  out[0] = kC0;
  if (degree < 1) return;
  out[1] = -kC1 * y;
  out[2] = kC1 * z;
  out[3] = -kC1 * x;
  if (degree < 2) return;
  const float xx = x * x, yy = y * y, zz = z * z, xy = x * y, yz = y * z, xz = x * z;
  out[4] = kC2[0] * xy;
  out[5] = kC2[1] * yz;
  out[6] = kC2[2] * (2.f * zz - xx - yy);
  out[7] = kC2[3] * xz;
  out[8] = kC2[4] * (xx - yy);
  if (degree < 3) return;
  out[9] = kC3[0] * y * (3.f * xx - yy);
  out[10] = kC3[1] * xy * z;
  out[11] = kC3[2] * y * (4.f * zz - xx - yy);
  out[12] = kC3[3] * z * (2.f * zz - 3.f * xx - 3.f * yy);
  out[13] = kC3[4] * x * (4.f * zz - xx - yy);
  out[14] = kC3[5] * z * (xx - yy);
  out[15] = kC3[6] * x * (xx - 3.f * yy);
}

void PlyGaussians::resize(size_t n) {
  means.resize(3 * n);
  sh_dc.resize(3 * n);
  sh_rest.resize(size_t(3 * (sh_coeff_count(sh_degree) - 1)) * n);
  opacity.resize(n);
  log_scales.resize(3 * n);
  rotations.resize(4 * n);
}

Status PlyGaussians::check() const {
  const size_t n = size();
  if (sh_degree < 0 || sh_degree > 3)
    return Status(StatusCode::kInvalidArgument, "ply: SH degree must be 0..3");
  const size_t rest = size_t(3 * (sh_coeff_count(sh_degree) - 1));
  if (means.size() != 3 * n || sh_dc.size() != 3 * n || sh_rest.size() != rest * n ||
      log_scales.size() != 3 * n || rotations.size() != 4 * n)
    return Status(StatusCode::kInvalidArgument, "ply: attribute arrays do not match the count");
  return OkStatus();
}

std::array<float, 3> PlyGaussians::color(size_t i, float x, float y, float z) const {
  float basis[16];
  sh_basis(sh_degree, x, y, z, basis);
  const int nb = sh_coeff_count(sh_degree);
  std::array<float, 3> c{};
  for (int ch = 0; ch < 3; ++ch) {
    float v = basis[0] * sh_dc[3 * i + size_t(ch)];
    const float* r = sh_rest.data() + i * size_t(3 * (nb - 1)) + size_t(ch * (nb - 1));
    for (int b = 1; b < nb; ++b) v += basis[b] * r[b - 1];
    c[size_t(ch)] = std::max(v + 0.5f, 0.f);
  }
  return c;
}

StatusOr<std::string> encode_ply(const PlyGaussians& g) {
  CRPGS_RETURN_IF_ERROR(g.check());
  const size_t n = g.size();
  const auto names = property_names(g.sh_degree);
  std::string out =
      "ply\nformat binary_little_endian 1.0\nelement vertex " + std::to_string(n) + "\n";
  for (const auto& p : names) out += "property float " + p + "\n";
  out += "end_header\n";
  const size_t header = out.size();
  const size_t rest = size_t(3 * (sh_coeff_count(g.sh_degree) - 1));
  out.resize(header + n * names.size() * sizeof(float));
  char* w = out.data() + header;
  auto put = [&w](const float* v, size_t k) {
    std::memcpy(w, v, k * sizeof(float));
    w += k * sizeof(float);
  };
  const float normal[3] = {0.f, 0.f, 0.f};
  float scale_floor = -std::numeric_limits<float>::infinity();
  if (n > 0) {
    std::vector<float> sorted(g.log_scales);
    auto mid = sorted.begin() + std::ptrdiff_t(sorted.size() / 2);
    std::nth_element(sorted.begin(), mid, sorted.end());
    scale_floor = *mid - kPlyLogScaleFloorBelowMedian;
  }
  for (size_t i = 0; i < n; ++i) {
    put(&g.means[3 * i], 3);
    put(normal, 3);
    put(&g.sh_dc[3 * i], 3);
    if (rest) put(&g.sh_rest[rest * i], rest);
    const float opacity = std::clamp(g.opacity[i], -kPlyMaxOpacityLogit, kPlyMaxOpacityLogit);
    put(&opacity, 1);
    float scales[3];
    for (int k = 0; k < 3; ++k) scales[k] = std::max(g.log_scales[3 * i + k], scale_floor);
    put(scales, 3);
    std::array<float, 4> q;
    std::copy_n(&g.rotations[4 * i], 4, q.begin());
    const double norm = std::sqrt(double(q[0]) * q[0] + double(q[1]) * q[1] + double(q[2]) * q[2] +
                                  double(q[3]) * q[3]);
    if (!(norm > 0))
      q = {1.f, 0.f, 0.f, 0.f};
    else if (std::abs(norm - 1.0) > 1e-6)
      for (float& c : q) c = float(c / norm);
    put(q.data(), 4);
  }
  return out;
}

Status write_ply(const std::string& path, const PlyGaussians& g) {
  CRPGS_ASSIGN_OR_RETURN(std::string bytes, encode_ply(g));
  return write_file_atomic(path, bytes);
}

StatusOr<PlyGaussians> decode_ply(const uint8_t* data, size_t size, const std::string& name) {
  // Header: lines up to "end_header\n", bounded.
  const std::string marker = "end_header";
  const size_t scan = std::min(size, kMaxHeader);
  const std::string head(reinterpret_cast<const char*>(data), scan);
  if (head.compare(0, 3, "ply") != 0) return bad(name, "not a .ply file (no 'ply' magic)");
  size_t end = std::string::npos;
  for (size_t pos = head.find(marker); pos != std::string::npos; pos = head.find(marker, pos + 1)) {
    if (pos > 0 && head[pos - 1] == '\n') {
      end = pos;
      break;
    }
  }
  if (end == std::string::npos)
    return bad(name, size > kMaxHeader ? "no end_header in the first 64 KiB"
                                       : "truncated header (no end_header)");
  size_t body = head.find('\n', end);
  if (body == std::string::npos) return bad(name, "truncated header (no newline after end_header)");
  ++body;

  std::istringstream lines(head.substr(0, end));
  std::string line;
  std::vector<Element> elements;
  std::string format;
  size_t n_props = 0;
  while (std::getline(lines, line)) {
    if (!line.empty() && line.back() == '\r') line.pop_back();
    std::istringstream ls(line);
    std::string kw;
    ls >> kw;
    if (kw.empty() || kw == "ply" || kw == "comment" || kw == "obj_info") continue;
    if (kw == "format") {
      std::string version;
      ls >> format >> version;
      if (format == "ascii")
        return bad(name, "ascii .ply is not supported; convert it to binary_little_endian");
      if (format != "binary_little_endian")
        return bad(name, "format '" + format + "' is not supported (binary_little_endian only)");
    } else if (kw == "element") {
      Element e;
      std::string count;
      ls >> e.name >> count;
      if (e.name.empty() || count.empty() ||
          count.find_first_not_of("0123456789") != std::string::npos || count.size() > 19)
        return bad(name, "malformed element line '" + line + "'");
      e.count = std::stoull(count);
      elements.push_back(e);
    } else if (kw == "property") {
      if (elements.empty()) return bad(name, "property before any element");
      if (++n_props > kMaxProperties) return bad(name, "too many properties");
      Element& e = elements.back();
      std::string type, pname;
      ls >> type;
      if (type == "list") {
        e.has_list = true;
        continue;
      }
      ls >> pname;
      const Scalar s = scalar_type(type);
      if (s == Scalar::kBad || pname.empty())
        return bad(name, "malformed property line '" + line + "'");
      e.props.push_back({pname, s, e.stride});
      e.stride += scalar_size(s);
    } else {
      return bad(name, "unknown header line '" + line + "'");
    }
  }
  if (format.empty()) return bad(name, "no format line");

  // Skip the elements before `vertex` (fixed-size only), then read it.
  size_t offset = body;
  const Element* vertex = nullptr;
  for (const Element& e : elements) {
    if (e.name == "vertex") {
      vertex = &e;
      break;
    }
    if (e.has_list) return bad(name, "element '" + e.name + "' before vertex has list properties");
    if (e.stride && e.count > (size - offset) / e.stride)
      return bad(name, "file too short for its '" + e.name + "' element");
    offset += size_t(e.count) * e.stride;
  }
  if (!vertex) return bad(name, "no vertex element");
  if (vertex->has_list) return bad(name, "the vertex element has list properties");
  std::map<std::string, const Property*> by_name;
  for (const auto& p : vertex->props)
    if (!by_name.emplace(p.name, &p).second)
      return bad(name, "vertex property '" + p.name + "' appears twice");
  int rest = 0;
  while (by_name.count("f_rest_" + std::to_string(rest))) ++rest;
  int degree = -1;
  for (int d = 0; d <= 3; ++d)
    if (rest == 3 * (sh_coeff_count(d) - 1)) degree = d;
  if (degree < 0)
    return bad(name, std::to_string(rest) +
                         " f_rest properties: expected 0, 9, 24 or 45 (SH degree 0..3)");
  std::vector<const Property*> cols;
  for (const auto& pn : property_names(degree)) {
    if (pn[0] == 'n' && pn.size() == 2) continue;  // normals are not used
    auto it = by_name.find(pn);
    if (it == by_name.end()) return bad(name, "missing vertex property '" + pn + "'");
    cols.push_back(it->second);
  }
  const uint64_t n = vertex->count;
  if (vertex->stride == 0 || n > (size - offset) / vertex->stride)
    return bad(name, "file too short for " + std::to_string(n) + " vertices of " +
                         std::to_string(vertex->stride) + " bytes (" +
                         std::to_string(size - offset) + " bytes of data)");

  PlyGaussians g;
  g.sh_degree = degree;
  const size_t nr = size_t(rest);
  g.resize(n);
  std::vector<float> row(cols.size());
  size_t kept = 0;
  for (size_t i = 0; i < n; ++i) {
    const uint8_t* v = data + offset + i * vertex->stride;
    bool finite = true;
    for (size_t c = 0; c < cols.size(); ++c) {
      row[c] = read_scalar(cols[c]->type, v + cols[c]->offset);
      if (c == 6 + nr && std::isinf(row[c]))  // opacity: alpha 1 or 0
        row[c] = std::copysign(kPlyReadSaturatedLogit, row[c]);
      finite = finite && std::isfinite(row[c]);
    }
    if (!finite) {  // e.g. a Gaussian that diverged in training: it would render as nothing
      ++g.dropped_non_finite;
      continue;
    }
    const float* r = row.data();
    const size_t k = kept++;
    std::copy(r, r + 3, &g.means[3 * k]);
    std::copy(r + 3, r + 6, &g.sh_dc[3 * k]);
    std::copy(r + 6, r + 6 + nr, g.sh_rest.data() + nr * k);
    g.opacity[k] = r[6 + nr];
    std::copy(r + 7 + nr, r + 10 + nr, &g.log_scales[3 * k]);
    std::copy(r + 10 + nr, r + 14 + nr, &g.rotations[4 * k]);
  }
  g.resize(kept);
  return g;
}

StatusOr<PlyGaussians> read_ply(const std::string& path) {
  CRPGS_ASSIGN_OR_RETURN(std::vector<uint8_t> bytes, read_file_bytes(path));
  return decode_ply(bytes.data(), bytes.size(), path);
}

}  // namespace crpgs
