/// @file test_image.cpp
/// @brief Image I/O and resampling (image.h).
#include <gtest/gtest.h>

#include <cmath>
#include <filesystem>

#include "crpgs/image.h"
#include "io_test_util.h"

namespace crpgs {
namespace {

namespace fs = std::filesystem;

TEST(Image, PngRoundTripIsExactFor8BitValuesAndLeavesNoTempFiles) {
  const fs::path dir = test::fresh_dir();
  for (int c = 1; c <= 4; ++c) {
    Image im = Image::zeros(5, 3, c);
    for (size_t i = 0; i < im.pixels.size(); ++i) im.pixels[i] = float((i * 37) % 256) / 255.f;
    const std::string path = (dir / ("x" + std::to_string(c) + ".png")).string();
    ASSERT_TRUE(save_png(im, path).ok());
    auto back = load_image(path);
    ASSERT_TRUE(back.ok()) << back.status().message();
    EXPECT_EQ(back->width, 5);
    EXPECT_EQ(back->height, 3);
    EXPECT_EQ(back->channels, c);
    ASSERT_EQ(back->pixels.size(), im.pixels.size());
    for (size_t i = 0; i < im.pixels.size(); ++i) EXPECT_FLOAT_EQ(back->pixels[i], im.pixels[i]);
    auto info = read_image_info(path);
    ASSERT_TRUE(info.ok());
    EXPECT_EQ(info->width, 5);
    EXPECT_EQ(info->channels, c);
  }
  int files = 0;
  for (const auto& e : fs::directory_iterator(dir)) {
    ++files;
    EXPECT_EQ(e.path().extension(), ".png") << e.path();
  }
  EXPECT_EQ(files, 4);
}

TEST(Image, SavePngClampsAndRounds) {
  const fs::path dir = test::fresh_dir();
  Image im = Image::zeros(4, 1, 1);
  im.pixels = {-0.5f, 0.5f, 1.5f, 0.75f};
  ASSERT_TRUE(save_png(im, (dir / "c.png").string()).ok());
  auto back = load_image((dir / "c.png").string());
  ASSERT_TRUE(back.ok());
  EXPECT_FLOAT_EQ(back->pixels[0], 0.f);
  EXPECT_FLOAT_EQ(back->pixels[1], 128.f / 255.f);  // 127.5 rounds up
  EXPECT_FLOAT_EQ(back->pixels[2], 1.f);
  EXPECT_FLOAT_EQ(back->pixels[3], 191.f / 255.f);  // 191.25 -> 191
}

TEST(Image, SavePngRejectsBadImages) {
  const fs::path dir = test::fresh_dir();
  Image bad = Image::zeros(2, 2, 5);
  EXPECT_EQ(save_png(bad, (dir / "b.png").string()).code(), StatusCode::kInvalidArgument);
  Image empty;
  EXPECT_FALSE(save_png(empty, (dir / "e.png").string()).ok());
  EXPECT_FALSE(fs::exists(dir / "b.png"));
}

TEST(Image, LoadErrorsNameThePath) {
  const fs::path dir = test::fresh_dir();
  auto missing = load_image((dir / "nope.png").string());
  ASSERT_FALSE(missing.ok());
  EXPECT_EQ(missing.status().code(), StatusCode::kNotFound);
  EXPECT_NE(missing.status().message().find("nope.png"), std::string::npos);

  test::write_bytes(dir / "corrupt.png", "\x89PNG\r\n\x1a\n this is not a png body");
  auto corrupt = load_image((dir / "corrupt.png").string());
  ASSERT_FALSE(corrupt.ok());
  EXPECT_EQ(corrupt.status().code(), StatusCode::kIoError);
  EXPECT_NE(corrupt.status().message().find("corrupt.png"), std::string::npos);

  // A valid PNG cut in half must fail too, not return garbage.
  Image im = test::random_image(32, 32, 3, 1);
  ASSERT_TRUE(save_png(im, (dir / "full.png").string()).ok());
  const std::string bytes = test::read_bytes(dir / "full.png");
  test::write_bytes(dir / "half.png", bytes.substr(0, bytes.size() / 2));
  EXPECT_FALSE(load_image((dir / "half.png").string()).ok());

  // A few bytes declaring 20000 x 20000 grey pixels (IHDR width and height, big-endian at 16
  // and 20; stb itself refuses only above 2^30 bytes): refused before decoding, not 1.6 GB of
  // floats (in a loader thread, bad_alloc would end the process).
  ASSERT_TRUE(save_png(test::random_image(32, 32, 1, 2), (dir / "grey.png").string()).ok());
  std::string bomb = test::read_bytes(dir / "grey.png");
  for (int at : {16, 20}) bomb.replace(size_t(at), 4, std::string("\x00\x00\x4e\x20", 4));
  test::write_bytes(dir / "bomb.png", bomb);
  auto b = load_image((dir / "bomb.png").string());
  ASSERT_FALSE(b.ok());
  EXPECT_NE(b.status().message().find("declares 20000x20000 pixels"), std::string::npos)
      << b.status().message();
}

TEST(Image, DownscaleAveragesBlocks) {
  Image im = Image::zeros(4, 2, 1);
  im.pixels = {0, 1, 2, 3,  //
               4, 5, 6, 7};
  const Image d = downscale(im, 2);
  ASSERT_EQ(d.width, 2);
  ASSERT_EQ(d.height, 1);
  EXPECT_FLOAT_EQ(d.pixels[0], (0 + 1 + 4 + 5) / 4.f);
  EXPECT_FLOAT_EQ(d.pixels[1], (2 + 3 + 6 + 7) / 4.f);
  // A remainder smaller than the factor is dropped.
  const Image r = downscale(test::random_image(5, 7, 3, 2), 2);
  EXPECT_EQ(r.width, 2);
  EXPECT_EQ(r.height, 3);
  EXPECT_EQ(r.channels, 3);
  // Factor 1 is the identity.
  EXPECT_EQ(downscale(im, 1).pixels, im.pixels);
}

TEST(Image, ResizeAreaMatchesBoxFilterAndHandComputedWeights) {
  const Image im = test::random_image(12, 8, 3, 3);
  const Image a = resize_area(im, 3, 2), b = downscale(im, 4);
  ASSERT_EQ(a.pixels.size(), b.pixels.size());
  for (size_t i = 0; i < a.pixels.size(); ++i) EXPECT_NEAR(a.pixels[i], b.pixels[i], 1e-6);

  Image row = Image::zeros(3, 1, 1);
  row.pixels = {0, 1, 2};
  const Image r = resize_area(row, 2, 1);  // each output covers 1.5 source pixels
  EXPECT_NEAR(r.pixels[0], (0 * 1.0 + 1 * 0.5) / 1.5, 1e-6);
  EXPECT_NEAR(r.pixels[1], (1 * 0.5 + 2 * 1.0) / 1.5, 1e-6);
  // Mean is preserved by area resampling.
  const Image s = resize_area(im, 5, 3);
  double m0 = 0, m1 = 0;
  for (float v : im.pixels) m0 += v;
  for (float v : s.pixels) m1 += v;
  EXPECT_NEAR(m0 / im.pixels.size(), m1 / s.pixels.size(), 1e-5);
}

TEST(Image, CompositeRgbaOverBackground) {
  Image rgba = Image::zeros(2, 1, 4);
  rgba.pixels = {1, 0, 0, 0.25f, 0.2f, 0.4f, 0.6f, 1};
  const float bg[3] = {0, 0, 1};
  const Image rgb = composite_rgba(rgba, bg);
  ASSERT_EQ(rgb.channels, 3);
  EXPECT_FLOAT_EQ(rgb.at(0, 0, 0), 0.25f);
  EXPECT_FLOAT_EQ(rgb.at(0, 0, 1), 0.f);
  EXPECT_FLOAT_EQ(rgb.at(0, 0, 2), 0.75f);
  EXPECT_FLOAT_EQ(rgb.at(0, 1, 0), 0.2f);
  EXPECT_FLOAT_EQ(rgb.at(0, 1, 2), 0.6f);
  Image grey = Image::zeros(1, 1, 2);
  grey.pixels = {0.5f, 0.5f};
  const Image g = composite_rgba(grey, bg);
  EXPECT_FLOAT_EQ(g.at(0, 0, 0), 0.25f);
  EXPECT_FLOAT_EQ(g.at(0, 0, 2), 0.75f);
}

TEST(Image, Quantize8Bit) {
  Image im = Image::zeros(5, 1, 1);
  im.pixels = {0.5f, -1.f, 2.f, std::nanf(""), 0.2f};
  const Image q = quantize_8bit(im);
  EXPECT_FLOAT_EQ(q.pixels[0], 128.f / 255.f);
  EXPECT_FLOAT_EQ(q.pixels[1], 0.f);
  EXPECT_FLOAT_EQ(q.pixels[2], 1.f);
  EXPECT_FLOAT_EQ(q.pixels[3], 0.f);
  EXPECT_FLOAT_EQ(q.pixels[4], 51.f / 255.f);
  EXPECT_EQ(quantize_8bit(q).pixels, q.pixels);  // idempotent
}

}  // namespace
}  // namespace crpgs
