/// @file bd_rate.h
/// @brief Bjøntegaard metrics between two rate-distortion curves, as CRP-GS reports them:
/// dominated points are removed, a PCHIP (monotone cubic) is fitted on log(size), and the gap
/// is averaged over the interval both curves cover.
#pragma once

#include <optional>
#include <vector>

namespace crpgs::experiments {

struct RdPoint {
  double size = 0;  ///< bytes (> 0)
  double psnr = 0;  ///< dB
};

/// Drops every point that another point dominates (size <= and PSNR >=; of exact duplicates
/// one is kept) and non-positive / non-finite sizes; the rest sorted by size, so PSNR is
/// strictly increasing.
std::vector<RdPoint> pareto_front(const std::vector<RdPoint>& points);

/// Piecewise cubic Hermite interpolant with Fritsch–Carlson monotone slopes (the slope rule of
/// PCHIP: weighted harmonic mean inside, shape-preserving three-point formula at the ends).
/// Monotone data gives a monotone interpolant without overshoot. Two points give a line.
class Pchip {
 public:
  /// `x` strictly increasing, same length as `y`, at least 2 points.
  Pchip(std::vector<double> x, std::vector<double> y);
  double operator()(double x) const;  ///< clamps to the end segments' cubics outside the range
  /// Exact integral over [a, b] (a <= b, within the data range).
  double integrate(double a, double b) const;
  const std::vector<double>& slopes() const { return d_; }

 private:
  size_t segment(double x) const;
  std::vector<double> x_, y_, d_;
};

/// A Bjøntegaard figure and what it integrates over, so that a report can say it.
struct BdFigure {
  double value = 0;       ///< BD-rate in percent, or BD-PSNR in dB
  double lo = 0, hi = 0;  ///< the common interval: PSNR in dB (BD-rate), size in bytes (BD-PSNR)
  int anchor_points = 0;  ///< non-dominated points of each curve
  int test_points = 0;
};

/// Average size difference of `test` relative to `anchor` at equal PSNR, in percent (negative:
/// `test` is smaller). nullopt when a curve has fewer than 2 non-dominated points or their PSNR
/// ranges do not overlap.
std::optional<BdFigure> bd_rate_figure(const std::vector<RdPoint>& anchor,
                                       const std::vector<RdPoint>& test);
/// Average PSNR difference of `test` minus `anchor` at equal log size, in dB; nullopt likewise
/// when their log-size ranges do not overlap.
std::optional<BdFigure> bd_psnr_figure(const std::vector<RdPoint>& anchor,
                                       const std::vector<RdPoint>& test);
/// The figures' values alone.
std::optional<double> bd_rate(const std::vector<RdPoint>& anchor, const std::vector<RdPoint>& test);
std::optional<double> bd_psnr(const std::vector<RdPoint>& anchor, const std::vector<RdPoint>& test);

}  // namespace crpgs::experiments
