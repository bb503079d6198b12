/// @file project_kernels.h
/// @brief The projection's per-Gaussian maths, forward and backward, four Gaussians at a time in
/// double (one lane each); no libtorch header, so that it compiles for several instruction sets.
#pragma once

#include <cstdint>

namespace crpgs::raster::kernels {

/// The camera as the projection uses it (stages.cpp make_cam).
struct ProjectCamera {
  double R[3][3], t[3];
  double fx, fy, cx, cy, near_plane, far_plane;
  double lim_x_pos, lim_x_neg, lim_y_pos, lim_y_neg;  // clamps of x/z and y/z in the Jacobian
};

/// One Gaussian's projection: what project_forward keeps of it.
struct Projected {
  float u, v;      // pixel position of the mean
  float conic[3];  // inverse 2D covariance (a, b, c)
  float depth;     // camera-space z
  double radius;   // ceil(3 sqrt(largest eigenvalue)), clamped; valid only if `ok`
  bool ok;         // in the depth range with a positive-definite 2D covariance
};

/// Projects Gaussians [b, e) of means [N, 3], scales [N, 3] and quaternions [N, 4] (w, x, y, z)
/// into out[0 .. e - b): rotation, 3D covariance, the clamped Jacobian (as 3DGS and gsplat
/// clamp x/z), the dilated 2D covariance, its conic and 3-sigma radius.
void project_range(const ProjectCamera& cam, const float* means, const float* scales,
                   const float* quats, int64_t b, int64_t e, Projected* out);

/// project_backward's per-Gaussian work for [b, e): for each Gaussian with radii[i] > 0 that
/// still projects, the gradients of its mean [N, 3], scales [N, 3] and quaternion [N, 4] from
/// those of its 2D mean [N, 2], conic [N, 3] and depth [N]; the others are left untouched.
void project_backward_range(const ProjectCamera& cam, const float* means, const float* scales,
                            const float* quats, const int32_t* radii, const float* v_means2d,
                            const float* v_conics, const float* v_depths, int64_t b, int64_t e,
                            float* v_means, float* v_scales, float* v_quats);

}  // namespace crpgs::raster::kernels
