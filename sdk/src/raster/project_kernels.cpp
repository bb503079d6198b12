/// @file project_kernels.cpp
/// @brief project_range and project_backward_range, compiled for x86-64-v4, x86-64-v3 and
/// baseline x86-64 (target_clones) without FMA contraction: four Gaussians per step in double
/// vectors, the same IEEE operations in every clone, so the result does not depend on which clone
/// runs. The backward recomputes the forward's state with the same code (project_state).
#include "raster/project_kernels.h"

#include <algorithm>
#include <cmath>

#include "crpgs/target_clones.h"
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
typedef int64_t vl __attribute__((vector_size(kLanes * sizeof(int64_t))));
// A lane mask (all ones / all zeros) kept as doubles, and back.
CRPGS_INLINE vd bits(vl m) {
  return __builtin_bit_cast(vd, m);
}
CRPGS_INLINE vl bitsl(vd m) {
  return __builtin_bit_cast(vl, m);
}
// a where the mask is set, else +0.
CRPGS_INLINE vd keep(vd mask, vd a) {
  return __builtin_bit_cast(vd, bitsl(mask) & __builtin_bit_cast(vl, a));
}
CRPGS_INLINE vd keep(vl mask, vd a) {
  return keep(bits(mask), a);
}

// Lanes of four Gaussians.
struct Inputs {
  vd m[3], s[3], q[4];
};

CRPGS_INLINE Inputs load_lanes(const float* means, const float* scales, const float* quats,
                               const int64_t* idx) {
  Inputs in;
  for (int l = 0; l < kLanes; ++l) {
    const int64_t i = idx[l];
    for (int k = 0; k < 3; ++k) in.m[k][l] = means[3 * i + k], in.s[k][l] = scales[3 * i + k];
    for (int k = 0; k < 4; ++k) in.q[k][l] = quats[4 * i + k];
  }
  return in;
}

// What the projection computes, kept for the backward.
struct State {
  vd p[3];                        // camera-space mean
  vd qnorm, qn[4];                // |q| and the normalised quaternion
  vd Rq[3][3], M[3][3], S[3][3];  // rotation, Rq diag(s), 3D covariance M M^T
  vd tx, ty;                      // clamped x, y of the Jacobian
  vd clamp_x, clamp_y;            // all-ones bits where x/z, y/z were clamped
  vd T[2][3];                     // J R
  vd c00, c01, c11, det;          // dilated 2D covariance
};

CRPGS_INLINE void project_state(const ProjectCamera& c, const Inputs& in, State& st) {
  for (int r = 0; r < 3; ++r)
    st.p[r] = ((c.R[r][0] * in.m[0] + c.R[r][1] * in.m[1]) + c.R[r][2] * in.m[2]) + c.t[r];
  const vd z = st.p[2];
  const vd* q = in.q;
  st.qnorm = vsqrt(((q[0] * q[0] + q[1] * q[1]) + q[2] * q[2]) + q[3] * q[3]);
  const vd inv = 1.0 / vmax(st.qnorm, vd{} + kQuatEps);
  for (int k = 0; k < 4; ++k) st.qn[k] = q[k] * inv;
  const vd w = st.qn[0], x = st.qn[1], y = st.qn[2], zq = st.qn[3];
  // Rotation of the normalised quaternion (as stages.cpp's quat_to_rot).
  vd(&Rq)[3][3] = st.Rq;
  Rq[0][0] = 1 - 2 * (y * y + zq * zq);
  Rq[0][1] = 2 * (x * y - w * zq);
  Rq[0][2] = 2 * (x * zq + w * y);
  Rq[1][0] = 2 * (x * y + w * zq);
  Rq[1][1] = 1 - 2 * (x * x + zq * zq);
  Rq[1][2] = 2 * (y * zq - w * x);
  Rq[2][0] = 2 * (x * zq - w * y);
  Rq[2][1] = 2 * (y * zq + w * x);
  Rq[2][2] = 1 - 2 * (x * x + y * y);
  for (int r = 0; r < 3; ++r)
    for (int k = 0; k < 3; ++k) st.M[r][k] = Rq[r][k] * in.s[k];
  for (int r = 0; r < 3; ++r)
    for (int k = r; k < 3; ++k)
      st.S[r][k] = st.S[k][r] =
          (st.M[r][0] * st.M[k][0] + st.M[r][1] * st.M[k][1]) + st.M[r][2] * st.M[k][2];
  const vd xz = st.p[0] / z, yz = st.p[1] / z;
  const vd lo_x = vd{} - c.lim_x_neg, hi_x = vd{} + c.lim_x_pos;
  const vd lo_y = vd{} - c.lim_y_neg, hi_y = vd{} + c.lim_y_pos;
  st.clamp_x = bits(~((xz >= lo_x) & (xz <= hi_x)));
  st.clamp_y = bits(~((yz >= lo_y) & (yz <= hi_y)));
  st.tx = z * vmin(hi_x, vmax(lo_x, xz));
  st.ty = z * vmin(hi_y, vmax(lo_y, yz));
  const vd j00 = c.fx / z, j02 = -c.fx * st.tx / (z * z);
  const vd j11 = c.fy / z, j12 = -c.fy * st.ty / (z * z);
  for (int k = 0; k < 3; ++k) {
    st.T[0][k] = j00 * c.R[0][k] + j02 * c.R[2][k];
    st.T[1][k] = j11 * c.R[1][k] + j12 * c.R[2][k];
  }
  // T Sigma T^T = B B^T with B = T M, rows u and v.
  vd B[2][3];
  for (int r = 0; r < 2; ++r)
    for (int k = 0; k < 3; ++k)
      B[r][k] = (st.T[r][0] * st.M[0][k] + st.T[r][1] * st.M[1][k]) + st.T[r][2] * st.M[2][k];
  const vd uu = (B[0][0] * B[0][0] + B[0][1] * B[0][1]) + B[0][2] * B[0][2];
  const vd vv = (B[1][0] * B[1][0] + B[1][1] * B[1][1]) + B[1][2] * B[1][2];
  st.c00 = uu + kCovDilation;
  st.c01 = (B[0][0] * B[1][0] + B[0][1] * B[1][1]) + B[0][2] * B[1][2];
  st.c11 = vv + kCovDilation;
  // det = |u x v|^2 + d(|u|^2 + |v|^2) + d^2 (Lagrange's identity): non-negative terms, so it
  // stays positive and accurate for needles where c00·c11 − c01² cancels (σ² ≳ 1e14 px²).
  const vd w0 = B[0][1] * B[1][2] - B[0][2] * B[1][1];
  const vd w1 = B[0][2] * B[1][0] - B[0][0] * B[1][2];
  const vd w2 = B[0][0] * B[1][1] - B[0][1] * B[1][0];
  st.det = ((w0 * w0 + w1 * w1) + w2 * w2) + kCovDilation * (uu + vv) + kCovDilation * kCovDilation;
}

// In the depth range with a positive-definite 2D covariance: the Gaussian projects.
CRPGS_INLINE bool lane_ok(const ProjectCamera& c, const State& st, int l) {
  const double z = st.p[2][l], det = st.det[l];
  return z >= c.near_plane && z <= c.far_plane && std::isfinite(det) && det > 0;
}

CRPGS_INLINE void project_lanes(const ProjectCamera& c, const Inputs& in, Projected* out) {
  State st;
  project_state(c, in, st);
  const vd z = st.p[2];
  const vd mid = 0.5 * (st.c00 + st.c11);
  const vd lambda = mid + vsqrt(vmax(vd{}, mid * mid - st.det));
  const vd u = c.fx * st.p[0] / z + c.cx, v = c.fy * st.p[1] / z + c.cy;
  for (int l = 0; l < kLanes; ++l) {
    Projected& o = out[l];
    const double dl = st.det[l];
    o.ok = lane_ok(c, st, l);
    o.radius = std::min(kMaxRadius, std::ceil(3.0 * std::sqrt(lambda[l])));
    o.u = float(u[l]);
    o.v = float(v[l]);
    o.conic[0] = float(st.c11[l] / dl);
    o.conic[1] = float(-st.c01[l] / dl);
    o.conic[2] = float(st.c00[l] / dl);
    o.depth = float(z[l]);
  }
}

// The gradients of means, scales and quaternions from those of the 2D mean (vu, vv), the conic
// (va, vb, vc: a, b, c of [[a, b], [b, c]]) and the depth.
CRPGS_INLINE void project_backward_lanes(const ProjectCamera& c, const Inputs& in, const vd v2[2],
                                         const vd vcon[3], const vd vdep, vd v_m[3], vd v_s[3],
                                         vd v_q[4], State& st) {
  project_state(c, in, st);
  const vd x = st.p[0], y = st.p[1], z = st.p[2];
  vd vp[3];
  vp[0] = c.fx / z * v2[0];
  vp[1] = c.fy / z * v2[1];
  vp[2] = (-c.fx * x / (z * z) * v2[0] - c.fy * y / (z * z) * v2[1]) + vdep;
  // Conic = cov^-1: v_cov = -K G K with G the symmetric gradient of (a, b, c). For a needle, K
  // times T Sigma cancels terms of size σ² (σ in pixels): the gradients below lose ~1e-16·σ² of
  // their accuracy (1e-4 at σ = 1e6 px; the forward stays exact, project_state).
  const vd k00 = st.c11 / st.det, k01 = -st.c01 / st.det, k11 = st.c00 / st.det;
  const vd g00 = vcon[0], g01 = 0.5 * vcon[1], g11 = vcon[2];
  const vd kg00 = k00 * g00 + k01 * g01, kg01 = k00 * g01 + k01 * g11;
  const vd kg10 = k01 * g00 + k11 * g01, kg11 = k01 * g01 + k11 * g11;
  vd vc[2][2];
  vc[0][0] = -(kg00 * k00 + kg01 * k01);
  vc[0][1] = -(kg00 * k01 + kg01 * k11);
  vc[1][0] = -(kg10 * k00 + kg11 * k01);
  vc[1][1] = -(kg10 * k01 + kg11 * k11);
  // cov = T Sigma T^T (+ dilation), T = J R.
  vd A[2][3];  // v_cov T
  for (int r = 0; r < 2; ++r)
    for (int k = 0; k < 3; ++k) A[r][k] = vc[r][0] * st.T[0][k] + vc[r][1] * st.T[1][k];
  vd vT[2][3];  // 2 v_cov T Sigma
  for (int r = 0; r < 2; ++r)
    for (int k = 0; k < 3; ++k)
      vT[r][k] = 2.0 * ((A[r][0] * st.S[0][k] + A[r][1] * st.S[1][k]) + A[r][2] * st.S[2][k]);
  vd vS[3][3];  // T^T v_cov T
  for (int a = 0; a < 3; ++a)
    for (int b = 0; b < 3; ++b) vS[a][b] = st.T[0][a] * A[0][b] + st.T[1][a] * A[1][b];
  auto vJ = [&](int r, int a) {  // (v_T R^T)[r][a]
    return (vT[r][0] * c.R[a][0] + vT[r][1] * c.R[a][1]) + vT[r][2] * c.R[a][2];
  };
  const vd vJ00 = vJ(0, 0), vJ02 = vJ(0, 2), vJ11 = vJ(1, 1), vJ12 = vJ(1, 2);
  // J = [[fx/z, 0, -fx tx/z^2], [0, fy/z, -fy ty/z^2]].
  const vd z2 = z * z, z3 = z2 * z;
  vp[2] += ((-c.fx / z2 * vJ00 - c.fy / z2 * vJ11) + 2 * c.fx * st.tx / z3 * vJ02) +
           2 * c.fy * st.ty / z3 * vJ12;
  const vd v_tx = -c.fx / z2 * vJ02, v_ty = -c.fy / z2 * vJ12;
  // tx = z * limit where clamped, else x.
  vp[2] += keep(st.clamp_x, st.tx / z * v_tx) + keep(st.clamp_y, st.ty / z * v_ty);
  vp[0] += keep(~bitsl(st.clamp_x), v_tx);
  vp[1] += keep(~bitsl(st.clamp_y), v_ty);
  for (int k = 0; k < 3; ++k) v_m[k] = (c.R[0][k] * vp[0] + c.R[1][k] * vp[1]) + c.R[2][k] * vp[2];
  // Sigma = M M^T, M = Rq diag(s).
  vd vM[3][3];
  for (int a = 0; a < 3; ++a)
    for (int k = 0; k < 3; ++k)
      vM[a][k] = 2.0 * ((vS[a][0] * st.M[0][k] + vS[a][1] * st.M[1][k]) + vS[a][2] * st.M[2][k]);
  for (int k = 0; k < 3; ++k)
    v_s[k] = (st.Rq[0][k] * vM[0][k] + st.Rq[1][k] * vM[1][k]) + st.Rq[2][k] * vM[2][k];
  vd Gr[3][3];
  for (int a = 0; a < 3; ++a)
    for (int k = 0; k < 3; ++k) Gr[a][k] = vM[a][k] * in.s[k];
  const vd w = st.qn[0], qx = st.qn[1], qy = st.qn[2], qz = st.qn[3];
  vd vq[4];
  vq[0] = 2 * (-qz * Gr[0][1] + qy * Gr[0][2] + qz * Gr[1][0] - qx * Gr[1][2] - qy * Gr[2][0] +
               qx * Gr[2][1]);
  vq[1] = 2 * (qy * Gr[0][1] + qz * Gr[0][2] + qy * Gr[1][0] - 2 * qx * Gr[1][1] - w * Gr[1][2] +
               qz * Gr[2][0] + w * Gr[2][1] - 2 * qx * Gr[2][2]);
  vq[2] = 2 * (-2 * qy * Gr[0][0] + qx * Gr[0][1] + w * Gr[0][2] + qx * Gr[1][0] + qz * Gr[1][2] -
               w * Gr[2][0] + qz * Gr[2][1] - 2 * qy * Gr[2][2]);
  vq[3] = 2 * (-2 * qz * Gr[0][0] - w * Gr[0][1] + qx * Gr[0][2] + w * Gr[1][0] -
               2 * qz * Gr[1][1] + qy * Gr[1][2] + qx * Gr[2][0] + qy * Gr[2][1]);
  // qn = q / max(|q|, eps): project out the radial part when the norm is not clamped.
  const vd dot = ((st.qn[0] * vq[0] + st.qn[1] * vq[1]) + st.qn[2] * vq[2]) + st.qn[3] * vq[3];
  const auto unclamped = st.qnorm > kQuatEps;
  for (int k = 0; k < 4; ++k)
    v_q[k] = unclamped ? (vq[k] - st.qn[k] * dot) / st.qnorm : vq[k] / kQuatEps;
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
    project_lanes(cam, load_lanes(means, scales, quats, idx), tmp);
    for (int l = 0; l < kLanes && i + l < e; ++l) out[i - b + l] = tmp[l];
  }
}

CRPGS_TARGET_CLONES
void project_backward_range(const ProjectCamera& cam, const float* means, const float* scales,
                            const float* quats, const int32_t* radii, const float* v_means2d,
                            const float* v_conics, const float* v_depths, int64_t b, int64_t e,
                            float* v_means, float* v_scales, float* v_quats) {
  for (int64_t i = b; i < e; i += kLanes) {
    int64_t idx[kLanes];
    for (int l = 0; l < kLanes; ++l) idx[l] = std::min(i + l, e - 1);
    vd v2[2], vcon[3], vdep;
    for (int l = 0; l < kLanes; ++l) {
      const int64_t j = idx[l];
      for (int k = 0; k < 2; ++k) v2[k][l] = v_means2d[2 * j + k];
      for (int k = 0; k < 3; ++k) vcon[k][l] = v_conics[3 * j + k];
      vdep[l] = v_depths[j];
    }
    vd vm[3], vs[3], vq[4];
    State st;
    project_backward_lanes(cam, load_lanes(means, scales, quats, idx), v2, vcon, vdep, vm, vs, vq,
                           st);
    for (int l = 0; l < kLanes && i + l < e; ++l) {
      const int64_t j = i + l;
      if (radii[j] <= 0 || !lane_ok(cam, st, l)) continue;
      for (int k = 0; k < 3; ++k) v_means[3 * j + k] = float(vm[k][l]);
      for (int k = 0; k < 3; ++k) v_scales[3 * j + k] = float(vs[k][l]);
      for (int k = 0; k < 4; ++k) v_quats[4 * j + k] = float(vq[k][l]);
    }
  }
}

}  // namespace crpgs::raster::kernels
