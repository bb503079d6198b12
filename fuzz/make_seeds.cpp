/// @file make_seeds.cpp
/// @brief `fuzz_make_seeds <dir>`: writes the seed bitstreams (fuzz_seeds.h) into <dir>.
#include <cstdio>

#include "crpgs/atomic_file.h"
#include "crpgs/components.h"
#include "fuzz_seeds.h"

int main(int argc, char** argv) {
  if (argc != 2) {
    std::fprintf(stderr, "usage: %s <output dir>\n", argv[0]);
    return 2;
  }
  crpgs::ComponentRegistry registry = crpgs::builtin_registry();
  registry.load_plugins({CRPGS_PLUGIN_BUILD_DIR});
  auto seeds = crpgs::fuzz::make_seeds(registry);
  if (!seeds.ok()) {
    std::fprintf(stderr, "%s\n", seeds.status().to_string().c_str());
    return 1;
  }
  for (const auto& s : *seeds) {
    const std::string path = std::string(argv[1]) + "/" + s.name;
    const crpgs::Status st = crpgs::write_file_atomic(path, s.bytes);
    if (!st.ok()) {
      std::fprintf(stderr, "%s\n", st.to_string().c_str());
      return 1;
    }
    std::printf("%s: %zu bytes\n", path.c_str(), s.bytes.size());
  }
  return 0;
}
