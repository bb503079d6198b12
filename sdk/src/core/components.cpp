/// @file components.cpp
/// @brief Built-in components (rasterizers, identity feature model) and typed creation helpers.
#include "crpgs/components.h"

#include <vector>

#include "crpgs/plugin.h"
#include "raster/cpu_rasterizer.h"
#if CRPGS_BUILT_WITH_CUDA
#include "raster/cuda_rasterizer.h"
#endif

namespace crpgs {
namespace {

/// The default feature model: the MLPs see the coded feature itself (plain HAC).
class IdentityFeatures final : public FeatureModel {
 public:
  IdentityFeatures(const YAML::Node&, const crpgs_create_args& args) : dim_(args.feature_dim) {
    if (dim_ <= 0) throw std::invalid_argument("identity: feature_dim must be positive");
  }
  std::string type_name() const override { return "identity"; }
  YAML::Node hyperparams() const override {
    YAML::Node n;
    n["type"] = type_name();
    return n;
  }
  int64_t coded_dim() const override { return dim_; }
  int64_t feature_dim() const override { return dim_; }
  torch::Tensor forward(const torch::Tensor& coded, const torch::Tensor&) override { return coded; }

 private:
  int64_t dim_;
};

CRPGS_DESCRIPTOR_FUNCTION(identity_features_descriptor, CRPGS_KIND_FEATURES, FeatureModel,
                          IdentityFeatures, "org.crpgs.features.identity", "identity", 1, 0, "[]")

}  // namespace

std::shared_ptr<FeatureModel> identity_feature_model(int feature_dim) {
  crpgs_create_args args{};
  args.feature_dim = feature_dim;
  return std::make_shared<IdentityFeatures>(YAML::Node(), args);
}

ComponentRegistry builtin_registry() {
  ComponentRegistry r;
  std::vector<const crpgs_plugin_descriptor*> builtins = {cpu_rasterizer_descriptor(),
                                                          identity_features_descriptor()};
#if CRPGS_BUILT_WITH_CUDA
  builtins.push_back(cuda_rasterizer_descriptor());
#endif
  for (const crpgs_plugin_descriptor* d : builtins) {
    Status st = r.add_builtin(d);
    if (!st.ok()) throw StatusError(st);  // a broken built-in is a programming error
  }
  return r;
}

crpgs_create_args create_args_for(const Config& resolved) {
  crpgs_create_args a{};
  const YAML::Node model = resolved.section("model");
  a.feature_dim = model && model["feature_dim"] ? model["feature_dim"].as<int>() : 50;
  a.n_offsets = model && model["n_offsets"] ? model["n_offsets"].as<int>() : 10;
  // Components are built on the CPU (the same initial values on every machine, and a decoder
  // needs no GPU); train.device: cuda moves the model and the components it optimises
  // (AnchorModel::to). The `cuda` rasterizer takes either (cuda_rasterizer.h).
  a.device_cuda = 0;
  a.coded_dim = a.feature_dim;  // the feature model may shrink it (SFA): set after creating it
  return a;
}

}  // namespace crpgs
