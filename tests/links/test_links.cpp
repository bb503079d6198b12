/// @file test_links.cpp
/// @brief Anchor-link algorithms (crpgs/links.h): cosine and nearest candidates against brute
/// force, the numerical-stability cases of docs/method.md (zero-norm and identical features, fewer
/// anchors than M, everything masked), Algorithm 1's decaying threshold on hand-made examples,
/// one hop and one-to-one on clustered data, thread-count independence, random pairing, and the
/// validity check's messages; the link_* plugins through the registry.
#include <gtest/gtest.h>

#include <cmath>
#include <limits>
#include <set>
#include <tuple>

#include <ATen/Parallel.h>
#include <torch/torch.h>

#include "crpgs/context_model.h"
#include "crpgs/links.h"
#include "plugins/plugin_test_util.h"

namespace crpgs {
namespace {

const float kNegInf = -std::numeric_limits<float>::infinity();
const std::vector<double> kPaperTaus = {1.0, 0.95, 0.9, 0.85, 0.8};

template <typename T>
T value_or_die(StatusOr<T> s) {
  if (!s.ok()) throw StatusError(s.status());
  return std::move(s).value();
}

/// Features around `clusters` random directions (many pairs above 0.8), [n, d] float.
torch::Tensor clustered_features(int64_t n, int64_t d, int64_t clusters, double noise,
                                 uint64_t seed) {
  torch::manual_seed(seed);
  auto centers = torch::randn({clusters, d});
  auto which = torch::randint(clusters, {n}, torch::kLong);
  return centers.index_select(0, which) + noise * torch::randn({n, d});
}

torch::Tensor random_mask(int64_t n, double p, uint64_t seed) {
  torch::manual_seed(seed);
  return torch::rand({n}) < p;
}

std::vector<int64_t> to_vec(const torch::Tensor& t) {
  auto c = t.contiguous();
  return std::vector<int64_t>(c.data_ptr<int64_t>(), c.data_ptr<int64_t>() + c.numel());
}

TEST(LinksCosine, ZeroNormRowsAreNeverLinkedAndIdenticalDirectionsScoreOne) {
  auto f = torch::tensor({0.f, 0.f, 0.f,     // 0: zero norm
                          1.f, 2.f, 3.f,     // 1
                          2.f, 4.f, 6.f,     // 2: same direction as 1
                          -1.f, -2.f, -3.f,  // 3: opposite
                          1.f, 0.f, 0.f,     // 4
                          NAN, 1.f, 1.f})    // 5: non-finite, treated like zero norm
               .view({6, 3});
  auto c = value_or_die(cosine_candidates(f, {}, 3));
  ASSERT_EQ(c.index.sizes(), (torch::IntArrayRef{6, 3}));
  for (int64_t i : {0, 5})
    for (int64_t t = 0; t < 3; ++t) {
      EXPECT_EQ(c.index[i][t].item<int64_t>(), -1);
      EXPECT_EQ(c.score[i][t].item<float>(), kNegInf);
    }
  EXPECT_FALSE(c.index.eq(0).any().item<bool>());
  EXPECT_FALSE(c.index.eq(5).any().item<bool>());
  // Self first, then the identical direction with score exactly 1.
  EXPECT_EQ(c.index[1][0].item<int64_t>(), 1);
  EXPECT_EQ(c.score[1][0].item<float>(), 1.f);
  EXPECT_EQ(c.index[1][1].item<int64_t>(), 2);
  EXPECT_EQ(c.score[1][1].item<float>(), 1.f);
  EXPECT_EQ(c.index[2][1].item<int64_t>(), 1);
  EXPECT_NEAR(c.score[1][2].item<float>(), 1.0 / std::sqrt(14.0), 1e-6);  // with anchor 4
  EXPECT_EQ(c.index[1][2].item<int64_t>(), 4);
  EXPECT_TRUE(torch::isfinite(c.score.index({c.index.ge(0)})).all().item<bool>());

  auto links = value_or_die(greedy_links(c, kPaperTaus, {}));
  EXPECT_EQ(to_vec(links), (std::vector<int64_t>{-1, 2, -1, -1, -1, -1}));
  EXPECT_TRUE(check_links(links, {}).ok());
}

TEST(LinksCosine, AllAnchorsIdenticalPairInIndexOrder) {
  auto f = torch::tensor({0.3f, -1.2f, 0.7f}).repeat({25, 1});
  auto c = value_or_die(cosine_candidates(f, {}, 10));
  EXPECT_TRUE(c.score.eq(1.f).all().item<bool>());
  // Ties are broken by index distance, then index: self, then the nearest indices.
  EXPECT_EQ(to_vec(c.index[24]), (std::vector<int64_t>{24, 23, 22, 21, 20, 19, 18, 17, 16, 15}));
  EXPECT_EQ(to_vec(c.index[3]), (std::vector<int64_t>{3, 2, 4, 1, 5, 0, 6, 7, 8, 9}));
  auto links = value_or_die(greedy_links(c, kPaperTaus, {}));
  ASSERT_TRUE(check_links(links, {}).ok());
  std::vector<int64_t> expect(25, -1);
  for (int64_t t = 0; t < 12; ++t) expect[size_t(2 * t)] = 2 * t + 1;  // anchor 24 finds none
  EXPECT_EQ(to_vec(links), expect);
}

TEST(LinksCosine, BlocksOfIdenticalRowsAmongOthersMatchBruteForce) {
  // Two blocks of identical rows among random rows, across several similarity blocks: every list
  // is the brute-force order (cosine, |j - i|, j). One block is row 1 scaled by 4, which is
  // exact, so its rows have row 1's direction to the last bit (row 1 belongs to it too).
  torch::manual_seed(11);
  auto f = torch::randn({240, 6});
  const auto pick = torch::rand({240});
  const auto row0 = f[0].clone(), row1 = f[1].clone();
  f = torch::where((pick < 0.3).unsqueeze(1), row0.unsqueeze(0), f);
  f = torch::where((pick > 0.8).unsqueeze(1), 4 * row1.unsqueeze(0), f);
  f[1] = row1;
  const auto active = random_mask(240, 0.8, 4);
  const int64_t m = 6;
  auto c = value_or_die(cosine_candidates(f, active, m, 4 * 240 * 50));
  auto fd = f.to(torch::kDouble);
  fd = fd / fd.norm(2, 1, true);
  const auto sim = fd.mm(fd.t());  // [N, N]
  for (int64_t i = 0; i < 240; ++i) {
    if (!active[i].item<bool>()) continue;
    std::vector<std::tuple<double, int64_t, int64_t>> order;  // (-cos rounded, |j - i|, j)
    for (int64_t j = 0; j < 240; ++j)
      if (j != i && active[j].item<bool>())
        order.emplace_back(-std::round(sim[i][j].item<double>() * 1e6) / 1e6, std::abs(j - i), j);
    std::sort(order.begin(), order.end());
    std::vector<int64_t> expect{i};
    for (int64_t t = 0; t < m - 1; ++t) expect.push_back(std::get<2>(order[size_t(t)]));
    EXPECT_EQ(to_vec(c.index[i]), expect) << i;
  }
}

TEST(LinksCosine, FewerActiveAnchorsThanMArePadded) {
  auto f = torch::randn({6, 4});
  auto active = torch::tensor({true, false, true, true, false, false});
  auto c = value_or_die(cosine_candidates(f, active, 10));
  ASSERT_EQ(c.index.sizes(), (torch::IntArrayRef{6, 10}));
  for (int64_t i : {1, 4, 5}) EXPECT_TRUE(c.index[i].eq(-1).all().item<bool>()) << i;
  for (int64_t i : {0, 2, 3}) {
    const auto first3 = to_vec(c.index[i].slice(0, 0, 3));
    std::set<int64_t> got(first3.begin(), first3.end());
    EXPECT_EQ(got, (std::set<int64_t>{0, 2, 3})) << i;
    EXPECT_EQ(c.index[i][0].item<int64_t>(), i);
    EXPECT_TRUE(c.index[i].slice(0, 3).eq(-1).all().item<bool>());
    EXPECT_TRUE(c.score[i].slice(0, 3).eq(kNegInf).all().item<bool>());
  }
  auto n = value_or_die(nearest_candidates(torch::randn({6, 3}), active, 10));
  EXPECT_TRUE(n.index.slice(1, 3).eq(-1).all().item<bool>());
  EXPECT_TRUE(n.index.slice(1, 0, 3).ge(0).sum().item<int64_t>() == 9);
  auto l = value_or_die(greedy_links(n, {-INFINITY}, active));
  EXPECT_TRUE(check_links(l, active).ok());
  EXPECT_EQ(link_stats(l, active).leaves, 1);  // 3 active anchors: one pair
}

TEST(LinksCosine, AllMaskedGivesNoCandidatesAndNoLinks) {
  auto active = torch::zeros({50}, torch::kBool);
  auto c = value_or_die(cosine_candidates(torch::randn({50, 30}), active, 10));
  EXPECT_TRUE(c.index.eq(-1).all().item<bool>());
  auto n = value_or_die(nearest_candidates(torch::randn({50, 3}), active, 10));
  EXPECT_TRUE(n.index.eq(-1).all().item<bool>());
  for (const auto& cand : {c, n}) {
    auto l = value_or_die(greedy_links(cand, kPaperTaus, active));
    EXPECT_TRUE(l.eq(-1).all().item<bool>());
    EXPECT_TRUE(check_links(l, active).ok());
  }
  auto r = value_or_die(random_links(active, 1));
  EXPECT_TRUE(r.eq(-1).all().item<bool>());
  // Empty inputs too.
  auto e = value_or_die(cosine_candidates(torch::zeros({0, 30}), {}, 10));
  EXPECT_EQ(e.index.sizes(), (torch::IntArrayRef{0, 10}));
}

TEST(LinksCosine, MatchesBruteForceForAnyMemoryBudget) {
  auto f = torch::randn({300, 30}, torch::kDouble);
  auto active = random_mask(300, 0.7, 3);
  auto big = value_or_die(cosine_candidates(f, active, 10));
  auto tiny = value_or_die(cosine_candidates(f, active, 10, 1));  // one row per block
  auto mid = value_or_die(cosine_candidates(f, active, 10, 37 * 4 * 210));
  EXPECT_TRUE(torch::equal(big.index, tiny.index));
  EXPECT_TRUE(torch::equal(big.score, tiny.score));
  EXPECT_TRUE(torch::equal(big.index, mid.index));
  EXPECT_TRUE(torch::equal(big.score, mid.score));

  auto ids = active.nonzero().view(-1);
  auto fn = f.index_select(0, ids);
  fn = fn / fn.norm(2, 1, true);
  auto sim = fn.mm(fn.t());                       // [Na, Na]
  sim.fill_diagonal_(2.0);                        // self first
  auto top = std::get<1>(sim.topk(10, 1, true));  // random data: no ties
  for (int64_t v = 0; v < ids.size(0); ++v) {
    const int64_t i = ids[v].item<int64_t>();
    EXPECT_TRUE(torch::equal(big.index[i], ids.index_select(0, top[v]))) << i;
    auto expect = sim[v].index_select(0, top[v]).to(torch::kFloat);
    expect[0] = 1.f;
    EXPECT_TRUE(torch::allclose(big.score[i], expect, 0, 1e-6)) << i;
  }
}

TEST(LinksNearest, MatchesBruteForceOnSpreadFlatAndDuplicatePoints) {
  torch::manual_seed(5);
  auto spread = torch::rand({1500, 3}) * torch::tensor({10.f, 1.f, 3.f});
  auto flat = torch::rand({1500, 3}) * torch::tensor({5.f, 5.f, 0.f});
  auto dup = torch::rand({300, 3}).repeat({3, 1});  // exact duplicates: ties broken by index
  auto outlier = torch::cat({torch::rand({500, 3}), torch::tensor({{1e4f, 0.f, 0.f}})});
  // A dense object and far background: 1e-4 of the extent holds 99% of the points.
  auto cluster = torch::cat({torch::rand({1200, 3}) * 1e-2, torch::rand({12, 3}) * 100});
  for (const auto& p : {spread, flat, dup, outlier, cluster}) {
    const int64_t n = p.size(0);
    auto active = random_mask(n, 0.7, 9);
    auto nn = value_or_die(nearest_neighbors(p, active, 7, false));
    auto ids = active.nonzero().view(-1);
    auto pa = p.index_select(0, ids).to(torch::kDouble);
    auto d2 = torch::cdist(pa, pa).pow(2);  // [Na, Na]
    d2.fill_diagonal_(INFINITY);
    for (int64_t v = 0; v < ids.size(0); v += 7) {
      const int64_t i = ids[v].item<int64_t>();
      // Expected order: (distance, index), with distances compared at the found precision.
      auto got = nn.index[i];
      ASSERT_TRUE(got.ge(0).all().item<bool>());
      auto kth = nn.sq_dist[i][6].item<double>();
      auto closer = d2[v].lt(kth * (1 - 1e-9)).sum().item<int64_t>();
      EXPECT_LE(closer, 6) << i;
      for (int64_t t = 0; t < 7; ++t) {
        const int64_t j = got[t].item<int64_t>();
        const int64_t vj = (ids == j).nonzero().item<int64_t>();
        EXPECT_NEAR(d2[v][vj].item<double>(), nn.sq_dist[i][t].item<double>(), 1e-6) << i;
      }
      auto row = nn.sq_dist[i];
      EXPECT_TRUE(row.slice(0, 1).ge(row.slice(0, 0, 6)).all().item<bool>());
    }
    EXPECT_TRUE(nn.index.index({~active}).eq(-1).all().item<bool>());
  }
  // Duplicates: the 2 copies of point 0 (indices 300, 600) come first, lower index first.
  auto all = value_or_die(nearest_neighbors(dup, {}, 3, true));
  EXPECT_EQ(to_vec(all.index[0]), (std::vector<int64_t>{0, 300, 600}));
  EXPECT_EQ(to_vec(all.index[600]), (std::vector<int64_t>{600, 0, 300}));
  auto c = value_or_die(nearest_candidates(dup, {}, 3));
  EXPECT_EQ(c.score[0][1].item<float>(), -0.f);
}

TEST(LinksNearest, TiesAtEqualDistancesGoToTheLowerIndexAsInBruteForce) {
  // Integer lattice points (every squared distance exact) with 30 copies of one of them: most
  // neighbours tie with others, often more of them than k takes.
  torch::manual_seed(3);
  auto lattice = torch::randint(0, 5, {400, 3}).to(torch::kFloat);
  auto p = torch::cat({lattice, lattice[7].unsqueeze(0).repeat({30, 1})});
  const int64_t n = p.size(0), k = 5;
  auto active = random_mask(n, 0.8, 2);
  const auto pd = p.to(torch::kDouble);
  const auto d2 = (pd.unsqueeze(1) - pd.unsqueeze(0)).pow(2).sum(2);  // [n, n], exact
  const auto d2a = d2.accessor<double, 2>();
  const auto act = active.accessor<bool, 1>();
  for (bool with_self : {false, true}) {
    auto nn = value_or_die(nearest_neighbors(p, active, k, with_self));
    for (int64_t i = 0; i < n; ++i) {
      if (!act[i]) continue;
      std::vector<std::pair<double, int64_t>> order;  // (squared distance, index)
      for (int64_t j = 0; j < n; ++j)
        if (j != i && act[j]) order.emplace_back(d2a[i][j], j);
      std::sort(order.begin(), order.end());
      std::vector<int64_t> expect;
      if (with_self) expect.push_back(i);
      for (size_t t = 0; expect.size() < size_t(k); ++t) expect.push_back(order[t].second);
      EXPECT_EQ(to_vec(nn.index[i]), expect) << i << (with_self ? " with self" : "");
    }
  }
}

TEST(LinksGreedy, DecayingThresholdPrefersExactMatchesFirst) {
  // cos(0,1) = cos(0,2) = 0.9, cos(1,2) = 1: the τ = 1 pass pairs 1 with 2 before anchor 0,
  // visited first, can take 1 at τ = 0.9; a single τ = 0.8 pass would pair 0 with 1.
  const float s = std::sqrt(1.f - 0.81f);
  auto f = torch::tensor({1.f, 0.f, 0.9f, s, 0.9f, s}).view({3, 2});
  auto c = value_or_die(cosine_candidates(f, {}, 10));
  EXPECT_EQ(to_vec(value_or_die(greedy_links(c, kPaperTaus, {}))),
            (std::vector<int64_t>{-1, 2, -1}));
  EXPECT_EQ(to_vec(value_or_die(greedy_links(c, {0.8}, {}))), (std::vector<int64_t>{1, -1, -1}));
  // Below τ_min nothing links.
  EXPECT_EQ(to_vec(value_or_die(greedy_links(c, {1.0, 0.95}, {}))),
            (std::vector<int64_t>{-1, 2, -1}));
}

TEST(LinksGreedy, ThresholdToleranceAndPassOrderOnHandMadeCandidates) {
  // Anchor 0 sees 1 at 0.849 (passes only at τ = 0.8); anchor 2 sees 1 at 0.85 (float 0.85 is
  // within 1e-6 of τ = 1 - 3·0.05). So 2 takes 1 in the τ = 0.85 pass although 0 is visited first.
  LinkCandidates c;
  c.index = torch::tensor({0, 1, 1, -1, 2, 1}, torch::kLong).view({3, 2});
  c.score = torch::tensor({1.f, 0.849f, 1.f, kNegInf, 1.f, 0.85f}).view({3, 2});
  auto taus = value_or_die(decaying_thresholds(1.0, 0.8, 0.05));
  EXPECT_EQ(to_vec(value_or_die(greedy_links(c, taus, {}))), (std::vector<int64_t>{-1, -1, 1}));
  EXPECT_EQ(to_vec(value_or_die(greedy_links(c, {0.8}, {}))), (std::vector<int64_t>{1, -1, -1}));
  // An inactive root candidate is skipped.
  auto active = torch::tensor({true, false, true});
  EXPECT_TRUE(value_or_die(greedy_links(c, taus, active)).eq(-1).all().item<bool>());
  // Out-of-range candidates are an error, not a silent read.
  c.index[0][1] = 7;
  EXPECT_FALSE(greedy_links(c, taus, {}).ok());
}

TEST(LinksGreedy, PaperThresholdsFromAnIntegerCounter) {
  auto t = value_or_die(decaying_thresholds(1.0, 0.8, 0.05));
  ASSERT_EQ(t.size(), 5u);
  for (size_t k = 0; k < 5; ++k) EXPECT_NEAR(t[k], kPaperTaus[k], 1e-12);
  EXPECT_EQ(value_or_die(decaying_thresholds(0.9, 0.9, 0.1)).size(), 1u);
  EXPECT_EQ(value_or_die(decaying_thresholds(1.0, 0.7, 0.1)).size(), 4u);
  EXPECT_FALSE(decaying_thresholds(1.0, 0.8, 0.0).ok());
  EXPECT_FALSE(decaying_thresholds(0.8, 1.0, 0.05).ok());
}

TEST(LinksGreedy, ChainsStayOneHop) {
  // 0 -> 1 -> 2 at 10° steps: 0 takes 1; 2's best (1) is then a root and its next (0) a leaf.
  auto ang = torch::tensor({0.0, 10.0, 20.0}) * (3.14159265358979323846 / 180);
  auto f = torch::stack({ang.cos(), ang.sin()}, 1);
  auto c = value_or_die(cosine_candidates(f, {}, 10));
  auto l = value_or_die(greedy_links(c, kPaperTaus, {}));
  EXPECT_EQ(to_vec(l), (std::vector<int64_t>{1, -1, -1}));
  EXPECT_TRUE(check_links(l, {}).ok());
}

TEST(LinksGreedy, OneToOneOneHopAndAboveTauMinOnClusteredFeatures) {
  auto f = clustered_features(3000, 30, 150, 0.25, 11);
  auto active = random_mask(3000, 0.7, 12);
  auto c = value_or_die(cosine_candidates(f, active, 10));
  auto l = value_or_die(greedy_links(c, kPaperTaus, active));
  ASSERT_TRUE(check_links(l, active).ok()) << check_links(l, active).to_string();
  const auto st = link_stats(l, active);
  EXPECT_GT(st.leaves, st.active / 4);  // clusters are tight: most anchors find a partner
  EXPECT_LE(2 * st.leaves, st.active);
  auto leaves = l.ne(-1).nonzero().view(-1);
  auto roots = l.index_select(0, leaves);
  auto fn = f / f.norm(2, 1, true);
  auto cos = (fn.index_select(0, leaves) * fn.index_select(0, roots)).sum(1);
  EXPECT_TRUE(cos.ge(0.8 - 1e-5).all().item<bool>());
  // Roots and leaves disjoint, each root once.
  auto both = torch::cat({leaves, roots});
  EXPECT_EQ(std::get<0>(at::_unique(both)).numel(), both.numel());
}

TEST(LinksDeterminism, SameResultWithOneAndTwoThreads) {
  const int saved = at::get_num_threads();
  auto f = clustered_features(4000, 30, 100, 0.3, 21);
  auto p = torch::rand({4000, 3});
  auto active = random_mask(4000, 0.7, 22);
  std::vector<torch::Tensor> out[2];
  for (int t : {1, 2}) {
    at::set_num_threads(t);
    auto c = value_or_die(cosine_candidates(f, active, 10, 1 << 20));
    auto n = value_or_die(nearest_candidates(p, active, 10));
    out[t - 1] = {c.index, c.score, n.index, n.score,
                  value_or_die(greedy_links(c, kPaperTaus, active))};
  }
  at::set_num_threads(saved);
  for (size_t k = 0; k < out[0].size(); ++k)
    EXPECT_TRUE(torch::equal(out[0][k], out[1][k])) << "output " << k;
}

TEST(LinksRandom, ReproduciblePerSeedAndOneToOne) {
  auto active = random_mask(1001, 0.7, 31);
  const int64_t na = active.sum().item<int64_t>();
  auto a = value_or_die(random_links(active, 42));
  auto b = value_or_die(random_links(active, 42));
  auto c = value_or_die(random_links(active, 43));
  EXPECT_TRUE(torch::equal(a, b));
  EXPECT_FALSE(torch::equal(a, c));
  for (const auto& l : {a, c}) {
    EXPECT_TRUE(check_links(l, active).ok());
    EXPECT_EQ(link_stats(l, active).leaves, na / 2);
  }
  auto part = value_or_die(random_links(active, 42, 0.2));
  EXPECT_TRUE(check_links(part, active).ok());
  EXPECT_EQ(link_stats(part, active).leaves, int64_t(std::floor(0.2 * double(na))));
  EXPECT_FALSE(random_links(active, 1, 0.6).ok());
}

TEST(LinksCheck, NamesTheFirstViolation) {
  auto act = torch::tensor({true, true, true, true, false});
  auto msg = [&](std::vector<int64_t> l) {
    return check_links(torch::tensor(l, torch::kLong), act).message();
  };
  EXPECT_TRUE(check_links(torch::tensor({1, -1, 3, -1, -1}, torch::kLong), act).ok());
  EXPECT_NE(msg({5, -1, -1, -1, -1}).find("outside"), std::string::npos);
  EXPECT_NE(msg({-2, -1, -1, -1, -1}).find("outside"), std::string::npos);
  EXPECT_NE(msg({0, -1, -1, -1, -1}).find("itself"), std::string::npos);
  EXPECT_NE(msg({-1, -1, -1, -1, 0}).find("inactive leaf"), std::string::npos);
  EXPECT_NE(msg({4, -1, -1, -1, -1}).find("inactive root"), std::string::npos);
  EXPECT_NE(msg({1, 2, -1, -1, -1}).find("chain"), std::string::npos);
  EXPECT_NE(msg({1, -1, 1, -1, -1}).find("two leaves"), std::string::npos);
  EXPECT_FALSE(check_links(torch::tensor({1, -1, -1}, torch::kLong), act).ok());      // size
  EXPECT_FALSE(check_links(torch::tensor({1.f, -1.f, -1.f, -1.f, -1.f}), act).ok());  // dtype
}

TEST(LinksInputs, BadShapesAreErrors) {
  EXPECT_FALSE(cosine_candidates(torch::randn({10}), {}, 10).ok());
  EXPECT_FALSE(cosine_candidates(torch::randn({10, 3}), {}, -1).ok());
  EXPECT_FALSE(cosine_candidates(torch::randn({10, 3}), torch::ones({9}, torch::kBool), 3).ok());
  EXPECT_FALSE(nearest_candidates(torch::randn({10, 2}), {}, 3).ok());
  auto bad = torch::randn({10, 3});
  bad[4][1] = NAN;
  EXPECT_FALSE(nearest_candidates(bad, {}, 3).ok());
  auto act = torch::ones({10}, torch::kBool);
  act[4] = false;  // a non-finite inactive point is ignored
  EXPECT_TRUE(nearest_candidates(bad, act, 3).ok());
}

// ---- The link plugins, built through the registry as the pipeline does. ----

LinkInputs plugin_inputs(uint64_t seed) {
  LinkInputs in;
  in.features = clustered_features(2000, 30, 100, 0.25, 41);
  torch::manual_seed(42);
  in.positions = torch::rand({2000, 3});
  in.active = random_mask(2000, 0.7, 43);
  in.seed = seed;
  return in;
}

TEST(LinkPlugins, CohsIsCosineCandidatesPlusAlgorithmOne) {
  auto cohs = test::make_plugin<ContextModel>("links", "{type: link_cohs}");
  ASSERT_NE(cohs, nullptr);
  EXPECT_EQ(cohs->output_dim(), 0);
  const auto in = plugin_inputs(0);
  auto l = cohs->build_links(in);
  ASSERT_TRUE(check_links(l, in.active).ok());
  auto c = value_or_die(cosine_candidates(in.features, in.active, 10));
  EXPECT_TRUE(torch::equal(l, value_or_die(greedy_links(c, kPaperTaus, in.active))));
  EXPECT_GT(link_stats(l, in.active).leaves, 0);
  // A stricter τ_min links fewer anchors; M = 2 still links (self + 1).
  auto strict = test::make_plugin<ContextModel>("links", "{type: link_cohs, tau_min: 0.95}");
  ASSERT_NE(strict, nullptr);
  EXPECT_LT(link_stats(strict->build_links(in), in.active).leaves, link_stats(l, in.active).leaves);
  auto m2 = test::make_plugin<ContextModel>("links", "{type: link_cohs, candidates: 2}");
  ASSERT_NE(m2, nullptr);
  auto l2 = m2->build_links(in);
  EXPECT_TRUE(check_links(l2, in.active).ok());
  EXPECT_GT(link_stats(l2, in.active).leaves, 0);
}

TEST(LinkPlugins, CohsRejectsAnEmptyThresholdRange) {
  auto cfg = Config::from_string("links: {type: link_cohs, tau_max: 0.8, tau_min: 0.9}\n", "t");
  ASSERT_TRUE(cfg.ok());
  auto r = cfg->resolve(test::plugin_registry());
  ASSERT_TRUE(r.ok()) << r.status().to_string();
  auto c = create_component<ContextModel>(test::plugin_registry(), r->section("links"),
                                          crpgs_create_args{50, 10, 0, 50, {0, 0, 0, 0}});
  ASSERT_FALSE(c.ok());
  EXPECT_NE(c.status().message().find("tau_min"), std::string::npos) << c.status().message();
}

TEST(LinkPlugins, DistanceLinksNearestFreeAnchors) {
  auto dist = test::make_plugin<ContextModel>("links", "{type: link_distance}");
  ASSERT_NE(dist, nullptr);
  const auto in = plugin_inputs(0);
  auto l = dist->build_links(in);
  ASSERT_TRUE(check_links(l, in.active).ok());
  auto c = value_or_die(nearest_candidates(in.positions, in.active, 10));
  EXPECT_TRUE(torch::equal(l, value_or_die(greedy_links(c, {-INFINITY}, in.active))));
  const auto st = link_stats(l, in.active);
  EXPECT_GT(4 * st.leaves, st.active);  // most anchors find a free neighbour among 9
  // The first active anchor takes its nearest active neighbour.
  const int64_t i0 = in.active.nonzero()[0][0].item<int64_t>();
  EXPECT_EQ(l[i0].item<int64_t>(), c.index[i0][1].item<int64_t>());
}

TEST(LinkPlugins, RandomIsReproducibleForASeed) {
  auto rnd = test::make_plugin<ContextModel>("links", "{type: link_random}");
  ASSERT_NE(rnd, nullptr);
  auto a = rnd->build_links(plugin_inputs(7));
  auto b = rnd->build_links(plugin_inputs(7));
  auto c = rnd->build_links(plugin_inputs(8));
  const auto in = plugin_inputs(7);
  EXPECT_TRUE(torch::equal(a, b));
  EXPECT_FALSE(torch::equal(a, c));
  EXPECT_TRUE(check_links(a, in.active).ok());
  EXPECT_EQ(link_stats(a, in.active).leaves, in.active.sum().item<int64_t>() / 2);
  auto part = test::make_plugin<ContextModel>("links", "{type: link_random, leaf_fraction: 0.1}");
  ASSERT_NE(part, nullptr);
  EXPECT_EQ(link_stats(part->build_links(in), in.active).leaves,
            int64_t(std::floor(0.1 * double(in.active.sum().item<int64_t>()))));
}

TEST(LinkPlugins, AllStrategiesShareTheLinkForm) {
  const auto in = plugin_inputs(3);
  for (const char* type : {"link_none", "link_cohs", "link_distance", "link_random"}) {
    auto p = test::make_plugin<ContextModel>("links", std::string("{type: ") + type + "}");
    ASSERT_NE(p, nullptr) << type;
    auto l = p->build_links(in);
    EXPECT_EQ(l.scalar_type(), torch::kLong) << type;
    EXPECT_EQ(l.sizes(), (torch::IntArrayRef{2000})) << type;
    EXPECT_TRUE(check_links(l, in.active).ok()) << type;
    // link_none is the form with no links at all: every anchor free (-1).
    if (std::string(type) == "link_none") {
      EXPECT_TRUE((l == -1).all().item<bool>());
    }
  }
}

}  // namespace
}  // namespace crpgs
