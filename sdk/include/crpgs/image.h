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
  /// A zero-filled image of the given size.
  static Image zeros(int width, int height, int channels) {
    Image im;
    im.width = width;
    im.height = height;
    im.channels = channels;
    im.pixels.assign(size_t(width) * height * channels, 0.f);
    return im;
  }
};

/// Decodes PNG/JPEG/BMP/TGA (stb). Keeps the file's channel count (1 grey, 2 grey+alpha, 3 RGB,
/// 4 RGBA); 16-bit PNGs keep their precision. Errors name the path and stb's reason.
StatusOr<Image> load_image(const std::string& path);
/// Images above this many pixels are refused before decoding (a few header bytes must not ask
/// for gigabytes): 2^28, e.g. 16384 x 16384.
inline constexpr int64_t kMaxImagePixels = int64_t(1) << 28;
/// Largest image side a camera may declare.
inline constexpr int kMaxImageSide = 1 << 16;
/// Width, height and channel count from the file header, without decoding the pixels.
struct ImageInfo {
  int width = 0, height = 0, channels = 0;
};
StatusOr<ImageInfo> read_image_info(const std::string& path);
/// Writes an 8-bit PNG (values clamped to [0,1], rounded), via a temporary file and rename.
/// Accepts 1 to 4 channels.
Status save_png(const Image& image, const std::string& path);
/// Box-filter downscale by an integer factor (as PIL's reduce for integer factors). Output is
/// floor(w/factor) x floor(h/factor): a remainder of fewer than `factor` rows/columns is dropped.
/// factor <= 1 returns a copy.
Image downscale(const Image& image, int factor);
/// Area resize to an arbitrary size (each output pixel averages the source area it covers,
/// partial pixels weighted by overlap). Meant for shrinking; enlarging replicates pixels.
Image resize_area(const Image& image, int width, int height);
/// RGBA -> RGB composited over `background` (straight alpha). Grey+alpha is composited too (grey
/// expanded to RGB); 1- and 3-channel inputs are returned as RGB (grey replicated).
Image composite_rgba(const Image& rgba, const float background[3]);
/// Quantises to 8 bits and back (the PNG round trip the evaluation protocol measures on):
/// round(clamp(v, 0, 1) * 255) / 255, NaN -> 0.
Image quantize_8bit(const Image& image);

}  // namespace crpgs
