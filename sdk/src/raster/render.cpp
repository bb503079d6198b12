// The autograd function shared by the `cpu` and `cuda` rasterizers: the stages of the
// Gaussians' device forward, and their backward passes in reverse.
#include "raster/render.h"

#include <torch/torch.h>

#include "raster/stages.h"
#if CRPGS_BUILT_WITH_CUDA
#include "raster/cuda/stages.h"
#endif

namespace crpgs::raster {
namespace {

// Each stage on the Gaussians' device. A build without CUDA never gets CUDA tensors here:
// render()'s caller is the cpu component, whose inputs render() checks.
ProjectResult project(const at::Tensor& means, const at::Tensor& scales,
                      const at::Tensor& rotations, const Camera& cam, const RenderSettings& s,
                      int nt) {
#if CRPGS_BUILT_WITH_CUDA
  if (means.is_cuda()) return cuda::project_forward(means, scales, rotations, cam, s);
#endif
  return project_forward(means, scales, rotations, cam, s, nt);
}

TileIntersections intersect(const ProjectResult& pr, const at::Tensor& opac, const Camera& cam,
                            int nt) {
#if CRPGS_BUILT_WITH_CUDA
  if (opac.is_cuda())
    return cuda::intersect_tiles(pr.means2d, pr.radii, pr.depths, cam.width, cam.height, pr.conics,
                                 opac);
#endif
  return intersect_tiles(pr.means2d, pr.radii, pr.depths, cam.width, cam.height, nt, pr.conics,
                         opac);
}

RasterizeResult rasterize(const ProjectResult& pr, const at::Tensor& opac, const at::Tensor& colors,
                          const TileIntersections& is, const Camera& cam, const RenderSettings& s,
                          int nt) {
#if CRPGS_BUILT_WITH_CUDA
  if (opac.is_cuda())
    return cuda::rasterize_forward(pr.means2d, pr.conics, opac, colors, pr.depths, is, cam.width,
                                   cam.height, s.background, s.render_depth);
#endif
  return rasterize_forward(pr.means2d, pr.conics, opac, colors, pr.depths, is, cam.width,
                           cam.height, s.background, s.render_depth, nt);
}

RasterizeGrads rasterize_grads(const ProjectResult& pr, const at::Tensor& opac,
                               const at::Tensor& colors, const TileIntersections& is,
                               const RasterizeResult& rr, const Camera& cam,
                               const RenderSettings& s, const at::Tensor& v_image,
                               const at::Tensor& v_alpha, const at::Tensor& v_depth, int nt) {
#if CRPGS_BUILT_WITH_CUDA
  if (opac.is_cuda())
    return cuda::rasterize_backward(pr.means2d, pr.conics, opac, colors, pr.depths, is, rr,
                                    cam.width, cam.height, s.background, s.render_depth, v_image,
                                    v_alpha, v_depth);
#endif
  return rasterize_backward(pr.means2d, pr.conics, opac, colors, pr.depths, is, rr, cam.width,
                            cam.height, s.background, s.render_depth, v_image, v_alpha, v_depth,
                            nt);
}

ProjectGrads project_grads(const at::Tensor& means, const at::Tensor& scales,
                           const at::Tensor& rotations, const Camera& cam, const ProjectResult& pr,
                           const RasterizeGrads& rg, int nt) {
#if CRPGS_BUILT_WITH_CUDA
  if (means.is_cuda())
    return cuda::project_backward(means, scales, rotations, cam, pr, rg.v_means2d, rg.v_conics,
                                  rg.v_depths);
#endif
  return project_backward(means, scales, rotations, cam, pr, rg.v_means2d, rg.v_conics, rg.v_depths,
                          nt);
}

using torch::autograd::AutogradContext;
using torch::autograd::variable_list;

// Camera and settings travel through autograd as small float64 tensors.
at::Tensor pack_camera(const Camera& c) {
  at::Tensor t = at::empty({18}, at::kDouble);
  double* p = t.data_ptr<double>();
  p[0] = c.fx;
  p[1] = c.fy;
  p[2] = c.cx;
  p[3] = c.cy;
  for (int r = 0; r < 3; ++r)
    for (int k = 0; k < 3; ++k) p[4 + 3 * r + k] = c.R(r, k);
  for (int k = 0; k < 3; ++k) p[13 + k] = c.t[k];
  p[16] = c.width;
  p[17] = c.height;
  return t;
}

Camera unpack_camera(const at::Tensor& t) {
  const double* p = t.data_ptr<double>();
  Camera c;
  c.fx = p[0];
  c.fy = p[1];
  c.cx = p[2];
  c.cy = p[3];
  for (int r = 0; r < 3; ++r)
    for (int k = 0; k < 3; ++k) c.R(r, k) = p[4 + 3 * r + k];
  for (int k = 0; k < 3; ++k) c.t[k] = p[13 + k];
  c.width = int(p[16]);
  c.height = int(p[17]);
  return c;
}

at::Tensor pack_settings(const RenderSettings& s) {
  at::Tensor t = at::empty({6}, at::kDouble);
  double* p = t.data_ptr<double>();
  for (int k = 0; k < 3; ++k) p[k] = s.background[k];
  p[3] = s.near_plane;
  p[4] = s.far_plane;
  p[5] = s.render_depth ? 1.0 : 0.0;
  return t;
}

RenderSettings unpack_settings(const at::Tensor& t) {
  const double* p = t.data_ptr<double>();
  RenderSettings s;
  for (int k = 0; k < 3; ++k) s.background[k] = float(p[k]);
  s.near_plane = float(p[3]);
  s.far_plane = float(p[4]);
  s.render_depth = p[5] != 0.0;
  return s;
}

at::Tensor contiguous_or_undefined(const at::Tensor& t) {
  return t.defined() ? t.contiguous() : t;
}

struct RasterizeFunction : public torch::autograd::Function<RasterizeFunction> {
  // Outputs: image [H,W,3], alpha [H,W,1], accumulated depth [H,W,1] (or [0]), radii [N].
  static variable_list forward(AutogradContext* ctx, const at::Tensor& means_in,
                               const at::Tensor& scales_in, const at::Tensor& rotations_in,
                               const at::Tensor& opacities_in, const at::Tensor& colors_in,
                               const at::Tensor& holder, const at::Tensor& cam_t,
                               const at::Tensor& set_t, int64_t threads) {
    const Camera cam = unpack_camera(cam_t);
    const RenderSettings s = unpack_settings(set_t);
    const int nt = int(threads);
    const at::Tensor means = means_in.contiguous(), scales = scales_in.contiguous();
    const at::Tensor rotations = rotations_in.contiguous(), opac = opacities_in.contiguous();
    const at::Tensor colors = colors_in.contiguous();
    const ProjectResult pr = project(means, scales, rotations, cam, s, nt);
    const TileIntersections is = intersect(pr, opac, cam, nt);
    const RasterizeResult rr = rasterize(pr, opac, colors, is, cam, s, nt);
    ctx->save_for_backward({means, scales, rotations, opac, colors, pr.means2d, pr.conics,
                            pr.depths, pr.radii, is.tile_offsets, is.gaussian_ids, rr.final_T,
                            rr.last_contrib, cam_t, set_t});
    ctx->saved_data["threads"] = threads;
    ctx->saved_data["tiles_x"] = int64_t(is.tiles_x);
    ctx->saved_data["tiles_y"] = int64_t(is.tiles_y);
    ctx->saved_data["holder"] = holder.numel() > 0;
    const at::Tensor depth = s.render_depth ? rr.depth : at::zeros({0}, means.options());
    if (!s.render_depth) ctx->mark_non_differentiable({depth});
    ctx->mark_non_differentiable({pr.radii});
    return {rr.image, rr.alpha, depth, pr.radii};
  }

  static variable_list backward(AutogradContext* ctx, variable_list grads) {
    const variable_list saved = ctx->get_saved_variables();
    const at::Tensor &means = saved[0], &scales = saved[1], &rotations = saved[2];
    const at::Tensor &opac = saved[3], &colors = saved[4];
    ProjectResult pr{saved[5], saved[6], saved[7], saved[8]};
    TileIntersections is;
    is.tiles_x = int(ctx->saved_data["tiles_x"].toInt());
    is.tiles_y = int(ctx->saved_data["tiles_y"].toInt());
    is.tile_offsets = saved[9];
    is.gaussian_ids = saved[10];
    RasterizeResult rr;
    rr.final_T = saved[11];
    rr.last_contrib = saved[12];
    const Camera cam = unpack_camera(saved[13]);
    const RenderSettings s = unpack_settings(saved[14]);
    const int nt = int(ctx->saved_data["threads"].toInt());
    const at::Tensor v_image = contiguous_or_undefined(grads[0]);
    const at::Tensor v_alpha = contiguous_or_undefined(grads[1]);
    const at::Tensor v_depth = s.render_depth ? contiguous_or_undefined(grads[2]) : at::Tensor();
    const RasterizeGrads rg =
        rasterize_grads(pr, opac, colors, is, rr, cam, s, v_image, v_alpha, v_depth, nt);
    const ProjectGrads pg = project_grads(means, scales, rotations, cam, pr, rg, nt);
    const at::Tensor v_holder = ctx->saved_data["holder"].toBool() ? rg.v_means2d : at::Tensor();
    return {pg.v_means, pg.v_scales,  pg.v_rotations, rg.v_opacities, rg.v_colors,
            v_holder,   at::Tensor(), at::Tensor(),   at::Tensor()};
  }
};

void check_input(const torch::Tensor& t, const char* name, int64_t n, int64_t cols,
                 torch::Device device) {
  const char* who = device.is_cuda() ? "cuda rasterizer: " : "cpu rasterizer: ";
  TORCH_CHECK(t.defined(), who, name, " is undefined");
  TORCH_CHECK(t.device() == device, who, name, " must be on ", device.str(), ", got ",
              t.device().str());
  TORCH_CHECK(t.scalar_type() == at::kFloat, who, name, " must be float32");
  if (cols > 0) {
    TORCH_CHECK(t.dim() == 2 && t.size(0) == n && t.size(1) == cols, who, name, " must be [", n,
                ", ", cols, "], got ", t.sizes());
  } else {
    TORCH_CHECK(t.numel() == n, who, name, " must have ", n, " elements, got ", t.sizes());
  }
}

}  // namespace

RenderOutput render(const GaussianBatch& g, const Camera& camera, const RenderSettings& settings,
                    torch::Device device, int threads) {
  TORCH_CHECK(g.means.defined() && g.means.dim() == 2, device.is_cuda() ? "cuda" : "cpu",
              " rasterizer: means must be [N, 3]");
  const int64_t n = g.means.size(0);
  check_input(g.means, "means", n, 3, device);
  check_input(g.scales, "scales", n, 3, device);
  check_input(g.rotations, "rotations", n, 4, device);
  check_input(g.opacities, "opacities", n, 0, device);
  check_input(g.colors, "colors", n, 3, device);
  at::Tensor holder = at::empty({0, 2}, g.means.options());
  if (g.means2d_grad_holder.defined() && g.means2d_grad_holder.numel() > 0) {
    check_input(g.means2d_grad_holder, "means2d_grad_holder", n, 2, device);
    holder = g.means2d_grad_holder;
  }
  const variable_list outs = RasterizeFunction::apply(
      g.means, g.scales, g.rotations, g.opacities.reshape({-1}), g.colors, holder,
      pack_camera(camera), pack_settings(settings), int64_t(threads));
  RenderOutput out;
  out.image = outs[0];
  out.alpha = outs[1];
  // Expected depth: sum w_i z_i / sum w_i (0 where nothing was drawn).
  if (settings.render_depth) out.depth = outs[2] / outs[1].clamp_min(1e-10);
  out.radii = outs[3];
  return out;
}

RenderOutput render_bridged(const GaussianBatch& g, const Camera& camera,
                            const RenderSettings& settings, torch::Device device, int threads) {
  TORCH_CHECK(g.means.defined(), "rasterizer: means is undefined");
  const torch::Device home = g.means.device();
  if (home == device) return render(g, camera, settings, device, threads);
  auto there = [&](const at::Tensor& t) { return t.defined() ? t.to(device) : t; };
  const GaussianBatch moved{there(g.means),     there(g.scales), there(g.rotations),
                            there(g.opacities), there(g.colors), there(g.means2d_grad_holder)};
  RenderOutput out = render(moved, camera, settings, device, threads);
  auto back = [&](const at::Tensor& t) { return t.defined() ? t.to(home) : t; };
  return RenderOutput{back(out.image), back(out.alpha), back(out.depth), back(out.radii)};
}

}  // namespace crpgs::raster
