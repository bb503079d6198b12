// Pixel loops of the tile rasterizer. A tile is 16 rows of two 8-pixel chunks; each Gaussian
// of the tile's list is applied to the chunks its alpha >= 1/255 ellipse reaches, 8 pixels at a
// time in GCC vector types, branch-free with lane masks. The same inline code is compiled for
// x86-64-v4, x86-64-v3 (AVX2) and baseline x86-64 (target_clones; the baseline clone is slow, GCC
// splits the 8-lane code there); all do the same IEEE operations in the same order (no FMA
// contraction), so the results do not depend on which clone runs.
#include "raster/tile_kernels.h"

#include <algorithm>
#include <cmath>
#include <vector>

#include "crpgs/target_clones.h"
#include "raster/constants.h"

#define CRPGS_INLINE inline __attribute__((always_inline))
#define CRPGS_LAMBDA_INLINE __attribute__((always_inline))

namespace crpgs::raster::kernels {
namespace {

constexpr int kLanes = 8;
typedef float vf __attribute__((vector_size(kLanes * sizeof(float))));
typedef int32_t vi __attribute__((vector_size(kLanes * sizeof(int32_t))));

constexpr int kChunksPerRow = kTileSize / kLanes;
static_assert(kChunksPerRow == 2, "the pixel loops handle one or two chunks per row");
constexpr int kChunks = kTileSize * kChunksPerRow;
constexpr int kTilePixels = kTileSize * kTileSize;
static_assert(kTileSize % kLanes == 0, "a tile row is a whole number of chunks");

CRPGS_INLINE vf splat(float s) {
  return vf{} + s;
}
CRPGS_INLINE vi splati(int32_t s) {
  return vi{} + s;
}
// Lane selects as bit operations on all-ones / all-zeros masks: GCC expands `m ? a : b` with a
// compare against zero and a blend, and scalarises it on baseline x86-64.
CRPGS_INLINE vi select(vi m, vi a, vi b) {
  return (a & m) | (b & ~m);
}
CRPGS_INLINE vf select(vi m, vf a, vf b) {
  return __builtin_bit_cast(vf, select(m, __builtin_bit_cast(vi, a), __builtin_bit_cast(vi, b)));
}
// Clamps from a direct compare (GCC emits compare + blend / min / max for these).
CRPGS_INLINE vf clamp_lo(vf x, float lo) {
  return x < lo ? splat(lo) : x;
}
CRPGS_INLINE vf clamp_hi(vf x, float hi) {
  return x < hi ? x : splat(hi);
}
// a where the mask is set, else +0 (one AND, where m ? a : 0 costs a compare and a blend).
CRPGS_INLINE vf keep(vi m, vf a) {
  return __builtin_bit_cast(vf, __builtin_bit_cast(vi, a) & m);
}

// Cephes-style exp for x <= 0 (about 2 ulp), lane-wise.
CRPGS_INLINE vf vexp(vf x) {
  x = clamp_lo(x, -87.f);
  const vf kf = (x * 1.44269504088896341f + 12582912.f) - 12582912.f;  // round to nearest
  const vf r = x - kf * 0.693359375f - kf * -2.12194440e-4f;
  // 1 + r + r^2 (c5 + c4 r + c3 r^2 + c2 r^3 + c1 r^4 + c0 r^5), Estrin's scheme (short chains).
  const vf r2 = r * r, r4 = r2 * r2;
  const vf lo = 5.0000001201e-1f + 1.6666665459e-1f * r;
  const vf mid = 4.1665795894e-2f + 8.3334519073e-3f * r;
  const vf hi = 1.3981999507e-3f + 1.9875691500e-4f * r;
  const vf p = (r + 1.f) + r2 * ((lo + r2 * mid) + r4 * hi);
  const vi bits = (__builtin_convertvector(kf, vi) + 127) << 23;
  return p * __builtin_bit_cast(vf, bits);
}

CRPGS_INLINE bool any(vi m) {
  int32_t o = 0;
  for (int l = 0; l < kLanes; ++l) o |= m[l];
  return o != 0;
}

CRPGS_INLINE bool all(vi m) {
  int32_t o = -1;
  for (int l = 0; l < kLanes; ++l) o &= m[l];
  return o != 0;
}

// Fixed-order lane sum (a fixed tree: deterministic for any thread count and instruction set).
CRPGS_INLINE float hsum(vf v) {
  typedef float vf4 __attribute__((vector_size(4 * sizeof(float))));
  static_assert(kLanes == 8, "the tree below sums 8 lanes");
  const vf4 h =
      __builtin_shufflevector(v, v, 0, 1, 2, 3) + __builtin_shufflevector(v, v, 4, 5, 6, 7);
  return (h[0] + h[2]) + (h[1] + h[3]);
}

struct TileGeom {
  int x0, y0, w, h;
};

CRPGS_INLINE TileGeom tile_geom(int tile, int tiles_x, int width, int height) {
  const int tx = tile % tiles_x, ty = tile / tiles_x;
  TileGeom g;
  g.x0 = tx * kTileSize;
  g.y0 = ty * kTileSize;
  g.w = std::min(kTileSize, width - g.x0);
  g.h = std::min(kTileSize, height - g.y0);
  return g;
}

// One tile entry as the pixel loops use it: the Gaussian and its pixel box in the tile.
struct Entry {
  float mx, my, a, b, c, op, r, g, bl, d;
  int k;                  // index in the tile list
  int8_t l0, l1, r0, r1;  // tile rows [l0, l1] of the left chunk column and [r0, r1] of the right
};

// Pixels [x0, x1] x [y0, y1] (tile-relative) that the Gaussian can reach; false when none.
CRPGS_INLINE bool pixel_range(const Packed& g, const TileGeom& tg, int& x0, int& x1, int& y0,
                              int& y1) {
  if (g.ex < 0) return false;
  // Pixel x has its centre at x + 0.5 and is inside when |x + 0.5 - mx| <= ex.
  const float fx0 = std::ceil(g.mx - g.ex - 0.5f), fx1 = std::floor(g.mx + g.ex - 0.5f);
  const float fy0 = std::ceil(g.my - g.ey - 0.5f), fy1 = std::floor(g.my + g.ey - 0.5f);
  const float lo_x = float(tg.x0), hi_x = float(tg.x0 + tg.w - 1);
  const float lo_y = float(tg.y0), hi_y = float(tg.y0 + tg.h - 1);
  if (!(fx1 >= lo_x && fx0 <= hi_x && fy1 >= lo_y && fy0 <= hi_y)) return false;
  x0 = int(std::max(fx0, lo_x)) - tg.x0;
  x1 = int(std::min(fx1, hi_x)) - tg.x0;
  y0 = int(std::max(fy0, lo_y)) - tg.y0;
  y1 = int(std::min(fy1, hi_y)) - tg.y0;
  return true;
}

// Tile rows (within [y0, y1]) where the ellipse d^T K d <= q reaches pixel centres x <= xb
// (left) or x >= xb (!left). The ellipse is convex, so these rows form an interval; its ends
// are the ellipse's top / bottom points when they lie on that side, else the ends of the chord
// x = xb. In double with a margin, like the box, so float rounding never loses a pixel.
CRPGS_INLINE void strip_rows(const Packed& g, const TileGeom& tg, double xb, bool left, int y0,
                             int y1, int8_t& ya, int8_t& yb) {
  const double a = g.a, b = g.b, c = g.c, q = double(g.q) * (1 + 2e-3);
  const double det = a * c - b * b;
  if (!(det > 0)) {  // no ellipse (alpha_extent): every row of the box
    ya = int8_t(y0);
    yb = int8_t(y1);
    return;
  }
  const double ey = std::sqrt(q * a / det);
  const double x_top = g.mx + b * ey / a, x_bot = g.mx - b * ey / a;  // at y = my -/+ ey
  const double dx = g.mx - xb;
  const double disc = c * q - det * dx * dx;
  const double half = disc > 0 ? std::sqrt(disc) / c : 0.0, mid = g.my + b * dx / c;
  auto inside = [&](double x) { return left ? x <= xb : x >= xb; };
  double lo, hi;
  if (inside(x_top)) {
    lo = g.my - ey;
  } else if (disc >= 0) {
    lo = mid - half;
  } else {
    ya = 0, yb = -1;
    return;
  }
  hi = inside(x_bot) ? g.my + ey : mid + half;
  constexpr double kMargin = 0.05;  // pixels
  const double fa = std::ceil(lo - kMargin - 0.5) - tg.y0,
               fb = std::floor(hi + kMargin - 0.5) - tg.y0;
  ya = int8_t(std::max<double>(y0, std::min<double>(fa, y1 + 1)));
  yb = int8_t(std::min<double>(y1, std::max<double>(fb, y0 - 1)));
}

// Gathers entries [0, count) of the tile (those that reach a pixel) into `out`; the gather
// loads are independent, so their cache misses overlap.
CRPGS_INLINE int gather(const TileInputs& in, int tile, const TileGeom& tg, int count,
                        std::vector<Entry>& out) {
  const int start = in.offsets[tile];
  if (int(out.size()) < count) out.resize(size_t(count));
  int n = 0;
  constexpr int kAhead = 16;  // prefetch distance: the Gaussians are scattered in memory
  for (int k = 0; k < std::min(count, kAhead); ++k) __builtin_prefetch(&in.gs[in.ids[start + k]]);
  for (int k = 0; k < count; ++k) {
    if (k + kAhead < count) __builtin_prefetch(&in.gs[in.ids[start + k + kAhead]]);
    const Packed& g = in.gs[in.ids[start + k]];
    int xa, xb, ya, yb;
    if (!pixel_range(g, tg, xa, xb, ya, yb)) continue;
    Entry& e = out[size_t(n++)];
    e.mx = g.mx;
    e.my = g.my;
    e.a = g.a;
    e.b = g.b;
    e.c = g.c;
    e.op = g.op;
    e.r = g.r;
    e.g = g.g;
    e.bl = g.bl;
    e.d = g.d;
    e.k = k;
    e.l0 = e.r0 = 0;
    e.l1 = e.r1 = -1;
    if (xb < kLanes) {
      e.l0 = int8_t(ya);
      e.l1 = int8_t(yb);
    } else if (xa >= kLanes) {
      e.r0 = int8_t(ya);
      e.r1 = int8_t(yb);
    } else {  // both chunk columns: each gets the rows where the ellipse reaches it
      const double xm = tg.x0 + kLanes;  // first pixel of the right column; centres at +0.5
      strip_rows(g, tg, xm - 0.5 + 0.05, true, ya, yb, e.l0, e.l1);
      strip_rows(g, tg, xm + 0.5 - 0.05, false, ya, yb, e.r0, e.r1);
    }
  }
  return n;
}

// Calls one(c, y) for the chunk column c of every row of the entry's strips, and two(y) for
// rows where both columns are needed, so that both loop bodies stay branch-regular.
template <typename One, typename Two>
CRPGS_INLINE void for_each_strip_row(const Entry& e, const One& one, const Two& two) {
  const int bs = std::max(e.l0, e.r0), be = std::min(e.l1, e.r1);
  if (bs <= be) {
    for (int y = bs; y <= be; ++y) two(y);
    for (int y = e.l0; y < bs && y <= e.l1; ++y) one(0, y);
    for (int y = std::max(be + 1, int(e.l0)); y <= e.l1; ++y) one(0, y);
    for (int y = e.r0; y < bs && y <= e.r1; ++y) one(1, y);
    for (int y = std::max(be + 1, int(e.r0)); y <= e.r1; ++y) one(1, y);
  } else {
    for (int y = e.l0; y <= e.l1; ++y) one(0, y);
    for (int y = e.r0; y <= e.r1; ++y) one(1, y);
  }
}

// Per-column and per-row terms of the exponent, shared by forward and backward so that both
// compute bitwise the same alpha: power = -0.5 (a dx^2 + c dy^2) - b dx dy.
struct ColTerms {
  vf dx, hadx2;  // mx - pixel centre, -0.5 a dx^2
};

CRPGS_INLINE void col_terms(const Entry& e, const vf* px, ColTerms* ct) {
  for (int c = 0; c < kChunksPerRow; ++c) {
    ct[c].dx = e.mx - px[c];
    ct[c].hadx2 = -0.5f * (e.a * ct[c].dx * ct[c].dx);
  }
}

struct RowTerms {
  float dy, hcdy2, bdy;  // my - pixel centre, -0.5 c dy^2, b dy
};

CRPGS_INLINE RowTerms row_terms(const Entry& e, float py) {
  RowTerms t;
  t.dy = e.my - py;
  t.hcdy2 = -0.5f * (e.c * t.dy * t.dy);
  t.bdy = e.b * t.dy;
  return t;
}

CRPGS_INLINE vf power_of(const ColTerms& ct, const RowTerms& rt) {
  return (ct.hadx2 + rt.hcdy2) - rt.bdy * ct.dx;
}

// Per-row factors of the exponent's gradient (backward only).
struct RowGrad {
  float cdy, hdy2, ndy;  // c dy, -0.5 dy^2, -dy
};

CRPGS_INLINE RowGrad row_grad(const Entry& e, const RowTerms& rt) {
  return RowGrad{e.c * rt.dy, -0.5f * rt.dy * rt.dy, -rt.dy};
}

thread_local std::vector<Entry> tl_entries;

template <bool kDepth>
CRPGS_INLINE void forward_impl(int tile, const TileInputs& in, const ForwardOutputs& out) {
  const TileGeom tg = tile_geom(tile, in.tiles_x, in.width, in.height);
  vf T[kChunks], cr[kChunks], cg[kChunks], cb[kChunks], cd[kChunks];
  vi last[kChunks], done[kChunks];
  bool chunk_done[kChunks];
  vf px[kChunksPerRow];
  for (int c = 0; c < kChunksPerRow; ++c)
    for (int l = 0; l < kLanes; ++l) px[c][l] = float(tg.x0 + c * kLanes + l) + 0.5f;
  int n_done = 0;
  for (int i = 0; i < kChunks; ++i) {
    T[i] = splat(1.f);
    cr[i] = cg[i] = cb[i] = cd[i] = splat(0.f);
    last[i] = splati(0);
    // Padding pixels of a partial tile count as finished.
    const int row = i / kChunksPerRow, col0 = (i % kChunksPerRow) * kLanes;
    for (int l = 0; l < kLanes; ++l) {
      const bool pad = row >= tg.h || col0 + l >= tg.w;
      done[i][l] = pad ? -1 : 0;
      n_done += pad ? 1 : 0;
    }
    chunk_done[i] = all(done[i]);
  }
  const int count = in.offsets[tile + 1] - in.offsets[tile];
  std::vector<Entry>& es = tl_entries;
  const int n = gather(in, tile, tg, count, es);
  for (int j = 0; j < n && n_done < kTilePixels; ++j) {
    const Entry& e = es[size_t(j)];
    const vi kk = splati(e.k + 1);
    vi stopped = splati(0);  // minus the number of pixels that stop, per lane
    ColTerms ct[kChunksPerRow];
    col_terms(e, px, ct);
    auto step = [&](int i, const ColTerms& col, const RowTerms& rt) CRPGS_LAMBDA_INLINE {
      vf power = power_of(col, rt);
      power = keep(power <= 0.f, power);  // min(power, 0)
      const vf vis = e.op * vexp(power);
      const vf al = clamp_hi(vis, kMaxAlpha);
      const vi ok = ~done[i] & (al >= kMinAlpha);
      const vf t = T[i];
      const vf nt = t * (1.f - al);
      const vi stop = ok & (nt <= kMinTransmittance);
      const vi acc = ok & ~stop;
      const vf w = keep(acc, al * t);
      cr[i] += w * e.r;
      cg[i] += w * e.g;
      cb[i] += w * e.bl;
      if (kDepth) cd[i] += w * e.d;
      T[i] = select(acc, nt, t);
      last[i] = select(acc, kk, last[i]);
      done[i] |= stop;
      stopped += stop;
    };
    for_each_strip_row(
        e,
        [&](int c, int y) CRPGS_LAMBDA_INLINE {
          const int i = y * kChunksPerRow + c;
          if (chunk_done[i]) return;
          step(i, ct[c], row_terms(e, float(tg.y0 + y) + 0.5f));
        },
        [&](int y) CRPGS_LAMBDA_INLINE {
          const int i = y * kChunksPerRow;
          if (chunk_done[i] & chunk_done[i + 1]) return;
          const RowTerms rt = row_terms(e, float(tg.y0 + y) + 0.5f);
          step(i, ct[0], rt);
          step(i + 1, ct[1], rt);
        });
    if (any(stopped)) {  // some pixels finished: count them, update the finished chunks
      for (int l = 0; l < kLanes; ++l) n_done -= stopped[l];
      for (int i = 0; i < kChunks; ++i) chunk_done[i] = all(done[i]);
    }
  }
  for (int py = 0; py < tg.h; ++py) {
    for (int px_ = 0; px_ < tg.w; ++px_) {
      const int i = py * kChunksPerRow + px_ / kLanes, l = px_ % kLanes;
      const int64_t pix = int64_t(tg.y0 + py) * in.width + (tg.x0 + px_);
      const float t = T[i][l];
      out.image[3 * pix + 0] = cr[i][l] + t * in.bg[0];
      out.image[3 * pix + 1] = cg[i][l] + t * in.bg[1];
      out.image[3 * pix + 2] = cb[i][l] + t * in.bg[2];
      out.alpha[pix] = 1.f - t;
      if (kDepth) out.depth[pix] = cd[i][l];
      out.final_T[pix] = t;
      out.last[pix] = last[i][l];
    }
  }
}

template <bool kDepth>
CRPGS_INLINE void backward_impl(int tile, const TileInputs& in, const BackwardInputs& bw,
                                float* entry_grads) {
  const TileGeom tg = tile_geom(tile, in.tiles_x, in.width, in.height);
  vf T[kChunks], Rr[kChunks], Rg[kChunks], Rb[kChunks], Rd[kChunks];
  vf gr[kChunks], gg[kChunks], gb[kChunks], gd[kChunks], tf[kChunks];
  vi last[kChunks];
  int chunk_last[kChunks];  // max of last over the chunk: entries at or after it are skipped
  vf px[kChunksPerRow];
  for (int c = 0; c < kChunksPerRow; ++c)
    for (int l = 0; l < kLanes; ++l) px[c][l] = float(tg.x0 + c * kLanes + l) + 0.5f;
  int kmax = 0;
  for (int i = 0; i < kChunks; ++i) {
    const int row = i / kChunksPerRow, col0 = (i % kChunksPerRow) * kLanes;
    chunk_last[i] = 0;
    for (int l = 0; l < kLanes; ++l) {
      float t = 1.f, vr = 0.f, vg = 0.f, vb = 0.f, vd = 0.f, va = 0.f;
      int32_t lc = 0;
      if (row < tg.h && col0 + l < tg.w) {
        const int64_t pix = int64_t(tg.y0 + row) * in.width + (tg.x0 + col0 + l);
        t = bw.final_T[pix];
        lc = bw.last[pix];
        if (bw.v_image) {
          vr = bw.v_image[3 * pix];
          vg = bw.v_image[3 * pix + 1];
          vb = bw.v_image[3 * pix + 2];
        }
        if (kDepth && bw.v_depth) vd = bw.v_depth[pix];
        if (bw.v_alpha) va = bw.v_alpha[pix];
      }
      T[i][l] = t;
      last[i][l] = lc;
      gr[i][l] = vr;
      gg[i][l] = vg;
      gb[i][l] = vb;
      gd[i][l] = vd;
      // d(bg term + alpha output)/d alpha_i = T_final * (v_alpha - bg . v_image) / (1 - alpha_i).
      tf[i][l] = t * (va - (in.bg[0] * vr + in.bg[1] * vg + in.bg[2] * vb));
      chunk_last[i] = std::max(chunk_last[i], int(lc));
    }
    Rr[i] = Rg[i] = Rb[i] = Rd[i] = splat(0.f);
    kmax = std::max(kmax, chunk_last[i]);
  }
  const int start = in.offsets[tile];
  std::vector<Entry>& es = tl_entries;
  const int n = gather(in, tile, tg, kmax, es);
  for (int j = n - 1; j >= 0; --j) {
    const Entry& e = es[size_t(j)];
    const int k = e.k;
    const vi kv = splati(k);
    vf acc[kGradSlots];
    for (int s = 0; s < kGradSlots; ++s) acc[s] = splat(0.f);
    ColTerms ct[kChunksPerRow];
    col_terms(e, px, ct);
    vf adx[kChunksPerRow], bdx[kChunksPerRow], hdx2[kChunksPerRow];
    for (int c = 0; c < kChunksPerRow; ++c) {
      adx[c] = e.a * ct[c].dx;
      bdx[c] = e.b * ct[c].dx;
      hdx2[c] = -0.5f * (ct[c].dx * ct[c].dx);
    }
    auto step = [&](int i, int c, const RowTerms& rt, const RowGrad& rw) CRPGS_LAMBDA_INLINE {
      const ColTerms& col = ct[c];
      const vf cadx = adx[c], cbdx = bdx[c], chdx2 = hdx2[c];
      const vf dx = col.dx;
      vf power = power_of(col, rt);
      const vi nonpos = power <= 0.f;
      power = keep(nonpos, power);  // min(power, 0), as in the forward
      const vf G = vexp(power);
      const vf vis = e.op * G;
      const vf al = clamp_hi(vis, kMaxAlpha);
      const vi ok = (kv < last[i]) & (al >= kMinAlpha);
      const vf t = T[i], rr = Rr[i], rg = Rg[i], rb = Rb[i];
      const vf pr = gr[i], pg = gg[i], pb = gb[i];
      const vf oma = 1.f - al;
      const vf inv = 1.f / oma;
      const vf ti = t * inv;
      const vf w = keep(ok, al * ti);
      vf v_al = ti * ((e.r - rr) * pr + (e.g - rg) * pg + (e.bl - rb) * pb) + tf[i] * inv;
      if (kDepth) v_al += ti * (e.d - Rd[i]) * gd[i];
      v_al = keep(ok, v_al);
      acc[6] += w * pr;
      acc[7] += w * pg;
      acc[8] += w * pb;
      if (kDepth) acc[9] += w * gd[i];
      Rr[i] = select(ok, al * e.r + oma * rr, rr);
      Rg[i] = select(ok, al * e.g + oma * rg, rg);
      Rb[i] = select(ok, al * e.bl + oma * rb, rb);
      if (kDepth) Rd[i] = select(ok, al * e.d + oma * Rd[i], Rd[i]);
      T[i] = select(ok, ti, t);
      const vi unclamped = vis <= kMaxAlpha;
      const vf gv = G * v_al;
      acc[5] += keep(unclamped, gv);
      const vf v_pow = keep(unclamped & nonpos, gv * e.op);
      acc[0] -= v_pow * (cadx + rt.bdy);
      acc[1] -= v_pow * (cbdx + rw.cdy);
      acc[2] += v_pow * chdx2;
      acc[3] += v_pow * (dx * rw.ndy);
      acc[4] += v_pow * rw.hdy2;
    };
    for_each_strip_row(
        e,
        [&](int c, int y) CRPGS_LAMBDA_INLINE {
          const int i = y * kChunksPerRow + c;
          if (k >= chunk_last[i]) return;
          const RowTerms rt = row_terms(e, float(tg.y0 + y) + 0.5f);
          step(i, c, rt, row_grad(e, rt));
        },
        [&](int y) CRPGS_LAMBDA_INLINE {
          const int i = y * kChunksPerRow;
          if (k >= chunk_last[i] && k >= chunk_last[i + 1]) return;
          const RowTerms rt = row_terms(e, float(tg.y0 + y) + 0.5f);
          const RowGrad rw = row_grad(e, rt);
          step(i, 0, rt, rw);
          step(i + 1, 1, rt, rw);
        });
    float* o = entry_grads + int64_t(start + k) * kGradSlots;
    for (int s = 0; s < kGradSlots; ++s) o[s] = hsum(acc[s]);
  }
}

}  // namespace

Packed pack_one(const float* m2, const float* con, float op, const float* col, float depth) {
  Packed p{};
  p.mx = m2[0];
  p.my = m2[1];
  p.a = con[0];
  p.b = con[1];
  p.c = con[2];
  p.op = op;
  p.r = col[0];
  p.g = col[1];
  p.bl = col[2];
  p.d = depth;
  p.q = float(alpha_extent(con, op, p.ex, p.ey));
  return p;
}

double alpha_extent(const float* con, float op, float& ex, float& ey) {
  // alpha >= 1/255 needs q = d^T K d <= Q = 2 ln(255 op); the ellipse's x half-extent is
  // sqrt(Q * (K^-1)_xx). A small margin covers float rounding in the pixel loop.
  const double Q = 2.0 * std::log(255.0 * double(op));
  const double det = double(con[0]) * con[2] - double(con[1]) * con[1];
  if (!(Q > 0) || !std::isfinite(det)) {  // too faint, or a non-finite conic: draws nothing
    ex = ey = -1.f;
  } else if (!(det > 0)) {
    // A needle too long for float conics (σ ≳ 3000 px): a c − b² of the stored floats is exact
    // here and not positive, so the loop's test bounds no ellipse; the radius box does.
    ex = ey = kUnboundedExtent;
  } else {
    ex = float(std::sqrt(Q * con[2] / det) * (1 + 1e-4) + 1e-3);
    ey = float(std::sqrt(Q * con[0] / det) * (1 + 1e-4) + 1e-3);
  }
  return Q;
}

CRPGS_TARGET_CLONES
void forward_tile(int tile, const TileInputs& in, const ForwardOutputs& out) {
  if (in.depth) {
    forward_impl<true>(tile, in, out);
  } else {
    forward_impl<false>(tile, in, out);
  }
}

CRPGS_TARGET_CLONES
void backward_tile(int tile, const TileInputs& in, const BackwardInputs& bw, float* entry_grads) {
  if (in.depth) {
    backward_impl<true>(tile, in, bw, entry_grads);
  } else {
    backward_impl<false>(tile, in, bw, entry_grads);
  }
}

}  // namespace crpgs::raster::kernels
