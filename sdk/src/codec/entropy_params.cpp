/// @file entropy_params.cpp
#include "crpgs/entropy_params.h"

#include <torch/torch.h>

#include "crpgs/runtime.h"

namespace crpgs {

EntropyParams split_entropy_params(const torch::Tensor& out, const EntropyParamLayout& layout,
                                   const QuantSteps& q0) {
  TORCH_CHECK(out.dim() == 2 && out.size(1) == layout.width(), "context output must be [N, ",
              layout.width(), "], got ", out.sizes());
  const int64_t dc = layout.coded_dim, ko = 3 * layout.n_offsets;
  auto parts =
      torch::split_with_sizes(out, {dc, dc, 6, 6, ko, ko, EntropyParamLayout::kStepColumns}, 1);
  EntropyParams p;
  p.mu_f = parts[0];
  p.sigma_f = parts[1];
  p.mu_s = parts[2];
  p.sigma_s = parts[3];
  p.mu_o = parts[4];
  p.sigma_o = parts[5];
  set_quant_steps(parts[6], q0, &p);
  return p;
}

void set_quant_steps(const torch::Tensor& step_columns, const QuantSteps& q0, EntropyParams* p) {
  TORCH_CHECK(step_columns.dim() == 2 && step_columns.size(1) == EntropyParamLayout::kStepColumns,
              "step columns must be [N, 3], got ", step_columns.sizes());
  const auto a = torch::tanh(step_columns) + 1;
  p->q_f = q0.feature * a.slice(1, 0, 1);
  p->q_s = q0.scaling * a.slice(1, 1, 2);
  p->q_o = q0.offset * a.slice(1, 2, 3);
}

EntropyParams predict_entropy_params(ContextModel& context, const torch::Tensor& positions01,
                                     const EntropyParamLayout& layout, const QuantSteps& q0,
                                     int64_t chunk) {
  TORCH_CHECK(chunk > 0, "chunk must be positive");
  // Encoder, decoder and the training-side quantised model must get bit-identical parameters:
  // one thread in torch and in OpenBLAS, whose kernels may otherwise split sums by thread count.
  ScopedComputeThreads one_thread(1);
  std::vector<torch::Tensor> outs;
  for (int64_t s = 0; s < positions01.size(0); s += chunk)
    outs.push_back(
        context.forward(positions01.slice(0, s, std::min(s + chunk, positions01.size(0)))));
  torch::Tensor out =
      outs.empty() ? torch::zeros({0, layout.width()}, positions01.options()) : torch::cat(outs, 0);
  return split_entropy_params(out, layout, q0);
}

StatusOr<LeafMlp> leaf_mlp_from(const std::map<std::string, torch::Tensor>& mlps, int64_t coded_dim,
                                bool residual) {
  LeafMlp m;
  m.residual = residual;
  torch::Tensor* dst[4] = {&m.w1, &m.b1, &m.w2, &m.b2};
  int found = 0;
  for (int i = 0; i < 4; ++i) {
    auto it = mlps.find(kLeafMlpNames[i]);
    if (it == mlps.end()) continue;
    *dst[i] = it->second;
    ++found;
  }
  if (found == 0) return LeafMlp{};
  auto bad = [](const std::string& msg) {
    return Status(StatusCode::kInvalidArgument, "leaf MLP: " + msg);
  };
  if (found != 4) return bad("some of its tensors are missing");
  const int64_t H = m.w1.dim() == 2 ? m.w1.size(0) : -1;
  if (H < 1 || m.w1.sizes() != torch::IntArrayRef({H, coded_dim + 6}) ||
      m.b1.sizes() != torch::IntArrayRef({H}) ||
      m.w2.sizes() != torch::IntArrayRef({coded_dim, H}) ||
      m.b2.sizes() != torch::IntArrayRef({coded_dim}))
    return bad("tensor shapes do not match a feature width of " + std::to_string(coded_dim));
  return m;
}

torch::Tensor leaf_feature_mean(const LeafMlp& mlp, const torch::Tensor& root_features,
                                const torch::Tensor& root_pos01, const torch::Tensor& leaf_pos01,
                                const torch::Tensor& base_mu) {
  const auto in = torch::cat({root_features, root_pos01, leaf_pos01}, 1);  // [L, Dc + 6]
  auto mu = torch::linear(torch::relu(torch::linear(in, mlp.w1, mlp.b1)), mlp.w2, mlp.b2);
  return mlp.residual ? base_mu + mu : mu;
}

}  // namespace crpgs
