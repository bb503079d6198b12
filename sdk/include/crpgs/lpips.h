/// @file lpips.h
/// @brief LPIPS (the learned perceptual distance of Zhang et al., 2018) from a TorchScript module
/// the user exported: its VGG weights cannot be shipped in this repository or downloaded at run
/// time. docs/lpips.md says how to export one; `crpgs eval --lpips-weights FILE` uses it.
#pragma once

#include <memory>
#include <string>

#include "crpgs/image.h"
#include "crpgs/status.h"

namespace crpgs {

class Lpips {
 public:
  /// Loads the module (on the CPU) and checks it on a pair of small images: `forward(x, y)`
  /// takes two [1, 3, H, W] float tensors in [-1, 1] and returns one finite number (a tensor of
  /// one element). Errors name the file and what it did.
  static StatusOr<std::shared_ptr<Lpips>> load(const std::string& path);
  /// The distance between two RGB images with values in [0, 1] (as evaluation holds them).
  StatusOr<double> distance(const Image& a, const Image& b) const;
  const std::string& path() const { return path_; }
  ~Lpips();

 private:
  struct Module;
  Lpips(std::string path, std::unique_ptr<Module> module);
  std::string path_;
  std::unique_ptr<Module> module_;
};

}  // namespace crpgs
