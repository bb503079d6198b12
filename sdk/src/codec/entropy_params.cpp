/// @file entropy_params.cpp
#include "crpgs/entropy_params.h"

#include <torch/torch.h>

namespace crpgs {

EntropyParams split_entropy_params(const torch::Tensor& out, const EntropyParamLayout& layout,
                                   const QuantSteps& q0) {
  TORCH_CHECK(out.dim() == 2 && out.size(1) == layout.width(), "context output must be [N, ",
              layout.width(), "], got ", out.sizes());
  const int64_t dc = layout.coded_dim, ko = 3 * layout.n_offsets;
  auto parts = torch::split_with_sizes(out, {dc, dc, 6, 6, ko, ko, 1, 1, 1}, 1);
  EntropyParams p;
  p.mu_f = parts[0];
  p.sigma_f = parts[1];
  p.mu_s = parts[2];
  p.sigma_s = parts[3];
  p.mu_o = parts[4];
  p.sigma_o = parts[5];
  p.q_f = q0.feature * (1 + torch::tanh(parts[6]));
  p.q_s = q0.scaling * (1 + torch::tanh(parts[7]));
  p.q_o = q0.offset * (1 + torch::tanh(parts[8]));
  return p;
}

EntropyParams predict_entropy_params(ContextModel& context, const torch::Tensor& positions01,
                                     const EntropyParamLayout& layout, const QuantSteps& q0,
                                     int64_t chunk) {
  TORCH_CHECK(chunk > 0, "chunk must be positive");
  std::vector<torch::Tensor> outs;
  for (int64_t s = 0; s < positions01.size(0); s += chunk)
    outs.push_back(
        context.forward(positions01.slice(0, s, std::min(s + chunk, positions01.size(0)))));
  torch::Tensor out =
      outs.empty() ? torch::zeros({0, layout.width()}, positions01.options()) : torch::cat(outs, 0);
  return split_entropy_params(out, layout, q0);
}

}  // namespace crpgs
