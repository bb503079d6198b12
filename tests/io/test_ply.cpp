// 3DGS .ply: layout, bit-exact round trip, SH basis, malformed files refused with messages.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <random>

#include "crpgs/ply.h"
#include "io/io_test_util.h"

namespace crpgs {
namespace {

PlyGaussians random_gaussians(int degree, size_t n, unsigned seed) {
  std::mt19937 rng(seed);
  std::normal_distribution<float> u(0.f, 1.f);
  auto fill = [&](std::vector<float>& v, size_t k) {
    v.resize(k);
    for (auto& x : v) x = u(rng);
  };
  PlyGaussians g;
  g.sh_degree = degree;
  fill(g.means, 3 * n);
  fill(g.sh_dc, 3 * n);
  fill(g.sh_rest, size_t(3 * (sh_coeff_count(degree) - 1)) * n);
  fill(g.opacity, n);
  fill(g.log_scales, 3 * n);
  fill(g.rotations, 4 * n);
  for (size_t i = 0; i < n; ++i) {  // unit quaternions, as a file holds them
    float* q = &g.rotations[4 * i];
    const float norm = std::sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3]);
    for (int k = 0; k < 4; ++k) q[k] /= norm;
  }
  return g;
}

bool same_bits(const std::vector<float>& a, const std::vector<float>& b) {
  return a.size() == b.size() && std::memcmp(a.data(), b.data(), a.size() * sizeof(float)) == 0;
}

StatusOr<PlyGaussians> decode(const std::string& s) {
  return decode_ply(reinterpret_cast<const uint8_t*>(s.data()), s.size(), "test.ply");
}

std::string header_with(size_t n, const std::vector<std::string>& props,
                        const std::string& format = "binary_little_endian") {
  std::string h = "ply\nformat " + format + " 1.0\nelement vertex " + std::to_string(n) + "\n";
  for (const auto& p : props) h += "property float " + p + "\n";
  return h + "end_header\n";
}

std::vector<std::string> inria_props(int degree) {
  std::vector<std::string> p = {"x", "y", "z", "nx", "ny", "nz", "f_dc_0", "f_dc_1", "f_dc_2"};
  for (int i = 0; i < 3 * (sh_coeff_count(degree) - 1); ++i)
    p.push_back("f_rest_" + std::to_string(i));
  for (const char* s :
       {"opacity", "scale_0", "scale_1", "scale_2", "rot_0", "rot_1", "rot_2", "rot_3"})
    p.push_back(s);
  return p;
}

void expect_refused(const std::string& bytes, const std::string& words) {
  auto r = decode(bytes);
  ASSERT_FALSE(r.ok()) << "accepted: " << words;
  EXPECT_NE(r.status().message().find(words), std::string::npos) << r.status().message();
}

TEST(Ply, WritesTheInriaLayout) {
  for (int d = 0; d <= 3; ++d) {
    auto g = random_gaussians(d, 5, 1);
    auto bytes = encode_ply(g);
    ASSERT_TRUE(bytes.ok()) << bytes.status().message();
    const std::string expected_header = header_with(5, inria_props(d));
    ASSERT_EQ(bytes->compare(0, expected_header.size(), expected_header), 0) << *bytes;
    const size_t floats = inria_props(d).size();
    ASSERT_EQ(bytes->size(), expected_header.size() + 5 * floats * 4);
    // Vertex 2: x at 0, normals zero, f_rest channel-major right after f_dc, opacity after.
    const char* v = bytes->data() + expected_header.size() + 2 * floats * 4;
    float f[64];
    std::memcpy(f, v, floats * 4);
    EXPECT_EQ(f[0], g.means[6]);
    EXPECT_EQ(f[3], 0.f);
    EXPECT_EQ(f[5], 0.f);
    EXPECT_EQ(f[6], g.sh_dc[6]);
    const size_t rest = floats - 17;
    for (size_t k = 0; k < rest; ++k) EXPECT_EQ(f[9 + k], g.sh_rest[2 * rest + k]);
    EXPECT_EQ(f[9 + rest], g.opacity[2]);
    EXPECT_EQ(f[13 + rest], g.rotations[8]);
  }
}

TEST(Ply, RoundTripIsBitExactForEveryDegree) {
  const auto dir = test::fresh_dir();
  for (int d = 0; d <= 3; ++d) {
    auto g = random_gaussians(d, 257, unsigned(10 + d));
    const std::string path = (dir / ("s" + std::to_string(d) + ".ply")).string();
    ASSERT_TRUE(write_ply(path, g).ok());
    auto r = read_ply(path);
    ASSERT_TRUE(r.ok()) << r.status().message();
    EXPECT_EQ(r->sh_degree, d);
    EXPECT_EQ(r->size(), g.size());
    EXPECT_TRUE(same_bits(r->means, g.means));
    EXPECT_TRUE(same_bits(r->sh_dc, g.sh_dc));
    EXPECT_TRUE(same_bits(r->sh_rest, g.sh_rest));
    EXPECT_TRUE(same_bits(r->opacity, g.opacity));
    EXPECT_TRUE(same_bits(r->log_scales, g.log_scales));
    EXPECT_TRUE(same_bits(r->rotations, g.rotations));
    EXPECT_EQ(*encode_ply(*r), *encode_ply(g));
  }
}

TEST(Ply, IgnoresExtraPropertiesAndConvertsTypes) {
  // Reordered, with a uchar colour and a double x, and a trailing face element.
  std::vector<std::string> props = inria_props(0);
  std::string h =
      "ply\nformat binary_little_endian 1.0\ncomment made by hand\nelement vertex 1\n"
      "property double x\nproperty uchar red\n";
  for (size_t i = 1; i < props.size(); ++i) h += "property float " + props[i] + "\n";
  h += "element face 0\nproperty list uchar int vertex_indices\nend_header\n";
  std::string body;
  const double x = 1.25;
  body.append(reinterpret_cast<const char*>(&x), 8);
  body.push_back(char(200));
  for (size_t i = 1; i < props.size(); ++i) {
    const float v = float(i);
    body.append(reinterpret_cast<const char*>(&v), 4);
  }
  auto r = decode(h + body);
  ASSERT_TRUE(r.ok()) << r.status().message();
  EXPECT_EQ(r->sh_degree, 0);
  EXPECT_EQ(r->means[0], 1.25f);
  EXPECT_EQ(r->means[1], 1.f);
  EXPECT_EQ(r->sh_dc[0], 6.f);
  EXPECT_EQ(r->opacity[0], 9.f);
  EXPECT_EQ(r->rotations[3], 16.f);
}

TEST(Ply, RefusesMalformedFilesWithMessages) {
  const std::string good = *encode_ply(random_gaussians(1, 4, 3));
  expect_refused(good.substr(0, good.size() - 3), "file too short for 4 vertices");
  expect_refused(good.substr(0, 40), "truncated header");
  expect_refused("not a ply", "not a .ply file");
  expect_refused(header_with(2, inria_props(0), "ascii") + "1 2 3\n",
                 "ascii .ply is not supported");
  expect_refused(header_with(2, inria_props(0), "binary_big_endian"), "not supported");
  expect_refused(header_with(4000000000000ull, inria_props(0)) + std::string(64, '\0'),
                 "file too short for 4000000000000 vertices");
  expect_refused(
      "ply\nformat binary_little_endian 1.0\nelement vertex 99999999999999999999\n"
      "end_header\n",
      "malformed element line");
  auto no_opacity = inria_props(0);
  no_opacity.erase(std::find(no_opacity.begin(), no_opacity.end(), "opacity"));
  expect_refused(header_with(0, no_opacity), "missing vertex property 'opacity'");
  auto five_rest = inria_props(0);
  for (int i = 0; i < 5; ++i) five_rest.push_back("f_rest_" + std::to_string(i));
  expect_refused(header_with(0, five_rest), "5 f_rest properties");
  expect_refused("ply\nformat binary_little_endian 1.0\nelement vertex 1\nproperty float x\n" +
                     std::string(70000, 'c'),
                 "no end_header in the first 64 KiB");
  expect_refused("ply\nformat binary_little_endian 1.0\nproperty float x\nend_header\n",
                 "property before any element");
  expect_refused(
      "ply\nformat binary_little_endian 1.0\nelement vertex 1\nproperty quad x\n"
      "end_header\n",
      "malformed property line");
  auto twice = inria_props(0);
  twice.push_back("opacity");
  expect_refused(header_with(0, twice), "vertex property 'opacity' appears twice");
  PlyGaussians inconsistent = random_gaussians(2, 3, 4);
  inconsistent.sh_rest.pop_back();
  EXPECT_FALSE(encode_ply(inconsistent).ok());
}

TEST(Ply, VerticesWithNonFiniteValuesAreLeftOutAndCounted) {
  PlyGaussians g = random_gaussians(1, 5, 7);
  g.means[3 * 1 + 2] = std::numeric_limits<float>::quiet_NaN();   // vertex 1
  g.sh_rest[9 * 3 + 4] = std::numeric_limits<float>::infinity();  // vertex 3
  auto r = decode(*encode_ply(g));
  ASSERT_TRUE(r.ok()) << r.status().message();
  EXPECT_EQ(r->dropped_non_finite, 2u);
  ASSERT_EQ(r->size(), 3u);
  EXPECT_TRUE(r->check().ok());
  for (size_t k = 0; k < 3; ++k) {  // vertices 0, 2, 4 in order
    const size_t i = 2 * k;
    EXPECT_EQ(r->opacity[k], g.opacity[i]);
    EXPECT_EQ(r->means[3 * k + 2], g.means[3 * i + 2]);
    EXPECT_EQ(r->sh_rest[9 * k + 8], g.sh_rest[9 * i + 8]);
    EXPECT_EQ(r->rotations[4 * k + 3], g.rotations[4 * i + 3]);
  }
}

// What every consumer reads: 8-bit alpha formats (.spz, .sog) turn an opacity above 254.5/255
// into 255, an infinite logit when read back (bench/results/export.md); a viewer may assume unit
// quaternions. Read back, an infinite opacity is a saturated alpha, not a broken vertex.
TEST(Ply, WritesOpacitiesEightBitAlphaHoldsAndUnitRotations) {
  PlyGaussians g = random_gaussians(0, 4, 3);
  g.opacity = {7.9f, -10.6f, 5.0f, -1.0f};
  const float q1[4] = {0.6f, 0.f, 0.8f * 1.05f, 0.f};  // norm 1.0197
  std::copy(q1, q1 + 4, &g.rotations[4]);
  std::fill(&g.rotations[8], &g.rotations[12], 0.f);
  auto r = decode(*encode_ply(g));
  ASSERT_TRUE(r.ok()) << r.status().message();
  EXPECT_EQ(r->opacity[0], kPlyMaxOpacityLogit);
  EXPECT_EQ(r->opacity[1], -kPlyMaxOpacityLogit);
  EXPECT_EQ(r->opacity[2], 5.0f);
  EXPECT_NEAR(1.f / (1.f + std::exp(-kPlyMaxOpacityLogit)), 254.f / 255.f, 1e-6f);
  const double n1 = std::hypot(std::hypot(r->rotations[4], r->rotations[5]),
                               std::hypot(r->rotations[6], r->rotations[7]));
  EXPECT_NEAR(n1, 1.0, 1e-6);
  EXPECT_NEAR(r->rotations[6] / r->rotations[4], 0.8f * 1.05f / 0.6f, 1e-5f);  // same rotation
  EXPECT_EQ(r->rotations[8], 1.f);  // a zero quaternion: the identity
  EXPECT_TRUE(same_bits({&r->rotations[0], &r->rotations[4]},
                        {&g.rotations[0], &g.rotations[4]}));  // unit ones as they are

  std::string bytes = *encode_ply(g);
  const size_t body = bytes.find("end_header\n") + 11, floats = inria_props(0).size();
  const float inf = std::numeric_limits<float>::infinity();
  std::memcpy(&bytes[body + 9 * 4], &inf, 4);              // vertex 0's opacity
  std::memcpy(&bytes[body + (floats + 10) * 4], &inf, 4);  // vertex 1's scale_0
  const float neg = -inf;
  std::memcpy(&bytes[body + (3 * floats + 9) * 4], &neg, 4);  // vertex 3's opacity
  auto back = decode(bytes);
  ASSERT_TRUE(back.ok()) << back.status().message();
  EXPECT_EQ(back->dropped_non_finite, 1u);  // vertex 1 only
  ASSERT_EQ(back->size(), 3u);
  EXPECT_EQ(back->opacity[0], kPlyReadSaturatedLogit);
  EXPECT_EQ(back->opacity[2], -kPlyReadSaturatedLogit);
}

// A flat Gaussian's thin axis is written at most e^10 below the median size, so that formats
// with a 256-entry scale codebook keep their bins for the scales that show.
TEST(Ply, WritesLogScalesAboveAFloorBelowTheMedian) {
  PlyGaussians g = random_gaussians(0, 3, 2);
  g.log_scales = {-69.f, -5.f, -4.f, -6.f, -5.5f, -4.5f, -3.f, 2.f, -5.2f};  // median -5
  auto r = decode(*encode_ply(g));
  ASSERT_TRUE(r.ok()) << r.status().message();
  EXPECT_EQ(r->log_scales[0], -5.f - kPlyLogScaleFloorBelowMedian);
  for (size_t k = 1; k < g.log_scales.size(); ++k) EXPECT_EQ(r->log_scales[k], g.log_scales[k]);
}

TEST(Ply, ShBasisMatchesTheReferenceFormulas) {
  float b[16];
  sh_basis(0, 0.f, 0.f, 1.f, b);
  EXPECT_FLOAT_EQ(b[0], 0.28209479177387814f);
  const float x = 0.48f, y = -0.6f, z = 0.64f;  // unit
  sh_basis(3, x, y, z, b);
  EXPECT_FLOAT_EQ(b[1], -0.4886025119029199f * y);
  EXPECT_FLOAT_EQ(b[2], 0.4886025119029199f * z);
  EXPECT_FLOAT_EQ(b[3], -0.4886025119029199f * x);
  EXPECT_FLOAT_EQ(b[6], 0.31539156525252005f * (2 * z * z - x * x - y * y));
  EXPECT_FLOAT_EQ(b[8], 0.5462742152960396f * (x * x - y * y));
  EXPECT_FLOAT_EQ(b[12], 0.3731763325901154f * z * (2 * z * z - 3 * x * x - 3 * y * y));
  EXPECT_FLOAT_EQ(b[15], -0.5900435899266435f * x * (x * x - 3 * y * y));
  // Colour: 0.5 + SH, clamped at 0.
  PlyGaussians g = random_gaussians(1, 1, 5);
  g.sh_dc = {1.f, -10.f, 0.f};
  g.sh_rest = {0.f, 0.f, 1.f, 0.f, 0.f, 0.f, 0.f, 0.f, 0.f};  // R: coefficient 3 (-C1 x)
  const auto c = g.color(0, x, y, z);
  EXPECT_FLOAT_EQ(c[0], 0.5f + 0.28209479177387814f - 0.4886025119029199f * x);
  EXPECT_EQ(c[1], 0.f);
  EXPECT_FLOAT_EQ(c[2], 0.5f);
}

}  // namespace
}  // namespace crpgs
