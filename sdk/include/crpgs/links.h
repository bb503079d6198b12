/// @file links.h
/// @brief Anchor links (CRP-GS COHS, docs/method.md §6.2): candidate retrieval (cosine top-M over
/// the coded features, or k nearest anchors), the greedy one-to-one root/leaf matching of Algorithm
/// 1, and the link-vector validity check. Shared by the link_* context plugins, the trainer and the
/// codec. Everything runs on CPU tensors (inputs on another device are copied) and is
/// deterministic: the output does not depend on the number of threads.
///
/// Link vector: int64 [N], entry i = index of the root anchor i is conditioned on, or -1.
/// An anchor with a root is a leaf. One hop (a root is never a leaf), one-to-one (a root has
/// exactly one leaf), leaves and roots are active, no self links.
#pragma once

#include <cstdint>
#include <vector>

#include <torch/types.h>

#include "crpgs/status.h"

namespace crpgs {

/// Per-anchor candidate lists. Row i (active anchor with candidates) starts with i itself; the
/// rest is ordered by score descending (cosine: equal scores by |j - i|, then j; nearest: by j).
/// Unused slots (inactive rows, zero-norm rows, fewer candidates than M) are index -1, score -inf.
struct LinkCandidates {
  torch::Tensor index;  ///< [N, M] int64
  torch::Tensor score;  ///< [N, M] float32; higher is more similar
};

/// k nearest neighbours among the active points: index [N, k] int64 and squared distance
/// [N, k] float64, ordered by (distance, index); -1 / +inf where there are fewer than k, and in
/// inactive rows. Exact (k-d tree), O(N log N) to build and about O(k log N) per query for any
/// distribution of the points.
struct NeighborLists {
  torch::Tensor index;    ///< [N, k] int64
  torch::Tensor sq_dist;  ///< [N, k] float64
};

/// Exact k nearest active neighbours of every active point. points: [N, 3] (any float dtype,
/// finite in active rows); active: [N] bool, or undefined for all active. include_self puts the
/// point itself first (distance 0) and counts it in k.
StatusOr<NeighborLists> nearest_neighbors(const torch::Tensor& points, const torch::Tensor& active,
                                          int64_t k, bool include_self);

/// Top-M cosine-similar active anchors of every active anchor (docs/method.md §7.5: self included,
/// so M-1 others). features: [N, D]; active: [N] bool or undefined (all). Rows with zero norm or a
/// non-finite entry have similarity -inf to everything: their list is empty and they are never a
/// candidate. The [rows, N_active] float32 similarity block of the chunked matmul stays within
/// memory_budget_bytes (at least one row). Scores are exact cosines of the features rounded to
/// ~2^-23 (see links.cpp), so the lists do not depend on BLAS or thread count.
StatusOr<LinkCandidates> cosine_candidates(const torch::Tensor& features,
                                           const torch::Tensor& active, int64_t m,
                                           int64_t memory_budget_bytes = int64_t(256) << 20);

/// The M nearest active anchors (self first) with score = -Euclidean distance.
StatusOr<LinkCandidates> nearest_candidates(const torch::Tensor& positions,
                                            const torch::Tensor& active, int64_t m);

/// tau_max, tau_max - step, ... down to tau_min (inclusive within 1e-6), from an integer counter.
/// {1.0, 0.95, 0.9, 0.85, 0.8} for the paper's values. Errors if step <= 0 or tau_min > tau_max.
StatusOr<std::vector<double>> decaying_thresholds(double tau_max, double tau_min, double step);

/// Algorithm 1 (docs/method.md §6.2). For each threshold tau, visit the anchors i in index order;
/// skip i if inactive, a leaf or a root; among its candidates keep j != i, j active, not a leaf,
/// not a root, score >= tau - 1e-6; link i to the best kept (first in list order on equal scores)
/// and make it a root. Returns the link vector [N] int64 (passes check_links). An empty threshold
/// list gives no links; use -infinity for "no threshold".
StatusOr<torch::Tensor> greedy_links(const LinkCandidates& candidates,
                                     const std::vector<double>& thresholds,
                                     const torch::Tensor& active);

/// A uniformly random one-to-one pairing of the active anchors, reproducible from seed
/// (splitmix64 + Fisher-Yates, independent of libtorch's generators): shuffle the active
/// indices, take floor(leaf_fraction * N_active) consecutive pairs (leaf, root).
/// leaf_fraction in [0, 0.5].
StatusOr<torch::Tensor> random_links(const torch::Tensor& active, uint64_t seed,
                                     double leaf_fraction = 0.5);

/// OK when links is a valid link vector for active ([N] bool or undefined = all active);
/// otherwise kInvalidArgument naming the first violation in index order: wrong shape or dtype,
/// out-of-range entry, self link, inactive leaf, inactive root, chain (root that is a leaf),
/// root with two leaves.
Status check_links(const torch::Tensor& links, const torch::Tensor& active);

/// Counts of a valid link vector, for logs and tests.
struct LinkStats {
  int64_t leaves = 0;  ///< anchors with a root (= number of roots)
  int64_t active = 0;
};
LinkStats link_stats(const torch::Tensor& links, const torch::Tensor& active);

}  // namespace crpgs
