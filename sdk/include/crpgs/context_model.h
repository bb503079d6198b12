/// @file context_model.h
/// @brief The context family. Grid contexts (`hash_grid`) turn anchor positions into context
/// features for the entropy parameters; link strategies (`link_cohs`, `link_random`,
/// `link_distance`, `link_none`) choose, per anchor, an already-decoded root to condition on.
/// Both return the same forms whichever made them, so the pipeline cannot tell them apart.
#pragma once

#include <functional>

#include <torch/types.h>

#include "crpgs/component.h"

namespace crpgs {

/// What a link strategy sees when (re)building links.
struct LinkInputs {
  torch::Tensor features;   ///< [N, D] current raw coded features
  torch::Tensor positions;  ///< [N, 3]
  torch::Tensor active;     ///< [N] bool: anchors that will be coded
  uint64_t seed = 0;        ///< for random strategies; stored with the links
};

class ContextModel : public Component {
 public:
  /// Width of the per-anchor output; 0 for a pure link strategy. For a grid context it is the
  /// entropy-parameter layout of HAC's mlp_grid, 2*(Dc + 6 + 3K) + 3 (see EntropyParams).
  virtual int64_t output_dim() const { return 0; }
  /// positions01: [N, 3] normalised by the scene bounds (values outside [0,1] are allowed: the
  /// component decides what they read). Returns [N, output_dim()].
  virtual torch::Tensor forward(const torch::Tensor& positions01) {
    return torch::zeros({positions01.size(0), 0}, positions01.options());
  }
  /// forward() in portable arithmetic (crpgs/portable_math.h: the same bits on every machine),
  /// which the codec uses for the entropy parameters. The default is forward(): a context whose
  /// forward() uses BLAS or vectorised ATen maths must override it, or its bitstreams decode
  /// only where the same kernels run.
  virtual torch::Tensor forward_portable(const torch::Tensor& positions01) {
    return forward(positions01);
  }
  /// forward() as training needs it: the last `tail` columns for every row, the whole row only
  /// for the rows asked for later. Every visible anchor needs its quantisation steps, only the
  /// rate subset (5 %) its means and scales, so a grid context skips ~98 % of its output layer.
  struct PartialOutput {
    torch::Tensor tail;                                            ///< [N, tail]
    std::function<torch::Tensor(const torch::Tensor& rows)> rows;  ///< int64 rows -> [R, width]
  };
  virtual PartialOutput forward_partial(const torch::Tensor& positions01, int64_t tail) {
    auto out = forward(positions01);
    return {out.slice(1, out.size(1) - tail),
            [out](const torch::Tensor& rows) { return out.index_select(0, rows); }};
  }
  /// Link strategies: int64 [N], entry i = index of the root anchor i is conditioned on, or -1.
  /// One hop only: a root is never itself a leaf. Grid contexts return all -1.
  virtual torch::Tensor build_links(const LinkInputs& in) {
    return torch::full({in.features.size(0)}, -1, torch::kLong);
  }
};

}  // namespace crpgs
