/// @file project_kernels.cpp
/// @brief project_range, compiled for x86-64-v4, x86-64-v3 and baseline x86-64 (target_clones)
/// without FMA contraction: four Gaussians per step in double vectors, the same IEEE operations
/// in every clone, so the result does not depend on which clone runs.
#include "raster/project_kernels.h"

#include <algorithm>
#include <cmath>

#include "core/target_clones.h"
#include "raster/constants.h"

namespace crpgs::raster::kernels {
namespace {

constexpr int kLanes = 4;
typedef double vd __attribute__((vector_size(kLanes * sizeof(double))));

#define CRPGS_INLINE inline __attribute__((always_inline))

CRPGS_INLINE vd vsqrt(vd x) {
  vd r;
  for (int l = 0; l < kLanes; ++l) r[l] = __builtin_sqrt(x[l]);
  return r;
}
CRPGS_INLINE vd vmax(vd a, vd b) {
  return a < b ? b : a;
}
CRPGS_INLINE vd vmin(vd a, vd b) {
  return b < a ? b : a;
}

CRPGS_INLINE void project_lanes(const ProjectCamera& c, const float* means, const float* scales,
                                const float* quats, const int64_t* idx, Projected* out) {
  vd m[3], s[3], q[4];
  for (int l = 0; l < kLanes; ++l) {
    const int64_t i = idx[l];
    for (int k = 0; k < 3; ++k) m[k][l] = means[3 * i + k], s[k][l] = scales[3 * i + k];
    for (int k = 0; k < 4; ++k) q[k][l] = quats[4 * i + k];
  }
  vd p[3];
  for (int r = 0; r < 3; ++r)
    p[r] = ((c.R[r][0] * m[0] + c.R[r][1] * m[1]) + c.R[r][2] * m[2]) + c.t[r];
  const vd z = p[2];
  const vd qnorm = vsqrt(((q[0] * q[0] + q[1] * q[1]) + q[2] * q[2]) + q[3] * q[3]);
  const vd inv = 1.0 / vmax(qnorm, vd{} + kQuatEps);
  const vd w = q[0] * inv, x = q[1] * inv, y = q[2] * inv, zq = q[3] * inv;
  // Rotation of the normalised quaternion (stages.cpp quat_to_rot), then M = Rq diag(s).
  vd Rq[3][3];
  Rq[0][0] = 1 - 2 * (y * y + zq * zq);
  Rq[0][1] = 2 * (x * y - w * zq);
  Rq[0][2] = 2 * (x * zq + w * y);
  Rq[1][0] = 2 * (x * y + w * zq);
  Rq[1][1] = 1 - 2 * (x * x + zq * zq);
  Rq[1][2] = 2 * (y * zq - w * x);
  Rq[2][0] = 2 * (x * zq - w * y);
  Rq[2][1] = 2 * (y * zq + w * x);
  Rq[2][2] = 1 - 2 * (x * x + y * y);
  vd M[3][3];
  for (int r = 0; r < 3; ++r)
    for (int k = 0; k < 3; ++k) M[r][k] = Rq[r][k] * s[k];
  vd S[3][3];  // Sigma = M M^T
  for (int r = 0; r < 3; ++r)
    for (int k = r; k < 3; ++k)
      S[r][k] = S[k][r] = (M[r][0] * M[k][0] + M[r][1] * M[k][1]) + M[r][2] * M[k][2];
  const vd xz = p[0] / z, yz = p[1] / z;
  const vd tx = z * vmin(vd{} + c.lim_x_pos, vmax(vd{} - c.lim_x_neg, xz));
  const vd ty = z * vmin(vd{} + c.lim_y_pos, vmax(vd{} - c.lim_y_neg, yz));
  const vd j00 = c.fx / z, j02 = -c.fx * tx / (z * z);
  const vd j11 = c.fy / z, j12 = -c.fy * ty / (z * z);
  vd T[2][3];  // J R
  for (int k = 0; k < 3; ++k) {
    T[0][k] = j00 * c.R[0][k] + j02 * c.R[2][k];
    T[1][k] = j11 * c.R[1][k] + j12 * c.R[2][k];
  }
  vd U[2][3];  // T Sigma
  for (int r = 0; r < 2; ++r)
    for (int k = 0; k < 3; ++k)
      U[r][k] = (T[r][0] * S[0][k] + T[r][1] * S[1][k]) + T[r][2] * S[2][k];
  const vd c00 = ((U[0][0] * T[0][0] + U[0][1] * T[0][1]) + U[0][2] * T[0][2]) + kCovDilation;
  const vd c01 = (U[0][0] * T[1][0] + U[0][1] * T[1][1]) + U[0][2] * T[1][2];
  const vd c11 = ((U[1][0] * T[1][0] + U[1][1] * T[1][1]) + U[1][2] * T[1][2]) + kCovDilation;
  const vd det = c00 * c11 - c01 * c01;
  const vd mid = 0.5 * (c00 + c11);
  const vd lambda = mid + vsqrt(vmax(vd{}, mid * mid - det));
  const vd u = c.fx * p[0] / z + c.cx, v = c.fy * p[1] / z + c.cy;
  for (int l = 0; l < kLanes; ++l) {
    Projected& o = out[l];
    const double zl = z[l], dl = det[l];
    o.ok = zl >= c.near_plane && zl <= c.far_plane && std::isfinite(dl) && dl > 0;
    o.radius = std::min(kMaxRadius, std::ceil(3.0 * std::sqrt(lambda[l])));
    o.u = float(u[l]);
    o.v = float(v[l]);
    o.conic[0] = float(c11[l] / dl);
    o.conic[1] = float(-c01[l] / dl);
    o.conic[2] = float(c00[l] / dl);
    o.depth = float(zl);
  }
}

}  // namespace

CRPGS_TARGET_CLONES
void project_range(const ProjectCamera& cam, const float* means, const float* scales,
                   const float* quats, int64_t b, int64_t e, Projected* out) {
  for (int64_t i = b; i < e; i += kLanes) {
    // The last group repeats its last Gaussian in the unused lanes and keeps only the rest.
    int64_t idx[kLanes];
    for (int l = 0; l < kLanes; ++l) idx[l] = std::min(i + l, e - 1);
    Projected tmp[kLanes];
    project_lanes(cam, means, scales, quats, idx, tmp);
    for (int l = 0; l < kLanes && i + l < e; ++l) out[i - b + l] = tmp[l];
  }
}

}  // namespace crpgs::raster::kernels
