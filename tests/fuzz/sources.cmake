# Hostile bitstreams (issue #9). test_hostile_coding: absurd counts at the coding layer (base).
# test_fuzz_corpus: the fuzzers' committed corpus and crashes replayed through their own harness
# (fuzz/fuzz_harness.cpp), the seed generator (fuzz/fuzz_seeds.cpp), and hostile sections behind
# valid CRCs. Paths relative to tests/.
list(APPEND CRPGS_BASE_TEST_SOURCES fuzz/test_hostile_coding.cpp)
list(APPEND CRPGS_TORCH_TEST_SOURCES fuzz/test_fuzz_corpus.cpp ../fuzz/fuzz_harness.cpp
  ../fuzz/fuzz_seeds.cpp)
