/// @file scene_generator.h
/// @brief The embedded synthetic scene: a procedural set of objects (some repeated far apart)
/// made of 3D Gaussians, rendered with a crpgs rasterizer from a ring of cameras to give the
/// ground-truth views, plus SfM-like points sampled from the objects. Flags switch on exactly
/// the effects a test needs. Dataset format "synthetic" (empty dataset.path) means this.
#pragma once

#include <array>
#include <cstdint>

#include "crpgs/dataset.h"
#include "crpgs/rasterizer.h"
#include "crpgs/status.h"

namespace crpgs {

struct SyntheticSceneOptions {
  int width = 128, height = 96;
  int views = 32;                ///< cameras on a ring around the scene
  int test_every = 8;            ///< idx % test_every == 0 are test views; 0 = none
  int sfm_points = 3000;         ///< points sampled from the objects (0 = none: random init)
  bool repeated_objects = true;  ///< the same object placed at far-apart positions
  bool view_dependent = false;   ///< one specular object whose colour depends on the view
  bool appearance = false;       ///< per-image exposure change (needs an appearance embedding)
  std::array<float, 3> background{0.f, 0.f, 0.f};
  uint64_t seed = 1;
};

/// Generates the scene and renders its views with `rasterizer` (on its device). The scene spans
/// about [-2, 2]^3 around the origin; cameras look at the origin from radius ~6.
StatusOr<Dataset> generate_scene(const SyntheticSceneOptions& options, Rasterizer& rasterizer);

}  // namespace crpgs
