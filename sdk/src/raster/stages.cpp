// The CPU rasterizer stages: raw-pointer loops over float32 buffers, parallel over Gaussians or
// tiles. Every per-Gaussian or per-tile result is computed by the same code whatever the thread
// count and reduced in a fixed order, so outputs are bitwise identical for any thread count.
#include "raster/stages.h"

#include "raster/project_kernels.h"
#include "raster/tile_kernels.h"

#include <algorithm>
#include <cmath>
#include <cstring>
#include <limits>
#include <thread>
#include <utility>
#include <vector>

#ifdef _OPENMP
#include <omp.h>
#endif

namespace crpgs::raster {
namespace {

// Runs f(i) for i in [0, n); dynamic scheduling only changes who computes an item, not how.
template <typename F>
void parallel_items(int64_t n, int threads, const F& f) {
#ifdef _OPENMP
  if (threads > 1 && n > 1) {
#pragma omp parallel for num_threads(threads) schedule(dynamic, 1)
    for (int64_t i = 0; i < n; ++i) f(i);
    return;
  }
#endif
  for (int64_t i = 0; i < n; ++i) f(i);
}

// Runs f(begin, end) over chunks of a range of Gaussians.
template <typename F>
void parallel_chunks(int64_t n, int threads, const F& f) {
  constexpr int64_t kChunk = 2048;
  const int64_t chunks = (n + kChunk - 1) / kChunk;
  parallel_items(chunks, threads, [&](int64_t c) { f(c * kChunk, std::min(n, (c + 1) * kChunk)); });
}

void check_float(const at::Tensor& t, const char* name, int64_t cols) {
  TORCH_CHECK(t.defined(), "rasterizer: ", name, " is undefined");
  TORCH_CHECK(t.device().is_cpu(), "rasterizer: ", name, " must be on the CPU");
  TORCH_CHECK(t.scalar_type() == at::kFloat, "rasterizer: ", name, " must be float32");
  TORCH_CHECK(t.is_contiguous(), "rasterizer: ", name, " must be contiguous");
  if (cols > 0) {
    TORCH_CHECK(t.dim() == 2 && t.size(1) == cols, "rasterizer: ", name, " must be [N, ", cols,
                "], got ", t.sizes());
  } else {
    TORCH_CHECK(t.dim() == 1, "rasterizer: ", name, " must be [N], got ", t.sizes());
  }
}

using kernels::Packed;

std::vector<Packed> pack_all(const at::Tensor& means2d, const at::Tensor& conics,
                             const at::Tensor& opacities, const at::Tensor& colors,
                             const at::Tensor& depths, int threads) {
  const int64_t n = means2d.size(0);
  std::vector<Packed> out(static_cast<size_t>(n));
  const float* m2 = means2d.data_ptr<float>();
  const float* con = conics.data_ptr<float>();
  const float* op = opacities.data_ptr<float>();
  const float* col = colors.data_ptr<float>();
  const float* dep = depths.data_ptr<float>();
  parallel_chunks(n, threads, [&](int64_t b, int64_t e) {
    for (int64_t i = b; i < e; ++i) {
      out[i] = kernels::pack_one(m2 + 2 * i, con + 3 * i, op[i], col + 3 * i, dep[i]);
    }
  });
  return out;
}

// Tiles by decreasing length of their list (ties by index), so that the dynamic schedule
// starts the long tiles first; each tile's result does not depend on who computes it.
std::vector<int32_t> tiles_by_work(const int32_t* offsets, int n_tiles) {
  std::vector<int32_t> order(static_cast<size_t>(n_tiles));
  for (int t = 0; t < n_tiles; ++t) order[t] = t;
  std::stable_sort(order.begin(), order.end(), [&](int32_t x, int32_t y) {
    return offsets[x + 1] - offsets[x] > offsets[y + 1] - offsets[y];
  });
  return order;
}

kernels::TileInputs tile_inputs(const std::vector<Packed>& gs, const TileIntersections& isect,
                                int width, int height, const std::array<float, 3>& bg, bool depth) {
  kernels::TileInputs in;
  in.gs = gs.data();
  in.offsets = isect.tile_offsets.data_ptr<int32_t>();
  in.ids = isect.gaussian_ids.data_ptr<int32_t>();
  in.tiles_x = isect.tiles_x;
  in.width = width;
  in.height = height;
  for (int k = 0; k < 3; ++k) in.bg[k] = bg[k];
  in.depth = depth;
  return in;
}

// min(hi, max(0, floor(v))) without floor: clamping first and truncating gives the same int for
// every v (NaN -> 0), in a few branch-free instructions where baseline x86-64's floor is a
// branchy bit trick.
int clamped_floor(double v, int hi) {
  return int(std::min<double>(hi, std::max(0.0, v)));
}

// Tiles holding a pixel whose centre lies in the Gaussian's alpha >= 1/255 box (the pixel
// loops' own test, pixel_range, in the same float arithmetic); empty when there is none.
TileRect alpha_tile_rect(const float* m2, const float* con, float op, int tiles_x, int tiles_y) {
  float ex, ey;
  kernels::alpha_extent(con, op, ex, ey);
  if (ex < 0) return TileRect{0, 0, 0, 0};
  const float fx0 = std::ceil(m2[0] - ex - 0.5f), fx1 = std::floor(m2[0] + ex - 0.5f);
  const float fy0 = std::ceil(m2[1] - ey - 0.5f), fy1 = std::floor(m2[1] + ey - 0.5f);
  if (!(fx1 >= fx0 && fy1 >= fy0)) return TileRect{0, 0, 0, 0};
  // First tile of a pixel coordinate, and one past the last, clamped to [0, tiles].
  auto tile = [](float p, int tiles, int past) {
    return clamped_floor(double(p) / kTileSize + past, tiles);
  };
  return TileRect{tile(fx0, tiles_x, 0), tile(fy0, tiles_y, 0), tile(fx1, tiles_x, 1),
                  tile(fy1, tiles_y, 1)};
}

// Indices of the Gaussians with a non-empty tile rectangle, sorted by (depth, index): a stable
// LSD radix sort on the depth's bits mapped to an unsigned order (negative depths included).
std::vector<int32_t> depth_order(const float* depth, const std::vector<TileRect>& rects) {
  std::vector<int32_t> idx;
  std::vector<uint32_t> key;
  idx.reserve(rects.size());
  key.reserve(rects.size());
  for (size_t i = 0; i < rects.size(); ++i) {
    const TileRect& r = rects[i];
    if (r.x1 <= r.x0 || r.y1 <= r.y0) continue;
    uint32_t bits;
    std::memcpy(&bits, &depth[i], sizeof(bits));
    idx.push_back(int32_t(i));
    key.push_back(bits & 0x80000000u ? ~bits : bits | 0x80000000u);
  }
  constexpr int kDigitBits = 11, kBuckets = 1 << kDigitBits;
  std::vector<int32_t> idx_tmp(idx.size());
  std::vector<uint32_t> key_tmp(key.size());
  std::vector<size_t> start(kBuckets);
  for (int shift = 0; shift < 32; shift += kDigitBits) {
    std::fill(start.begin(), start.end(), size_t(0));
    for (uint32_t k : key) ++start[(k >> shift) & (kBuckets - 1)];
    if (start[(key.empty() ? 0 : key[0] >> shift) & (kBuckets - 1)] == key.size()) continue;
    size_t sum = 0;
    for (size_t& s : start) sum += std::exchange(s, sum);
    for (size_t j = 0; j < key.size(); ++j) {
      const size_t to = start[(key[j] >> shift) & (kBuckets - 1)]++;
      key_tmp[to] = key[j];
      idx_tmp[to] = idx[j];
    }
    key.swap(key_tmp);
    idx.swap(idx_tmp);
  }
  return idx;
}

}  // namespace

int resolve_threads(int requested) {
  if (requested > 0) return requested;
#ifdef _OPENMP
  return std::max(1, omp_get_num_procs());
#else
  return std::max(1u, std::thread::hardware_concurrency());
#endif
}

kernels::ProjectCamera project_camera(const Camera& c, const RenderSettings& s) {
  TORCH_CHECK(c.width > 0 && c.height > 0 && c.fx > 0 && c.fy > 0,
              "rasterizer: camera needs positive size and focal lengths");
  kernels::ProjectCamera d;
  for (int r = 0; r < 3; ++r) {
    for (int k = 0; k < 3; ++k) d.R[r][k] = c.R(r, k);
    d.t[r] = c.t[r];
  }
  d.fx = c.fx;
  d.fy = c.fy;
  d.cx = c.cx;
  d.cy = c.cy;
  d.near_plane = s.near_plane;
  d.far_plane = s.far_plane;
  const double tan_x = 0.5 * c.width / c.fx, tan_y = 0.5 * c.height / c.fy;
  d.lim_x_pos = (c.width - c.cx) / c.fx + 0.3 * tan_x;
  d.lim_x_neg = c.cx / c.fx + 0.3 * tan_x;
  d.lim_y_pos = (c.height - c.cy) / c.fy + 0.3 * tan_y;
  d.lim_y_neg = c.cy / c.fy + 0.3 * tan_y;
  return d;
}

TileRect tile_rect(float mx, float my, int radius, int tiles_x, int tiles_y) {
  const double r = radius;
  TileRect t;
  t.x0 = clamped_floor((mx - r) / kTileSize, tiles_x);
  t.y0 = clamped_floor((my - r) / kTileSize, tiles_y);
  t.x1 = clamped_floor((mx + r + kTileSize - 1) / kTileSize, tiles_x);
  t.y1 = clamped_floor((my + r + kTileSize - 1) / kTileSize, tiles_y);
  return t;
}

ProjectResult project_forward(const at::Tensor& means, const at::Tensor& scales,
                              const at::Tensor& rotations, const Camera& camera,
                              const RenderSettings& settings, int threads) {
  check_float(means, "means", 3);
  check_float(scales, "scales", 3);
  check_float(rotations, "rotations", 4);
  const int64_t n = means.size(0);
  TORCH_CHECK(scales.size(0) == n && rotations.size(0) == n,
              "rasterizer: means, scales and rotations must have the same N");
  const kernels::ProjectCamera cam = project_camera(camera, settings);
  const int tiles_x = tile_count(camera.width);
  const int tiles_y = tile_count(camera.height);
  const auto fopt = means.options();
  ProjectResult out;
  out.means2d = at::zeros({n, 2}, fopt);
  out.conics = at::zeros({n, 3}, fopt);
  out.depths = at::zeros({n}, fopt);
  out.radii = at::zeros({n}, fopt.dtype(at::kInt));
  const float* m = means.data_ptr<float>();
  const float* s = scales.data_ptr<float>();
  const float* q = rotations.data_ptr<float>();
  float* m2 = out.means2d.data_ptr<float>();
  float* con = out.conics.data_ptr<float>();
  float* dep = out.depths.data_ptr<float>();
  int32_t* rad = out.radii.data_ptr<int32_t>();
  parallel_chunks(n, threads, [&](int64_t b, int64_t e) {
    thread_local std::vector<kernels::Projected> projected;
    projected.resize(size_t(e - b));
    kernels::project_range(cam, m, s, q, b, e, projected.data());
    for (int64_t i = b; i < e; ++i) {
      const kernels::Projected& o = projected[size_t(i - b)];
      if (!o.ok || !(o.radius > 0) || !std::isfinite(o.u) || !std::isfinite(o.v)) continue;
      const TileRect tr = tile_rect(o.u, o.v, int(o.radius), tiles_x, tiles_y);
      if (tr.x1 <= tr.x0 || tr.y1 <= tr.y0) continue;
      m2[2 * i] = o.u;
      m2[2 * i + 1] = o.v;
      for (int k = 0; k < 3; ++k) con[3 * i + k] = o.conic[k];
      dep[i] = o.depth;
      rad[i] = int32_t(o.radius);
    }
  });
  return out;
}

ProjectGrads project_backward(const at::Tensor& means, const at::Tensor& scales,
                              const at::Tensor& rotations, const Camera& camera,
                              const ProjectResult& fwd, const at::Tensor& v_means2d,
                              const at::Tensor& v_conics, const at::Tensor& v_depths, int threads) {
  const int64_t n = means.size(0);
  check_float(v_means2d, "v_means2d", 2);
  check_float(v_conics, "v_conics", 3);
  check_float(v_depths, "v_depths", 0);
  RenderSettings s;  // culling is read from fwd.radii; near/far are not needed here
  s.near_plane = -std::numeric_limits<float>::infinity();
  s.far_plane = std::numeric_limits<float>::infinity();
  const kernels::ProjectCamera cam = project_camera(camera, s);
  ProjectGrads g;
  g.v_means = at::zeros({n, 3}, means.options());
  g.v_scales = at::zeros({n, 3}, means.options());
  g.v_rotations = at::zeros({n, 4}, means.options());
  const float* m = means.data_ptr<float>();
  const float* sc = scales.data_ptr<float>();
  const float* q = rotations.data_ptr<float>();
  const int32_t* rad = fwd.radii.data_ptr<int32_t>();
  const float* vm2 = v_means2d.data_ptr<float>();
  const float* vcon = v_conics.data_ptr<float>();
  const float* vdep = v_depths.data_ptr<float>();
  float* om = g.v_means.data_ptr<float>();
  float* os = g.v_scales.data_ptr<float>();
  float* oq = g.v_rotations.data_ptr<float>();
  parallel_chunks(n, threads, [&](int64_t b, int64_t e) {
    kernels::project_backward_range(cam, m, sc, q, rad, vm2, vcon, vdep, b, e, om, os, oq);
  });
  return g;
}

TileIntersections intersect_tiles(const at::Tensor& means2d, const at::Tensor& radii,
                                  const at::Tensor& depths, int width, int height, int threads,
                                  const at::Tensor& conics, const at::Tensor& opacities) {
  check_float(means2d, "means2d", 2);
  check_float(depths, "depths", 0);
  TORCH_CHECK(conics.defined() == opacities.defined(),
              "rasterizer: intersect_tiles takes both conics and opacities or neither");
  const bool alpha_boxes = conics.defined();
  if (alpha_boxes) {
    check_float(conics, "conics", 3);
    check_float(opacities, "opacities", 0);
  }
  TORCH_CHECK(radii.scalar_type() == at::kInt && radii.is_contiguous(),
              "rasterizer: radii must be contiguous int32");
  const int64_t n = means2d.size(0);
  TileIntersections out;
  out.tiles_x = tile_count(width);
  out.tiles_y = tile_count(height);
  const int n_tiles = out.tiles_x * out.tiles_y;
  const float* m2 = means2d.data_ptr<float>();
  const int32_t* rad = radii.data_ptr<int32_t>();
  const float* dep = depths.data_ptr<float>();
  // The Gaussians that touch a tile, front to back: (depth, index) order, so that filling the
  // tiles in that order leaves every tile's list sorted.
  std::vector<TileRect> rects(static_cast<size_t>(n));
  const float* con = alpha_boxes ? conics.data_ptr<float>() : nullptr;
  const float* op = alpha_boxes ? opacities.data_ptr<float>() : nullptr;
  parallel_chunks(n, threads, [&](int64_t b, int64_t e) {
    for (int64_t i = b; i < e; ++i) {
      if (rad[i] <= 0) {
        rects[i] = TileRect{0, 0, 0, 0};
        continue;
      }
      TileRect r = tile_rect(m2[2 * i], m2[2 * i + 1], rad[i], out.tiles_x, out.tiles_y);
      if (alpha_boxes) {
        const TileRect a =
            alpha_tile_rect(m2 + 2 * i, con + 3 * i, op[i], out.tiles_x, out.tiles_y);
        r = {std::max(r.x0, a.x0), std::max(r.y0, a.y0), std::min(r.x1, a.x1),
             std::min(r.y1, a.y1)};
      }
      rects[i] = r;
    }
  });
  const std::vector<int32_t> front_to_back = depth_order(dep, rects);
  const int64_t n_drawn = int64_t(front_to_back.size());
  // That order in `parts` contiguous ranges: counts per (range, tile), offsets tile-major then
  // range-minor, and each range fills its own slots of every tile.
  const int parts = int(std::max<int64_t>(1, std::min<int64_t>(threads, n_drawn / 4096)));
  auto part_begin = [&](int64_t p) { return n_drawn * p / parts; };
  std::vector<int64_t> counts(static_cast<size_t>(parts) * n_tiles, 0);
  parallel_items(parts, threads, [&](int64_t p) {
    int64_t* c = counts.data() + p * n_tiles;
    for (int64_t k = part_begin(p); k < part_begin(p + 1); ++k) {
      const TileRect& r = rects[size_t(front_to_back[size_t(k)])];
      for (int ty = r.y0; ty < r.y1; ++ty)
        for (int tx = r.x0; tx < r.x1; ++tx) ++c[ty * out.tiles_x + tx];
    }
  });
  std::vector<int64_t> cursor(counts.size());
  out.tile_offsets = at::empty({n_tiles + 1}, radii.options());
  int32_t* off = out.tile_offsets.data_ptr<int32_t>();
  int64_t total = 0;
  for (int t = 0; t < n_tiles; ++t) {
    TORCH_CHECK(total <= std::numeric_limits<int32_t>::max(),
                "rasterizer: too many tile intersections (", total, ")");
    off[t] = int32_t(total);
    for (int p = 0; p < parts; ++p) {
      cursor[size_t(p) * n_tiles + t] = total;
      total += counts[size_t(p) * n_tiles + t];
    }
  }
  TORCH_CHECK(total <= std::numeric_limits<int32_t>::max(),
              "rasterizer: too many tile intersections (", total, ")");
  off[n_tiles] = int32_t(total);
  out.gaussian_ids = at::empty({total}, radii.options());
  int32_t* ids = out.gaussian_ids.data_ptr<int32_t>();
  parallel_items(parts, threads, [&](int64_t p) {
    int64_t* cur = cursor.data() + p * n_tiles;
    for (int64_t k = part_begin(p); k < part_begin(p + 1); ++k) {
      const int32_t i = front_to_back[size_t(k)];
      const TileRect& r = rects[size_t(i)];
      for (int ty = r.y0; ty < r.y1; ++ty)
        for (int tx = r.x0; tx < r.x1; ++tx) ids[cur[ty * out.tiles_x + tx]++] = i;
    }
  });
  return out;
}

RasterizeResult rasterize_forward(const at::Tensor& means2d, const at::Tensor& conics,
                                  const at::Tensor& opacities, const at::Tensor& colors,
                                  const at::Tensor& depths, const TileIntersections& isect,
                                  int width, int height, const std::array<float, 3>& background,
                                  bool render_depth, int threads) {
  check_float(means2d, "means2d", 2);
  check_float(conics, "conics", 3);
  check_float(opacities, "opacities", 0);
  check_float(colors, "colors", 3);
  check_float(depths, "depths", 0);
  const auto fopt = means2d.options();
  RasterizeResult out;
  out.image = at::empty({height, width, 3}, fopt);
  out.alpha = at::empty({height, width, 1}, fopt);
  if (render_depth) out.depth = at::empty({height, width, 1}, fopt);
  out.final_T = at::empty({height, width}, fopt);
  out.last_contrib = at::empty({height, width}, fopt.dtype(at::kInt));
  const std::vector<Packed> gs = pack_all(means2d, conics, opacities, colors, depths, threads);
  const kernels::TileInputs in = tile_inputs(gs, isect, width, height, background, render_depth);
  kernels::ForwardOutputs fo;
  fo.image = out.image.data_ptr<float>();
  fo.alpha = out.alpha.data_ptr<float>();
  fo.depth = render_depth ? out.depth.data_ptr<float>() : nullptr;
  fo.final_T = out.final_T.data_ptr<float>();
  fo.last = out.last_contrib.data_ptr<int32_t>();
  const std::vector<int32_t> order = tiles_by_work(in.offsets, isect.tiles_x * isect.tiles_y);
  parallel_items(int64_t(order.size()), threads,
                 [&](int64_t t) { kernels::forward_tile(order[t], in, fo); });
  return out;
}

RasterizeGrads rasterize_backward(const at::Tensor& means2d, const at::Tensor& conics,
                                  const at::Tensor& opacities, const at::Tensor& colors,
                                  const at::Tensor& depths, const TileIntersections& isect,
                                  const RasterizeResult& fwd, int width, int height,
                                  const std::array<float, 3>& background, bool render_depth,
                                  const at::Tensor& v_image, const at::Tensor& v_alpha,
                                  const at::Tensor& v_depth, int threads) {
  const int64_t n = means2d.size(0);
  const auto fopt = means2d.options();
  auto ptr_or_null = [&](const at::Tensor& t, int64_t numel) -> const float* {
    if (!t.defined()) return nullptr;
    TORCH_CHECK(t.scalar_type() == at::kFloat && t.is_contiguous() && t.numel() == numel,
                "rasterizer: output gradient has the wrong shape or type");
    return t.data_ptr<float>();
  };
  const int64_t npix = int64_t(width) * height;
  const float* vi = ptr_or_null(v_image, npix * 3);
  const float* va = ptr_or_null(v_alpha, npix);
  const float* vd = render_depth ? ptr_or_null(v_depth, npix) : nullptr;
  const std::vector<Packed> gs = pack_all(means2d, conics, opacities, colors, depths, threads);
  const kernels::TileInputs in = tile_inputs(gs, isect, width, height, background, render_depth);
  kernels::BackwardInputs bi;
  bi.final_T = fwd.final_T.data_ptr<float>();
  bi.last = fwd.last_contrib.data_ptr<int32_t>();
  bi.v_image = vi;
  bi.v_alpha = va;
  bi.v_depth = vd;
  const int32_t* ids = in.ids;
  const int64_t m = isect.gaussian_ids.numel();
  constexpr int kGradSlots = kernels::kGradSlots;
  std::vector<float> entry(static_cast<size_t>(m) * kGradSlots, 0.f);
  const std::vector<int32_t> order = tiles_by_work(in.offsets, isect.tiles_x * isect.tiles_y);
  parallel_items(int64_t(order.size()), threads,
                 [&](int64_t t) { kernels::backward_tile(order[t], in, bi, entry.data()); });
  RasterizeGrads g;
  g.v_means2d = at::zeros({n, 2}, fopt);
  g.v_conics = at::zeros({n, 3}, fopt);
  g.v_opacities = at::zeros({n}, fopt);
  g.v_colors = at::zeros({n, 3}, fopt);
  g.v_depths = at::zeros({n}, fopt);
  float* om = g.v_means2d.data_ptr<float>();
  float* oc = g.v_conics.data_ptr<float>();
  float* oo = g.v_opacities.data_ptr<float>();
  float* ocol = g.v_colors.data_ptr<float>();
  float* od = g.v_depths.data_ptr<float>();
  // Fixed-order reduction over entries (tile-major) for every Gaussian, independent of the
  // thread count: each part owns a range of Gaussians and scans all entries. (A per-Gaussian
  // row of sums in one extra buffer measured a little faster in training but faulted pages on
  // every call under glibc's default allocator: bench/results/raster.md, session 11.)
  const int parts = int(std::max<int64_t>(1, std::min<int64_t>(threads, m / 65536)));
  parallel_items(parts, threads, [&](int64_t p) {
    const int64_t lo = n * p / parts, hi = n * (p + 1) / parts;
    for (int64_t k = 0; k < m; ++k) {
      const int64_t i = ids[k];
      if (i < lo || i >= hi) continue;
      const float* e = entry.data() + k * kGradSlots;
      om[2 * i] += e[0];
      om[2 * i + 1] += e[1];
      oc[3 * i] += e[2];
      oc[3 * i + 1] += e[3];
      oc[3 * i + 2] += e[4];
      oo[i] += e[5];
      ocol[3 * i] += e[6];
      ocol[3 * i + 1] += e[7];
      ocol[3 * i + 2] += e[8];
      od[i] += e[9];
    }
  });
  return g;
}

at::Tensor identity_rotations(int64_t n, const at::TensorOptions& options) {
  at::Tensor rot = at::zeros({n, 4}, options);
  if (n > 0) rot.select(1, 0).fill_(1.f);
  return rot;
}

at::Tensor visible_anchors(const at::Tensor& positions, const at::Tensor& extents,
                           const Camera& camera, const RenderSettings& settings, int threads) {
  const at::Tensor rot = identity_rotations(positions.size(0), positions.options());
  return project_forward(positions, extents, rot, camera, settings, threads).radii.gt(0);
}

}  // namespace crpgs::raster
