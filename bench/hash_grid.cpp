// Benchmarks of the binary hash grid (HAC layout, 96 outputs) on 100k uniformly random points:
// CPU kernel forward and backward at 1 and 2 threads, the points in random or Morton order, the
// ATen reference forward for the speed-up, and the table's rate term B_h (forward + backward, paid
// once per grid and training iteration in the rate phase). Results are recorded by hand in
// bench/results/hash_grid.md.
#include <benchmark/benchmark.h>

#include <ATen/Parallel.h>
#include <torch/torch.h>

#include <algorithm>
#include <cstdlib>
#include <fstream>
#include <utility>
#include <vector>

#include "crpgs/runtime.h"
#include "hash_grid/binary_grid.h"
#include "hash_grid/hash_grid_kernels.h"

namespace {

using crpgs::hash_grid::GridSpec;

struct Inputs {
  GridSpec spec;
  torch::Tensor pos, table, grad_out;
  torch::Tensor pos_morton;  // the same points in Morton order of a 1024^3 grid
};

// Rows of p [N, 3] in [0, 1) sorted by their Morton code on a 1024^3 grid.
torch::Tensor morton_sorted(const torch::Tensor& p) {
  auto spread = [](uint64_t v) {  // 10 bits -> every third of 30
    uint64_t x = v & 0x3ff;
    x = (x | (x << 16)) & 0x30000ff;
    x = (x | (x << 8)) & 0x300f00f;
    x = (x | (x << 4)) & 0x30c30c3;
    return (x | (x << 2)) & 0x9249249;
  };
  const auto a = p.contiguous();
  const float* d = a.data_ptr<float>();
  std::vector<std::pair<uint64_t, int64_t>> keys(size_t(a.size(0)));
  for (int64_t i = 0; i < a.size(0); ++i) {
    uint64_t k = 0;
    for (int c = 0; c < 3; ++c) k |= spread(uint64_t(d[i * 3 + c] * 1024)) << c;
    keys[size_t(i)] = {k, i};
  }
  std::sort(keys.begin(), keys.end());
  std::vector<int64_t> order;
  for (const auto& k : keys) order.push_back(k.second);
  return a.index_select(0, torch::tensor(order));
}

const Inputs& inputs() {
  static const Inputs in = [] {
    crpgs::keep_freed_memory_in_heap();  // as training does: no page faults on each new output
    Inputs i;
    i.spec = crpgs::hash_grid::make_grid_spec(
        {18, 24, 33, 44, 59, 80, 108, 148, 201, 275, 376, 514}, 13, {130, 258, 514, 1026}, 15, 4);
    torch::manual_seed(0);
    i.pos = torch::rand({100000, 3});
    // CRPGS_BENCH_POINTS=FILE: a model's anchors instead (float32 x, y, z rows in [0, 1), in the
    // model's order), e.g. dumped from a checkpoint's model__anchor normalised by its bounds.
    if (const char* file = std::getenv("CRPGS_BENCH_POINTS")) {
      std::ifstream f(file, std::ios::binary | std::ios::ate);
      const int64_t n = int64_t(f.tellg()) / int64_t(3 * sizeof(float));
      i.pos = torch::empty({n, 3});
      f.seekg(0);
      f.read(reinterpret_cast<char*>(i.pos.data_ptr<float>()), std::streamsize(n * 3 * 4));
    }
    i.table = torch::empty({i.spec.n_entries, 4}).uniform_(-1e-4, 1e-4);
    i.grad_out = torch::randn({i.pos.size(0), i.spec.output_dim()});
    i.pos_morton = morton_sorted(i.pos);
    return i;
  }();
  return in;
}

void BM_Forward(benchmark::State& state) {
  at::set_num_threads(int(state.range(0)));
  const auto& in = inputs();
  const auto& pos = state.range(1) ? in.pos_morton : in.pos;
  for (auto _ : state)
    benchmark::DoNotOptimize(crpgs::hash_grid::grid_forward(in.spec, pos, in.table, true));
  state.SetItemsProcessed(state.iterations() * in.pos.size(0));
}

void BM_Backward(benchmark::State& state) {
  at::set_num_threads(int(state.range(0)));
  const auto& in = inputs();
  const auto& pos = state.range(1) ? in.pos_morton : in.pos;
  for (auto _ : state)
    benchmark::DoNotOptimize(
        crpgs::hash_grid::grid_backward(in.spec, pos, in.table, in.grad_out, true));
  state.SetItemsProcessed(state.iterations() * in.pos.size(0));
}

void BM_ReferenceForward(benchmark::State& state) {
  at::set_num_threads(int(state.range(0)));
  const auto& in = inputs();
  torch::NoGradGuard g;
  for (auto _ : state)
    benchmark::DoNotOptimize(
        crpgs::hash_grid::grid_forward_reference(in.spec, in.pos, in.table, true));
  state.SetItemsProcessed(state.iterations() * in.pos.size(0));
}

void BM_TableBits(benchmark::State& state) {
  at::set_num_threads(int(state.range(0)));
  const auto& in = inputs();
  auto table = in.table.clone().requires_grad_(true);
  for (auto _ : state) {
    table.mutable_grad() = torch::Tensor();
    crpgs::hash_grid::table_bits(table, true).backward();
    benchmark::DoNotOptimize(table.grad().data_ptr<float>());
  }
  state.SetItemsProcessed(state.iterations() * table.numel());
}

// Second argument: the points in random order (0) or Morton order (1), as a model keeps them.
BENCHMARK(BM_Forward)->ArgsProduct({{1, 2}, {0, 1}})->Unit(benchmark::kMillisecond)->UseRealTime();
BENCHMARK(BM_Backward)->ArgsProduct({{1, 2}, {0, 1}})->Unit(benchmark::kMillisecond)->UseRealTime();
BENCHMARK(BM_ReferenceForward)->Arg(1)->Arg(2)->Unit(benchmark::kMillisecond)->UseRealTime();
BENCHMARK(BM_TableBits)->Arg(1)->Arg(2)->Unit(benchmark::kMillisecond)->UseRealTime();

}  // namespace

// main(): bench/main/bench_main.cpp
