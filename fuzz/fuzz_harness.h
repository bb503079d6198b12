/// @file fuzz_harness.h
/// @brief What the decoder fuzz targets do with one input, shared by the libFuzzer entry points
/// (fuzz_main.cpp) and the GoogleTest replay of the committed corpus and crashes
/// (tests/fuzz/test_fuzz_corpus.cpp), so a regression test runs exactly what the fuzzer ran.
#pragma once

#include <cstddef>
#include <cstdint>
#include <string>
#include <vector>

#include "crpgs/registry.h"

namespace crpgs::fuzz {

/// The input with every checksum recomputed where its layout can be followed: the container
/// header CRC, each section's CRC, and the CRC in front of a Draco GEOM payload. Anything the
/// walk cannot follow (bad magic, a section running past the end) is left as it is. Mutations of
/// a sealed input reach the section payload parsers instead of stopping at a CRC mismatch.
std::vector<uint8_t> reseal(const uint8_t* data, size_t size);

struct Outcome {
  bool decoded = false;  ///< decode_model and model_from_decoded both succeeded
  std::string message;   ///< why it was refused (empty when decoded)
};

/// decode_model on the bytes (re-sealed first when `sealed`); when it succeeds, the render-ready
/// model is built from it as `crpgs render` does (model_from_decoded). Never throws: anything
/// thrown is a finding and escapes to the fuzzer as a crash.
Outcome run_one(const uint8_t* data, size_t size, bool sealed, const ComponentRegistry& registry);

}  // namespace crpgs::fuzz
