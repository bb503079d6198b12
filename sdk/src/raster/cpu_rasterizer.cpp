// The `cpu` rasterizer: render.cpp's autograd function over the CPU stages.
#include "raster/cpu_rasterizer.h"

#include <stdexcept>

#include <torch/torch.h>

#include "crpgs/plugin.h"
#include "raster/render.h"
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
  return raster::render(g, camera, settings, torch::kCPU, resolve_threads(threads_));
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
