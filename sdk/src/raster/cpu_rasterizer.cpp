// The `cpu` rasterizer: one autograd function over project -> intersect_tiles ->
// rasterize_to_pixels, whose backward runs the stages' backward passes in reverse.
#include "raster/cpu_rasterizer.h"

#include <stdexcept>

#include <torch/torch.h>

#include "crpgs/plugin.h"
#include "raster/stages.h"

namespace crpgs {
namespace raster {
constexpr const char* kSchemaYaml = R"(- key: threads
  type: int
  default: 0
  min: 0
  max: 1024
  doc: "worker threads for the tile and Gaussian loops; 0 = all available processors"
)";

namespace {

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
    const ProjectResult pr = project_forward(means, scales, rotations, cam, s, nt);
    const TileIntersections is = intersect_tiles(pr.means2d, pr.radii, pr.depths, cam.width,
                                                 cam.height, nt, pr.conics, opac);
    const RasterizeResult rr =
        rasterize_forward(pr.means2d, pr.conics, opac, colors, pr.depths, is, cam.width, cam.height,
                          s.background, s.render_depth, nt);
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
    const RasterizeGrads rg = rasterize_backward(
        pr.means2d, pr.conics, opac, colors, pr.depths, is, rr, cam.width, cam.height, s.background,
        s.render_depth, contiguous_or_undefined(grads[0]), contiguous_or_undefined(grads[1]),
        s.render_depth ? contiguous_or_undefined(grads[2]) : at::Tensor(), nt);
    const ProjectGrads pg = project_backward(means, scales, rotations, cam, pr, rg.v_means2d,
                                             rg.v_conics, rg.v_depths, nt);
    const at::Tensor v_holder = ctx->saved_data["holder"].toBool() ? rg.v_means2d : at::Tensor();
    return {pg.v_means, pg.v_scales,  pg.v_rotations, rg.v_opacities, rg.v_colors,
            v_holder,   at::Tensor(), at::Tensor(),   at::Tensor()};
  }
};

void check_input(const torch::Tensor& t, const char* name, int64_t n, int64_t cols) {
  TORCH_CHECK(t.defined(), "cpu rasterizer: ", name, " is undefined");
  TORCH_CHECK(t.device().is_cpu(), "cpu rasterizer: ", name, " must be on the CPU");
  TORCH_CHECK(t.scalar_type() == at::kFloat, "cpu rasterizer: ", name, " must be float32");
  if (cols > 0) {
    TORCH_CHECK(t.dim() == 2 && t.size(0) == n && t.size(1) == cols, "cpu rasterizer: ", name,
                " must be [", n, ", ", cols, "], got ", t.sizes());
  } else {
    TORCH_CHECK(t.numel() == n, "cpu rasterizer: ", name, " must have ", n, " elements, got ",
                t.sizes());
  }
}

int read_threads(const YAML::Node& cfg) {
  const int t = cfg && cfg["threads"] ? cfg["threads"].as<int>() : 0;
  if (t < 0) throw std::invalid_argument("cpu rasterizer: threads must be >= 0");
  return t;
}

}  // namespace

CpuRasterizer::CpuRasterizer(const YAML::Node& resolved_config, const crpgs_create_args& args)
    : threads_(read_threads(resolved_config)) {
  if (args.device_cuda) {
    throw std::invalid_argument(
        "the cpu rasterizer cannot render CUDA tensors; use `type: cuda` or a CPU device");
  }
}

CpuRasterizer::CpuRasterizer(int threads) : threads_(threads) {
  if (threads < 0) throw std::invalid_argument("cpu rasterizer: threads must be >= 0");
}

YAML::Node CpuRasterizer::hyperparams() const {
  YAML::Node n;
  n["type"] = "cpu";
  n["threads"] = threads_;
  return n;
}

RenderOutput CpuRasterizer::render(const GaussianBatch& g, const Camera& camera,
                                   const RenderSettings& settings) {
  TORCH_CHECK(g.means.defined() && g.means.dim() == 2, "cpu rasterizer: means must be [N, 3]");
  const int64_t n = g.means.size(0);
  check_input(g.means, "means", n, 3);
  check_input(g.scales, "scales", n, 3);
  check_input(g.rotations, "rotations", n, 4);
  check_input(g.opacities, "opacities", n, 0);
  check_input(g.colors, "colors", n, 3);
  at::Tensor holder = at::empty({0, 2}, g.means.options());
  if (g.means2d_grad_holder.defined() && g.means2d_grad_holder.numel() > 0) {
    check_input(g.means2d_grad_holder, "means2d_grad_holder", n, 2);
    holder = g.means2d_grad_holder;
  }
  const variable_list outs = RasterizeFunction::apply(
      g.means, g.scales, g.rotations, g.opacities.reshape({-1}), g.colors, holder,
      pack_camera(camera), pack_settings(settings), int64_t(resolve_threads(threads_)));
  RenderOutput out;
  out.image = outs[0];
  out.alpha = outs[1];
  // Expected depth: sum w_i z_i / sum w_i (0 where nothing was drawn).
  if (settings.render_depth) out.depth = outs[2] / outs[1].clamp_min(1e-10);
  out.radii = outs[3];
  return out;
}

torch::Tensor CpuRasterizer::visible_anchors(const torch::Tensor& positions,
                                             const torch::Tensor& extents, const Camera& camera,
                                             const RenderSettings& settings) {
  TORCH_CHECK(positions.defined() && positions.dim() == 2 && positions.size(1) == 3,
              "cpu rasterizer: anchor positions must be [N, 3]");
  const int64_t n = positions.size(0);
  TORCH_CHECK(
      extents.defined() && extents.dim() == 2 && extents.size(0) == n && extents.size(1) == 3,
      "cpu rasterizer: anchor extents must be [N, 3]");
  TORCH_CHECK(positions.device().is_cpu() && extents.device().is_cpu(),
              "cpu rasterizer: anchors must be on the CPU");
  const at::Tensor p = positions.detach().to(at::kFloat).contiguous();
  const at::Tensor e = extents.detach().to(at::kFloat).contiguous();
  return raster::visible_anchors(p, e, camera, settings, resolve_threads(threads_));
}

}  // namespace raster

CRPGS_DESCRIPTOR_FUNCTION(cpu_rasterizer_descriptor, CRPGS_KIND_RASTERIZER, crpgs::Rasterizer,
                          crpgs::raster::CpuRasterizer, "org.crpgs.rasterizer.cpu", "cpu", 1, 0,
                          crpgs::raster::kSchemaYaml)

}  // namespace crpgs
