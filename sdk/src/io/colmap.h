/// @file colmap.h
/// @brief COLMAP sparse models (cameras, images, points3D) in text and binary form: readers with
/// truncation checks, writers (for tests and tools), conversion to crpgs::Camera. Internal.
#pragma once

#include <array>
#include <cstdint>
#include <map>
#include <string>
#include <utility>
#include <vector>

#include <Eigen/Core>

#include "crpgs/camera.h"
#include "crpgs/status.h"

namespace crpgs::io {

struct ColmapCamera {
  int id = 0;
  int model_id = 1;  ///< COLMAP model id (0 SIMPLE_PINHOLE, 1 PINHOLE, 2 SIMPLE_RADIAL, ...)
  uint64_t width = 0, height = 0;
  std::vector<double> params;
};

struct ColmapImage {
  int id = 0;
  Eigen::Vector4d qvec{1, 0, 0, 0};  ///< world-to-camera rotation (w, x, y, z)
  Eigen::Vector3d tvec = Eigen::Vector3d::Zero();
  int camera_id = 0;
  std::string name;
  std::vector<Eigen::Vector2d> xys;  ///< 2D keypoints (may be empty)
  std::vector<int64_t> point3d_ids;  ///< -1 where the keypoint has no 3D point
};

struct ColmapPoint {
  uint64_t id = 0;
  Eigen::Vector3d xyz = Eigen::Vector3d::Zero();
  std::array<uint8_t, 3> rgb{0, 0, 0};
  double error = 0;
  std::vector<std::pair<int, int>> track;  ///< (image_id, point2D_idx)
};

struct ColmapModel {
  std::map<int, ColmapCamera> cameras;
  std::vector<ColmapImage> images;  ///< file order
  std::vector<ColmapPoint> points;
  bool has_points_file = false;  ///< points3D.{bin,txt} existed
};

/// Model name -> id and parameter count; -1 / 0 for unknown.
int colmap_model_id(const std::string& name);
const char* colmap_model_name(int model_id);
int colmap_model_num_params(int model_id);

/// Directory holding a model: `dir` itself, `dir/sparse/0` or `dir/sparse`; "" if none.
std::string find_colmap_model_dir(const std::string& dir);
/// Reads a model; binary if cameras.bin exists, else text.
StatusOr<ColmapModel> read_colmap_model(const std::string& model_dir);
StatusOr<ColmapModel> read_colmap_binary(const std::string& model_dir);
StatusOr<ColmapModel> read_colmap_text(const std::string& model_dir);
/// Only the points of a model directory (points3D.bin, else points3D.txt); kNotFound if neither.
StatusOr<std::vector<ColmapPoint>> read_colmap_points(const std::string& model_dir);
/// Writers (points3D is written only when `model.has_points_file` or points are present).
Status write_colmap_binary(const ColmapModel& model, const std::string& model_dir);
Status write_colmap_text(const ColmapModel& model, const std::string& model_dir);

/// Pinhole camera for one image at the camera's native size. Distortion of SIMPLE_RADIAL,
/// RADIAL, OPENCV, FULL_OPENCV is ignored with a warning appended to `warnings`; other models
/// are rejected (kInvalidArgument).
StatusOr<Camera> colmap_camera(const ColmapCamera& cam, const ColmapImage& image,
                               std::vector<std::string>* warnings);

}  // namespace crpgs::io
