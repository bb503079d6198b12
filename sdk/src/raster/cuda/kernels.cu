// The CUDA rasterizer's kernels: the CPU rasterizer's maths (project_kernels.cpp,
// tile_kernels.cpp, stages.cpp) ported operation for operation. Compiled with --fmad=false, so
// float and double operations round as the CPU's (which builds without contraction).
#include "raster/cuda/kernels.h"

#include <cub/device/device_radix_sort.cuh>
#include <cub/device/device_scan.cuh>

#include "raster/constants.h"

namespace crpgs::raster::cuda_kernels {
namespace {

using kernels::ProjectCamera;

constexpr int kBlock = kTileSize * kTileSize;  // one thread per pixel of a tile
constexpr int kLinearBlock = 256;
constexpr int kGradSlots = 10;  // tile_kernels.h: mean2d (2), conic (3), opacity, colour (3), depth

const char* last_error() {
  const cudaError_t e = cudaGetLastError();
  return e == cudaSuccess ? nullptr : cudaGetErrorString(e);
}

unsigned blocks_for(int64_t n) {
  return unsigned((n + kLinearBlock - 1) / kLinearBlock);
}

// ---- Projection (project_kernels.cpp's project_state, one Gaussian per thread) ------------

struct State {
  double p[3];
  double qnorm, qn[4];
  double Rq[3][3], M[3][3], S[3][3];
  double tx, ty;
  bool clamp_x, clamp_y;
  double T[2][3];
  double c00, c01, c11, det;
};

__device__ inline double dmax(double a, double b) {  // vmax: a < b ? b : a
  return a < b ? b : a;
}
__device__ inline double dmin(double a, double b) {  // vmin: b < a ? b : a
  return b < a ? b : a;
}

__device__ void project_state(const ProjectCamera& c, const float* m, const float* s,
                              const float* qi, State& st) {
  const double mx = m[0], my = m[1], mz = m[2];
  for (int r = 0; r < 3; ++r)
    st.p[r] = ((c.R[r][0] * mx + c.R[r][1] * my) + c.R[r][2] * mz) + c.t[r];
  const double z = st.p[2];
  const double q[4] = {qi[0], qi[1], qi[2], qi[3]};
  st.qnorm = sqrt(((q[0] * q[0] + q[1] * q[1]) + q[2] * q[2]) + q[3] * q[3]);
  const double inv = 1.0 / dmax(st.qnorm, kQuatEps);
  for (int k = 0; k < 4; ++k) st.qn[k] = q[k] * inv;
  const double w = st.qn[0], x = st.qn[1], y = st.qn[2], zq = st.qn[3];
  double(&Rq)[3][3] = st.Rq;
  Rq[0][0] = 1 - 2 * (y * y + zq * zq);
  Rq[0][1] = 2 * (x * y - w * zq);
  Rq[0][2] = 2 * (x * zq + w * y);
  Rq[1][0] = 2 * (x * y + w * zq);
  Rq[1][1] = 1 - 2 * (x * x + zq * zq);
  Rq[1][2] = 2 * (y * zq - w * x);
  Rq[2][0] = 2 * (x * zq - w * y);
  Rq[2][1] = 2 * (y * zq + w * x);
  Rq[2][2] = 1 - 2 * (x * x + y * y);
  const double sc[3] = {s[0], s[1], s[2]};
  for (int r = 0; r < 3; ++r)
    for (int k = 0; k < 3; ++k) st.M[r][k] = Rq[r][k] * sc[k];
  for (int r = 0; r < 3; ++r)
    for (int k = r; k < 3; ++k)
      st.S[r][k] = st.S[k][r] =
          (st.M[r][0] * st.M[k][0] + st.M[r][1] * st.M[k][1]) + st.M[r][2] * st.M[k][2];
  const double xz = st.p[0] / z, yz = st.p[1] / z;
  const double lo_x = 0.0 - c.lim_x_neg, hi_x = 0.0 + c.lim_x_pos;
  const double lo_y = 0.0 - c.lim_y_neg, hi_y = 0.0 + c.lim_y_pos;
  st.clamp_x = !((xz >= lo_x) && (xz <= hi_x));
  st.clamp_y = !((yz >= lo_y) && (yz <= hi_y));
  st.tx = z * dmin(hi_x, dmax(lo_x, xz));
  st.ty = z * dmin(hi_y, dmax(lo_y, yz));
  const double j00 = c.fx / z, j02 = -c.fx * st.tx / (z * z);
  const double j11 = c.fy / z, j12 = -c.fy * st.ty / (z * z);
  for (int k = 0; k < 3; ++k) {
    st.T[0][k] = j00 * c.R[0][k] + j02 * c.R[2][k];
    st.T[1][k] = j11 * c.R[1][k] + j12 * c.R[2][k];
  }
  double B[2][3];
  for (int r = 0; r < 2; ++r)
    for (int k = 0; k < 3; ++k)
      B[r][k] = (st.T[r][0] * st.M[0][k] + st.T[r][1] * st.M[1][k]) + st.T[r][2] * st.M[2][k];
  const double uu = (B[0][0] * B[0][0] + B[0][1] * B[0][1]) + B[0][2] * B[0][2];
  const double vv = (B[1][0] * B[1][0] + B[1][1] * B[1][1]) + B[1][2] * B[1][2];
  st.c00 = uu + kCovDilation;
  st.c01 = (B[0][0] * B[1][0] + B[0][1] * B[1][1]) + B[0][2] * B[1][2];
  st.c11 = vv + kCovDilation;
  const double w0 = B[0][1] * B[1][2] - B[0][2] * B[1][1];
  const double w1 = B[0][2] * B[1][0] - B[0][0] * B[1][2];
  const double w2 = B[0][0] * B[1][1] - B[0][1] * B[1][0];
  st.det = ((w0 * w0 + w1 * w1) + w2 * w2) + kCovDilation * (uu + vv) + kCovDilation * kCovDilation;
}

__device__ inline bool state_ok(const ProjectCamera& c, const State& st) {
  const double z = st.p[2], det = st.det;
  return z >= c.near_plane && z <= c.far_plane && isfinite(det) && det > 0;
}

// stages.cpp's clamped_floor: min(hi, max(0, v)) truncated (NaN -> 0).
__device__ inline int clamped_floor(double v, int hi) {
  const double lo = 0.0 < v ? v : 0.0;
  return int(lo < hi ? lo : double(hi));
}

struct Rect {
  int x0, y0, x1, y1;
};

__device__ inline Rect tile_rect(float mx, float my, int radius, int tiles_x, int tiles_y) {
  const double r = radius;
  return Rect{clamped_floor((mx - r) / kTileSize, tiles_x),
              clamped_floor((my - r) / kTileSize, tiles_y),
              clamped_floor((mx + r + kTileSize - 1) / kTileSize, tiles_x),
              clamped_floor((my + r + kTileSize - 1) / kTileSize, tiles_y)};
}

__global__ void project_forward_kernel(ProjectCamera cam, int64_t n, const float* means,
                                       const float* scales, const float* quats, int tiles_x,
                                       int tiles_y, float* means2d, float* conics, float* depths,
                                       int32_t* radii) {
  const int64_t i = int64_t(blockIdx.x) * blockDim.x + threadIdx.x;
  if (i >= n) return;
  State st;
  project_state(cam, means + 3 * i, scales + 3 * i, quats + 4 * i, st);
  const double z = st.p[2];
  const double mid = 0.5 * (st.c00 + st.c11);
  const double lambda = mid + sqrt(dmax(0.0, mid * mid - st.det));
  const double rc = ceil(3.0 * sqrt(lambda));
  const double radius = rc < kMaxRadius ? rc : kMaxRadius;  // std::min(kMaxRadius, rc)
  const float u = float(cam.fx * st.p[0] / z + cam.cx), v = float(cam.fy * st.p[1] / z + cam.cy);
  if (!state_ok(cam, st) || !(radius > 0) || !isfinite(u) || !isfinite(v)) return;
  const Rect tr = tile_rect(u, v, int(radius), tiles_x, tiles_y);
  if (tr.x1 <= tr.x0 || tr.y1 <= tr.y0) return;
  means2d[2 * i] = u;
  means2d[2 * i + 1] = v;
  conics[3 * i] = float(st.c11 / st.det);
  conics[3 * i + 1] = float(-st.c01 / st.det);
  conics[3 * i + 2] = float(st.c00 / st.det);
  depths[i] = float(z);
  radii[i] = int32_t(radius);
}

__global__ void project_backward_kernel(ProjectCamera c, int64_t n, const float* means,
                                        const float* scales, const float* quats,
                                        const int32_t* radii, const float* v_means2d,
                                        const float* v_conics, const float* v_depths,
                                        float* v_means, float* v_scales, float* v_quats) {
  const int64_t i = int64_t(blockIdx.x) * blockDim.x + threadIdx.x;
  if (i >= n || radii[i] <= 0) return;
  State st;
  project_state(c, means + 3 * i, scales + 3 * i, quats + 4 * i, st);
  if (!state_ok(c, st)) return;
  const double v2[2] = {v_means2d[2 * i], v_means2d[2 * i + 1]};
  const double vcon[3] = {v_conics[3 * i], v_conics[3 * i + 1], v_conics[3 * i + 2]};
  const double vdep = v_depths[i];
  const double x = st.p[0], y = st.p[1], z = st.p[2];
  double vp[3];
  vp[0] = c.fx / z * v2[0];
  vp[1] = c.fy / z * v2[1];
  vp[2] = (-c.fx * x / (z * z) * v2[0] - c.fy * y / (z * z) * v2[1]) + vdep;
  const double k00 = st.c11 / st.det, k01 = -st.c01 / st.det, k11 = st.c00 / st.det;
  const double g00 = vcon[0], g01 = 0.5 * vcon[1], g11 = vcon[2];
  const double kg00 = k00 * g00 + k01 * g01, kg01 = k00 * g01 + k01 * g11;
  const double kg10 = k01 * g00 + k11 * g01, kg11 = k01 * g01 + k11 * g11;
  double vc[2][2];
  vc[0][0] = -(kg00 * k00 + kg01 * k01);
  vc[0][1] = -(kg00 * k01 + kg01 * k11);
  vc[1][0] = -(kg10 * k00 + kg11 * k01);
  vc[1][1] = -(kg10 * k01 + kg11 * k11);
  double A[2][3];
  for (int r = 0; r < 2; ++r)
    for (int k = 0; k < 3; ++k) A[r][k] = vc[r][0] * st.T[0][k] + vc[r][1] * st.T[1][k];
  double vT[2][3];
  for (int r = 0; r < 2; ++r)
    for (int k = 0; k < 3; ++k)
      vT[r][k] = 2.0 * ((A[r][0] * st.S[0][k] + A[r][1] * st.S[1][k]) + A[r][2] * st.S[2][k]);
  double vS[3][3];
  for (int a = 0; a < 3; ++a)
    for (int b = 0; b < 3; ++b) vS[a][b] = st.T[0][a] * A[0][b] + st.T[1][a] * A[1][b];
  auto vJ = [&](int r, int a) {
    return (vT[r][0] * c.R[a][0] + vT[r][1] * c.R[a][1]) + vT[r][2] * c.R[a][2];
  };
  const double vJ00 = vJ(0, 0), vJ02 = vJ(0, 2), vJ11 = vJ(1, 1), vJ12 = vJ(1, 2);
  const double z2 = z * z, z3 = z2 * z;
  vp[2] += ((-c.fx / z2 * vJ00 - c.fy / z2 * vJ11) + 2 * c.fx * st.tx / z3 * vJ02) +
           2 * c.fy * st.ty / z3 * vJ12;
  const double v_tx = -c.fx / z2 * vJ02, v_ty = -c.fy / z2 * vJ12;
  vp[2] += (st.clamp_x ? st.tx / z * v_tx : 0.0) + (st.clamp_y ? st.ty / z * v_ty : 0.0);
  vp[0] += st.clamp_x ? 0.0 : v_tx;
  vp[1] += st.clamp_y ? 0.0 : v_ty;
  for (int k = 0; k < 3; ++k)
    v_means[3 * i + k] = float((c.R[0][k] * vp[0] + c.R[1][k] * vp[1]) + c.R[2][k] * vp[2]);
  double vM[3][3];
  for (int a = 0; a < 3; ++a)
    for (int k = 0; k < 3; ++k)
      vM[a][k] = 2.0 * ((vS[a][0] * st.M[0][k] + vS[a][1] * st.M[1][k]) + vS[a][2] * st.M[2][k]);
  for (int k = 0; k < 3; ++k)
    v_scales[3 * i + k] =
        float((st.Rq[0][k] * vM[0][k] + st.Rq[1][k] * vM[1][k]) + st.Rq[2][k] * vM[2][k]);
  const double s[3] = {scales[3 * i], scales[3 * i + 1], scales[3 * i + 2]};
  double Gr[3][3];
  for (int a = 0; a < 3; ++a)
    for (int k = 0; k < 3; ++k) Gr[a][k] = vM[a][k] * s[k];
  const double w = st.qn[0], qx = st.qn[1], qy = st.qn[2], qz = st.qn[3];
  double vq[4];
  vq[0] = 2 * (-qz * Gr[0][1] + qy * Gr[0][2] + qz * Gr[1][0] - qx * Gr[1][2] - qy * Gr[2][0] +
               qx * Gr[2][1]);
  vq[1] = 2 * (qy * Gr[0][1] + qz * Gr[0][2] + qy * Gr[1][0] - 2 * qx * Gr[1][1] - w * Gr[1][2] +
               qz * Gr[2][0] + w * Gr[2][1] - 2 * qx * Gr[2][2]);
  vq[2] = 2 * (-2 * qy * Gr[0][0] + qx * Gr[0][1] + w * Gr[0][2] + qx * Gr[1][0] + qz * Gr[1][2] -
               w * Gr[2][0] + qz * Gr[2][1] - 2 * qy * Gr[2][2]);
  vq[3] = 2 * (-2 * qz * Gr[0][0] - w * Gr[0][1] + qx * Gr[0][2] + w * Gr[1][0] -
               2 * qz * Gr[1][1] + qy * Gr[1][2] + qx * Gr[2][0] + qy * Gr[2][1]);
  const double dot = ((st.qn[0] * vq[0] + st.qn[1] * vq[1]) + st.qn[2] * vq[2]) + st.qn[3] * vq[3];
  const bool unclamped = st.qnorm > kQuatEps;
  for (int k = 0; k < 4; ++k)
    v_quats[4 * i + k] = float(unclamped ? (vq[k] - st.qn[k] * dot) / st.qnorm : vq[k] / kQuatEps);
}

// ---- Tile intersection (stages.cpp's intersect_tiles) -------------------------------------

// tile_kernels.cpp's alpha_extent: false when the Gaussian draws nothing; unbounded extents
// when the float conic bounds no ellipse.
__device__ inline bool alpha_extent(float a, float b, float c, float op, float& ex, float& ey) {
  const double Q = 2.0 * log(255.0 * double(op));
  const double det = double(a) * c - double(b) * b;
  if (!(Q > 0) || !isfinite(det)) return false;
  if (!(det > 0)) {
    ex = ey = 1e30f;
  } else {
    ex = float(sqrt(Q * c / det) * (1 + 1e-4) + 1e-3);
    ey = float(sqrt(Q * a / det) * (1 + 1e-4) + 1e-3);
  }
  return true;
}

__device__ inline Rect alpha_tile_rect(const float* m2, const float* con, float op, int tiles_x,
                                       int tiles_y) {
  float ex, ey;
  if (!alpha_extent(con[0], con[1], con[2], op, ex, ey)) return Rect{0, 0, 0, 0};
  const float fx0 = ceilf(m2[0] - ex - 0.5f), fx1 = floorf(m2[0] + ex - 0.5f);
  const float fy0 = ceilf(m2[1] - ey - 0.5f), fy1 = floorf(m2[1] + ey - 0.5f);
  if (!(fx1 >= fx0 && fy1 >= fy0)) return Rect{0, 0, 0, 0};
  auto tile = [](float p, int tiles, int past) {
    return clamped_floor(double(p) / kTileSize + past, tiles);
  };
  return Rect{tile(fx0, tiles_x, 0), tile(fy0, tiles_y, 0), tile(fx1, tiles_x, 1),
              tile(fy1, tiles_y, 1)};
}

__global__ void tile_rects_kernel(int64_t n, const float* means2d, const int32_t* radii,
                                  const float* conics, const float* opacities, int tiles_x,
                                  int tiles_y, int32_t* rects, int64_t* counts) {
  const int64_t i = int64_t(blockIdx.x) * blockDim.x + threadIdx.x;
  if (i >= n) return;
  Rect r{0, 0, 0, 0};
  if (radii[i] > 0) {
    r = tile_rect(means2d[2 * i], means2d[2 * i + 1], radii[i], tiles_x, tiles_y);
    if (conics) {
      const Rect a =
          alpha_tile_rect(means2d + 2 * i, conics + 3 * i, opacities[i], tiles_x, tiles_y);
      r = Rect{max(r.x0, a.x0), max(r.y0, a.y0), min(r.x1, a.x1), min(r.y1, a.y1)};
    }
  }
  const bool empty = r.x1 <= r.x0 || r.y1 <= r.y0;
  rects[4 * i] = r.x0;
  rects[4 * i + 1] = r.y0;
  rects[4 * i + 2] = r.x1;
  rects[4 * i + 3] = r.y1;
  counts[i] = empty ? 0 : int64_t(r.x1 - r.x0) * (r.y1 - r.y0);
}

__global__ void emit_kernel(int64_t n, const int32_t* rects, const int64_t* cumulative,
                            const float* depths, int tiles_x, int64_t* keys, int32_t* ids) {
  const int64_t i = int64_t(blockIdx.x) * blockDim.x + threadIdx.x;
  if (i >= n) return;
  const int x0 = rects[4 * i], y0 = rects[4 * i + 1], x1 = rects[4 * i + 2], y1 = rects[4 * i + 3];
  if (x1 <= x0 || y1 <= y0) return;
  // Depth bits in an unsigned order (negative depths included), as stages.cpp's depth_order.
  const uint32_t bits = __float_as_uint(depths[i]);
  const uint64_t key = bits & 0x80000000u ? ~bits : bits | 0x80000000u;
  int64_t k = cumulative[i] - int64_t(x1 - x0) * (y1 - y0);
  for (int ty = y0; ty < y1; ++ty)
    for (int tx = x0; tx < x1; ++tx, ++k) {
      keys[k] = int64_t((uint64_t(ty * tiles_x + tx) << 32) | key);
      ids[k] = int32_t(i);
    }
}

__global__ void tile_offsets_kernel(const int64_t* keys, int64_t m, int n_tiles, int32_t* offsets) {
  const int t = blockIdx.x * blockDim.x + threadIdx.x;
  if (t > n_tiles) return;
  int64_t lo = 0, hi = m;  // first entry whose tile is >= t
  while (lo < hi) {
    const int64_t mid = (lo + hi) / 2;
    if ((uint64_t(keys[mid]) >> 32) < uint64_t(t)) {
      lo = mid + 1;
    } else {
      hi = mid;
    }
  }
  offsets[t] = int32_t(lo);
}

// ---- Pixel loops (tile_kernels.cpp, one thread per pixel) ---------------------------------

// tile_kernels.cpp's vexp: Cephes-style exp, the same float operations.
__device__ inline float cephes_exp(float x) {
  x = x < -87.f ? -87.f : x;
  const float kf = (x * 1.44269504088896341f + 12582912.f) - 12582912.f;
  const float r = x - kf * 0.693359375f - kf * -2.12194440e-4f;
  const float r2 = r * r, r4 = r2 * r2;
  const float lo = 5.0000001201e-1f + 1.6666665459e-1f * r;
  const float mid = 4.1665795894e-2f + 8.3334519073e-3f * r;
  const float hi = 1.3981999507e-3f + 1.9875691500e-4f * r;
  const float p = (r + 1.f) + r2 * ((lo + r2 * mid) + r4 * hi);
  return p * __int_as_float((int(kf) + 127) << 23);
}

// One tile entry in shared memory.
struct Entry {
  float mx, my, a, b, c, op, r, g, bl, d;
  int32_t id;
  bool draws;  // alpha can reach 1/255 somewhere (alpha_extent)
};

__device__ inline void load_entry(const TileBuffers& in, int32_t id, Entry& e) {
  e.id = id;
  e.mx = in.means2d[2 * id];
  e.my = in.means2d[2 * id + 1];
  e.a = in.conics[3 * id];
  e.b = in.conics[3 * id + 1];
  e.c = in.conics[3 * id + 2];
  e.op = in.opacities[id];
  e.r = in.colors[3 * id];
  e.g = in.colors[3 * id + 1];
  e.bl = in.colors[3 * id + 2];
  e.d = in.depth ? in.depths[id] : 0.f;
  float ex, ey;
  e.draws = alpha_extent(e.a, e.b, e.c, e.op, ex, ey);
}

// power = -0.5 (a dx^2 + c dy^2) - b dx dy, min(power, 0), in tile_kernels.cpp's order.
__device__ inline float power_at(const Entry& e, float dx, float dy, bool& nonpos) {
  const float hadx2 = -0.5f * (e.a * dx * dx);
  const float hcdy2 = -0.5f * (e.c * dy * dy);
  const float power = (hadx2 + hcdy2) - e.b * dy * dx;
  nonpos = power <= 0.f;
  return nonpos ? power : 0.f;
}

// This thread's pixel of the block's tile (one thread per pixel, row-major).
struct TilePixel {
  int64_t pix;   // index in the image, valid when inside
  bool inside;   // within the image (the last tiles of a row / column may overhang)
  float xc, yc;  // pixel centre
};

__device__ inline TilePixel tile_pixel(const TileBuffers& in, int tile) {
  const int x = (tile % in.tiles_x) * kTileSize + int(threadIdx.x) % kTileSize;
  const int y = (tile / in.tiles_x) * kTileSize + int(threadIdx.x) / kTileSize;
  return TilePixel{int64_t(y) * in.width + x, x < in.width && y < in.height, float(x) + 0.5f,
                   float(y) + 0.5f};
}

__global__ void __launch_bounds__(kBlock)
    forward_kernel(TileBuffers in, float* image, float* alpha, float* depth, float* final_T,
                   int32_t* last) {
  const int tile = blockIdx.x;
  const TilePixel p = tile_pixel(in, tile);
  const bool inside = p.inside;
  const float pxc = p.xc, pyc = p.yc;
  const int start = in.offsets[tile], end = in.offsets[tile + 1];
  __shared__ Entry batch[kBlock];
  bool done = !inside;
  float T = 1.f, cr = 0.f, cg = 0.f, cb = 0.f, cd = 0.f;
  int32_t lastk = 0;
  for (int b0 = start; b0 < end; b0 += kBlock) {
    if (__syncthreads_count(done) == kBlock) break;
    if (b0 + int(threadIdx.x) < end) load_entry(in, in.ids[b0 + threadIdx.x], batch[threadIdx.x]);
    __syncthreads();
    const int count = min(kBlock, end - b0);
    for (int j = 0; j < count && !done; ++j) {
      const Entry& e = batch[j];
      if (!e.draws) continue;
      bool nonpos;
      const float power = power_at(e, e.mx - pxc, e.my - pyc, nonpos);
      const float vis = e.op * cephes_exp(power);
      const float al = vis < kMaxAlpha ? vis : kMaxAlpha;
      if (!(al >= kMinAlpha)) continue;
      const float nt = T * (1.f - al);
      if (nt <= kMinTransmittance) {
        done = true;
        break;
      }
      const float w = al * T;
      cr += w * e.r;
      cg += w * e.g;
      cb += w * e.bl;
      if (in.depth) cd += w * e.d;
      T = nt;
      lastk = b0 - start + j + 1;
    }
  }
  if (!inside) return;
  const int64_t pix = p.pix;
  image[3 * pix] = cr + T * in.bg[0];
  image[3 * pix + 1] = cg + T * in.bg[1];
  image[3 * pix + 2] = cb + T * in.bg[2];
  alpha[pix] = 1.f - T;
  if (in.depth) depth[pix] = cd;
  final_T[pix] = T;
  last[pix] = lastk;
}

__device__ inline float warp_sum(float v) {
  for (int o = 16; o > 0; o /= 2) v += __shfl_down_sync(0xffffffffu, v, o);
  return v;
}

__global__ void __launch_bounds__(kBlock)
    backward_kernel(TileBuffers in, const float* final_T, const int32_t* last, const float* v_image,
                    const float* v_alpha, const float* v_depth, float* v_means2d, float* v_conics,
                    float* v_opacities, float* v_colors, float* v_depths) {
  const int tile = blockIdx.x;
  const TilePixel p = tile_pixel(in, tile);
  const bool inside = p.inside;
  const float pxc = p.xc, pyc = p.yc;
  const int start = in.offsets[tile];
  float T = 1.f, pr = 0.f, pg = 0.f, pb = 0.f, gd = 0.f, va = 0.f;
  int32_t lastk = 0;
  if (inside) {
    const int64_t pix = p.pix;
    T = final_T[pix];
    lastk = last[pix];
    if (v_image) {
      pr = v_image[3 * pix];
      pg = v_image[3 * pix + 1];
      pb = v_image[3 * pix + 2];
    }
    if (in.depth && v_depth) gd = v_depth[pix];
    if (v_alpha) va = v_alpha[pix];
  }
  // d(background term + alpha output)/d alpha_i = T_final (v_alpha - bg . v_image) / (1 - alpha_i).
  const float tf = T * (va - (in.bg[0] * pr + in.bg[1] * pg + in.bg[2] * pb));
  float Rr = 0.f, Rg = 0.f, Rb = 0.f, Rd = 0.f;
  __shared__ int kmax;
  if (threadIdx.x == 0) kmax = 0;
  __syncthreads();
  atomicMax(&kmax, lastk);
  __syncthreads();
  __shared__ Entry batch[kBlock];
  const int lane = int(threadIdx.x) % 32;
  for (int b1 = kmax; b1 > 0; b1 -= kBlock) {
    const int b0 = max(0, b1 - kBlock);
    __syncthreads();  // the previous batch is no longer read
    if (b0 + int(threadIdx.x) < b1)
      load_entry(in, in.ids[start + b0 + threadIdx.x], batch[threadIdx.x]);
    __syncthreads();
    for (int k = b1 - 1; k >= b0; --k) {
      const Entry& e = batch[k - b0];
      if (!e.draws) continue;
      const float dx = e.mx - pxc, dy = e.my - pyc;
      bool nonpos;
      const float power = power_at(e, dx, dy, nonpos);
      const float G = cephes_exp(power);
      const float vis = e.op * G;
      const float al = vis < kMaxAlpha ? vis : kMaxAlpha;
      const bool ok = k < lastk && al >= kMinAlpha;
      if (!__any_sync(0xffffffffu, ok)) continue;
      float acc[kGradSlots];
      for (int s = 0; s < kGradSlots; ++s) acc[s] = 0.f;
      if (ok) {
        const float oma = 1.f - al;
        const float inv = 1.f / oma;
        const float ti = T * inv;
        const float w = al * ti;
        float v_al = ti * ((e.r - Rr) * pr + (e.g - Rg) * pg + (e.bl - Rb) * pb) + tf * inv;
        if (in.depth) v_al += ti * (e.d - Rd) * gd;
        acc[6] = w * pr;
        acc[7] = w * pg;
        acc[8] = w * pb;
        if (in.depth) acc[9] = w * gd;
        Rr = al * e.r + oma * Rr;
        Rg = al * e.g + oma * Rg;
        Rb = al * e.bl + oma * Rb;
        if (in.depth) Rd = al * e.d + oma * Rd;
        T = ti;
        const bool unclamped = vis <= kMaxAlpha;
        const float gv = G * v_al;
        if (unclamped) acc[5] = gv;
        if (unclamped && nonpos) {
          const float v_pow = gv * e.op;
          acc[0] = -(v_pow * (e.a * dx + e.b * dy));
          acc[1] = -(v_pow * (e.b * dx + e.c * dy));
          acc[2] = v_pow * (-0.5f * (dx * dx));
          acc[3] = v_pow * (dx * -dy);
          acc[4] = v_pow * (-0.5f * dy * dy);
        }
      }
      for (int s = 0; s < kGradSlots; ++s) acc[s] = warp_sum(acc[s]);
      if (lane == 0) {
        const int64_t i = e.id;
        atomicAdd(v_means2d + 2 * i, acc[0]);
        atomicAdd(v_means2d + 2 * i + 1, acc[1]);
        atomicAdd(v_conics + 3 * i, acc[2]);
        atomicAdd(v_conics + 3 * i + 1, acc[3]);
        atomicAdd(v_conics + 3 * i + 2, acc[4]);
        atomicAdd(v_opacities + i, acc[5]);
        atomicAdd(v_colors + 3 * i, acc[6]);
        atomicAdd(v_colors + 3 * i + 1, acc[7]);
        atomicAdd(v_colors + 3 * i + 2, acc[8]);
        if (in.depth) atomicAdd(v_depths + i, acc[9]);
      }
    }
  }
}

}  // namespace

const char* project_forward(const ProjectCamera& cam, int64_t n, const float* means,
                            const float* scales, const float* quats, int tiles_x, int tiles_y,
                            float* means2d, float* conics, float* depths, int32_t* radii) {
  if (n == 0) return nullptr;
  project_forward_kernel<<<blocks_for(n), kLinearBlock>>>(cam, n, means, scales, quats, tiles_x,
                                                          tiles_y, means2d, conics, depths, radii);
  return last_error();
}

const char* project_backward(const ProjectCamera& cam, int64_t n, const float* means,
                             const float* scales, const float* quats, const int32_t* radii,
                             const float* v_means2d, const float* v_conics, const float* v_depths,
                             float* v_means, float* v_scales, float* v_quats) {
  if (n == 0) return nullptr;
  project_backward_kernel<<<blocks_for(n), kLinearBlock>>>(cam, n, means, scales, quats, radii,
                                                           v_means2d, v_conics, v_depths, v_means,
                                                           v_scales, v_quats);
  return last_error();
}

const char* tile_rects(int64_t n, const float* means2d, const int32_t* radii, const float* conics,
                       const float* opacities, int tiles_x, int tiles_y, int32_t* rects,
                       int64_t* counts) {
  if (n == 0) return nullptr;
  tile_rects_kernel<<<blocks_for(n), kLinearBlock>>>(n, means2d, radii, conics, opacities, tiles_x,
                                                     tiles_y, rects, counts);
  return last_error();
}

const char* inclusive_sum(void* temp, size_t& temp_bytes, const int64_t* counts,
                          int64_t* cumulative, int64_t n) {
  const cudaError_t e = cub::DeviceScan::InclusiveSum(temp, temp_bytes, counts, cumulative, n);
  return e == cudaSuccess ? last_error() : cudaGetErrorString(e);
}

const char* emit_intersections(int64_t n, const int32_t* rects, const int64_t* cumulative,
                               const float* depths, int tiles_x, int64_t* keys, int32_t* ids) {
  if (n == 0) return nullptr;
  emit_kernel<<<blocks_for(n), kLinearBlock>>>(n, rects, cumulative, depths, tiles_x, keys, ids);
  return last_error();
}

const char* sort_intersections(void* temp, size_t& temp_bytes, const int64_t* keys_in,
                               int64_t* keys_out, const int32_t* ids_in, int32_t* ids_out,
                               int64_t m, int end_bit) {
  const cudaError_t e = cub::DeviceRadixSort::SortPairs(
      temp, temp_bytes, reinterpret_cast<const unsigned long long*>(keys_in),
      reinterpret_cast<unsigned long long*>(keys_out), ids_in, ids_out, m, 0, end_bit);
  return e == cudaSuccess ? last_error() : cudaGetErrorString(e);
}

const char* tile_offsets(const int64_t* sorted_keys, int64_t m, int n_tiles, int32_t* offsets) {
  tile_offsets_kernel<<<blocks_for(int64_t(n_tiles) + 1), kLinearBlock>>>(sorted_keys, m, n_tiles,
                                                                          offsets);
  return last_error();
}

const char* rasterize_forward(const TileBuffers& in, float* image, float* alpha, float* depth,
                              float* final_T, int32_t* last) {
  const int n_tiles = in.tiles_x * in.tiles_y;
  if (n_tiles == 0) return nullptr;
  forward_kernel<<<n_tiles, kBlock>>>(in, image, alpha, depth, final_T, last);
  return last_error();
}

const char* rasterize_backward(const TileBuffers& in, const float* final_T, const int32_t* last,
                               const float* v_image, const float* v_alpha, const float* v_depth,
                               float* v_means2d, float* v_conics, float* v_opacities,
                               float* v_colors, float* v_depths) {
  const int n_tiles = in.tiles_x * in.tiles_y;
  if (n_tiles == 0) return nullptr;
  backward_kernel<<<n_tiles, kBlock>>>(in, final_T, last, v_image, v_alpha, v_depth, v_means2d,
                                       v_conics, v_opacities, v_colors, v_depths);
  return last_error();
}

}  // namespace crpgs::raster::cuda_kernels
