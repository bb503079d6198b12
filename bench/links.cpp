// Benchmarks of the anchor-link strategies (crpgs/links.h): candidate retrieval and greedy
// matching for link_cohs (cosine top-10, τ = 1.0 .. 0.8) and link_distance (10 nearest, one
// pass) on N random anchors with 30-D features around 2000 cluster directions, uniform random
// positions and ~70% active; BM_DistanceCandidatesClustered puts 99.9% of the anchors in a cube
// 1e-4 of the scene's extent (a dense object with far background anchors). Arguments: {N, threads}.
// Counters: leaves, and the estimated peak working memory of the retrieval in MiB (similarity block
// + feature copies, or grid + lists). Results are recorded by hand in bench/results/links.md.
#include <benchmark/benchmark.h>

#include <ATen/Parallel.h>
#include <torch/torch.h>

#include <limits>
#include <map>

#include "crpgs/links.h"

namespace {

struct Inputs {
  torch::Tensor features, positions, active;
};

const Inputs& inputs(int64_t n) {
  static std::map<int64_t, Inputs> cache;
  auto it = cache.find(n);
  if (it != cache.end()) return it->second;
  torch::manual_seed(0);
  Inputs in;
  auto centers = torch::randn({2000, 30});
  in.features = centers.index_select(0, torch::randint(2000, {n}, torch::kLong)) +
                0.3 * torch::randn({n, 30});
  in.positions = torch::rand({n, 3});
  in.active = torch::rand({n}) < 0.7;
  return cache[n] = in;
}

template <typename T>
T ok(crpgs::StatusOr<T> s) {
  if (!s.ok()) throw crpgs::StatusError(s.status());
  return std::move(s).value();
}

constexpr int64_t kBudget = int64_t(256) << 20;

/// The last cosine lists per N, so the matching benchmark does not recompute them.
std::map<int64_t, crpgs::LinkCandidates>& cosine_cache() {
  static std::map<int64_t, crpgs::LinkCandidates> c;
  return c;
}

void BM_CohsCandidates(benchmark::State& state) {
  at::set_num_threads(int(state.range(1)));
  const auto& in = inputs(state.range(0));
  const double na = in.active.sum().item<double>();
  for (auto _ : state)
    cosine_cache()[state.range(0)] =
        ok(crpgs::cosine_candidates(in.features, in.active, 10, kBudget));
  // Block (<= budget) + float64 [N, D] input copy + integer and float32 copies of the active rows
  // + the duplicate search's hash map (~48 B per active row; no duplicates here, so no memo).
  const double block = std::min<double>(kBudget, 4.0 * na * na);
  state.counters["peak_MiB"] =
      (block + 8.0 * 30 * double(state.range(0)) + (12.0 * 30 + 48) * na) / (1 << 20);
}

/// 30% of the anchors share one feature vector (e.g. anchors grown from one parent and never
/// updated since): a block of exact ties that every row of the block must rescore.
void BM_CohsCandidatesDuplicates(benchmark::State& state) {
  at::set_num_threads(int(state.range(1)));
  const auto& in = inputs(state.range(0));
  torch::manual_seed(2);
  const auto same = (torch::rand({state.range(0)}) < 0.3).unsqueeze(1);
  const auto features = torch::where(same, in.features[0].unsqueeze(0), in.features);
  for (auto _ : state)
    benchmark::DoNotOptimize(ok(crpgs::cosine_candidates(features, in.active, 10, kBudget)));
}

void BM_CohsMatching(benchmark::State& state) {
  at::set_num_threads(int(state.range(1)));
  const auto& in = inputs(state.range(0));
  if (!cosine_cache().count(state.range(0)))
    cosine_cache()[state.range(0)] =
        ok(crpgs::cosine_candidates(in.features, in.active, 10, kBudget));
  const auto& c = cosine_cache()[state.range(0)];
  const auto taus = ok(crpgs::decaying_thresholds(1.0, 0.8, 0.05));
  torch::Tensor l;
  for (auto _ : state) l = ok(crpgs::greedy_links(c, taus, in.active));
  state.counters["leaves"] = double(crpgs::link_stats(l, in.active).leaves);
}

void BM_DistanceCandidates(benchmark::State& state) {
  at::set_num_threads(int(state.range(1)));
  const auto& in = inputs(state.range(0));
  for (auto _ : state)
    benchmark::DoNotOptimize(ok(crpgs::nearest_candidates(in.positions, in.active, 10)));
  // float64 positions, k-d tree (point order, <= N / 2 nodes of 80 B), [N, 10] index + distance
  // lists and the returned [N, 10] int64 + float32 candidates.
  const double n = double(state.range(0));
  state.counters["peak_MiB"] = (24 * n + 8 * n + 40 * n + 10 * (8 + 8 + 8 + 4) * n) / (1 << 20);
}

/// 99.9% of the points in [0, 0.01]^3, the rest in [0, 100]^3: a uniform grid sized by the bounding
/// box puts the whole cluster into one cell.
void BM_DistanceCandidatesClustered(benchmark::State& state) {
  at::set_num_threads(int(state.range(1)));
  const auto& in = inputs(state.range(0));
  torch::manual_seed(1);
  const int64_t n = state.range(0);
  const auto far = torch::rand({n}) < 0.001;
  const auto positions =
      torch::where(far.unsqueeze(1), torch::rand({n, 3}) * 100, torch::rand({n, 3}) * 0.01);
  for (auto _ : state)
    benchmark::DoNotOptimize(ok(crpgs::nearest_candidates(positions, in.active, 10)));
}

void BM_DistanceMatching(benchmark::State& state) {
  at::set_num_threads(int(state.range(1)));
  const auto& in = inputs(state.range(0));
  const auto c = ok(crpgs::nearest_candidates(in.positions, in.active, 10));
  torch::Tensor l;
  for (auto _ : state)
    l = ok(crpgs::greedy_links(c, {-std::numeric_limits<double>::infinity()}, in.active));
  state.counters["leaves"] = double(crpgs::link_stats(l, in.active).leaves);
}

}  // namespace

BENCHMARK(BM_CohsCandidates)
    ->Args({100000, 1})
    ->Args({100000, 2})
    ->Args({500000, 2})
    ->Unit(benchmark::kMillisecond)
    ->Iterations(1)
    ->UseRealTime();
BENCHMARK(BM_CohsCandidatesDuplicates)
    ->Args({50000, 1})
    ->Unit(benchmark::kMillisecond)
    ->Iterations(1)
    ->UseRealTime();
BENCHMARK(BM_CohsMatching)
    ->Args({100000, 1})
    ->Args({500000, 1})
    ->Unit(benchmark::kMillisecond)
    ->Iterations(3)
    ->UseRealTime();
BENCHMARK(BM_DistanceCandidates)
    ->Args({100000, 1})
    ->Args({100000, 2})
    ->Args({500000, 2})
    ->Unit(benchmark::kMillisecond)
    ->Iterations(3)
    ->UseRealTime();
BENCHMARK(BM_DistanceCandidatesClustered)
    ->Args({20000, 1})
    ->Args({100000, 1})
    ->Unit(benchmark::kMillisecond)
    ->Iterations(1)
    ->UseRealTime();
BENCHMARK(BM_DistanceMatching)
    ->Args({100000, 1})
    ->Args({500000, 1})
    ->Unit(benchmark::kMillisecond)
    ->Iterations(3)
    ->UseRealTime();

// main(): bench/main/bench_main.cpp
