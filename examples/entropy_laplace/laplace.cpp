/// @file laplace.cpp
/// @brief Example entropy model: a Laplacian instead of HAC's Gaussian. The likelihood of x
/// quantised with step q is F(x+q/2) − F(x−q/2) with the Laplace CDF of location μ and scale b,
/// floored at `likelihood_bound`.
#include <torch/torch.h>

#include "crpgs/entropy_model.h"
#include "crpgs/plugin.h"

namespace example {

constexpr const char* kSchema = R"yaml(
- {key: likelihood_bound, type: float, default: 1.0e-6, min: 0, max: 0.5, min_exclusive: true, doc: "floor of the likelihood"}
- {key: scale_bound, type: float, default: 1.0e-9, min: 0, max: 1, min_exclusive: true, doc: "lower bound of the scale b"}
)yaml";

class LaplaceEntropy final : public crpgs::EntropyModel {
 public:
  LaplaceEntropy(const YAML::Node& c, const crpgs_create_args&)
      : likelihood_bound_(c["likelihood_bound"].as<double>()),
        scale_bound_(c["scale_bound"].as<double>()) {}
  std::string type_name() const override { return "laplace"; }
  YAML::Node hyperparams() const override {
    YAML::Node n;
    n["type"] = type_name();
    n["likelihood_bound"] = likelihood_bound_;
    n["scale_bound"] = scale_bound_;
    return n;
  }
  torch::Tensor bits(const torch::Tensor& x, const torch::Tensor& mean, const torch::Tensor& scale,
                     const torch::Tensor& q) override {
    const auto b = torch::clamp_min(scale, scale_bound_);
    // Mirror into the lower tail, where the CDF is 0.5·exp(z): no cancellation.
    const auto v = torch::abs(x - mean);
    const auto lower_cdf = [&](const torch::Tensor& t) {
      return torch::where(t <= 0, 0.5 * torch::exp(torch::clamp_max(t, 0) / b),
                          1 - 0.5 * torch::exp(-torch::clamp_min(t, 0) / b));
    };
    const auto p = lower_cdf(q * 0.5 - v) - lower_cdf(-q * 0.5 - v);
    return -torch::log2(torch::clamp_min(p, likelihood_bound_));
  }

 private:
  double likelihood_bound_, scale_bound_;
};

}  // namespace example

CRPGS_PLUGIN(CRPGS_KIND_ENTROPY, crpgs::EntropyModel, example::LaplaceEntropy,
             "org.example.entropy.laplace", "laplace", 1, 0, example::kSchema)
