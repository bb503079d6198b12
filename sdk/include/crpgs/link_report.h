/// @file link_report.h
/// @brief What the COHS root/leaf hierarchy buys in a coded model (docs/method.md §6.4): the
/// feature stream's bits by anchor group, and the leaves' bits with and without the leaf model, to
/// set against the side information (AMSK + LINK) it costs.
#pragma once

#include "crpgs/codec.h"

namespace crpgs {

struct LinkRateReport {
  LinkCounts counts;
  /// FEAT bits (estimated Σ −log2 p under the coded entropy parameters, which track the coded
  /// sizes within a fraction of a percent) summed over each group.
  double root_bits = 0, free_bits = 0, leaf_bits = 0;
  /// The leaves' FEAT bits had they been coded with the base model's mean (no leaf MLP).
  double leaf_bits_base = 0;
  /// Mean cosine similarity of a leaf's dequantised coded feature to its root's.
  double mean_leaf_root_cosine = 0;
};

/// Estimated FEAT bits of every anchor [N] (double) under the parameters `p` it is coded with,
/// and under the base model's means (the same model coded without links); they differ on leaves.
struct FeatureRowBits {
  torch::Tensor coded, base;
  torch::Tensor features;  ///< [N, Dc] float: the dequantised coded features they were taken on
};
FeatureRowBits feature_row_bits(const CodedModel& m, const EntropyParams& p, ContextModel& context,
                                EntropyModel& entropy);

/// `m` must have links (a model without leaves has nothing to report: kInvalidArgument).
/// `p` are the entropy parameters it was coded with (canonical rows, e.g. DecodeResult::params).
StatusOr<LinkRateReport> link_rate_report(const CodedModel& m, const EntropyParams& p,
                                          ContextModel& context, EntropyModel& entropy);

}  // namespace crpgs
