/// @file entropy_params.cpp
#include "crpgs/entropy_params.h"

#include <torch/torch.h>

#include <ATen/Parallel.h>

#include <optional>

#include "codec/portable_kernels.h"
#include "crpgs/portable_math.h"
#include "crpgs/runtime.h"

namespace crpgs {

torch::Tensor portable_linear(const torch::Tensor& x, const torch::Tensor& w,
                              const torch::Tensor& b) {
  TORCH_CHECK(x.device().is_cpu() && w.device().is_cpu() && b.device().is_cpu() &&
                  x.scalar_type() == at::kFloat && w.scalar_type() == at::kFloat &&
                  b.scalar_type() == at::kFloat,
              "portable_linear: float CPU tensors only");
  TORCH_CHECK(x.dim() == 2 && w.dim() == 2 && b.dim() == 1 && x.size(1) == w.size(1) &&
                  b.size(0) == w.size(0),
              "portable_linear: shapes do not chain (x ", x.sizes(), ", w ", w.sizes(), ", b ",
              b.sizes(), ")");
  const auto xc = x.detach().contiguous(), wt = w.detach().t().contiguous();
  const auto bc = b.detach().contiguous();
  const int64_t in = w.size(1), out = w.size(0);
  auto y = torch::empty({x.size(0), out}, xc.options());
  const float *xp = xc.data_ptr<float>(), *wp = wt.data_ptr<float>(), *bp = bc.data_ptr<float>();
  float* yp = y.data_ptr<float>();
  at::parallel_for(0, x.size(0), 64, [&](int64_t first, int64_t last) {
    portable::linear_rows(xp, wp, bp, first, last, in, out, yp);
  });
  return y;
}

namespace {
using RangeKernel = void (*)(const float*, int64_t, int64_t, float*);

// An elementwise portable kernel over a float CPU tensor.
torch::Tensor map_portable(const torch::Tensor& x, RangeKernel kernel, const char* name) {
  TORCH_CHECK(x.device().is_cpu() && x.scalar_type() == at::kFloat, name,
              ": float CPU tensors only");
  const auto xc = x.detach().contiguous();
  auto y = torch::empty_like(xc);
  const float* xp = xc.data_ptr<float>();
  float* yp = y.data_ptr<float>();
  at::parallel_for(0, xc.numel(), 4096,
                   [&](int64_t first, int64_t last) { kernel(xp, first, last, yp); });
  return y;
}
}  // namespace

torch::Tensor portable_tanh(const torch::Tensor& x) {
  return map_portable(x, portable::tanh_range, "portable_tanh");
}

torch::Tensor portable_one_plus_tanh(const torch::Tensor& x) {
  return map_portable(x, portable::one_plus_tanh_range, "portable_one_plus_tanh");
}

EntropyParams split_entropy_params(const torch::Tensor& out, const EntropyParamLayout& layout,
                                   const QuantSteps& q0, Arithmetic arithmetic, StepForm steps) {
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
  set_quant_steps(parts[6], q0, &p, arithmetic, steps);
  return p;
}

void set_quant_steps(const torch::Tensor& step_columns, const QuantSteps& q0, EntropyParams* p,
                     Arithmetic arithmetic, StepForm steps) {
  TORCH_CHECK(step_columns.dim() == 2 && step_columns.size(1) == EntropyParamLayout::kStepColumns,
              "step columns must be [N, 3], got ", step_columns.sizes());
  // + 1 and the products with Q0 are single IEEE operations: portable once tanh is.
  const bool portable = arithmetic == Arithmetic::kPortable;
  torch::Tensor a;  // 1 + tanh(step_columns)
  if (steps == StepForm::kOnePlusTanh)
    a = (portable ? portable_tanh(step_columns) : torch::tanh(step_columns)) + 1;
  else
    a = portable ? portable_one_plus_tanh(step_columns) : 2 * torch::sigmoid(2 * step_columns);
  p->q_f = q0.feature * a.slice(1, 0, 1);
  p->q_s = q0.scaling * a.slice(1, 1, 2);
  p->q_o = q0.offset * a.slice(1, 2, 3);
}

EntropyParams predict_entropy_params(ContextModel& context, const torch::Tensor& positions01,
                                     const EntropyParamLayout& layout, const QuantSteps& q0,
                                     int64_t chunk, Arithmetic arithmetic, StepForm steps) {
  TORCH_CHECK(chunk > 0, "chunk must be positive");
  // Encoder, decoder and the training-side quantised model must get bit-identical parameters.
  // kFast: one thread in torch and in OpenBLAS, whose kernels may otherwise split sums by thread
  // count (and still differ between CPUs). kPortable does not depend on either.
  std::optional<ScopedComputeThreads> one_thread;
  if (arithmetic == Arithmetic::kFast) one_thread.emplace(1);
  std::vector<torch::Tensor> outs;
  for (int64_t s = 0; s < positions01.size(0); s += chunk) {
    const auto rows = positions01.slice(0, s, std::min(s + chunk, positions01.size(0)));
    outs.push_back(arithmetic == Arithmetic::kPortable ? context.forward_portable(rows)
                                                       : context.forward(rows));
  }
  torch::Tensor out =
      outs.empty() ? torch::zeros({0, layout.width()}, positions01.options()) : torch::cat(outs, 0);
  return split_entropy_params(out, layout, q0, arithmetic, steps);
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
                                const torch::Tensor& base_mu, Arithmetic arithmetic) {
  const auto in = torch::cat({root_features, root_pos01, leaf_pos01}, 1);  // [L, Dc + 6]
  const auto mu =
      arithmetic == Arithmetic::kPortable
          ? portable_linear(torch::relu(portable_linear(in, mlp.w1, mlp.b1)), mlp.w2, mlp.b2)
          : torch::linear(torch::relu(torch::linear(in, mlp.w1, mlp.b1)), mlp.w2, mlp.b2);
  return mlp.residual ? base_mu + mu : mu;
}

}  // namespace crpgs
