/// @file link_report.cpp
#include "crpgs/link_report.h"

#include <torch/torch.h>

namespace crpgs {

FeatureRowBits feature_row_bits(const CodedModel& m, const EntropyParams& p, ContextModel& context,
                                EntropyModel& entropy) {
  torch::NoGradGuard no_grad;
  const auto q = p.q_f.expand_as(p.mu_f).contiguous();  // [N, Dc]
  FeatureRowBits r;
  r.features = m.feature_sym.to(torch::kFloat) * q;
  auto row_bits = [&](const torch::Tensor& mu) {  // [N]
    return entropy.bits(r.features, mu, p.sigma_f, q).sum(1).to(torch::kDouble);
  };
  r.coded = row_bits(p.mu_f);
  r.base = r.coded;
  if (m.links.defined() && (m.links >= 0).any().item<bool>()) {
    // The base model's means: the same model coded without links (μ from the context alone).
    CodedModel base = m;
    base.links = torch::Tensor();
    r.base = row_bits(coded_entropy_params(base, context, m.feature_sym.size(1)).mu_f);
  }
  return r;
}

StatusOr<LinkRateReport> link_rate_report(const CodedModel& m, const EntropyParams& p,
                                          ContextModel& context, EntropyModel& entropy) {
  if (!m.links.defined())
    return Status(StatusCode::kInvalidArgument, "link report: the model has no links");
  torch::NoGradGuard no_grad;
  LinkRateReport r;
  r.counts = count_links(m.links);
  const auto links = m.links.to(torch::kLong);  // [N]
  const FeatureRowBits rows = feature_row_bits(m, p, context, entropy);
  const auto& bits = rows.coded;
  const auto is_leaf = links >= 0;
  auto is_root = torch::zeros_like(is_leaf);
  is_root.index_put_({links.masked_select(is_leaf)}, true);
  const auto is_free = is_leaf.logical_not().logical_and(is_root.logical_not());
  r.root_bits = bits.masked_select(is_root).sum().item<double>();
  r.free_bits = bits.masked_select(is_free).sum().item<double>();
  r.leaf_bits = bits.masked_select(is_leaf).sum().item<double>();
  if (r.counts.leaves > 0) {
    r.leaf_bits_base = rows.base.masked_select(is_leaf).sum().item<double>();
    const auto& f = rows.features;
    const auto leaf_idx = is_leaf.nonzero().squeeze(1);
    const auto cos = torch::cosine_similarity(
        f.index_select(0, leaf_idx), f.index_select(0, links.index_select(0, leaf_idx)), 1, 1e-8);
    r.mean_leaf_root_cosine = cos.to(torch::kDouble).mean().item<double>();
  }
  return r;
}

}  // namespace crpgs
