/// @file shuffle.h
/// @brief A seeded permutation that is the same with every standard library (std::shuffle's
/// draws are implementation-defined): the order in which training visits its views.
#pragma once

#include <cstdint>
#include <numeric>
#include <random>
#include <utility>
#include <vector>

namespace crpgs {

/// 0..n-1 in the order Fisher-Yates gives with mt19937_64(seed) and our own index draw.
inline std::vector<int> seeded_permutation(int n, uint64_t seed) {
  std::vector<int> perm(static_cast<size_t>(n > 0 ? n : 0));
  std::iota(perm.begin(), perm.end(), 0);
  std::mt19937_64 rng(seed);
  for (int i = n - 1; i > 0; --i) {
    const int j = int(rng() % uint64_t(i + 1));
    std::swap(perm[size_t(i)], perm[size_t(j)]);
  }
  return perm;
}

}  // namespace crpgs
