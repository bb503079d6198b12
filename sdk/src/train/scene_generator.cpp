/// @file scene_generator.cpp
/// @brief The procedural scene: a checkered ground, a cube, a striped sphere (twice, far apart,
/// when asked) and optionally a specular sphere, all made of small 3D Gaussians; rendered from a
/// ring of cameras. World z is up; cameras follow OpenCV (x right, y down, z forward).
#include "crpgs/scene_generator.h"

#include <torch/types.h>
#include <Eigen/Geometry>

#include <cmath>
#include <cstdio>
#include <random>

namespace crpgs {
namespace {

struct Splat {
  Eigen::Vector3f pos, color, normal;
  float scale = 0.05f;
  float opacity = 0.9f;
  bool specular = false;
};

void add_sphere(std::vector<Splat>& out, const Eigen::Vector3f& center, float radius, int n,
                bool striped, bool specular, const Eigen::Vector3f& tint) {
  // Fibonacci sphere: even coverage without randomness.
  const float golden = float(M_PI) * (3.f - std::sqrt(5.f));
  for (int i = 0; i < n; ++i) {
    const float z = 1.f - 2.f * (float(i) + 0.5f) / float(n);
    const float r = std::sqrt(std::max(0.f, 1.f - z * z));
    const float th = golden * float(i);
    Eigen::Vector3f nrm(r * std::cos(th), r * std::sin(th), z);
    Splat s;
    s.pos = center + radius * nrm;
    s.normal = nrm;
    const float stripe = striped ? (std::sin(8.f * z) > 0 ? 1.f : 0.35f) : 1.f;
    s.color = tint * stripe;
    s.scale = radius * std::sqrt(4.f * float(M_PI) / float(n)) * 0.6f;
    s.specular = specular;
    out.push_back(s);
  }
}

void add_cube(std::vector<Splat>& out, const Eigen::Vector3f& center, float half, int per_edge) {
  for (int face = 0; face < 6; ++face) {
    const int axis = face / 2;
    const float sign = face % 2 ? 1.f : -1.f;
    for (int i = 0; i < per_edge; ++i)
      for (int j = 0; j < per_edge; ++j) {
        const float u = (float(i) + 0.5f) / float(per_edge) * 2.f - 1.f;
        const float v = (float(j) + 0.5f) / float(per_edge) * 2.f - 1.f;
        Eigen::Vector3f p;
        p[axis] = sign;
        p[(axis + 1) % 3] = u;
        p[(axis + 2) % 3] = v;
        Splat s;
        s.pos = center + half * p;
        s.normal = Eigen::Vector3f::Zero();
        s.normal[axis] = sign;
        s.color =
            Eigen::Vector3f(0.5f + 0.5f * u, 0.5f + 0.5f * v, 0.3f + 0.2f * float(face) / 5.f);
        s.scale = half * 2.f / float(per_edge) * 0.6f;
        out.push_back(s);
      }
  }
}

void add_ground(std::vector<Splat>& out, float half, int n, float z) {
  for (int i = 0; i < n; ++i)
    for (int j = 0; j < n; ++j) {
      const float x = ((float(i) + 0.5f) / float(n) * 2.f - 1.f) * half;
      const float y = ((float(j) + 0.5f) / float(n) * 2.f - 1.f) * half;
      Splat s;
      s.pos = Eigen::Vector3f(x, y, z);
      s.normal = Eigen::Vector3f(0, 0, 1);
      const bool check = ((i / 4) + (j / 4)) % 2 == 0;
      s.color = check ? Eigen::Vector3f(0.85f, 0.8f, 0.7f) : Eigen::Vector3f(0.25f, 0.3f, 0.35f);
      s.scale = half * 2.f / float(n) * 0.6f;
      s.opacity = 0.95f;
      out.push_back(s);
    }
}

Camera ring_camera(int i, int n, int width, int height) {
  const double a = 2.0 * M_PI * double(i) / double(n);
  const double h = 2.5 + 0.8 * std::sin(3.0 * a);
  const Eigen::Vector3d c(6.0 * std::cos(a), 6.0 * std::sin(a), h);
  const Eigen::Vector3d target(0, 0, -0.5);
  const Eigen::Vector3d f = (target - c).normalized();
  const Eigen::Vector3d r = f.cross(Eigen::Vector3d(0, 0, 1)).normalized();
  const Eigen::Vector3d d = f.cross(r);
  Camera cam;
  cam.width = width;
  cam.height = height;
  cam.fx = cam.fy = double(width) / (2.0 * std::tan(30.0 * M_PI / 180.0));
  cam.cx = width / 2.0;
  cam.cy = height / 2.0;
  cam.R.row(0) = r.transpose();
  cam.R.row(1) = d.transpose();
  cam.R.row(2) = f.transpose();
  cam.t = -cam.R * c;
  char name[32];
  std::snprintf(name, sizeof(name), "synth_%03d.png", i);
  cam.name = name;
  return cam;
}

}  // namespace

StatusOr<Dataset> generate_scene(const SyntheticSceneOptions& o, Rasterizer& rasterizer) {
  if (o.width < 8 || o.height < 8 || o.views < 2)
    return Status(StatusCode::kInvalidArgument,
                  "synthetic scene: need >= 8x8 pixels and >= 2 views");
  // 1. Objects.
  std::vector<Splat> splats;
  add_ground(splats, 3.f, 48, -1.f);
  add_cube(splats, Eigen::Vector3f(0.f, 0.f, -0.4f), 0.6f, 14);
  add_sphere(splats, Eigen::Vector3f(-2.f, -1.8f, -0.45f), 0.55f, 900, true, false,
             Eigen::Vector3f(0.9f, 0.35f, 0.2f));
  if (o.repeated_objects)
    add_sphere(splats, Eigen::Vector3f(2.f, 1.8f, -0.45f), 0.55f, 900, true, false,
               Eigen::Vector3f(0.9f, 0.35f, 0.2f));
  if (o.view_dependent)
    add_sphere(splats, Eigen::Vector3f(1.9f, -1.9f, -0.5f), 0.5f, 900, false, true,
               Eigen::Vector3f(0.2f, 0.35f, 0.8f));
  const int64_t n = int64_t(splats.size());
  auto means = torch::empty({n, 3}), scales = torch::empty({n, 3}), base = torch::empty({n, 3}),
       normals = torch::empty({n, 3}), opac = torch::empty({n}), spec = torch::empty({n});
  for (int64_t i = 0; i < n; ++i) {
    const Splat& s = splats[size_t(i)];
    for (int a = 0; a < 3; ++a) {
      means[i][a] = s.pos[a];
      scales[i][a] = s.scale;
      base[i][a] = s.color[a];
      normals[i][a] = s.normal[a];
    }
    opac[i] = s.opacity;
    spec[i] = s.specular ? 1.f : 0.f;
  }
  auto rotations = torch::zeros({n, 4});
  rotations.select(1, 0).fill_(1.f);

  // 2. Views.
  Dataset ds;
  ds.name = "synthetic";
  ds.format = "synthetic";
  std::mt19937_64 rng(o.seed);
  std::uniform_real_distribution<float> gain_dist(0.75f, 1.25f);
  RenderSettings settings;
  settings.background = o.background;
  const Eigen::Vector3f light = Eigen::Vector3f(0.3f, -0.5f, 1.f).normalized();
  auto light_t = torch::tensor({light.x(), light.y(), light.z()});
  torch::NoGradGuard no_grad;
  for (int i = 0; i < o.views; ++i) {
    View v;
    v.index = i;
    v.camera = ring_camera(i, o.views, o.width, o.height);
    auto colors = base.clone();
    if (o.view_dependent) {
      const Eigen::Vector3d c = v.camera.center();
      auto cam = torch::tensor({float(c[0]), float(c[1]), float(c[2])});
      auto unit = [](const torch::Tensor& t) { return t / t.norm(2, 1, true).clamp_min(1e-12); };
      auto view_dir = unit(cam - means);
      auto half = unit(view_dir + light_t);
      auto hl = (half * normals).sum(1).clamp_min(0).pow(24.f) * spec;  // Blinn-Phong highlight
      colors = (colors + 0.8f * hl.unsqueeze(1)).clamp(0, 1);
    }
    GaussianBatch b;
    b.means = means;
    b.scales = scales;
    b.rotations = rotations;
    b.opacities = opac;
    b.colors = colors;
    auto img = rasterizer.render(b, v.camera, settings).image.to(torch::kCPU);  // [H, W, 3]
    if (o.appearance) img = (img * gain_dist(rng)).clamp(0, 1);  // per-image exposure
    img = img.clamp(0, 1).contiguous();
    v.image.width = o.width;
    v.image.height = o.height;
    v.image.channels = 3;
    v.image.pixels.assign(img.data_ptr<float>(), img.data_ptr<float>() + img.numel());
    if (o.test_every > 0 && i % o.test_every == 0)
      ds.test.push_back(std::move(v));
    else
      ds.train.push_back(std::move(v));
  }
  // 3. SfM-like points: a random subset of the splat centres, slightly jittered.
  std::normal_distribution<float> jitter(0.f, 0.01f);
  std::uniform_int_distribution<int64_t> pick(0, n - 1);
  for (int i = 0; i < o.sfm_points; ++i) {
    const Splat& s = splats[size_t(pick(rng))];
    ds.points.emplace_back(s.pos.x() + jitter(rng), s.pos.y() + jitter(rng),
                           s.pos.z() + jitter(rng));
    ds.point_colors.push_back(s.color);
  }
  return ds;
}

}  // namespace crpgs
