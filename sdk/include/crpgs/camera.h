/// @file camera.h
/// @brief A pinhole camera in the COLMAP/OpenCV convention (x right, y down, z forward).
#pragma once

#include <string>

#include <Eigen/Core>

namespace crpgs {

struct Camera {
  int width = 0, height = 0;
  double fx = 0, fy = 0, cx = 0, cy = 0;
  Eigen::Matrix3d R = Eigen::Matrix3d::Identity();  ///< world-to-camera rotation
  Eigen::Vector3d t = Eigen::Vector3d::Zero();      ///< x_cam = R x_world + t
  std::string name;                                 ///< image file name, for reports

  Eigen::Vector3d center() const { return -R.transpose() * t; }
  /// Row-major 4x4 world-to-camera matrix.
  Eigen::Matrix4d view_matrix() const {
    Eigen::Matrix4d m = Eigen::Matrix4d::Identity();
    m.topLeftCorner<3, 3>() = R;
    m.topRightCorner<3, 1>() = t;
    return m;
  }
  /// Rescales the intrinsics to a new image size (downscaled loading).
  Camera resized(int new_width, int new_height) const {
    Camera c = *this;
    const double sx = double(new_width) / width, sy = double(new_height) / height;
    c.width = new_width;
    c.height = new_height;
    c.fx *= sx;
    c.cx *= sx;
    c.fy *= sy;
    c.cy *= sy;
    return c;
  }
};

}  // namespace crpgs
