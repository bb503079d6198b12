/// @file portable_kernels.cpp
/// @brief The portable kernels. Built with -ffp-contract=off and without the precompiled header
/// (whose saved options would bring contraction back): a contracted a * b + c rounds once where
/// other machines round twice.
#include "codec/portable_kernels.h"

#include <cmath>
#include <limits>
#include <vector>

#include "crpgs/portable_math.h"
#include "crpgs/target_clones.h"

namespace crpgs {
namespace {

constexpr double kLn2Hi = 6.93147180369123816490e-01;  // fdlibm split of ln 2
constexpr double kLn2Lo = 1.90821492927058770002e-10;
constexpr double kInvLn2 = 1.44269504088896338700e+00;

}  // namespace

double portable_exp(double x) {
  if (std::isnan(x)) return x;
  if (x < -745.2) return 0.0;
  if (x > 709.7) return std::numeric_limits<double>::infinity();
  const double k = std::nearbyint(x * kInvLn2);
  const double r = (x - k * kLn2Hi) - k * kLn2Lo;  // |r| <= ~0.347
  double p = 1.0;
  for (int i = 17; i >= 1; --i) p = 1.0 + p * r / double(i);  // Taylor, Horner form
  return std::ldexp(p, int(k));
}

namespace portable {

namespace {

// Rows [n, n + R) at once: each weight row is loaded once for R rows.
template <int R>
inline void linear_block(const float* __restrict x, const float* __restrict wt,
                         const float* __restrict b, int64_t n, int64_t in, int64_t out,
                         float* __restrict y) {
  float* __restrict acc = y + n * out;
  for (int r = 0; r < R; ++r)
    for (int64_t o = 0; o < out; ++o) acc[r * out + o] = b[o];
  for (int64_t i = 0; i < in; ++i) {
    float xi[R];
    for (int r = 0; r < R; ++r) xi[r] = x[(n + r) * in + i];
    const float* __restrict wr = wt + i * out;
    for (int64_t o = 0; o < out; ++o) {
      const float w = wr[o];
      for (int r = 0; r < R; ++r) acc[r * out + o] = acc[r * out + o] + xi[r] * w;
    }
  }
}

}  // namespace

CRPGS_TARGET_CLONES
void linear_rows(const float* x, const float* wt, const float* b, int64_t first, int64_t last,
                 int64_t in, int64_t out, float* y) {
  // The sum over inputs is the outer loop, so the inner loop runs across outputs (vectorises;
  // every clone rounds alike without contraction) while each output adds its terms in input
  // order.
  int64_t n = first;
  for (; n + 4 <= last; n += 4) linear_block<4>(x, wt, b, n, in, out, y);
  for (; n < last; ++n) linear_block<1>(x, wt, b, n, in, out, y);
}

void tanh_range(const float* x, int64_t first, int64_t last, float* y) {
  for (int64_t i = first; i < last; ++i) {
    const double d = x[i], a = std::fabs(d);
    double t;
    if (std::isnan(d)) {
      t = d;
    } else if (a > 20.0) {  // 1 - tanh(20) < 2^-57: rounds to 1 in float and double
      t = 1.0;
    } else if (a < 1e-4) {  // where 1 - exp(-2a) cancels; the series' next term is < 1e-17 a
      t = a - a * a * a / 3.0;
    } else {
      const double e = portable_exp(-2.0 * a);
      t = (1.0 - e) / (1.0 + e);
    }
    y[i] = float(std::copysign(t, d));
  }
}

void one_plus_tanh_range(const float* x, int64_t first, int64_t last, float* y) {
  // No cancellation where tanh(x) is near −1; portable_exp gives 0 or inf at the far ends.
  for (int64_t i = first; i < last; ++i) {
    const double d = x[i];
    y[i] = std::isnan(d) ? x[i] : float(2.0 / (1.0 + portable_exp(-2.0 * d)));
  }
}

}  // namespace portable
}  // namespace crpgs
