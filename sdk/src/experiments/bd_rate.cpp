/// @file bd_rate.cpp
#include "crpgs/experiments/bd_rate.h"

#include <algorithm>
#include <cmath>
#include <stdexcept>

namespace crpgs::experiments {

std::vector<RdPoint> pareto_front(const std::vector<RdPoint>& points) {
  std::vector<RdPoint> p;
  for (const auto& q : points)
    if (std::isfinite(q.size) && q.size > 0 && std::isfinite(q.psnr)) p.push_back(q);
  // Smallest size first; at equal size the best PSNR first, so the others are dominated by it.
  std::sort(p.begin(), p.end(), [](const RdPoint& a, const RdPoint& b) {
    return a.size != b.size ? a.size < b.size : a.psnr > b.psnr;
  });
  std::vector<RdPoint> front;
  for (const auto& q : p)
    if (front.empty() || q.psnr > front.back().psnr) front.push_back(q);
  return front;
}

namespace {
int sign(double v) {
  return (v > 0) - (v < 0);
}
}  // namespace

Pchip::Pchip(std::vector<double> x, std::vector<double> y) : x_(std::move(x)), y_(std::move(y)) {
  const size_t n = x_.size();
  if (n < 2 || y_.size() != n) throw std::invalid_argument("Pchip: need >= 2 points, |x| == |y|");
  std::vector<double> h(n - 1), delta(n - 1);
  for (size_t k = 0; k + 1 < n; ++k) {
    h[k] = x_[k + 1] - x_[k];
    if (!(h[k] > 0)) throw std::invalid_argument("Pchip: x must be strictly increasing");
    delta[k] = (y_[k + 1] - y_[k]) / h[k];
  }
  d_.assign(n, 0.0);
  if (n == 2) {
    d_[0] = d_[1] = delta[0];
    return;
  }
  for (size_t k = 1; k + 1 < n; ++k) {
    // Zero slope at local extrema; otherwise a weighted harmonic mean, which keeps each cubic
    // inside the Fritsch–Carlson monotonicity region.
    if (sign(delta[k - 1]) * sign(delta[k]) <= 0) continue;
    const double w1 = 2 * h[k] + h[k - 1], w2 = h[k] + 2 * h[k - 1];
    d_[k] = (w1 + w2) / (w1 / delta[k - 1] + w2 / delta[k]);
  }
  // Ends: one-sided three-point estimate, limited so it cannot overshoot.
  auto end_slope = [](double h0, double h1, double d0, double d1) {
    double d = ((2 * h0 + h1) * d0 - h0 * d1) / (h0 + h1);
    if (sign(d) != sign(d0)) return 0.0;
    if (sign(d0) != sign(d1) && std::fabs(d) > 3 * std::fabs(d0)) return 3 * d0;
    return d;
  };
  d_[0] = end_slope(h[0], h[1], delta[0], delta[1]);
  d_[n - 1] = end_slope(h[n - 2], h[n - 3], delta[n - 2], delta[n - 3]);
}

size_t Pchip::segment(double x) const {
  const auto it = std::upper_bound(x_.begin(), x_.end(), x);
  const size_t i = static_cast<size_t>(it - x_.begin());
  return std::min(std::max<size_t>(i, 1), x_.size() - 1) - 1;
}

double Pchip::operator()(double x) const {
  const size_t k = segment(x);
  const double h = x_[k + 1] - x_[k], t = (x - x_[k]) / h;
  const double t2 = t * t, t3 = t2 * t;
  return (2 * t3 - 3 * t2 + 1) * y_[k] + (t3 - 2 * t2 + t) * h * d_[k] +
         (-2 * t3 + 3 * t2) * y_[k + 1] + (t3 - t2) * h * d_[k + 1];
}

double Pchip::integrate(double a, double b) const {
  // Each piece is a cubic: 2-point Gauss–Legendre on every sub-interval is exact.
  const double g = 1.0 / std::sqrt(3.0);
  double sum = 0;
  for (size_t k = 0; k + 1 < x_.size(); ++k) {
    const double lo = std::max(a, k == 0 ? a : x_[k]);
    const double hi = std::min(b, k + 2 == x_.size() ? b : x_[k + 1]);
    if (hi <= lo) continue;
    const double m = 0.5 * (lo + hi), r = 0.5 * (hi - lo);
    // Evaluate on this piece's own cubic (operator() picks by position, which is the same).
    sum += r * ((*this)(m - g * r) + (*this)(m + g * r));
  }
  return sum;
}

namespace {

/// Mean of (f_test - f_anchor) over the common x range, each curve a PCHIP of y over x; the
/// range and point counts go with it.
std::optional<BdFigure> mean_gap(const std::vector<double>& xa, const std::vector<double>& ya,
                                 const std::vector<double>& xt, const std::vector<double>& yt) {
  if (xa.size() < 2 || xt.size() < 2) return std::nullopt;
  BdFigure f;
  f.lo = std::max(xa.front(), xt.front());
  f.hi = std::min(xa.back(), xt.back());
  if (!(f.hi > f.lo)) return std::nullopt;
  const Pchip fa(xa, ya), ft(xt, yt);
  f.value = (ft.integrate(f.lo, f.hi) - fa.integrate(f.lo, f.hi)) / (f.hi - f.lo);
  f.anchor_points = int(xa.size());
  f.test_points = int(xt.size());
  return f;
}

void split(const std::vector<RdPoint>& curve, std::vector<double>& log_size,
           std::vector<double>& psnr) {
  for (const auto& p : pareto_front(curve)) {
    log_size.push_back(std::log(p.size));
    psnr.push_back(p.psnr);
  }
}

}  // namespace

std::optional<BdFigure> bd_rate_figure(const std::vector<RdPoint>& anchor,
                                       const std::vector<RdPoint>& test) {
  std::vector<double> ra, da, rt, dt;
  split(anchor, ra, da);
  split(test, rt, dt);
  // log(size) as a function of PSNR (PSNR is strictly increasing on a Pareto front).
  auto f = mean_gap(da, ra, dt, rt);
  if (f) f->value = (std::exp(f->value) - 1) * 100;
  return f;
}

std::optional<BdFigure> bd_psnr_figure(const std::vector<RdPoint>& anchor,
                                       const std::vector<RdPoint>& test) {
  std::vector<double> ra, da, rt, dt;
  split(anchor, ra, da);
  split(test, rt, dt);
  auto f = mean_gap(ra, da, rt, dt);
  if (f) f->lo = std::exp(f->lo), f->hi = std::exp(f->hi);  // log size back to bytes
  return f;
}

std::optional<double> bd_rate(const std::vector<RdPoint>& anchor,
                              const std::vector<RdPoint>& test) {
  const auto f = bd_rate_figure(anchor, test);
  return f ? std::optional<double>(f->value) : std::nullopt;
}

std::optional<double> bd_psnr(const std::vector<RdPoint>& anchor,
                              const std::vector<RdPoint>& test) {
  const auto f = bd_psnr_figure(anchor, test);
  return f ? std::optional<double>(f->value) : std::nullopt;
}

}  // namespace crpgs::experiments
