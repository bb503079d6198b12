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
  Camera camera;  ///< intrinsics already match `image`
  Image image;    ///< RGB float in [0,1] (RGBA composited on the background)
  int index = 0;  ///< position in the sorted full list (train and test together)
};

struct DatasetOptions {
  std::string path;             ///< dataset root
  std::string format = "auto";  ///< auto | colmap | nerf_synthetic | instant_ngp | llff
  std::string images = "";      ///< image folder name; "" = format default (images)
  int downscale = 1;            ///< integer downscale factor applied on load
  int max_width = 0;            ///< >0: downscale further so width <= max_width
  int test_every = 8;           ///< every Nth image (idx % N == 0) is a test view; 0 = none
  std::array<float, 3> background{0.f, 0.f, 0.f};  ///< for RGBA images
  int max_images = 0;       ///< >0: load at most this many views per split (quick runs)
  bool load_images = true;  ///< false: cameras only (sizes read from image headers)
  int threads = 2;          ///< image decoding threads (results are in a fixed order)
};

struct Dataset {
  std::string name;
  std::vector<View> train, test;
  std::vector<Eigen::Vector3f> points;        ///< SfM points, may be empty
  std::vector<Eigen::Vector3f> point_colors;  ///< same size as points, or empty
  std::vector<std::string> warnings;          ///< e.g. ignored distortion
  std::string format;                         ///< the format actually loaded (after auto)
};

/// Loads a dataset. Formats and their marker files (auto-detection tries them in this order):
///  - colmap: sparse/0/, sparse/ or the root holding cameras.{bin,txt} + images.{bin,txt}
///    (+ points3D.{bin,txt}); binary preferred when both exist. PINHOLE / SIMPLE_PINHOLE exact;
///    SIMPLE_RADIAL, RADIAL, OPENCV, FULL_OPENCV are used as pinhole with a warning naming the
///    ignored distortion; fisheye / FOV / THIN_PRISM models are rejected. A missing or empty
///    points3D yields no points plus a warning.
///  - nerf_synthetic: transforms_train.json (+ transforms_test.json / transforms_val.json).
///    OpenGL cameras converted to OpenCV. When no test image exists on disk, val is the test split
///    (warning).
///  - instant_ngp: transforms.json (fl_x/fl_y/cx/cy/w/h or camera_angle_x[/_y]); split by
///    test_every. nerfstudio's keys are read as nerfstudio defines them: camera_model (pinhole
///    models; OPENCV's distortion ignored with a warning, others refused), ply_file_path (the
///    initial points) and train/val/test_filenames (the split; test from val when it is empty).
///  - llff: poses_bounds.npy (N×17 float64; [down, right, back] axes converted; hwf rescaled to
///    the loaded image size, principal point at the centre); points from sparse/0 if present.
/// Views are sorted by image name; view i is a test view when i % test_every == 0, unless the
/// format has its own split (nerf_synthetic). Images default to the `images` folder.
/// Points colours are RGB in [0, 1]. Errors are Status with the offending path.
StatusOr<Dataset> load_dataset(const DatasetOptions& options);

/// The format load_dataset would pick for `path` ("colmap", "nerf_synthetic", "instant_ngp",
/// "llff"), or kNotFound listing the accepted formats and their marker files.
StatusOr<std::string> detect_dataset_format(const std::string& path);

}  // namespace crpgs
