/// @file dataset.h
/// @brief Posed images: COLMAP (text/binary), NeRF-synthetic / instant-ngp transforms.json,
/// LLFF poses_bounds.npy. Images are downscaled on load and intrinsics rescaled.
#pragma once

#include <array>
#include <string>
#include <vector>

#include <Eigen/Core>

#include "crpgs/camera.h"
#include "crpgs/image.h"
#include "crpgs/status.h"

namespace crpgs {

struct View {
  Camera camera;     ///< intrinsics already match `image`
  Image image;       ///< RGB float in [0,1] (RGBA composited on the background)
  int index = 0;     ///< position in the sorted full list (train and test together)
};

struct DatasetOptions {
  std::string path;               ///< dataset root
  std::string format = "auto";    ///< auto | colmap | nerf_synthetic | instant_ngp | llff
  std::string images = "";        ///< image folder name; "" = format default (images)
  int downscale = 1;              ///< integer downscale factor applied on load
  int max_width = 0;              ///< >0: downscale further so width <= max_width
  int test_every = 8;             ///< every Nth image (idx % N == 0) is a test view; 0 = none
  std::array<float, 3> background{0.f, 0.f, 0.f};  ///< for RGBA images
  int max_images = 0;             ///< >0: load at most this many views per split (quick runs)
};

struct Dataset {
  std::string name;
  std::vector<View> train, test;
  std::vector<Eigen::Vector3f> points;        ///< SfM points, may be empty
  std::vector<Eigen::Vector3f> point_colors;  ///< same size as points, or empty
  std::vector<std::string> warnings;          ///< e.g. ignored distortion
};

StatusOr<Dataset> load_dataset(const DatasetOptions& options);

}  // namespace crpgs
