// Benchmarks of the binary hash grid (HAC layout, 96 outputs) on 100k uniformly random points:
// CPU kernel forward and backward at 1 and 2 threads, the ATen reference forward for the
// speed-up, and the table's rate term B_h (forward + backward, paid once per grid and training
// iteration in the rate phase). Results are recorded by hand in bench/results/hash_grid.md.
#include <benchmark/benchmark.h>

#include <ATen/Parallel.h>
#include <torch/torch.h>

// The kernels live in the plugin, which the bench does not link: compile them in here.
#include "../plugins/context/hash_grid/binary_grid.cpp"
#include "../plugins/context/hash_grid/hash_grid_kernels.cpp"
#include "crpgs/runtime.h"

namespace {

using crpgs::hash_grid::GridSpec;

struct Inputs {
  GridSpec spec;
  torch::Tensor pos, table, grad_out;
};

const Inputs& inputs() {
  static const Inputs in = [] {
    crpgs::keep_freed_memory_in_heap();  // as training does: no page faults on each new output
    Inputs i;
    i.spec = crpgs::hash_grid::make_grid_spec(
        {18, 24, 33, 44, 59, 80, 108, 148, 201, 275, 376, 514}, 13, {130, 258, 514, 1026}, 15, 4);
    torch::manual_seed(0);
    i.pos = torch::rand({100000, 3});
    i.table = torch::empty({i.spec.n_entries, 4}).uniform_(-1e-4, 1e-4);
    i.grad_out = torch::randn({100000, i.spec.output_dim()});
    return i;
  }();
  return in;
}

void BM_Forward(benchmark::State& state) {
  at::set_num_threads(int(state.range(0)));
  const auto& in = inputs();
  for (auto _ : state)
    benchmark::DoNotOptimize(crpgs::hash_grid::grid_forward(in.spec, in.pos, in.table, true));
  state.SetItemsProcessed(state.iterations() * in.pos.size(0));
}

void BM_Backward(benchmark::State& state) {
  at::set_num_threads(int(state.range(0)));
  const auto& in = inputs();
  for (auto _ : state)
    benchmark::DoNotOptimize(
        crpgs::hash_grid::grid_backward(in.spec, in.pos, in.table, in.grad_out, true));
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

BENCHMARK(BM_Forward)->Arg(1)->Arg(2)->Unit(benchmark::kMillisecond)->UseRealTime();
BENCHMARK(BM_Backward)->Arg(1)->Arg(2)->Unit(benchmark::kMillisecond)->UseRealTime();
BENCHMARK(BM_ReferenceForward)->Arg(1)->Arg(2)->Unit(benchmark::kMillisecond)->UseRealTime();
BENCHMARK(BM_TableBits)->Arg(1)->Arg(2)->Unit(benchmark::kMillisecond)->UseRealTime();

}  // namespace

// main(): bench/main/bench_main.cpp
