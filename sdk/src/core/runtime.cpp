/// @file runtime.cpp
/// @brief Thread pools (libtorch and OpenBLAS together) and allocator settings.
#include "crpgs/runtime.h"

#include <dlfcn.h>
#include <elf.h>
#include <link.h>
#include <malloc.h>
#include <unistd.h>

#include <algorithm>
#include <cctype>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <map>
#include <string>
#include <thread>
#include <utility>

#include <ATen/Parallel.h>

#include "crpgs/hashing.h"

namespace crpgs {
namespace {

// OpenBLAS is found at run time: libtorch links the system BLAS, which may be another library.
struct OpenBlas {
  void (*set)(int) = nullptr;
  int (*get)() = nullptr;
  char* (*corename)() = nullptr;  // the kernels a DYNAMIC_ARCH build picked
  OpenBlas() {
    set = reinterpret_cast<void (*)(int)>(dlsym(RTLD_DEFAULT, "openblas_set_num_threads"));
    get = reinterpret_cast<int (*)()>(dlsym(RTLD_DEFAULT, "openblas_get_num_threads"));
    if (!set || !get) set = nullptr, get = nullptr;
    corename = reinterpret_cast<char* (*)()>(dlsym(RTLD_DEFAULT, "openblas_get_corename"));
  }
};

const OpenBlas& openblas() {
  static const OpenBlas blas;
  return blas;
}

void set_pools(int torch_threads, int blas_threads) {
  at::set_num_threads(torch_threads);
  if (openblas().set && blas_threads > 0) openblas().set(blas_threads);
}

}  // namespace

int resolve_threads(int requested) {
  return requested > 0 ? requested : std::max(1, int(std::thread::hardware_concurrency()));
}

void set_compute_threads(int requested) {
  const int n = resolve_threads(requested);
  set_pools(n, n);
}

ScopedComputeThreads::ScopedComputeThreads(int requested)
    : torch_threads_(at::get_num_threads()), blas_threads_(openblas().get ? openblas().get() : 0) {
  set_compute_threads(requested);
}

ScopedComputeThreads::~ScopedComputeThreads() {
  set_pools(torch_threads_, blas_threads_);
}

SingleThreadedBlas::SingleThreadedBlas() : blas_threads_(openblas().get ? openblas().get() : 0) {
  if (blas_threads_ > 1) openblas().set(1);
}

SingleThreadedBlas::~SingleThreadedBlas() {
  if (blas_threads_ > 1) openblas().set(blas_threads_);
}

std::string blas_kernels() {
  const std::string core = openblas_core();
  return core.empty() ? std::string("unknown") : "OpenBLAS " + core;
}

std::string blas_kernels_explained() {
  const char* forced = std::getenv("OPENBLAS_CORETYPE");
  if (!forced) return blas_kernels();
  const char* picked = std::getenv(kOpenBlasPickedVariable);
  return blas_kernels() + (picked ? std::string(" (OpenBLAS picked ") + picked +
                                        ", narrower than this CPU runs; crpgs set "
                                        "OPENBLAS_CORETYPE)"
                                  : std::string(" (forced by OPENBLAS_CORETYPE)"));
}

std::string openblas_core() {
  const char* core = openblas().corename ? openblas().corename() : nullptr;
  return core ? core : "";
}

int openblas_core_vector_level(const std::string& core) {
  // OpenBLAS's x86-64 DYNAMIC_ARCH targets (its corename strings, compared case-blind).
  static const std::map<std::string, int> kLevels = {
      {"katmai", 0},     {"coppermine", 0},  {"northwood", 0},   {"prescott", 0},
      {"banias", 0},     {"atom", 0},        {"core2", 0},       {"penryn", 0},
      {"dunnington", 0}, {"nehalem", 0},     {"opteron", 0},     {"opteron_sse3", 0},
      {"barcelona", 0},  {"bobcat", 0},      {"sandybridge", 1}, {"bulldozer", 1},
      {"piledriver", 1}, {"steamroller", 1}, {"excavator", 1},   {"haswell", 2},
      {"zen", 2},        {"skylakex", 3},    {"cooperlake", 3},  {"sapphirerapids", 3}};
  std::string key = core;
  std::transform(key.begin(), key.end(), key.begin(),
                 [](unsigned char c) { return static_cast<char>(std::tolower(c)); });
  const auto it = kLevels.find(key);
  return it == kLevels.end() ? -1 : it->second;
}

int cpu_vector_level() {
#if defined(__x86_64__) || defined(__i386__)
  __builtin_cpu_init();  // libgcc's checks include the OS's saving of the wide registers
  if (__builtin_cpu_supports("avx512f") && __builtin_cpu_supports("avx512cd") &&
      __builtin_cpu_supports("avx512bw") && __builtin_cpu_supports("avx512dq") &&
      __builtin_cpu_supports("avx512vl"))
    return 3;
  if (__builtin_cpu_supports("avx2") && __builtin_cpu_supports("fma")) return 2;
  if (__builtin_cpu_supports("avx")) return 1;
#endif
  return 0;
}

std::string wider_openblas_core(const std::string& picked, int cpu_level) {
  const int level = openblas_core_vector_level(picked);
  if (level < 0 || level >= cpu_level) return "";
  static const char* const kByLevel[] = {"", "Sandybridge", "Haswell", "SkylakeX"};
  return cpu_level >= 1 && cpu_level <= 3 ? kByLevel[cpu_level] : "";
}

namespace {
// Idle threads that sleep: libgomp's and OpenBLAS's settings, read when they load.
constexpr std::pair<const char*, const char*> kIdleThreadsThatSleep[] = {
    {"OMP_WAIT_POLICY", "PASSIVE"}, {"OPENBLAS_THREAD_TIMEOUT", "4"}};
}  // namespace

std::string idle_thread_settings() {
  std::string out;
  for (const auto& setting : kIdleThreadsThatSleep) {
    const char* name = setting.first;
    const char* value = std::getenv(name);
    out += (out.empty() ? "" : ", ") + std::string(name) + "=" + (value ? value : "(unset)");
  }
  return out;
}

void restart_with_compute_environment(char** argv) {
  // Under valgrind the restarted process would run natively (--trace-children=no), outside the
  // measurement; valgrind's own CPU has no AVX-512 for wider kernels anyway.
  if (const char* preload = std::getenv("LD_PRELOAD"); preload && std::strstr(preload, "vgpreload"))
    return;
  bool changed = false;
  for (const auto& [name, value] : kIdleThreadsThatSleep)
    if (!std::getenv(name)) changed = setenv(name, value, 0) == 0 || changed;
  if (!std::getenv("OPENBLAS_CORETYPE")) {
    const std::string picked = openblas_core();
    const std::string wider = wider_openblas_core(picked, cpu_vector_level());
    if (!wider.empty() && setenv("OPENBLAS_CORETYPE", wider.c_str(), 1) == 0) {
      setenv(kOpenBlasPickedVariable, picked.c_str(), 1);  // for blas_kernels_explained()
      changed = true;
    }
  }
  if (changed) execv("/proc/self/exe", argv);  // if it fails, run on as we are
}

void keep_freed_memory_in_heap() {
  // Blocks of any size come from the heap, and a free never trims it.
  mallopt(M_MMAP_THRESHOLD, 1 << 30);
  mallopt(M_TRIM_THRESHOLD, -1);
}

namespace {

/// The NT_GNU_BUILD_ID bytes in one loaded object's PT_NOTE segments ("" if none).
std::string gnu_build_id(const dl_phdr_info* info) {
  for (int i = 0; i < info->dlpi_phnum; ++i) {
    const ElfW(Phdr)& ph = info->dlpi_phdr[i];
    if (ph.p_type != PT_NOTE) continue;
    const auto* p = reinterpret_cast<const char*>(info->dlpi_addr + ph.p_vaddr);
    const char* end = p + ph.p_memsz;
    auto align4 = [](size_t n) { return (n + 3) & ~size_t(3); };
    while (p + sizeof(ElfW(Nhdr)) <= end) {
      ElfW(Nhdr) note;
      std::memcpy(&note, p, sizeof note);
      const char* name = p + sizeof note;
      const char* desc = name + align4(note.n_namesz);
      if (desc + note.n_descsz > end) break;
      if (note.n_type == NT_GNU_BUILD_ID && note.n_namesz == 4 && std::memcmp(name, "GNU", 4) == 0)
        return std::string(desc, note.n_descsz);
      p = desc + align4(note.n_descsz);
    }
  }
  return "";
}

}  // namespace

std::string code_build_id() {
  std::map<std::string, std::string> ids;  // by file name, so the load order does not matter
  dl_iterate_phdr(
      [](dl_phdr_info* info, size_t, void* out) {
        const std::string path = info->dlpi_name ? info->dlpi_name : "";
        const std::string file = path.substr(path.find_last_of('/') + 1);
        if (file.rfind("libcrpgs", 0) == 0)
          (*static_cast<std::map<std::string, std::string>*>(out))[file] = gnu_build_id(info);
        return 0;
      },
      &ids);
  uint64_t h = kFnv1a64Offset;
  bool any = false;
  for (const auto& [file, id] : ids) {
    any = any || !id.empty();
    h = fnv1a64(file + '\0' + id + '\0', h);
  }
  return any ? hex64(h) : "";
}

}  // namespace crpgs
