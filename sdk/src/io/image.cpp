/// @file image.cpp
/// @brief stb-based image I/O and the CPU resampling helpers of image.h.
#include "crpgs/image.h"

#include <stb_image.h>
#include <stb_image_write.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <memory>
#include <string>

#include "crpgs/atomic_file.h"

namespace crpgs {
namespace {

std::string stb_reason() {
  const char* r = stbi_failure_reason();
  return r ? r : "unknown reason";
}

uint8_t to_u8(float v) {
  if (!(v > 0.f)) return 0;  // also NaN
  if (v >= 1.f) return 255;
  return static_cast<uint8_t>(std::lround(v * 255.f));
}

// Separable area weights: for each output index, the source indices and their overlap weights.
struct AreaTaps {
  std::vector<int> begin, count;
  std::vector<float> index_weight;  // normalised per output
  std::vector<int> index;
};

AreaTaps area_taps(int src, int dst) {
  AreaTaps t;
  t.begin.resize(size_t(dst));
  t.count.resize(size_t(dst));
  const double scale = double(src) / dst;
  for (int o = 0; o < dst; ++o) {
    const double a = o * scale, b = (o + 1) * scale;
    int i0 = int(std::floor(a));
    int i1 = std::min(src, int(std::ceil(b)));
    t.begin[size_t(o)] = int(t.index.size());
    double total = 0;
    std::vector<double> w;
    for (int i = i0; i < i1; ++i) {
      const double ov = std::min(b, double(i + 1)) - std::max(a, double(i));
      if (ov <= 1e-12) continue;
      t.index.push_back(i);
      w.push_back(ov);
      total += ov;
    }
    for (double x : w) t.index_weight.push_back(float(x / total));
    t.count[size_t(o)] = int(w.size());
  }
  return t;
}

}  // namespace

StatusOr<Image> load_image(const std::string& path) {
  std::unique_ptr<FILE, int (*)(FILE*)> f(std::fopen(path.c_str(), "rb"), &std::fclose);
  if (!f) return Status(StatusCode::kNotFound, "image not found: " + path);
  Image im;
  int w = 0, h = 0, c = 0;
  if (stbi_info_from_file(f.get(), &w, &h, &c) && int64_t(w) * h > kMaxImagePixels)
    return Status(StatusCode::kIoError, path + " declares " + std::to_string(w) + "x" +
                                            std::to_string(h) + " pixels, more than the limit of " +
                                            std::to_string(kMaxImagePixels));
  const bool is16 = stbi_is_16_bit_from_file(f.get()) != 0;
  if (is16) {
    stbi_us* data = stbi_load_from_file_16(f.get(), &w, &h, &c, 0);
    if (!data)
      return Status(StatusCode::kIoError, "cannot decode image " + path + ": " + stb_reason());
    im = Image::zeros(w, h, c);
    for (size_t i = 0; i < im.pixels.size(); ++i) im.pixels[i] = float(data[i]) / 65535.f;
    stbi_image_free(data);
  } else {
    stbi_uc* data = stbi_load_from_file(f.get(), &w, &h, &c, 0);
    if (!data)
      return Status(StatusCode::kIoError, "cannot decode image " + path + ": " + stb_reason());
    im = Image::zeros(w, h, c);
    for (size_t i = 0; i < im.pixels.size(); ++i) im.pixels[i] = float(data[i]) / 255.f;
    stbi_image_free(data);
  }
  return im;
}

StatusOr<ImageInfo> read_image_info(const std::string& path) {
  std::unique_ptr<FILE, int (*)(FILE*)> f(std::fopen(path.c_str(), "rb"), &std::fclose);
  if (!f) return Status(StatusCode::kNotFound, "image not found: " + path);
  ImageInfo info;
  if (!stbi_info_from_file(f.get(), &info.width, &info.height, &info.channels))
    return Status(StatusCode::kIoError, "cannot read image header " + path + ": " + stb_reason());
  return info;
}

Status save_png(const Image& image, const std::string& path) {
  if (image.width <= 0 || image.height <= 0 || image.channels < 1 || image.channels > 4 ||
      image.pixels.size() != size_t(image.width) * image.height * image.channels)
    return Status(StatusCode::kInvalidArgument,
                  "save_png(" + path + "): bad image " + std::to_string(image.width) + "x" +
                      std::to_string(image.height) + "x" + std::to_string(image.channels));
  std::vector<uint8_t> bytes(image.pixels.size());
  for (size_t i = 0; i < bytes.size(); ++i) bytes[i] = to_u8(image.pixels[i]);
  std::string png;
  auto sink = [](void* ctx, void* data, int size) {
    static_cast<std::string*>(ctx)->append(static_cast<const char*>(data), size_t(size));
  };
  if (!stbi_write_png_to_func(sink, &png, image.width, image.height, image.channels, bytes.data(),
                              image.width * image.channels))
    return Status(StatusCode::kIoError, "cannot encode PNG for " + path);
  return write_file_atomic(path, png);
}

Image downscale(const Image& image, int factor) {
  if (factor <= 1) return image;
  const int w = image.width / factor, h = image.height / factor, c = image.channels;
  Image out = Image::zeros(w, h, c);
  const double inv = 1.0 / (double(factor) * factor);
  std::vector<double> acc(size_t(w) * c);
  for (int y = 0; y < h; ++y) {
    std::fill(acc.begin(), acc.end(), 0.0);
    for (int dy = 0; dy < factor; ++dy) {
      const float* row = &image.pixels[size_t(y * factor + dy) * image.width * c];
      for (int x = 0; x < w; ++x)
        for (int dx = 0; dx < factor; ++dx)
          for (int k = 0; k < c; ++k)
            acc[size_t(x) * c + k] += row[size_t(x * factor + dx) * c + k];
    }
    float* dst = &out.pixels[size_t(y) * w * c];
    for (size_t i = 0; i < acc.size(); ++i) dst[i] = float(acc[i] * inv);
  }
  return out;
}

Image resize_area(const Image& image, int width, int height) {
  if (width == image.width && height == image.height) return image;
  if (width <= 0 || height <= 0 || image.empty())
    return Image::zeros(std::max(width, 0), std::max(height, 0), image.channels);
  const int c = image.channels;
  const AreaTaps tx = area_taps(image.width, width), ty = area_taps(image.height, height);
  // Horizontal pass [H, width, C], then vertical [height, width, C].
  std::vector<float> tmp(size_t(image.height) * width * c);
  for (int y = 0; y < image.height; ++y) {
    const float* src = &image.pixels[size_t(y) * image.width * c];
    float* dst = &tmp[size_t(y) * width * c];
    for (int x = 0; x < width; ++x)
      for (int k = 0; k < c; ++k) {
        double s = 0;
        for (int j = 0; j < tx.count[size_t(x)]; ++j) {
          const size_t t = size_t(tx.begin[size_t(x)] + j);
          s += double(tx.index_weight[t]) * src[size_t(tx.index[t]) * c + k];
        }
        dst[size_t(x) * c + k] = float(s);
      }
  }
  Image out = Image::zeros(width, height, c);
  const size_t row = size_t(width) * c;
  std::vector<double> acc(row);
  for (int y = 0; y < height; ++y) {
    std::fill(acc.begin(), acc.end(), 0.0);
    for (int j = 0; j < ty.count[size_t(y)]; ++j) {
      const size_t t = size_t(ty.begin[size_t(y)] + j);
      const float* src = &tmp[size_t(ty.index[t]) * row];
      const double wgt = ty.index_weight[t];
      for (size_t i = 0; i < row; ++i) acc[i] += wgt * src[i];
    }
    for (size_t i = 0; i < row; ++i) out.pixels[size_t(y) * row + i] = float(acc[i]);
  }
  return out;
}

Image composite_rgba(const Image& rgba, const float background[3]) {
  Image out = Image::zeros(rgba.width, rgba.height, 3);
  const size_t n = size_t(rgba.width) * rgba.height;
  const int c = rgba.channels;
  for (size_t i = 0; i < n; ++i) {
    const float* p = &rgba.pixels[i * c];
    float* q = &out.pixels[i * 3];
    float rgb[3];
    float alpha = 1.f;
    if (c >= 3) {
      rgb[0] = p[0], rgb[1] = p[1], rgb[2] = p[2];
      if (c == 4) alpha = p[3];
    } else {
      rgb[0] = rgb[1] = rgb[2] = p[0];
      if (c == 2) alpha = p[1];
    }
    for (int k = 0; k < 3; ++k) q[k] = rgb[k] * alpha + background[k] * (1.f - alpha);
  }
  return out;
}

Image quantize_8bit(const Image& image) {
  Image out = image;
  for (float& v : out.pixels) v = float(to_u8(v)) / 255.f;
  return out;
}

}  // namespace crpgs
