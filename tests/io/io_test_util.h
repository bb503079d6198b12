/// @file io_test_util.h
/// @brief Helpers shared by the io tests: per-test temp dirs, synthetic images.
#pragma once

#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>
#include <random>
#include <string>

#include "crpgs/image.h"

namespace crpgs::test {

/// A fresh, empty directory for the running test.
inline std::filesystem::path fresh_dir(const std::string& tag = "") {
  const auto* info = ::testing::UnitTest::GetInstance()->current_test_info();
  std::filesystem::path d = std::filesystem::path(CRPGS_TEST_TMP_DIR) / "io" /
                            (std::string(info->test_suite_name()) + "." + info->name() + tag);
  std::filesystem::remove_all(d);
  std::filesystem::create_directories(d);
  return d;
}

/// Deterministic pseudo-random image in [0, 1].
inline Image random_image(int w, int h, int c, unsigned seed) {
  Image im = Image::zeros(w, h, c);
  std::mt19937 rng(seed);
  std::uniform_real_distribution<float> u(0.f, 1.f);
  for (float& v : im.pixels) v = u(rng);
  return im;
}

inline void write_bytes(const std::filesystem::path& p, const std::string& bytes) {
  std::filesystem::create_directories(p.parent_path());
  std::ofstream(p, std::ios::binary) << bytes;
}

inline std::string read_bytes(const std::filesystem::path& p) {
  std::ifstream in(p, std::ios::binary);
  return std::string(std::istreambuf_iterator<char>(in), {});
}

inline std::string shared_data(const std::string& name) {
  return (std::filesystem::path(CRPGS_SHARED_DATA_DIR) / name).string();
}

}  // namespace crpgs::test
