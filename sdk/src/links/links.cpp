/// @file links.cpp
/// @brief Anchor-link algorithms (docs/method.md §6.2, §7 items 5, 10): cosine / nearest candidate
/// retrieval, the greedy one-to-one matching of Algorithm 1, random pairing and the validity check.
///
/// Determinism of the cosine lists: the features are normalised and rounded to integers of
/// b = floor((52 - ceil(log2 D)) / 2) bits, so every dot product of two rows is a sum of integers
/// below 2^53 and is exact in float64 whatever the summation order. A float32 matmul (fast, but
/// BLAS/thread dependent in the last bits) only screens: a column is rescored exactly whenever its
/// screened cosine is within kScreenEps of the current M-th best, which is far above the float32
/// error bound (~(D + 2) * 2^-24). The selected lists and scores are therefore a function of the
/// exact scores alone. Equal scores (identical directions) prefer the nearest index |j - i|, so a
/// block of identical anchors pairs up with neighbours instead of all pointing at the lowest
/// indices, which would leave most of them unlinked.
#include "crpgs/links.h"

#include <ATen/ATen.h>
#include <ATen/Parallel.h>

#include <algorithm>
#include <cmath>
#include <limits>
#include <string>
#include <unordered_map>
#include <utility>

namespace crpgs {
namespace {

constexpr double kInf = std::numeric_limits<double>::infinity();

Status invalid(const std::string& msg) {
  return Status(StatusCode::kInvalidArgument, msg);
}

/// active as bytes (1 = active); undefined means all active.
StatusOr<std::vector<uint8_t>> active_bytes(const torch::Tensor& active, int64_t n,
                                            const char* fn) {
  if (!active.defined()) return std::vector<uint8_t>(size_t(n), 1);
  if (active.dim() != 1 || active.size(0) != n)
    return invalid(std::string(fn) + ": active must be [" + std::to_string(n) + "], got " +
                   std::to_string(active.dim()) + "-D with " + std::to_string(active.numel()) +
                   " entries");
  auto a = active.detach().to(torch::kCPU).ne(0).to(torch::kUInt8).contiguous();
  const uint8_t* p = a.data_ptr<uint8_t>();
  return std::vector<uint8_t>(p, p + n);
}

/// Sorted top list of (key, index) pairs, best first: larger key when larger_is_better, smaller
/// otherwise; equal keys by |index - center| when center >= 0, then by smaller index.
struct TopList {
  std::vector<double> key;
  std::vector<int64_t> idx;
  int64_t cap = 0, count = 0;
  bool larger_is_better = true;
  int64_t center = -1;
  TopList(int64_t k, bool larger)
      : key(size_t(k)), idx(size_t(k)), cap(k), larger_is_better(larger) {}
  bool better(double a, int64_t ia, double b, int64_t ib) const {
    if (a != b) return larger_is_better ? a > b : a < b;
    if (center >= 0) {
      const int64_t da = std::abs(ia - center), db = std::abs(ib - center);
      if (da != db) return da < db;
    }
    return ia < ib;
  }
  bool full() const { return count == cap; }
  double worst() const { return key[size_t(count - 1)]; }
  void offer(double k, int64_t j) {
    if (cap == 0) return;
    if (full() && !better(k, j, key[size_t(cap - 1)], idx[size_t(cap - 1)])) return;
    int64_t pos = full() ? cap - 1 : count++;
    while (pos > 0 && better(k, j, key[size_t(pos - 1)], idx[size_t(pos - 1)])) {
      key[size_t(pos)] = key[size_t(pos - 1)];
      idx[size_t(pos)] = idx[size_t(pos - 1)];
      --pos;
    }
    key[size_t(pos)] = k;
    idx[size_t(pos)] = j;
  }
};

/// k-d tree over the active points: median splits on the widest axis, leaves of at most kLeaf
/// points, each node with its tight bounding box and smallest point index. Depth O(log n) for any
/// distribution; a uniform grid sized by the bounding box put a dense object with a few far
/// anchors into one cell and scanned it for every query (O(n²)).
struct KdTree {
  static constexpr int64_t kLeaf = 8;
  struct Node {
    double lo[3], hi[3];
    int64_t begin, end;  // range of `order`
    int64_t child = -1;  // first of two consecutive children; -1 for a leaf
    int64_t min_index;
  };
  std::vector<Node> nodes;
  std::vector<int64_t> order;  // point indices, grouped by node

  KdTree(const double* P, std::vector<int64_t> ids) : order(std::move(ids)) {
    nodes.reserve(size_t(4 * order.size() / kLeaf + 2));
    nodes.push_back(Node{});
    nodes[0].begin = 0;
    nodes[0].end = int64_t(order.size());
    std::vector<int64_t> todo{0};
    while (!todo.empty()) {
      const int64_t id = todo.back();
      todo.pop_back();
      Node nd = nodes[size_t(id)];
      for (int a = 0; a < 3; ++a) nd.lo[a] = kInf, nd.hi[a] = -kInf;
      nd.min_index = std::numeric_limits<int64_t>::max();
      for (int64_t s = nd.begin; s < nd.end; ++s) {
        const int64_t j = order[size_t(s)];
        nd.min_index = std::min(nd.min_index, j);
        for (int a = 0; a < 3; ++a) {
          nd.lo[a] = std::min(nd.lo[a], P[3 * j + a]);
          nd.hi[a] = std::max(nd.hi[a], P[3 * j + a]);
        }
      }
      if (nd.end - nd.begin > kLeaf) {
        int axis = 0;
        for (int a = 1; a < 3; ++a)
          if (nd.hi[a] - nd.lo[a] > nd.hi[axis] - nd.lo[axis]) axis = a;
        // (coordinate, index) order: identical points split by index, so a block of
        // duplicates still gives a balanced tree whose low-index leaves come first.
        const int64_t mid = nd.begin + (nd.end - nd.begin) / 2;
        std::nth_element(order.begin() + nd.begin, order.begin() + mid, order.begin() + nd.end,
                         [&](int64_t x, int64_t y) {
                           const double cx = P[3 * x + axis], cy = P[3 * y + axis];
                           return cx != cy ? cx < cy : x < y;
                         });
        nd.child = int64_t(nodes.size());
        Node left{}, right{};
        left.begin = nd.begin;
        left.end = right.begin = mid;
        right.end = nd.end;
        nodes.push_back(left);
        nodes.push_back(right);
        todo.push_back(nd.child);
        todo.push_back(nd.child + 1);
      }
      nodes[size_t(id)] = nd;
    }
  }

  /// Squared distance from p to the node's box, deflated by 1e-12 so that rounding (or FMA
  /// contraction) can never make it exceed the computed distance of a point inside.
  double lower_bound(const Node& nd, const double* p) const {
    double g[3];
    for (int a = 0; a < 3; ++a)
      g[a] = p[a] < nd.lo[a] ? nd.lo[a] - p[a] : (p[a] > nd.hi[a] ? p[a] - nd.hi[a] : 0.0);
    return (g[0] * g[0] + g[1] * g[1] + g[2] * g[2]) * (1 - 1e-12);
  }
};

}  // namespace

StatusOr<NeighborLists> nearest_neighbors(const torch::Tensor& points, const torch::Tensor& active,
                                          int64_t k, bool include_self) {
  if (!points.defined() || points.dim() != 2 || points.size(1) != 3)
    return invalid("nearest_neighbors: points must be [N, 3]");
  if (k < 0) return invalid("nearest_neighbors: k must be >= 0, got " + std::to_string(k));
  const int64_t n = points.size(0);
  CRPGS_ASSIGN_OR_RETURN(std::vector<uint8_t> act, active_bytes(active, n, "nearest_neighbors"));
  auto pts = points.detach().to(torch::kCPU, torch::kDouble).contiguous();
  const double* P = pts.data_ptr<double>();
  std::vector<int64_t> ids;
  for (int64_t i = 0; i < n; ++i)
    if (act[size_t(i)]) {
      if (!std::isfinite(P[3 * i]) || !std::isfinite(P[3 * i + 1]) || !std::isfinite(P[3 * i + 2]))
        return invalid("nearest_neighbors: active point " + std::to_string(i) +
                       " has a non-finite coordinate");
      ids.push_back(i);
    }
  NeighborLists out;
  out.index = torch::full({n, k}, -1, torch::kLong);
  out.sq_dist = torch::full({n, k}, kInf, torch::kDouble);
  if (k == 0 || ids.empty()) return out;
  const int64_t na = int64_t(ids.size());
  const KdTree tree(P, std::move(ids));
  int64_t* OI = out.index.data_ptr<int64_t>();
  double* OD = out.sq_dist.data_ptr<double>();
  const int64_t others = include_self ? k - 1 : k;
  // Queries in tree order, so consecutive queries share the nodes they visit.
  at::parallel_for(0, na, 64, [&](int64_t begin, int64_t end) {
    TopList best(others, /*larger=*/false);
    std::vector<std::pair<double, int64_t>> stack;  // (lower bound, node)
    for (int64_t v = begin; v < end; ++v) {
      const int64_t i = tree.order[size_t(v)];
      const double* p = P + 3 * i;
      best.count = 0;
      // A node can hold a better point than the current k-th (distance, index) only if its bound
      // is below that distance, or equal to it with a smaller index somewhere inside.
      auto may_improve = [&](double bound, const KdTree::Node& nd) {
        if (!best.full()) return true;
        const double worst = best.worst();
        return bound < worst || (bound == worst && nd.min_index < best.idx[size_t(best.cap - 1)]);
      };
      stack.assign(1, {tree.lower_bound(tree.nodes[0], p), 0});
      while (!stack.empty() && others > 0) {
        const auto [bound, id] = stack.back();
        stack.pop_back();
        const KdTree::Node& nd = tree.nodes[size_t(id)];
        if (!may_improve(bound, nd)) continue;
        if (nd.child < 0) {
          for (int64_t s = nd.begin; s < nd.end; ++s) {
            const int64_t j = tree.order[size_t(s)];
            if (j == i) continue;
            const double dx = P[3 * j] - p[0], dy = P[3 * j + 1] - p[1], dz = P[3 * j + 2] - p[2];
            best.offer(dx * dx + dy * dy + dz * dz, j);
          }
          continue;
        }
        const KdTree::Node& a = tree.nodes[size_t(nd.child)];
        const KdTree::Node& b = tree.nodes[size_t(nd.child + 1)];
        std::pair<double, int64_t> near{tree.lower_bound(a, p), nd.child};
        std::pair<double, int64_t> far{tree.lower_bound(b, p), nd.child + 1};
        if (far.first < near.first || (far.first == near.first && b.min_index < a.min_index))
          std::swap(near, far);
        stack.push_back(far);  // popped after the nearer subtree has tightened the bound
        stack.push_back(near);
      }
      int64_t slot = 0;
      if (include_self) {
        OI[i * k] = i;
        OD[i * k] = 0;
        slot = 1;
      }
      for (int64_t t = 0; t < best.count; ++t) {
        OI[i * k + slot + t] = best.idx[size_t(t)];
        OD[i * k + slot + t] = best.key[size_t(t)];
      }
    }
  });
  return out;
}

StatusOr<LinkCandidates> nearest_candidates(const torch::Tensor& positions,
                                            const torch::Tensor& active, int64_t m) {
  CRPGS_ASSIGN_OR_RETURN(NeighborLists nn, nearest_neighbors(positions, active, m, true));
  LinkCandidates out;
  out.index = nn.index;
  out.score = nn.sq_dist.sqrt().neg().to(torch::kFloat);  // +inf -> -inf in unused slots
  return out;
}

StatusOr<LinkCandidates> cosine_candidates(const torch::Tensor& features,
                                           const torch::Tensor& active, int64_t m,
                                           int64_t memory_budget_bytes) {
  if (!features.defined() || features.dim() != 2)
    return invalid("cosine_candidates: features must be [N, D]");
  if (m < 0) return invalid("cosine_candidates: M must be >= 0, got " + std::to_string(m));
  if (memory_budget_bytes <= 0) return invalid("cosine_candidates: memory budget must be > 0");
  const int64_t n = features.size(0), d = features.size(1);
  CRPGS_ASSIGN_OR_RETURN(std::vector<uint8_t> act, active_bytes(active, n, "cosine_candidates"));
  LinkCandidates out;
  out.index = torch::full({n, m}, -1, torch::kLong);
  out.score = torch::full({n, m}, -std::numeric_limits<float>::infinity(), torch::kFloat);
  if (m == 0 || n == 0 || d == 0) return out;

  auto f = features.detach().to(torch::kCPU, torch::kDouble).contiguous();  // [N, D]
  const double* F = f.data_ptr<double>();
  // Rows that can be linked: active, finite, non-zero norm.
  std::vector<int64_t> ids;
  std::vector<double> norms;
  for (int64_t i = 0; i < n; ++i) {
    if (!act[size_t(i)]) continue;
    double s = 0;
    bool finite = true;
    for (int64_t c = 0; c < d; ++c) {
      finite = finite && std::isfinite(F[i * d + c]);
      s += F[i * d + c] * F[i * d + c];
    }
    if (!finite || !(s > 0) || !std::isfinite(s)) continue;
    ids.push_back(i);
    norms.push_back(std::sqrt(s));
  }
  const int64_t nv = int64_t(ids.size());
  if (nv == 0) return out;

  // Exact integer representation (see the file comment).
  int log2d = 0;
  while ((int64_t(1) << log2d) < d) ++log2d;
  const int bits = (52 - log2d) / 2;
  const double scale = std::ldexp(1.0, bits);
  std::vector<double> q(size_t(nv * d));               // [Nv, D] integers
  std::vector<double> inv(static_cast<size_t>(nv));    // 1 / |q|
  auto screen = torch::empty({nv, d}, torch::kFloat);  // [Nv, D] q / |q|
  float* S = screen.data_ptr<float>();
  for (int64_t v = 0; v < nv; ++v) {
    const double* x = F + ids[size_t(v)] * d;
    double s = 0;
    for (int64_t c = 0; c < d; ++c) {
      const double qc = std::nearbyint(x[c] / norms[size_t(v)] * scale);
      q[size_t(v * d + c)] = qc;
      s += qc * qc;
    }
    inv[size_t(v)] = 1.0 / std::sqrt(s);  // s > 0: the largest |x_c| / |x| >= 1/sqrt(D)
    for (int64_t c = 0; c < d; ++c) S[v * d + c] = float(q[size_t(v * d + c)] * inv[size_t(v)]);
  }
  auto exact = [&](int64_t v, int64_t w) {
    const double* a = q.data() + v * d;
    const double* b = q.data() + w * d;
    double s = 0;
    for (int64_t c = 0; c < d; ++c) s += a[c] * b[c];
    return s * inv[size_t(v)] * inv[size_t(w)];
  };
  // Rows with identical integers score identically against every row: each query scores one
  // member of such a group exactly and reuses it for the rest, so a block of B identical anchors
  // costs B² comparisons, not B² dot products. A hash collision between different rows leaves
  // the later one, and its copies, outside any group: slower, never wrong.
  std::vector<int64_t> group(static_cast<size_t>(nv), -1);  // duplicate group id, or -1
  int64_t groups = 0;
  {
    std::unordered_map<uint64_t, int64_t> first;
    first.reserve(size_t(nv));
    for (int64_t v = 0; v < nv; ++v) {
      uint64_t h = 1469598103934665603ull;  // FNV-1a over the integer values
      for (int64_t c = 0; c < d; ++c) {
        h ^= uint64_t(int64_t(q[size_t(v * d + c)]));
        h *= 1099511628211ull;
      }
      const auto [it, fresh] = first.emplace(h, v);
      const int64_t u = it->second;
      const bool same =
          !fresh && std::equal(q.begin() + u * d, q.begin() + (u + 1) * d, q.begin() + v * d);
      if (same && group[size_t(u)] < 0) group[size_t(u)] = groups++;
      if (same) group[size_t(v)] = group[size_t(u)];
    }
  }
  struct Memo {  // per thread: the exact score of each duplicate group for the query `row`
    std::vector<double> score;
    std::vector<int64_t> row;
  };
  std::vector<Memo> memos(groups > 0 ? size_t(at::get_num_threads()) : 0);
  for (Memo& mm : memos) {
    mm.score.resize(size_t(groups));
    mm.row.assign(size_t(groups), -1);
  }
  const float eps = float(1e-4 + 1e-6 * double(d));
  const auto screen_t = screen.t().contiguous();  // [D, Nv]
  const int64_t rows =
      std::clamp<int64_t>(memory_budget_bytes / (int64_t(sizeof(float)) * nv), 1, nv);
  int64_t* OI = out.index.data_ptr<int64_t>();
  float* OS = out.score.data_ptr<float>();
  auto clamp1 = [](double s) { return float(std::clamp(s, -1.0, 1.0)); };
  for (int64_t r0 = 0; r0 < nv; r0 += rows) {
    const int64_t r1 = std::min(nv, r0 + rows);
    const auto block = at::mm(screen.slice(0, r0, r1), screen_t).contiguous();  // [rows, Nv]
    const float* B = block.data_ptr<float>();
    at::parallel_for(r0, r1, 1, [&](int64_t begin, int64_t end) {
      TopList best(m - 1, /*larger=*/true);
      Memo* memo = memos.empty() ? nullptr : &memos[size_t(at::get_thread_num())];
      for (int64_t v = begin; v < end; ++v) {
        const float* row = B + (v - r0) * nv;
        best.count = 0;
        best.center = ids[size_t(v)];
        float thr = -std::numeric_limits<float>::infinity();  // rescore above this
        constexpr int64_t kChunk = 64;
        for (int64_t w0 = 0; w0 < nv && m > 1; w0 += kChunk) {
          const int64_t w1 = std::min(nv, w0 + kChunk);
          int any = 0;
          for (int64_t w = w0; w < w1; ++w) any |= row[w] > thr;  // vectorises
          if (!any) continue;
          for (int64_t w = w0; w < w1; ++w) {
            if (w == v || !(row[w] > thr)) continue;
            const int64_t gw = group[size_t(w)];
            double score;
            if (gw < 0) {
              score = exact(v, w);
            } else {
              if (memo->row[size_t(gw)] != v) {
                memo->score[size_t(gw)] = exact(v, w);
                memo->row[size_t(gw)] = v;
              }
              score = memo->score[size_t(gw)];
            }
            best.offer(score, ids[size_t(w)]);
            if (best.full()) thr = float(best.worst()) - eps;
          }
        }
        const int64_t i = ids[size_t(v)];
        OI[i * m] = i;
        OS[i * m] = clamp1(exact(v, v));
        for (int64_t t = 0; t < best.count; ++t) {
          OI[i * m + 1 + t] = best.idx[size_t(t)];
          OS[i * m + 1 + t] = clamp1(best.key[size_t(t)]);
        }
      }
    });
  }
  return out;
}

StatusOr<std::vector<double>> decaying_thresholds(double tau_max, double tau_min, double step) {
  if (!(step > 0) || !std::isfinite(step))
    return invalid("thresholds: tau_step must be > 0, got " + std::to_string(step));
  if (!(tau_min <= tau_max) || !std::isfinite(tau_min) || !std::isfinite(tau_max))
    return invalid("thresholds: need tau_min <= tau_max, got tau_min " + std::to_string(tau_min) +
                   ", tau_max " + std::to_string(tau_max));
  const int64_t count = int64_t(std::floor((tau_max - tau_min) / step + 1e-6)) + 1;
  if (count > 100000) return invalid("thresholds: more than 100000 steps");
  std::vector<double> out;
  for (int64_t k = 0; k < count; ++k) out.push_back(tau_max - double(k) * step);
  return out;
}

StatusOr<torch::Tensor> greedy_links(const LinkCandidates& c, const std::vector<double>& thresholds,
                                     const torch::Tensor& active) {
  if (!c.index.defined() || !c.score.defined() || c.index.dim() != 2 ||
      c.index.sizes() != c.score.sizes())
    return invalid("greedy_links: candidate index and score must both be [N, M]");
  const int64_t n = c.index.size(0), m = c.index.size(1);
  CRPGS_ASSIGN_OR_RETURN(std::vector<uint8_t> act, active_bytes(active, n, "greedy_links"));
  const auto idx = c.index.detach().to(torch::kCPU, torch::kLong).contiguous();
  const auto sc = c.score.detach().to(torch::kCPU, torch::kFloat).contiguous();
  const int64_t* I = idx.data_ptr<int64_t>();
  const float* S = sc.data_ptr<float>();
  for (int64_t e = 0; e < n * m; ++e)
    if (I[e] < -1 || I[e] >= n)
      return invalid("greedy_links: candidate " + std::to_string(I[e]) + " of anchor " +
                     std::to_string(e / m) + " is out of range [0, " + std::to_string(n) + ")");
  auto links = torch::full({n}, -1, torch::kLong);
  int64_t* L = links.data_ptr<int64_t>();
  std::vector<uint8_t> is_root(size_t(n), 0);
  for (double tau : thresholds) {
    const double bar = tau - 1e-6;
    for (int64_t i = 0; i < n; ++i) {
      if (!act[size_t(i)] || L[i] >= 0 || is_root[size_t(i)]) continue;
      int64_t best = -1;
      float best_s = 0;
      for (int64_t t = 0; t < m; ++t) {
        const int64_t j = I[i * m + t];
        const float s = S[i * m + t];
        if (j < 0 || j == i || !act[size_t(j)] || L[j] >= 0 || is_root[size_t(j)]) continue;
        if (!(double(s) >= bar)) continue;
        if (best < 0 || s > best_s) best = j, best_s = s;
      }
      if (best >= 0) {
        L[i] = best;
        is_root[size_t(best)] = 1;
      }
    }
  }
  return links;
}

StatusOr<torch::Tensor> random_links(const torch::Tensor& active, uint64_t seed,
                                     double leaf_fraction) {
  if (!active.defined() || active.dim() != 1) return invalid("random_links: active must be [N]");
  if (!(leaf_fraction >= 0 && leaf_fraction <= 0.5))
    return invalid("random_links: leaf_fraction must be in [0, 0.5], got " +
                   std::to_string(leaf_fraction));
  const int64_t n = active.size(0);
  CRPGS_ASSIGN_OR_RETURN(std::vector<uint8_t> act, active_bytes(active, n, "random_links"));
  std::vector<int64_t> ids;
  for (int64_t i = 0; i < n; ++i)
    if (act[size_t(i)]) ids.push_back(i);
  uint64_t state = seed;
  auto next = [&state] {  // splitmix64
    uint64_t z = (state += 0x9E3779B97F4A7C15ull);
    z = (z ^ (z >> 30)) * 0xBF58476D1CE4E5B9ull;
    z = (z ^ (z >> 27)) * 0x94D049BB133111EBull;
    return z ^ (z >> 31);
  };
  auto below = [&next](uint64_t range) {  // uniform in [0, range), rejection sampling
    const uint64_t reject_under = (0 - range) % range;
    uint64_t x = next();
    while (x < reject_under) x = next();
    return x % range;
  };
  for (size_t t = ids.size(); t > 1; --t) std::swap(ids[t - 1], ids[size_t(below(t))]);
  const int64_t pairs = std::min<int64_t>(
      int64_t(ids.size()) / 2, int64_t(std::floor(leaf_fraction * double(ids.size()) + 1e-9)));
  auto links = torch::full({n}, -1, torch::kLong);
  int64_t* L = links.data_ptr<int64_t>();
  for (int64_t t = 0; t < pairs; ++t) L[ids[size_t(2 * t)]] = ids[size_t(2 * t + 1)];
  return links;
}

Status check_links(const torch::Tensor& links, const torch::Tensor& active) {
  if (!links.defined() || links.dim() != 1 || links.scalar_type() != torch::kLong)
    return invalid("links: must be a 1-D int64 tensor");
  const int64_t n = links.size(0);
  CRPGS_ASSIGN_OR_RETURN(std::vector<uint8_t> act, active_bytes(active, n, "links"));
  const auto l = links.detach().to(torch::kCPU).contiguous();
  const int64_t* L = l.data_ptr<int64_t>();
  std::vector<int64_t> leaf_of(size_t(n), -1);
  for (int64_t i = 0; i < n; ++i) {
    const int64_t j = L[i];
    const std::string at = "links: anchor " + std::to_string(i);
    if (j == -1) continue;
    if (j < -1 || j >= n)
      return invalid(at + " links to " + std::to_string(j) + ", outside [-1, " + std::to_string(n) +
                     ")");
    if (j == i) return invalid(at + " links to itself");
    if (!act[size_t(i)]) return invalid(at + " is an inactive leaf");
    if (!act[size_t(j)]) return invalid(at + " has the inactive root " + std::to_string(j));
    if (L[j] != -1)
      return invalid(at + " has the root " + std::to_string(j) + ", which is itself a leaf of " +
                     std::to_string(L[j]) + " (chain)");
    if (leaf_of[size_t(j)] >= 0)
      return invalid("links: root " + std::to_string(j) + " has two leaves, " +
                     std::to_string(leaf_of[size_t(j)]) + " and " + std::to_string(i));
    leaf_of[size_t(j)] = i;
  }
  return OkStatus();
}

LinkStats link_stats(const torch::Tensor& links, const torch::Tensor& active) {
  LinkStats s;
  s.leaves = links.ne(-1).sum().item<int64_t>();
  s.active = active.defined() ? active.ne(0).sum().item<int64_t>() : links.size(0);
  return s;
}

}  // namespace crpgs
