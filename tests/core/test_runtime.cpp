// The compute runtime's view of the BLAS.
#include <dlfcn.h>
#include <gtest/gtest.h>

#include <cstdlib>
#include <string>

#include "crpgs/runtime.h"

namespace crpgs {
namespace {

// scripts/setup installs libopenblas0-pthread: without it libtorch runs on the reference BLAS,
// ~30x slower. The kernels named are those OpenBLAS runs (OPENBLAS_CORETYPE's, when set).
TEST(Runtime, BlasIsOpenBlasAndNamesItsKernels) {
  const std::string kernels = blas_kernels();
  ASSERT_EQ(kernels.rfind("OpenBLAS ", 0), 0u) << kernels;
  EXPECT_GT(kernels.size(), std::string("OpenBLAS ").size());
  if (const char* forced = std::getenv("OPENBLAS_CORETYPE")) {
    std::string want = forced;
    if (want == "Haswell" || want == "SkylakeX" || want == "Cooperlake" || want == "Zen") {
      EXPECT_EQ(kernels, "OpenBLAS " + want);
    }
  }
}

// OpenBLAS falls back to SSE3 "Prescott" kernels on CPUs newer than itself; `crpgs` restarts
// with the widest kernels the CPU runs, and only when OpenBLAS picked narrower ones.
TEST(Runtime, AWiderOpenBlasCoreOnlyWhenOpenBlasPickedNarrowerKernelsThanTheCpuRuns) {
  EXPECT_EQ(wider_openblas_core("Prescott", 3), "SkylakeX");
  EXPECT_EQ(wider_openblas_core("Prescott", 2), "Haswell");
  EXPECT_EQ(wider_openblas_core("Nehalem", 1), "Sandybridge");
  EXPECT_EQ(wider_openblas_core("Sandybridge", 2), "Haswell");
  EXPECT_EQ(wider_openblas_core("Zen", 3), "SkylakeX");  // AVX-512 Zen on an older OpenBLAS
  EXPECT_EQ(wider_openblas_core("HASWELL", 3), "SkylakeX");
  EXPECT_EQ(wider_openblas_core("Prescott", 0), "");
  EXPECT_EQ(wider_openblas_core("Haswell", 2), "");
  EXPECT_EQ(wider_openblas_core("Cooperlake", 3), "");
  EXPECT_EQ(wider_openblas_core("SapphireRapids", 3), "");
  EXPECT_EQ(wider_openblas_core("SkylakeX", 2), "");    // never narrower than OpenBLAS's pick
  EXPECT_EQ(wider_openblas_core("NeoverseN1", 3), "");  // names not known here are left alone
  EXPECT_EQ(wider_openblas_core("", 3), "");
}

// OpenBLAS does not pick kernels the CPU cannot run.
TEST(Runtime, TheCpusVectorLevelCoversTheKernelsOpenBlasPicked) {
  const int cpu = cpu_vector_level();
  EXPECT_GE(cpu, 0);
  EXPECT_LE(cpu, 3);
  if (std::getenv("OPENBLAS_CORETYPE")) GTEST_SKIP() << "OPENBLAS_CORETYPE chose the kernels";
  const int running = openblas_core_vector_level(openblas_core());
  if (running < 0) GTEST_SKIP() << "kernels not known here: " << blas_kernels();
  EXPECT_LE(running, cpu) << blas_kernels();
}

// Checkpoints record which build wrote them: the id comes from the crpgs objects loaded, so
// loading one more (a plugin) changes it, and it is the same every time it is asked.
TEST(Runtime, CodeBuildIdFollowsTheLoadedCrpgsObjects) {
  const std::string before = code_build_id();
  ASSERT_EQ(before.size(), 16u) << before;  // libcrpgs.so, libcrpgs_base.so are linked
  EXPECT_EQ(before.find_first_not_of("0123456789abcdef"), std::string::npos) << before;
  EXPECT_EQ(code_build_id(), before);
  // A crpgs object this process has not loaded yet (the registry loads the real plugins).
  const std::string other = std::string(CRPGS_TEST_PLUGIN_DIR) + "/libcrpgs_test_not_a_plugin.so";
  if (dlopen(other.c_str(), RTLD_NOW | RTLD_NOLOAD))
    GTEST_SKIP() << other << " is loaded already (an earlier test of this process)";
  void* handle = dlopen(other.c_str(), RTLD_NOW | RTLD_LOCAL);
  if (!handle) GTEST_SKIP() << "cannot load " << other << ": " << dlerror();
  EXPECT_NE(code_build_id(), before);
  // Left loaded: libraries are never unloaded here (toolchain.md, trap 4).
}

}  // namespace
}  // namespace crpgs
