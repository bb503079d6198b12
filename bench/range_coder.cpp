/// @file range_coder.cpp
/// @brief Throughput of the rANS table coder on one core: 1M symbols drawn from discretised
/// Gaussians (64 tables, scales log-spaced 0.5 .. 20), as HAC's feature streams look.
/// Results: bench/results/range_coder.md.
#include <benchmark/benchmark.h>

#include <cmath>
#include <random>

#include "crpgs/coding/range_coder.h"

namespace {

using namespace crpgs::coding;

constexpr size_t kSymbols = 1 << 20;
constexpr int kTables = 64;

struct Workload {
  CdfTableSet tables;
  std::vector<uint32_t> indexes;
  std::vector<int32_t> symbols;
  std::vector<uint8_t> bits;  // p(1) = 0.1, for the Bernoulli coder
};

const Workload& workload() {
  static const Workload w = [] {
    Workload out;
    std::vector<double> scales(kTables);
    std::vector<CdfTable> tables;
    for (int t = 0; t < kTables; ++t) {
      scales[t] = 0.5 * std::pow(20.0 / 0.5, double(t) / (kTables - 1));
      // Symmetric table over [-c, c] with tail mass ~1e-9 (CompressAI's pmf_center).
      const int c = int(std::ceil(6.1 * scales[t]));
      std::vector<double> pmf;
      const double k = 1.0 / (scales[t] * std::sqrt(2.0));
      for (int v = -c; v <= c; ++v)
        pmf.push_back(0.5 * (std::erfc(-(v + 0.5) * k) - std::erfc(-(v - 0.5) * k)));
      tables.push_back(make_cdf_table(pmf, -c).value());
    }
    out.tables = CdfTableSet::create(std::move(tables)).value();
    std::mt19937 rng(42);
    std::normal_distribution<double> normal(0.0, 1.0);
    std::bernoulli_distribution coin(0.1);
    out.indexes.resize(kSymbols);
    out.symbols.resize(kSymbols);
    out.bits.resize(kSymbols);
    for (size_t i = 0; i < kSymbols; ++i) {
      out.indexes[i] = uint32_t(rng() % kTables);
      out.symbols[i] = int32_t(std::lround(normal(rng) * scales[out.indexes[i]]));
      out.bits[i] = coin(rng);
    }
    return out;
  }();
  return w;
}

void BM_Encode(benchmark::State& state) {
  const Workload& w = workload();
  size_t bytes = 0;
  for (auto _ : state) {
    auto enc = encode_symbols(w.symbols, w.indexes, w.tables);
    bytes = enc->size();
    benchmark::DoNotOptimize(enc->data());
  }
  state.SetItemsProcessed(int64_t(state.iterations()) * int64_t(kSymbols));
  state.counters["bits_per_symbol"] = 8.0 * double(bytes) / double(kSymbols);
}

void BM_Decode(benchmark::State& state) {
  const Workload& w = workload();
  const Bytes enc = encode_symbols(w.symbols, w.indexes, w.tables).value();
  std::vector<int32_t> out(kSymbols);
  for (auto _ : state) {
    const crpgs::Status st = decode_symbols(enc, w.indexes.data(), kSymbols, w.tables, out.data());
    if (!st.ok()) state.SkipWithError(st.message().c_str());
    benchmark::DoNotOptimize(out.data());
  }
  if (out != w.symbols) state.SkipWithError("decoded symbols differ");
  state.SetItemsProcessed(int64_t(state.iterations()) * int64_t(kSymbols));
}

// Chunks of 10000 symbols (HAC's sub-streams), one thread.
void BM_ChunkedEncode(benchmark::State& state) {
  const Workload& w = workload();
  const ChunkedEncoder encoder(kDefaultChunkSize, 1);
  size_t bytes = 0;
  for (auto _ : state) {
    auto enc = encoder.encode(w.symbols, w.indexes, w.tables);
    bytes = enc->size();
    benchmark::DoNotOptimize(enc->data());
  }
  state.SetItemsProcessed(int64_t(state.iterations()) * int64_t(kSymbols));
  state.counters["bits_per_symbol"] = 8.0 * double(bytes) / double(kSymbols);
}

void BM_ChunkedDecode(benchmark::State& state) {
  const Workload& w = workload();
  const Bytes enc =
      ChunkedEncoder(kDefaultChunkSize, 1).encode(w.symbols, w.indexes, w.tables).value();
  for (auto _ : state) {
    auto dec = ChunkedDecoder::decode(enc, w.indexes, w.tables, int(state.range(0)));
    if (!dec.ok()) state.SkipWithError(dec.status().message().c_str());
    benchmark::DoNotOptimize(dec->data());
  }
  state.SetItemsProcessed(int64_t(state.iterations()) * int64_t(kSymbols));
}

void BM_BernoulliDecode(benchmark::State& state) {
  const Workload& w = workload();
  const Bytes enc = encode_bernoulli(w.bits).value();
  for (auto _ : state) {
    auto dec = decode_bernoulli(enc, w.bits.size());
    if (!dec.ok()) state.SkipWithError(dec.status().message().c_str());
    benchmark::DoNotOptimize(dec->data());
  }
  state.SetItemsProcessed(int64_t(state.iterations()) * int64_t(kSymbols));
  state.counters["bits_per_symbol"] = 8.0 * double(enc.size()) / double(kSymbols);
}

BENCHMARK(BM_Encode)->Unit(benchmark::kMillisecond);
BENCHMARK(BM_Decode)->Unit(benchmark::kMillisecond);
BENCHMARK(BM_ChunkedEncode)->Unit(benchmark::kMillisecond);
// One thread: CPU time, robust to other load on the machine. Two threads: wall time (the
// thread pool's CPU time is not the main thread's), so it needs an idle machine.
BENCHMARK(BM_ChunkedDecode)->Arg(1)->Unit(benchmark::kMillisecond);
BENCHMARK(BM_ChunkedDecode)->Arg(2)->Unit(benchmark::kMillisecond)->UseRealTime();
BENCHMARK(BM_BernoulliDecode)->Unit(benchmark::kMillisecond);

}  // namespace

// main(): bench/main/bench_main.cpp
