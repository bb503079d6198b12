/// @file cuda_rasterizer.h
/// @brief The built-in `cuda` rasterizer (builds with CRPGS_CUDA_ENABLED): the CUDA stages of
/// raster/cuda behind the same autograd function as `cpu` (render.h), and its descriptor.
/// Gaussians on the CPU are moved to the GPU for rendering and the outputs (and the prefilter's
/// mask) come back to the CPU, so a model that stays on the CPU renders on the GPU; Gaussians
/// already on the GPU stay there.
#pragma once

#include <string>

#include <yaml-cpp/yaml.h>

#include "crpgs/plugin_abi.h"
#include "crpgs/rasterizer.h"

namespace crpgs {
const crpgs_plugin_descriptor* cuda_rasterizer_descriptor();
}  // namespace crpgs

namespace crpgs::raster {

class CudaRasterizer final : public Rasterizer {
 public:
  /// Config keys: device (int >= 0, the CUDA device index).
  CudaRasterizer(const YAML::Node& resolved_config, const crpgs_create_args& args);
  /// Throws std::invalid_argument naming the reason when no such CUDA device is usable.
  explicit CudaRasterizer(int device = 0);

  std::string type_name() const override { return "cuda"; }
  YAML::Node hyperparams() const override;
  torch::Device device() const override { return torch::Device(torch::kCUDA, device_); }
  RenderOutput render(const GaussianBatch& gaussians, const Camera& camera,
                      const RenderSettings& settings) override;
  torch::Tensor visible_anchors(const torch::Tensor& positions, const torch::Tensor& extents,
                                const Camera& camera, const RenderSettings& settings) override;

 private:
  int device_ = 0;
};

}  // namespace crpgs::raster
