/// @file gaussian_coding.cpp
/// @brief Deterministic table construction and chunked coding for the `gaussian` entropy model.
/// Everything that decides an integer (keys, PMFs) uses only IEEE-754 basic double operations,
/// so encoder and decoder agree on any machine; this file is built with -ffp-contract=off.
#include "gaussian_coding.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <limits>
#include <mutex>
#include <string>
#include <unordered_map>

#include "crpgs/portable_math.h"

namespace crpgs::gaussian_coding {
namespace {

constexpr double kSqrtHalf = 0.70710678118654752440;
constexpr double kInvSqrtPi = 0.56418958354775628695;
constexpr double kTailZ = 6.0;  // table half-width in scales: two-sided tail mass ≈ 2e-9

/// erfc(t) for t >= 0.
double erfc_pos(double t) {
  if (t < 2.5) {
    // erf(t) = 2/sqrt(pi) exp(-t^2) sum_n t (2t^2)^n / (1*3*...*(2n+1)): positive terms only.
    double term = t, sum = t;
    const double t2 = 2.0 * t * t;
    for (int n = 1; n < 200; ++n) {
      term = term * t2 / double(2 * n + 1);
      sum += term;
      if (term < sum * 1e-17) break;
    }
    return 1.0 - 2.0 * kInvSqrtPi * portable_exp(-t * t) * sum;
  }
  // Continued fraction erfc(t) = exp(-t^2)/sqrt(pi) / (t + (1/2)/(t + 1/(t + (3/2)/(t + ...)))).
  double f = t;
  const int depth = t < 3.5 ? 120 : (t < 6.0 ? 60 : 30);
  for (int n = depth; n >= 1; --n) f = t + (0.5 * double(n)) / f;
  return portable_exp(-t * t) * kInvSqrtPi / f;
}

/// Level boundaries: boundary k separates level k and k + 1 (geometric midpoint).
const std::array<double, kScaleLevels - 1>& level_boundaries() {
  static const std::array<double, kScaleLevels - 1> b = [] {
    std::array<double, kScaleLevels - 1> out{};
    const double r16 = std::sqrt(std::sqrt(std::sqrt(std::sqrt(2.0))));  // 2^(1/16)
    for (int k = 0; k + 1 < kScaleLevels; ++k) out[size_t(k)] = scale_level_value(k) * r16;
    return out;
  }();
  return b;
}

std::mutex g_cache_mutex;
std::unordered_map<uint32_t, coding::CdfTable>& cache() {
  static std::unordered_map<uint32_t, coding::CdfTable> c;
  return c;
}

Status invalid(const std::string& m) {
  return Status(StatusCode::kInvalidArgument, "gaussian coding: " + m);
}

/// Keys and centers of all elements, then the table set of the distinct keys (ascending) and
/// each element's index into it.
struct Plan {
  std::vector<int64_t> centers;
  std::vector<uint32_t> indexes;
  coding::CdfTableSet tables;
};

StatusOr<Plan> make_plan(const float* mean, const float* scale, const float* q, size_t n,
                         double scale_bound) {
  Plan plan;
  plan.centers.resize(n);
  plan.indexes.resize(n);
  std::vector<uint32_t> local(kNumKeys, 0);  // 0: unused, else local index + 1
  for (size_t i = 0; i < n; ++i) {
    const uint32_t key = element_key(mean[i], scale[i], q[i], scale_bound, &plan.centers[i]);
    plan.indexes[i] = key;
    local[key] = 1;
  }
  std::vector<coding::CdfTable> tables;
  for (uint32_t key = 0; key < kNumKeys; ++key) {
    if (!local[key]) continue;
    CRPGS_ASSIGN_OR_RETURN(coding::CdfTable t, table_for_key(key));
    tables.push_back(std::move(t));
    local[key] = uint32_t(tables.size());
  }
  for (size_t i = 0; i < n; ++i) plan.indexes[i] = local[plan.indexes[i]] - 1;
  CRPGS_ASSIGN_OR_RETURN(plan.tables, coding::CdfTableSet::create(std::move(tables), kPrecision));
  return plan;
}

}  // namespace

double normal_upper_tail(double x) {
  if (std::isnan(x)) return x;
  if (x < 0) return 1.0 - normal_upper_tail(-x);
  return 0.5 * erfc_pos(x * kSqrtHalf);
}

double normal_interval(double a, double b) {
  if (a >= 0) return normal_upper_tail(a) - normal_upper_tail(b);
  if (b <= 0) return normal_upper_tail(-b) - normal_upper_tail(-a);
  return 1.0 - normal_upper_tail(-a) - normal_upper_tail(b);
}

double scale_level_value(int level) {
  const int e = level + kLowestLevelExp;  // value 2^(e/8)
  const int oct = e >= 0 ? e / 8 : -((-e + 7) / 8);
  const int frac = e - 8 * oct;  // 0..7
  const double r4 = std::sqrt(2.0), r2 = std::sqrt(r4), r1 = std::sqrt(r2);
  const double fr[8] = {1.0, r1, r2, r2 * r1, r4, r4 * r1, r4 * r2, r4 * (r2 * r1)};
  return std::ldexp(fr[frac], oct);
}

int scale_level(double s) {
  if (!(s == s) || s > std::numeric_limits<double>::max()) return kScaleLevels - 1;
  const auto& b = level_boundaries();
  return int(std::upper_bound(b.begin(), b.end(), s) - b.begin());
}

uint32_t element_key(float mean, float scale, float q, double scale_bound, int64_t* center) {
  double qd = q;
  bool widest = false;
  if (!(qd > 0) || !std::isfinite(qd)) {
    qd = 1.0;
    widest = true;
  }
  const double sigma = double(scale) >= scale_bound ? double(scale) : scale_bound;
  const int level = widest ? kScaleLevels - 1 : scale_level(sigma / qd);
  double m = double(mean) / qd;
  if (m != m) m = 0;
  m = std::clamp(m, -1099511627776.0, 1099511627776.0);  // ±2^40
  const int64_t c = int64_t(std::floor(m * double(kMeanBins) + 0.5));
  const int64_t bin = c & (kMeanBins - 1);
  *center = (c - bin) / kMeanBins;
  return uint32_t(level) * kMeanBins + uint32_t(bin);
}

StatusOr<coding::CdfTable> table_for_key(uint32_t key) {
  if (key >= kNumKeys) return invalid("table key " + std::to_string(key) + " out of range");
  std::lock_guard<std::mutex> lock(g_cache_mutex);
  auto it = cache().find(key);
  if (it != cache().end()) return it->second;
  const int level = int(key / kMeanBins);
  const double mu = double(key % kMeanBins) / double(kMeanBins);
  const double s = scale_level_value(level);
  const int32_t w = int32_t(std::ceil(kTailZ * s)) + 1;
  // Cell edges e_i = (j - 1/2 - mu) / s; each cell as normal_interval() computes it, with the
  // tail value Q(|e_i|) of every edge computed once.
  const size_t n = size_t(2 * w + 2);
  std::vector<double> edge(n + 1), tail(n + 1);
  for (size_t i = 0; i <= n; ++i) {
    edge[i] = (double(int64_t(i) - w) - 0.5 - mu) / s;
    tail[i] = normal_upper_tail(edge[i] >= 0 ? edge[i] : -edge[i]);
  }
  std::vector<double> pmf(n);
  for (size_t i = 0; i < n; ++i) {
    if (edge[i] >= 0)
      pmf[i] = tail[i] - tail[i + 1];
    else if (edge[i + 1] <= 0)
      pmf[i] = tail[i + 1] - tail[i];
    else
      pmf[i] = 1.0 - tail[i] - tail[i + 1];
  }
  CRPGS_ASSIGN_OR_RETURN(coding::CdfTable t, coding::make_cdf_table(pmf, -w, kPrecision));
  cache().emplace(key, t);
  return t;
}

StatusOr<coding::Bytes> compress(const int32_t* symbols, const float* mean, const float* scale,
                                 const float* q, size_t n, double scale_bound) {
  CRPGS_ASSIGN_OR_RETURN(Plan plan, make_plan(mean, scale, q, n, scale_bound));
  std::vector<int32_t> residual(n);
  for (size_t i = 0; i < n; ++i)  // wrapping difference: any int32 symbol round-trips
    residual[i] = int32_t(uint32_t(symbols[i]) - uint32_t(uint64_t(plan.centers[i])));
  CRPGS_ASSIGN_OR_RETURN(
      coding::Bytes stream,
      coding::ChunkedEncoder(kChunkSize, 1).encode(residual, plan.indexes, plan.tables));
  coding::Bytes out;
  out.reserve(stream.size() + 1);
  out.push_back(kFormatVersion);
  out.insert(out.end(), stream.begin(), stream.end());
  return out;
}

StatusOr<std::vector<int32_t>> decompress(coding::ByteSpan bytes, const float* mean,
                                          const float* scale, const float* q, size_t n,
                                          double scale_bound, int num_threads) {
  if (bytes.size == 0)
    return Status(StatusCode::kCorruptBitstream, "gaussian stream: empty (no version byte)");
  if (bytes.data[0] != kFormatVersion)
    return Status(StatusCode::kUnsupportedVersion,
                  "gaussian stream: table format version " + std::to_string(bytes.data[0]) +
                      ", this build reads " + std::to_string(kFormatVersion));
  const coding::ByteSpan stream = bytes.subspan(1, bytes.size - 1);
  CRPGS_ASSIGN_OR_RETURN(coding::ChunkedStreamInfo info, coding::ChunkedDecoder::parse(stream));
  if (info.num_symbols != n)
    return Status(StatusCode::kCorruptBitstream,
                  "gaussian stream: holds " + std::to_string(info.num_symbols) +
                      " symbols, caller expects " + std::to_string(n));
  if (info.precision != kPrecision)
    return Status(StatusCode::kCorruptBitstream, "gaussian stream: precision " +
                                                     std::to_string(info.precision) +
                                                     ", expected " + std::to_string(kPrecision));
  CRPGS_ASSIGN_OR_RETURN(Plan plan, make_plan(mean, scale, q, n, scale_bound));
  CRPGS_ASSIGN_OR_RETURN(
      std::vector<int32_t> out,
      coding::ChunkedDecoder::decode(stream, plan.indexes, plan.tables, std::max(1, num_threads)));
  for (size_t i = 0; i < n; ++i)
    out[i] = int32_t(uint32_t(out[i]) + uint32_t(uint64_t(plan.centers[i])));
  return out;
}

}  // namespace crpgs::gaussian_coding
