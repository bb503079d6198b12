// Glue between libtorch and the CUDA kernels: checks, allocations (libtorch's caching
// allocator), the two data-dependent sizes of the tile lists, and the launches.
#include "raster/cuda/stages.h"

#include <limits>

#include <c10/core/DeviceGuard.h>

#include "raster/cuda/kernels.h"

namespace crpgs::raster::cuda {
namespace {

namespace k = cuda_kernels;

void check(const char* error, const char* what) {
  TORCH_CHECK(error == nullptr, "cuda rasterizer: ", what, " failed: ", error);
}

void check_float(const at::Tensor& t, const char* name, int64_t cols) {
  TORCH_CHECK(t.defined(), "cuda rasterizer: ", name, " is undefined");
  TORCH_CHECK(t.is_cuda(), "cuda rasterizer: ", name, " must be on a CUDA device");
  TORCH_CHECK(t.scalar_type() == at::kFloat, "cuda rasterizer: ", name, " must be float32");
  TORCH_CHECK(t.is_contiguous(), "cuda rasterizer: ", name, " must be contiguous");
  if (cols > 0) {
    TORCH_CHECK(t.dim() == 2 && t.size(1) == cols, "cuda rasterizer: ", name, " must be [N, ", cols,
                "], got ", t.sizes());
  } else {
    TORCH_CHECK(t.dim() == 1, "cuda rasterizer: ", name, " must be [N], got ", t.sizes());
  }
}

const float* ptr_or_null(const at::Tensor& t, int64_t numel) {
  if (!t.defined()) return nullptr;
  TORCH_CHECK(
      t.is_cuda() && t.scalar_type() == at::kFloat && t.is_contiguous() && t.numel() == numel,
      "cuda rasterizer: output gradient has the wrong shape, type or device");
  return t.data_ptr<float>();
}

at::Tensor bytes_on(const at::Tensor& like, size_t n) {
  return at::empty({int64_t(std::max<size_t>(n, 1))}, like.options().dtype(at::kByte));
}

k::TileBuffers tile_buffers(const at::Tensor& means2d, const at::Tensor& conics,
                            const at::Tensor& opacities, const at::Tensor& colors,
                            const at::Tensor& depths, const TileIntersections& isect, int width,
                            int height, const std::array<float, 3>& bg, bool render_depth) {
  check_float(means2d, "means2d", 2);
  check_float(conics, "conics", 3);
  check_float(opacities, "opacities", 0);
  check_float(colors, "colors", 3);
  check_float(depths, "depths", 0);
  TORCH_CHECK(isect.tiles_x == tile_count(width) && isect.tiles_y == tile_count(height),
              "cuda rasterizer: tile lists of another image size");
  k::TileBuffers b{};
  b.means2d = means2d.data_ptr<float>();
  b.conics = conics.data_ptr<float>();
  b.opacities = opacities.data_ptr<float>();
  b.colors = colors.data_ptr<float>();
  b.depths = depths.data_ptr<float>();
  b.offsets = isect.tile_offsets.data_ptr<int32_t>();
  b.ids = isect.gaussian_ids.data_ptr<int32_t>();
  b.width = width;
  b.height = height;
  b.tiles_x = isect.tiles_x;
  b.tiles_y = isect.tiles_y;
  for (int c = 0; c < 3; ++c) b.bg[c] = bg[c];
  b.depth = render_depth;
  return b;
}

}  // namespace

ProjectResult project_forward(const at::Tensor& means, const at::Tensor& scales,
                              const at::Tensor& rotations, const Camera& camera,
                              const RenderSettings& settings) {
  check_float(means, "means", 3);
  check_float(scales, "scales", 3);
  check_float(rotations, "rotations", 4);
  const int64_t n = means.size(0);
  TORCH_CHECK(scales.size(0) == n && rotations.size(0) == n,
              "cuda rasterizer: means, scales and rotations must have the same N");
  const c10::DeviceGuard guard(means.device());
  const auto fopt = means.options();
  ProjectResult out;
  out.means2d = at::zeros({n, 2}, fopt);
  out.conics = at::zeros({n, 3}, fopt);
  out.depths = at::zeros({n}, fopt);
  out.radii = at::zeros({n}, fopt.dtype(at::kInt));
  check(k::project_forward(project_camera(camera, settings), n, means.data_ptr<float>(),
                           scales.data_ptr<float>(), rotations.data_ptr<float>(),
                           tile_count(camera.width), tile_count(camera.height),
                           out.means2d.data_ptr<float>(), out.conics.data_ptr<float>(),
                           out.depths.data_ptr<float>(), out.radii.data_ptr<int32_t>()),
        "projection");
  return out;
}

ProjectGrads project_backward(const at::Tensor& means, const at::Tensor& scales,
                              const at::Tensor& rotations, const Camera& camera,
                              const ProjectResult& fwd, const at::Tensor& v_means2d,
                              const at::Tensor& v_conics, const at::Tensor& v_depths) {
  check_float(v_means2d, "v_means2d", 2);
  check_float(v_conics, "v_conics", 3);
  check_float(v_depths, "v_depths", 0);
  const int64_t n = means.size(0);
  const c10::DeviceGuard guard(means.device());
  RenderSettings s;  // culling is read from fwd.radii; near/far are not needed here
  s.near_plane = -std::numeric_limits<float>::infinity();
  s.far_plane = std::numeric_limits<float>::infinity();
  ProjectGrads g;
  g.v_means = at::zeros({n, 3}, means.options());
  g.v_scales = at::zeros({n, 3}, means.options());
  g.v_rotations = at::zeros({n, 4}, means.options());
  check(k::project_backward(
            project_camera(camera, s), n, means.data_ptr<float>(), scales.data_ptr<float>(),
            rotations.data_ptr<float>(), fwd.radii.data_ptr<int32_t>(), v_means2d.data_ptr<float>(),
            v_conics.data_ptr<float>(), v_depths.data_ptr<float>(), g.v_means.data_ptr<float>(),
            g.v_scales.data_ptr<float>(), g.v_rotations.data_ptr<float>()),
        "projection backward");
  return g;
}

TileIntersections intersect_tiles(const at::Tensor& means2d, const at::Tensor& radii,
                                  const at::Tensor& depths, int width, int height,
                                  const at::Tensor& conics, const at::Tensor& opacities) {
  check_float(means2d, "means2d", 2);
  check_float(depths, "depths", 0);
  TORCH_CHECK(conics.defined() == opacities.defined(),
              "cuda rasterizer: intersect_tiles takes both conics and opacities or neither");
  if (conics.defined()) {
    check_float(conics, "conics", 3);
    check_float(opacities, "opacities", 0);
  }
  TORCH_CHECK(radii.is_cuda() && radii.scalar_type() == at::kInt && radii.is_contiguous(),
              "cuda rasterizer: radii must be contiguous int32 on the device");
  const c10::DeviceGuard guard(means2d.device());
  const int64_t n = means2d.size(0);
  TileIntersections out;
  out.tiles_x = tile_count(width);
  out.tiles_y = tile_count(height);
  const int n_tiles = out.tiles_x * out.tiles_y;
  const auto iopt = radii.options();
  const auto lopt = iopt.dtype(at::kLong);
  const at::Tensor rects = at::empty({n, 4}, iopt);
  const at::Tensor counts = at::empty({n}, lopt);
  const at::Tensor cumulative = at::empty({n}, lopt);
  check(k::tile_rects(n, means2d.data_ptr<float>(), radii.data_ptr<int32_t>(),
                      conics.defined() ? conics.data_ptr<float>() : nullptr,
                      opacities.defined() ? opacities.data_ptr<float>() : nullptr, out.tiles_x,
                      out.tiles_y, rects.data_ptr<int32_t>(), counts.data_ptr<int64_t>()),
        "tile rectangles");
  int64_t total = 0;
  if (n > 0) {
    size_t bytes = 0;
    check(k::inclusive_sum(nullptr, bytes, counts.data_ptr<int64_t>(),
                           cumulative.data_ptr<int64_t>(), n),
          "prefix sum");
    const at::Tensor temp = bytes_on(means2d, bytes);
    check(k::inclusive_sum(temp.data_ptr(), bytes, counts.data_ptr<int64_t>(),
                           cumulative.data_ptr<int64_t>(), n),
          "prefix sum");
    total = cumulative[n - 1].item<int64_t>();
  }
  TORCH_CHECK(total <= std::numeric_limits<int32_t>::max(),
              "cuda rasterizer: too many tile intersections (", total, ")");
  out.gaussian_ids = at::empty({total}, iopt);
  const at::Tensor keys = at::empty({total}, lopt);
  if (total > 0) {
    const at::Tensor keys_unsorted = at::empty({total}, lopt);
    const at::Tensor ids_unsorted = at::empty({total}, iopt);
    check(
        k::emit_intersections(n, rects.data_ptr<int32_t>(), cumulative.data_ptr<int64_t>(),
                              depths.data_ptr<float>(), out.tiles_x,
                              keys_unsorted.data_ptr<int64_t>(), ids_unsorted.data_ptr<int32_t>()),
        "tile keys");
    int tile_bits = 0;
    while ((int64_t(1) << tile_bits) < n_tiles) ++tile_bits;
    size_t bytes = 0;
    check(k::sort_intersections(nullptr, bytes, keys_unsorted.data_ptr<int64_t>(),
                                keys.data_ptr<int64_t>(), ids_unsorted.data_ptr<int32_t>(),
                                out.gaussian_ids.data_ptr<int32_t>(), total, 32 + tile_bits),
          "radix sort");
    const at::Tensor temp = bytes_on(means2d, bytes);
    check(k::sort_intersections(temp.data_ptr(), bytes, keys_unsorted.data_ptr<int64_t>(),
                                keys.data_ptr<int64_t>(), ids_unsorted.data_ptr<int32_t>(),
                                out.gaussian_ids.data_ptr<int32_t>(), total, 32 + tile_bits),
          "radix sort");
  }
  out.tile_offsets = at::empty({n_tiles + 1}, iopt);
  check(k::tile_offsets(keys.data_ptr<int64_t>(), total, n_tiles,
                        out.tile_offsets.data_ptr<int32_t>()),
        "tile offsets");
  return out;
}

RasterizeResult rasterize_forward(const at::Tensor& means2d, const at::Tensor& conics,
                                  const at::Tensor& opacities, const at::Tensor& colors,
                                  const at::Tensor& depths, const TileIntersections& isect,
                                  int width, int height, const std::array<float, 3>& background,
                                  bool render_depth) {
  const k::TileBuffers in = tile_buffers(means2d, conics, opacities, colors, depths, isect, width,
                                         height, background, render_depth);
  const c10::DeviceGuard guard(means2d.device());
  const auto fopt = means2d.options();
  RasterizeResult out;
  out.image = at::empty({height, width, 3}, fopt);
  out.alpha = at::empty({height, width, 1}, fopt);
  if (render_depth) out.depth = at::empty({height, width, 1}, fopt);
  out.final_T = at::empty({height, width}, fopt);
  out.last_contrib = at::empty({height, width}, fopt.dtype(at::kInt));
  check(k::rasterize_forward(in, out.image.data_ptr<float>(), out.alpha.data_ptr<float>(),
                             render_depth ? out.depth.data_ptr<float>() : nullptr,
                             out.final_T.data_ptr<float>(), out.last_contrib.data_ptr<int32_t>()),
        "rasterization");
  return out;
}

RasterizeGrads rasterize_backward(const at::Tensor& means2d, const at::Tensor& conics,
                                  const at::Tensor& opacities, const at::Tensor& colors,
                                  const at::Tensor& depths, const TileIntersections& isect,
                                  const RasterizeResult& fwd, int width, int height,
                                  const std::array<float, 3>& background, bool render_depth,
                                  const at::Tensor& v_image, const at::Tensor& v_alpha,
                                  const at::Tensor& v_depth) {
  const k::TileBuffers in = tile_buffers(means2d, conics, opacities, colors, depths, isect, width,
                                         height, background, render_depth);
  const c10::DeviceGuard guard(means2d.device());
  const int64_t n = means2d.size(0), npix = int64_t(width) * height;
  const float* vi = ptr_or_null(v_image, npix * 3);
  const float* va = ptr_or_null(v_alpha, npix);
  const float* vd = render_depth ? ptr_or_null(v_depth, npix) : nullptr;
  const auto fopt = means2d.options();
  RasterizeGrads g;
  g.v_means2d = at::zeros({n, 2}, fopt);
  g.v_conics = at::zeros({n, 3}, fopt);
  g.v_opacities = at::zeros({n}, fopt);
  g.v_colors = at::zeros({n, 3}, fopt);
  g.v_depths = at::zeros({n}, fopt);
  check(
      k::rasterize_backward(in, fwd.final_T.data_ptr<float>(), fwd.last_contrib.data_ptr<int32_t>(),
                            vi, va, vd, g.v_means2d.data_ptr<float>(), g.v_conics.data_ptr<float>(),
                            g.v_opacities.data_ptr<float>(), g.v_colors.data_ptr<float>(),
                            g.v_depths.data_ptr<float>()),
      "rasterization backward");
  return g;
}

at::Tensor visible_anchors(const at::Tensor& positions, const at::Tensor& extents,
                           const Camera& camera, const RenderSettings& settings) {
  const at::Tensor rot = identity_rotations(positions.size(0), positions.options());
  return project_forward(positions, extents, rot, camera, settings).radii.gt(0);
}

}  // namespace crpgs::raster::cuda
