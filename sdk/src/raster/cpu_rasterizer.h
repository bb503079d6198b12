/// @file cpu_rasterizer.h
/// @brief The built-in `cpu` rasterizer: the stages of stages.h behind a libtorch autograd
/// function, and its registry descriptor.
#pragma once

#include <string>

#include <yaml-cpp/yaml.h>

#include "crpgs/plugin_abi.h"
#include "crpgs/rasterizer.h"

namespace crpgs {
const crpgs_plugin_descriptor* cpu_rasterizer_descriptor();
}  // namespace crpgs

namespace crpgs::raster {

class CpuRasterizer final : public Rasterizer {
 public:
  /// Config keys: threads (int >= 0, 0 = all available processors).
  CpuRasterizer(const YAML::Node& resolved_config, const crpgs_create_args& args);
  explicit CpuRasterizer(int threads = 0);

  std::string type_name() const override { return "cpu"; }
  YAML::Node hyperparams() const override;
  torch::Device device() const override { return torch::kCPU; }
  RenderOutput render(const GaussianBatch& gaussians, const Camera& camera,
                      const RenderSettings& settings) override;
  torch::Tensor visible_anchors(const torch::Tensor& positions, const torch::Tensor& extents,
                                const Camera& camera, const RenderSettings& settings) override;

  int threads() const { return threads_; }

 private:
  int threads_ = 0;  // as configured; 0 = all available
};

}  // namespace crpgs::raster
