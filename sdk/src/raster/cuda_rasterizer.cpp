// The `cuda` rasterizer: render.cpp's autograd function over the CUDA stages.
#include "raster/cuda_rasterizer.h"

#include <stdexcept>
#include <string>

#include <torch/cuda.h>
#include <torch/torch.h>

#include "crpgs/plugin.h"
#include "raster/cuda/stages.h"
#include "raster/render.h"

namespace crpgs {
namespace raster {
namespace {

constexpr const char* kCudaSchemaYaml = R"(- key: device
  type: int
  default: 0
  min: 0
  max: 64
  doc: "CUDA device index"
)";

int checked_device(int device) {
  if (device < 0) throw std::invalid_argument("cuda rasterizer: device must be >= 0");
  if (!torch::cuda::is_available()) {
    throw std::invalid_argument(
        "cuda rasterizer: libtorch finds no CUDA device (a CPU-only libtorch, no GPU, or no "
        "driver); use `rasterizer: {type: cpu}`");
  }
  const int count = int(torch::cuda::device_count());
  if (device >= count) {
    throw std::invalid_argument("cuda rasterizer: device " + std::to_string(device) +
                                " does not exist (" + std::to_string(count) + " CUDA devices)");
  }
  return device;
}

}  // namespace

CudaRasterizer::CudaRasterizer(const YAML::Node& cfg, const crpgs_create_args&)
    : CudaRasterizer(cfg && cfg["device"] ? cfg["device"].as<int>() : 0) {}

CudaRasterizer::CudaRasterizer(int device) : device_(checked_device(device)) {}

YAML::Node CudaRasterizer::hyperparams() const {
  YAML::Node n;
  n["type"] = "cuda";
  n["device"] = device_;
  return n;
}

RenderOutput CudaRasterizer::render(const GaussianBatch& g, const Camera& camera,
                                    const RenderSettings& settings) {
  return render_bridged(g, camera, settings, device(), 0);
}

torch::Tensor CudaRasterizer::visible_anchors(const torch::Tensor& positions,
                                              const torch::Tensor& extents, const Camera& camera,
                                              const RenderSettings& settings) {
  TORCH_CHECK(positions.defined() && positions.dim() == 2 && positions.size(1) == 3,
              "cuda rasterizer: anchor positions must be [N, 3]");
  TORCH_CHECK(extents.defined() && extents.sizes() == positions.sizes(),
              "cuda rasterizer: anchor extents must be [N, 3]");
  const at::Tensor p = positions.detach().to(device(), at::kFloat).contiguous();
  const at::Tensor e = extents.detach().to(device(), at::kFloat).contiguous();
  return cuda::visible_anchors(p, e, camera, settings).to(positions.device());
}

}  // namespace raster

CRPGS_DESCRIPTOR_FUNCTION(cuda_rasterizer_descriptor, CRPGS_KIND_RASTERIZER, crpgs::Rasterizer,
                          crpgs::raster::CudaRasterizer, "org.crpgs.rasterizer.cuda", "cuda", 1, 0,
                          crpgs::raster::kCudaSchemaYaml)

}  // namespace crpgs
