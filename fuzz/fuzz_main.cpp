/// @file fuzz_main.cpp
/// @brief libFuzzer entry points: fuzz_decode (CRPGS_FUZZ_RESEAL 0) and fuzz_decode_sealed (1).
#include <cstdio>
#include <cstdlib>

#include "crpgs/components.h"
#include "fuzz_harness.h"

namespace {

const crpgs::ComponentRegistry* g_registry = nullptr;

}  // namespace

extern "C" int LLVMFuzzerInitialize(int*, char***) {
  static crpgs::ComponentRegistry registry = [] {
    crpgs::ComponentRegistry r = crpgs::builtin_registry();
    r.load_plugins({CRPGS_PLUGIN_BUILD_DIR});
    return r;
  }();
  if (!registry.find(CRPGS_KIND_CONTEXT, "hash_grid") ||
      !registry.find(CRPGS_KIND_ENTROPY, "gaussian")) {
    std::fprintf(stderr, "fuzz: the hash_grid/gaussian plugins are not built in %s\n",
                 CRPGS_PLUGIN_BUILD_DIR);
    std::exit(1);
  }
  g_registry = &registry;
  return 0;
}

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  const crpgs::fuzz::Outcome o =
      crpgs::fuzz::run_one(data, size, CRPGS_FUZZ_RESEAL != 0, *g_registry);
  // A refusal must say why.
  if (!o.decoded && o.message.empty()) std::abort();
  return 0;
}
