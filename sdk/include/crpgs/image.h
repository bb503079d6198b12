/// @file image.h
/// @brief 8-bit / float images without libtorch: load (PNG, JPEG via stb), save PNG atomically,
/// area downscaling.
#pragma once

#include <string>
#include <vector>

#include "crpgs/status.h"

namespace crpgs {

/// Interleaved HWC float image in [0, 1].
struct Image {
  int width = 0, height = 0, channels = 0;
  std::vector<float> pixels;  ///< size width*height*channels
  float& at(int y, int x, int c) { return pixels[(size_t(y) * width + x) * channels + c]; }
  float at(int y, int x, int c) const { return pixels[(size_t(y) * width + x) * channels + c]; }
  bool empty() const { return pixels.empty(); }
};

StatusOr<Image> load_image(const std::string& path);
/// Writes an 8-bit PNG (values clamped to [0,1], rounded), via a temporary file and rename.
Status save_png(const Image& image, const std::string& path);
/// Box-filter downscale by an integer factor (as PIL's reduce for integer factors).
Image downscale(const Image& image, int factor);
/// Area resize to an arbitrary size.
Image resize_area(const Image& image, int width, int height);
/// RGBA -> RGB composited over `background` (straight alpha).
Image composite_rgba(const Image& rgba, const float background[3]);
/// Quantises to 8 bits and back (the PNG round trip the evaluation protocol measures on).
Image quantize_8bit(const Image& image);

}  // namespace crpgs
