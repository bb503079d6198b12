// The compute runtime's view of the BLAS.
#include <gtest/gtest.h>

#include <cstdlib>
#include <string>

#include "crpgs/runtime.h"

namespace crpgs {
namespace {

// The README installs libopenblas0-pthread: without it libtorch runs on the reference BLAS,
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

}  // namespace
}  // namespace crpgs
