/// @file gain.cpp
/// @brief Example feature model: the MLPs see the coded feature scaled by a learnable
/// per-channel gain (initialised to `init`). Shows a plugin with trainable parameters.
#include <torch/torch.h>

#include "crpgs/feature_model.h"
#include "crpgs/plugin.h"

namespace example {

constexpr const char* kSchema = R"yaml(
- {key: init, type: float, default: 1.0, min: 0, max: 100, doc: "initial value of every channel gain"}
- {key: learnable, type: bool, default: true, doc: "train the gains with the feature parameters"}
)yaml";

class GainFeatures final : public crpgs::FeatureModel {
 public:
  GainFeatures(const YAML::Node& c, const crpgs_create_args& args)
      : init_(c["init"].as<double>()), learnable_(c["learnable"].as<bool>()) {
    if (args.feature_dim <= 0) throw std::invalid_argument("gain: feature_dim must be positive");
    gain_ = torch::full({args.feature_dim}, init_).set_requires_grad(learnable_);
  }
  std::string type_name() const override { return "gain"; }
  YAML::Node hyperparams() const override {
    YAML::Node n;
    n["type"] = type_name();
    n["init"] = init_;
    n["learnable"] = learnable_;
    return n;
  }
  std::vector<torch::Tensor> parameters() override {
    return learnable_ ? std::vector<torch::Tensor>{gain_} : std::vector<torch::Tensor>{};
  }
  int64_t coded_dim() const override { return gain_.size(0); }
  int64_t feature_dim() const override { return gain_.size(0); }
  torch::Tensor forward(const torch::Tensor& coded, const torch::Tensor&) override {
    return coded * gain_;
  }

 private:
  double init_;
  bool learnable_;
  torch::Tensor gain_;  // [D]
};

}  // namespace example

CRPGS_PLUGIN(CRPGS_KIND_FEATURES, crpgs::FeatureModel, example::GainFeatures,
             "org.example.features.gain", "gain", 1, 0, example::kSchema)
