/// @file gaussian_coding.h
/// @brief The coding path of the `gaussian` entropy model, torch-free: per element a table key
/// from (mean/q, scale/q) on a fixed grid, integer CDF tables built once per key with a
/// deterministic Φ (IEEE +,−,×,÷ only, no libm), and chunked rANS streams.
///
/// Element → table (encoder and decoder run exactly this, on the same float32 inputs):
///   qd = double(q); invalid (NaN, inf, <= 0) → qd = 1 and the widest scale level is used.
///   sigma = scale >= scale_bound ? scale : scale_bound (NaN → scale_bound);  s = sigma / qd.
///   level = number of level boundaries <= s (0 .. kScaleLevels-1; NaN/inf → top).
///   m = mean / qd (NaN → 0, clamped to ±2^40);  c = floor(m * kMeanBins + 0.5) (int64);
///   bin = c mod kMeanBins, center = (c - bin) / kMeanBins;  key = level * kMeanBins + bin.
/// The table of a key is the Gaussian N(bin / kMeanBins, s_level) integrated over unit cells
/// [j - 1/2, j + 1/2) for j in [-W, W + 1], W = ceil(6 s_level) + 1, plus the escape symbol with
/// the missing mass; the coded value is the residual symbol - center (int32, wrapping), so every
/// int32 symbol round-trips (far values through the coder's escape).
#pragma once

#include <cstddef>
#include <cstdint>
#include <vector>

#include "crpgs/coding/range_coder.h"
#include "crpgs/status.h"

namespace crpgs::gaussian_coding {

/// Version byte at the start of every stream; bumped whenever the table construction changes.
inline constexpr uint8_t kFormatVersion = 1;
inline constexpr int kPrecision = 20;        ///< CDF precision (bits)
inline constexpr int kMeanBins = 32;         ///< mean fraction grid: 1/32 of a step
inline constexpr int kLevelsPerOctave = 8;   ///< scale levels 2^(1/8) apart
inline constexpr int kLowestLevelExp = -26;  ///< level 0 = 2^(-26/8) ≈ 0.105 steps
inline constexpr int kScaleLevels = 107;     ///< top level = 2^(80/8) = 1024 steps
inline constexpr uint32_t kNumKeys = uint32_t(kScaleLevels) * kMeanBins;
inline constexpr uint32_t kChunkSize = 10000;  ///< symbols per independently decodable chunk

/// Upper tail Q(x) = P(N(0,1) > x), deterministic (relative error ~1e-14 over the used range).
double normal_upper_tail(double x);
/// P(a <= N(0,1) < b), a <= b, evaluated in the tail nearer to the interval for precision.
double normal_interval(double a, double b);

/// Scale (in steps) of level k, exactly 2^((k + kLowestLevelExp) / 8) up to rounding.
double scale_level_value(int level);
/// The level whose geometric cell contains s (s in steps).
int scale_level(double s);

/// Table key of one element and its integer center (see the file comment).
uint32_t element_key(float mean, float scale, float q, double scale_bound, int64_t* center);

/// The integer table of a key (cached; thread-safe). kInvalidArgument for a key out of range.
StatusOr<coding::CdfTable> table_for_key(uint32_t key);

/// Layout: u8 kFormatVersion | ChunkedEncoder stream (chunks of kChunkSize symbols, precision
/// kPrecision) of the residuals coded against the tables of the distinct keys used, in
/// ascending key order (the decoder rederives the same list from mean/scale/q).
StatusOr<coding::Bytes> compress(const int32_t* symbols, const float* mean, const float* scale,
                                 const float* q, size_t n, double scale_bound);
/// Inverse of compress(); num_threads decodes chunks in parallel (result independent of it).
StatusOr<std::vector<int32_t>> decompress(coding::ByteSpan bytes, const float* mean,
                                          const float* scale, const float* q, size_t n,
                                          double scale_bound, int num_threads);

}  // namespace crpgs::gaussian_coding
