/// @file gaussian.cpp
/// @brief HAC's conditional Gaussian entropy model (docs/method.md §2.4): the likelihood of a value
/// quantised with step q is |Φ((x+q/2−μ)/σ) − Φ((x−q/2−μ)/σ)|, lower-bounded, bits = −log2 p.
#include <cmath>

#include <ATen/Parallel.h>
#include <torch/torch.h>

#include "crpgs/entropy_model.h"
#include "crpgs/plugin.h"
#include "gaussian_coding.h"

namespace crpgs {
namespace {

constexpr const char* kSchema = R"yaml(
- {key: likelihood_bound, type: float, default: 1.0e-6, min: 0, max: 0.5, min_exclusive: true, doc: "floor of the likelihood (HAC 1e-6); below it the gradient passes only where it raises p"}
- {key: scale_bound, type: float, default: 1.0e-9, min: 0, max: 1, min_exclusive: true, doc: "lower bound of the predicted scale sigma (HAC 1e-9)"}
)yaml";

/// max(x, bound) whose backward passes the gradient where x >= bound, or where following it
/// would raise x (grad < 0), so a value stuck under the floor can still climb out.
struct LowerBound : torch::autograd::Function<LowerBound> {
  static torch::Tensor forward(torch::autograd::AutogradContext* ctx, const torch::Tensor& x,
                               double bound) {
    ctx->save_for_backward({x});
    ctx->saved_data["bound"] = bound;
    return torch::clamp_min(x, bound);
  }
  static torch::autograd::tensor_list backward(torch::autograd::AutogradContext* ctx,
                                               torch::autograd::tensor_list grads) {
    const auto x = ctx->get_saved_variables()[0];
    const double bound = ctx->saved_data["bound"].toDouble();
    const auto pass = (x >= bound).logical_or(grads[0] < 0);
    return {grads[0] * pass.to(grads[0].dtype()), torch::Tensor()};
  }
};

class GaussianEntropy final : public EntropyModel {
 public:
  GaussianEntropy(const YAML::Node& c, const crpgs_create_args&)
      : likelihood_bound_(c["likelihood_bound"].as<double>()),
        scale_bound_(c["scale_bound"].as<double>()) {}

  std::string type_name() const override { return "gaussian"; }
  YAML::Node hyperparams() const override {
    YAML::Node n;
    n["type"] = type_name();
    n["likelihood_bound"] = likelihood_bound_;
    n["scale_bound"] = scale_bound_;
    return n;
  }

  torch::Tensor bits(const torch::Tensor& x, const torch::Tensor& mean, const torch::Tensor& scale,
                     const torch::Tensor& q) override {
    const auto sigma = torch::clamp_min(scale, scale_bound_);
    // Evaluate in the lower tail (|x−μ| mirrored) so 1 − Φ never cancels catastrophically.
    const auto v = torch::abs(x - mean);
    const auto half = q * 0.5;
    const auto upper = cdf((half - v) / sigma);
    const auto lower = cdf((-half - v) / sigma);
    const auto p = LowerBound::apply(torch::abs(upper - lower), likelihood_bound_);
    return -torch::log2(p);
  }

  bool supports_coding() const override { return true; }

  /// Tables from (mean/q, scale/q) on a fixed grid (gaussian_coding.h); throws (c10::Error) on
  /// mismatched sizes, which is a caller bug, not bad data.
  std::vector<uint8_t> compress(const torch::Tensor& symbols, const torch::Tensor& mean,
                                const torch::Tensor& scale, const torch::Tensor& q) override {
    const int64_t m = symbols.numel();
    TORCH_CHECK(mean.numel() == m && scale.numel() == m && q.numel() == m, "gaussian compress: ", m,
                " symbols but mean/scale/q have ", mean.numel(), "/", scale.numel(), "/", q.numel(),
                " elements");
    const auto s = as_cpu(symbols, torch::kInt);
    const auto mu = as_cpu(mean, torch::kFloat), sc = as_cpu(scale, torch::kFloat),
               qq = as_cpu(q, torch::kFloat);
    auto bytes =
        gaussian_coding::compress(s.data_ptr<int32_t>(), mu.data_ptr<float>(), sc.data_ptr<float>(),
                                  qq.data_ptr<float>(), size_t(m), scale_bound_);
    TORCH_CHECK(bytes.ok(), "gaussian compress: ", bytes.status().to_string());
    return std::move(bytes).value();
  }

  torch::Tensor decompress(const std::vector<uint8_t>& bytes, const torch::Tensor& mean,
                           const torch::Tensor& scale, const torch::Tensor& q,
                           std::string* error) override {
    const int64_t m = mean.numel();
    if (scale.numel() != m || q.numel() != m) {
      if (error)
        *error = "gaussian decompress: mean/scale/q have " + std::to_string(m) + "/" +
                 std::to_string(scale.numel()) + "/" + std::to_string(q.numel()) + " elements";
      return {};
    }
    const auto mu = as_cpu(mean, torch::kFloat), sc = as_cpu(scale, torch::kFloat),
               qq = as_cpu(q, torch::kFloat);
    auto out = gaussian_coding::decompress(coding::ByteSpan(bytes), mu.data_ptr<float>(),
                                           sc.data_ptr<float>(), qq.data_ptr<float>(), size_t(m),
                                           scale_bound_, at::get_num_threads());
    if (!out.ok()) {
      if (error) *error = out.status().to_string();
      return {};
    }
    auto t = torch::empty({m}, torch::kInt);
    std::copy(out->begin(), out->end(), t.data_ptr<int32_t>());
    return t;
  }

 private:
  static torch::Tensor as_cpu(const torch::Tensor& t, torch::ScalarType type) {
    return t.detach().to(torch::kCPU, type).contiguous().reshape({-1});
  }
  static torch::Tensor cdf(const torch::Tensor& z) { return 0.5 * torch::erfc(z * -M_SQRT1_2); }
  double likelihood_bound_, scale_bound_;
};

}  // namespace
}  // namespace crpgs

CRPGS_PLUGIN(CRPGS_KIND_ENTROPY, crpgs::EntropyModel, crpgs::GaussianEntropy,
             "org.crpgs.entropy.gaussian", "gaussian", 1, 0, crpgs::kSchema)
