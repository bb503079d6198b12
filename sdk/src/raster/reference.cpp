// Float64 reference: tensor ops only, autograd gives every gradient. Culling decisions and tile
// lists are computed from detached values, exactly as the fast path decides them.
#include "raster/reference.h"

#include <algorithm>
#include <cmath>
#include <numeric>
#include <vector>

#include "raster/stages.h"

namespace crpgs::raster::reference {
namespace {

at::Tensor mat_tensor(const Eigen::Matrix3d& m) {
  at::Tensor t = at::empty({3, 3}, at::kDouble);
  auto a = t.accessor<double, 2>();
  for (int r = 0; r < 3; ++r)
    for (int c = 0; c < 3; ++c) a[r][c] = m(r, c);
  return t;
}

}  // namespace

Projection project(const at::Tensor& means, const at::Tensor& scales, const at::Tensor& rotations,
                   const Camera& camera, const RenderSettings& settings) {
  const int64_t n = means.size(0);
  const auto dopt = at::TensorOptions().dtype(at::kDouble);
  const at::Tensor R = mat_tensor(camera.R);
  const at::Tensor t = at::tensor({camera.t.x(), camera.t.y(), camera.t.z()}, dopt);
  Projection out;
  out.means2d = at::zeros({n, 2}, dopt);
  out.conics = at::zeros({n, 3}, dopt);
  out.depths = at::zeros({n}, dopt);
  out.radii = at::zeros({n}, at::kInt);
  if (n == 0) return out;

  // Depth culling first, so nothing below divides by a non-positive depth.
  const at::Tensor z_all = (at::matmul(means, R.t()) + t).select(1, 2).detach();
  const at::Tensor in_depth =
      z_all.ge(settings.near_plane).logical_and(z_all.le(settings.far_plane));
  const at::Tensor idx = in_depth.nonzero().flatten();
  if (idx.numel() == 0) return out;
  const at::Tensor m = means.index_select(0, idx), s = scales.index_select(0, idx);
  const at::Tensor q = rotations.index_select(0, idx);

  const at::Tensor p = at::matmul(m, R.t()) + t;
  const at::Tensor x = p.select(1, 0), y = p.select(1, 1), z = p.select(1, 2);
  const at::Tensor qn = q / q.norm(2, {1}, true).clamp_min(kQuatEps);
  const at::Tensor w = qn.select(1, 0), qx = qn.select(1, 1), qy = qn.select(1, 2),
                   qz = qn.select(1, 3);
  const at::Tensor Rq =
      at::stack({1 - 2 * (qy * qy + qz * qz), 2 * (qx * qy - w * qz), 2 * (qx * qz + w * qy),
                 2 * (qx * qy + w * qz), 1 - 2 * (qx * qx + qz * qz), 2 * (qy * qz - w * qx),
                 2 * (qx * qz - w * qy), 2 * (qy * qz + w * qx), 1 - 2 * (qx * qx + qy * qy)},
                1)
          .view({-1, 3, 3});
  const at::Tensor M = Rq * s.unsqueeze(1);  // M[:, r, k] = Rq[:, r, k] * s[:, k]

  const double tan_x = 0.5 * camera.width / camera.fx, tan_y = 0.5 * camera.height / camera.fy;
  const double lxp = (camera.width - camera.cx) / camera.fx + 0.3 * tan_x;
  const double lxn = camera.cx / camera.fx + 0.3 * tan_x;
  const double lyp = (camera.height - camera.cy) / camera.fy + 0.3 * tan_y;
  const double lyn = camera.cy / camera.fy + 0.3 * tan_y;
  const at::Tensor tx = z * (x / z).clamp(-lxn, lxp);
  const at::Tensor ty = z * (y / z).clamp(-lyn, lyp);
  const at::Tensor zero = at::zeros_like(z);
  const at::Tensor J = at::stack({camera.fx / z, zero, -camera.fx * tx / (z * z), zero,
                                  camera.fy / z, -camera.fy * ty / (z * z)},
                                 1)
                           .view({-1, 2, 3});
  const at::Tensor T = at::matmul(J, R);
  // T Sigma T^T = B B^T with B = T M, rows u and v (as the kernel).
  const at::Tensor B = at::matmul(T, M);
  const at::Tensor u = B.select(1, 0), v = B.select(1, 1);
  const at::Tensor uu = u.square().sum(1), vv = v.square().sum(1);
  const at::Tensor c00 = uu + kCovDilation;
  const at::Tensor c01 = (u * v).sum(1);
  const at::Tensor c11 = vv + kCovDilation;
  // Lagrange's identity: c00·c11 − c01² would cancel for huge needles.
  const at::Tensor det =
      at::cross(u, v, 1).square().sum(1) + kCovDilation * (uu + vv) + kCovDilation * kCovDilation;
  const at::Tensor conic = at::stack({c11 / det, -c01 / det, c00 / det}, 1);
  const at::Tensor m2 =
      at::stack({camera.fx * x / z + camera.cx, camera.fy * y / z + camera.cy}, 1);

  // Radii and tile culling on detached values.
  const at::Tensor mid = 0.5 * (c00 + c11).detach();
  const at::Tensor detd = det.detach();
  const at::Tensor lambda = mid + (mid * mid - detd).clamp_min(0).sqrt();
  const at::Tensor radius = (3.0 * lambda.sqrt()).ceil().clamp_max(kMaxRadius);
  const int tiles_x = tile_count(camera.width);
  const int tiles_y = tile_count(camera.height);
  const at::Tensor m2d = m2.detach().contiguous();
  at::Tensor rad_sub = at::zeros({idx.numel()}, at::kInt);
  auto ra = rad_sub.accessor<int32_t, 1>();
  auto rd = radius.accessor<double, 1>();
  auto dd = detd.accessor<double, 1>();
  auto ma = m2d.accessor<double, 2>();
  for (int64_t i = 0; i < idx.numel(); ++i) {
    if (!(std::isfinite(dd[i]) && dd[i] > 0) || !(rd[i] > 0)) continue;
    const float u = float(ma[i][0]), v = float(ma[i][1]);
    if (!std::isfinite(u) || !std::isfinite(v)) continue;
    const TileRect r = tile_rect(u, v, int(rd[i]), tiles_x, tiles_y);
    if (r.x1 > r.x0 && r.y1 > r.y0) ra[i] = int32_t(rd[i]);
  }
  out.means2d = out.means2d.index_copy(0, idx, m2);
  out.conics = out.conics.index_copy(0, idx, conic);
  out.depths = out.depths.index_copy(0, idx, z);
  out.radii = out.radii.index_copy(0, idx, rad_sub);
  return out;
}

Image rasterize(const Projection& proj, const at::Tensor& opacities, const at::Tensor& colors,
                int width, int height, const std::array<float, 3>& background, bool render_depth) {
  const auto dopt = at::TensorOptions().dtype(at::kDouble);
  const int tiles_x = tile_count(width);
  const int tiles_y = tile_count(height);
  const int64_t n = proj.means2d.size(0);
  const at::Tensor m2d = proj.means2d.detach().contiguous();
  const at::Tensor depd = proj.depths.detach().contiguous();
  const at::Tensor radc = proj.radii.contiguous();
  auto ma = m2d.accessor<double, 2>();
  auto da = depd.accessor<double, 1>();
  auto ra = radc.accessor<int32_t, 1>();
  std::vector<TileRect> rects(static_cast<size_t>(n));
  for (int64_t i = 0; i < n; ++i) {
    rects[i] = ra[i] > 0 ? tile_rect(float(ma[i][0]), float(ma[i][1]), ra[i], tiles_x, tiles_y)
                         : TileRect{0, 0, 0, 0};
  }
  const at::Tensor bg =
      at::tensor({double(background[0]), double(background[1]), double(background[2])}, dopt);
  std::vector<at::Tensor> pix_ids, cols, alphas, depths;
  for (int ty = 0; ty < tiles_y; ++ty) {
    for (int tx = 0; tx < tiles_x; ++tx) {
      std::vector<int64_t> sel;
      for (int64_t i = 0; i < n; ++i) {
        const TileRect& r = rects[i];
        if (tx >= r.x0 && tx < r.x1 && ty >= r.y0 && ty < r.y1) sel.push_back(i);
      }
      std::stable_sort(sel.begin(), sel.end(), [&](int64_t a, int64_t b) {
        return float(da[a]) < float(da[b]);  // the fast path sorts float32 depths
      });
      std::vector<int64_t> pids;
      std::vector<double> centres;
      for (int y = ty * kTileSize; y < std::min(height, (ty + 1) * kTileSize); ++y) {
        for (int x = tx * kTileSize; x < std::min(width, (tx + 1) * kTileSize); ++x) {
          pids.push_back(int64_t(y) * width + x);
          centres.push_back(x + 0.5);
          centres.push_back(y + 0.5);
        }
      }
      const int64_t np = int64_t(pids.size());
      pix_ids.push_back(at::tensor(pids, at::kLong));
      if (sel.empty()) {
        cols.push_back(bg.unsqueeze(0).expand({np, 3}));
        alphas.push_back(at::zeros({np}, dopt));
        depths.push_back(at::zeros({np}, dopt));
        continue;
      }
      const at::Tensor ids = at::tensor(sel, at::kLong);
      const at::Tensor pc = at::tensor(centres, dopt).view({np, 2});
      const at::Tensor mu = proj.means2d.index_select(0, ids);                            // [n, 2]
      const at::Tensor con = proj.conics.index_select(0, ids);                            // [n, 3]
      const at::Tensor op = opacities.index_select(0, ids);                               // [n]
      const at::Tensor col = colors.index_select(0, ids);                                 // [n, 3]
      const at::Tensor dep = proj.depths.index_select(0, ids);                            // [n]
      const at::Tensor dx = mu.select(1, 0).unsqueeze(0) - pc.select(1, 0).unsqueeze(1);  // [P,n]
      const at::Tensor dy = mu.select(1, 1).unsqueeze(0) - pc.select(1, 1).unsqueeze(1);
      const at::Tensor power = (-0.5 * (con.select(1, 0) * dx * dx + con.select(1, 2) * dy * dy) -
                                con.select(1, 1) * dx * dy)
                                   .clamp_max(0.0);
      const at::Tensor vis = op.unsqueeze(0) * power.exp();
      const at::Tensor al = vis.clamp_max(double(kMaxAlpha));
      const at::Tensor al1 = al * al.detach().ge(double(kMinAlpha)).to(at::kDouble);
      const at::Tensor t_incl = (1 - al1.detach()).cumprod(1);
      const at::Tensor al2 = al1 * t_incl.gt(double(kMinTransmittance)).to(at::kDouble);
      const at::Tensor one_minus = 1 - al2;
      const at::Tensor cp = one_minus.cumprod(1);
      const at::Tensor T = at::cat({at::ones({np, 1}, dopt), cp.narrow(1, 0, cp.size(1) - 1)}, 1);
      const at::Tensor wgt = al2 * T;                           // [P, n]
      const at::Tensor t_final = cp.select(1, cp.size(1) - 1);  // [P]
      cols.push_back(at::matmul(wgt, col) + t_final.unsqueeze(1) * bg.unsqueeze(0));
      alphas.push_back(1 - t_final);
      depths.push_back(at::matmul(wgt, dep));
    }
  }
  const int64_t npix = int64_t(width) * height;
  const at::Tensor all_ids = at::cat(pix_ids);
  Image out;
  out.image =
      at::zeros({npix, 3}, dopt).index_copy(0, all_ids, at::cat(cols)).view({height, width, 3});
  out.alpha =
      at::zeros({npix}, dopt).index_copy(0, all_ids, at::cat(alphas)).view({height, width, 1});
  if (render_depth) {
    out.depth =
        at::zeros({npix}, dopt).index_copy(0, all_ids, at::cat(depths)).view({height, width, 1});
  }
  return out;
}

RenderOutput render(const GaussianBatch& g, const Camera& camera, const RenderSettings& settings) {
  const at::Tensor means = g.means.to(at::kDouble), scales = g.scales.to(at::kDouble);
  const at::Tensor rots = g.rotations.to(at::kDouble);
  Projection proj = project(means, scales, rots, camera, settings);
  if (g.means2d_grad_holder.defined() && g.means2d_grad_holder.numel() > 0) {
    proj.means2d = proj.means2d + g.means2d_grad_holder.to(at::kDouble);
  }
  const Image img =
      rasterize(proj, g.opacities.to(at::kDouble).reshape({-1}), g.colors.to(at::kDouble),
                camera.width, camera.height, settings.background, settings.render_depth);
  RenderOutput out;
  out.image = img.image;
  out.alpha = img.alpha;
  if (settings.render_depth) out.depth = img.depth / img.alpha.clamp_min(1e-10);
  out.radii = proj.radii;
  return out;
}

}  // namespace crpgs::raster::reference
