/// @file entropy_params.h
/// @brief HAC's per-anchor entropy parameters (docs/method.md §2.2): the grid context's output
/// split into means, scales and adaptive quantisation steps for features, scaling and offsets. One
/// function shared by training (rate term, quantised evaluation) and the codec, so the steps the
/// model is evaluated with are exactly the ones in the bitstream.
#pragma once

#include <map>
#include <string>

#include <torch/types.h>

#include "crpgs/context_model.h"
#include "crpgs/entropy_model.h"
#include "crpgs/status.h"

namespace crpgs {

/// Initial quantisation steps Q0 (docs/method.md §2.2).
struct QuantSteps {
  double feature = 1.0, scaling = 0.001, offset = 0.2;
};

struct EntropyParams {
  torch::Tensor mu_f, sigma_f;  ///< [N, Dc]
  torch::Tensor mu_s, sigma_s;  ///< [N, 6]
  torch::Tensor mu_o, sigma_o;  ///< [N, K*3]
  torch::Tensor q_f, q_s, q_o;  ///< [N, 1] adaptive steps Q0·(1 + tanh a), in [0, 2·Q0]
};

/// How entropy parameters are computed. kFast: BLAS and ATen, differentiable (training), last
/// bits depend on the machine. kPortable: crpgs/portable_math.h, the same bits everywhere (the
/// codec since format 1.1; 1.0 files were coded with kFast and decode only where the same
/// kernels run).
enum class Arithmetic { kFast, kPortable };

/// How the steps' factor 1 + tanh(a) is evaluated. kOnePlusTanh: tanh, then + 1 in float
/// (format ≤ 1.1); it cancels to 0 for a ≲ −9, where its gradient is 0 too, so a saturated step
/// could never recover. kTwoSigmoid: 2 / (1 + e^(−2a)), the same function without the
/// cancellation (positive, with a gradient, down to a ≈ −44): format 1.2 and training.
enum class StepForm { kOnePlusTanh, kTwoSigmoid };

/// Splits a context output row ([N, layout.width()]) into EntropyParams. σ outputs are returned
/// raw (the entropy model clamps them).
EntropyParams split_entropy_params(const torch::Tensor& context_out,
                                   const EntropyParamLayout& layout, const QuantSteps& q0,
                                   Arithmetic arithmetic = Arithmetic::kFast,
                                   StepForm steps = StepForm::kTwoSigmoid);

/// Sets p's q_f, q_s, q_o from the step-adjustment columns [N, kStepColumns] (the layout's last).
void set_quant_steps(const torch::Tensor& step_columns, const QuantSteps& q0, EntropyParams* p,
                     Arithmetic arithmetic = Arithmetic::kFast,
                     StepForm steps = StepForm::kTwoSigmoid);

/// Evaluates `context` on positions01 in fixed chunks of `chunk` rows, in order, and splits.
/// The codec calls it with the same chunking on both sides; with kPortable (context.forward_
/// portable, portable tanh) encoder and decoder get the same bits on any machine.
EntropyParams predict_entropy_params(ContextModel& context, const torch::Tensor& positions01,
                                     const EntropyParamLayout& layout, const QuantSteps& q0,
                                     int64_t chunk, Arithmetic arithmetic,
                                     StepForm steps = StepForm::kTwoSigmoid);

/// CRP-GS's leaf-feature mean (docs/method.md §6.3, §7.8): μ_l = MLP([f̂_root; x_root; x_leaf]) with
/// Linear(Dc + 6 → H) → ReLU → Linear(H → Dc), positions normalised by the anchor bounds; with
/// `residual`, μ_l = μ_base + MLP(·). σ and Q of a leaf stay the base model's.
struct LeafMlp {
  torch::Tensor w1, b1, w2, b2;  ///< [H, Dc + 6], [H], [Dc, H], [Dc]
  bool residual = false;
  bool defined() const { return w1.defined(); }
};

/// Names of the leaf MLP's tensors among a model's MLP tensors (AnchorModel::mlp_tensors(), the
/// bitstream's MLPS section).
inline constexpr const char* kLeafMlpNames[4] = {"leaf_mlp.w1", "leaf_mlp.b1", "leaf_mlp.w2",
                                                 "leaf_mlp.b2"};

/// The leaf MLP from named tensors; undefined when `mlps` has none of them. kInvalidArgument if
/// only some are there or their shapes disagree with coded_dim.
StatusOr<LeafMlp> leaf_mlp_from(const std::map<std::string, torch::Tensor>& mlps, int64_t coded_dim,
                                bool residual);

/// μ of the leaves' features. root_features: the roots' decoded (quantised) features [L, Dc];
/// root_pos01, leaf_pos01: [L, 3]; base_mu: the base model's μ_f of the leaves [L, Dc] (used with
/// `residual`). Differentiable with kFast; the codec calls it in fixed chunks on both sides.
torch::Tensor leaf_feature_mean(const LeafMlp& mlp, const torch::Tensor& root_features,
                                const torch::Tensor& root_pos01, const torch::Tensor& leaf_pos01,
                                const torch::Tensor& base_mu,
                                Arithmetic arithmetic = Arithmetic::kFast);

}  // namespace crpgs
