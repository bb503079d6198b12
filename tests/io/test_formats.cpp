/// @file test_formats.cpp
/// @brief transforms.json (NeRF-synthetic, instant-ngp) and LLFF poses_bounds.npy on small
/// synthetic datasets with known cameras: axis conventions, intrinsics, splits, errors.
#include <gtest/gtest.h>

#include <Eigen/Geometry>
#include <Eigen/LU>
#include <algorithm>
#include <cmath>
#include <cstring>
#include <filesystem>

#include "crpgs/dataset.h"
#include "io/json.h"
#include "io/npy.h"
#include "io_test_util.h"

namespace crpgs {
namespace {

namespace fs = std::filesystem;

bool contains(const std::string& s, const std::string& part) {
  return s.find(part) != std::string::npos;
}

Eigen::Vector2d project(const Camera& c, const Eigen::Vector3d& x, double* depth = nullptr) {
  const Eigen::Vector3d p = c.R * x + c.t;
  if (depth) *depth = p.z();
  return {c.fx * p.x() / p.z() + c.cx, c.fy * p.y() / p.z() + c.cy};
}

std::string npy_bytes(const std::vector<double>& data, int rows, int cols) {
  std::string header = "{'descr': '<f8', 'fortran_order': False, 'shape': (" +
                       std::to_string(rows) + ", " + std::to_string(cols) + "), }";
  while ((10 + header.size() + 1) % 64 != 0) header += ' ';
  header += '\n';
  std::string out = "\x93NUMPY";
  out += char(1);
  out += char(0);
  out += char(header.size() & 0xff);
  out += char(header.size() >> 8);
  out += header;
  out.append(reinterpret_cast<const char*>(data.data()), data.size() * 8);
  return out;
}

TEST(Json, ParsesTransformsStyleDocuments) {
  auto v =
      io::parse_json("{\t\"a\": [1, -2.5e1, true, null],\n \"s\": \"x\\\"y\\u00e9\", \"o\": {}}");
  ASSERT_TRUE(v.ok()) << v.status().message();
  EXPECT_DOUBLE_EQ(v->find("a")->array[1].number, -25.0);
  EXPECT_EQ(v->find("s")->string, "x\"y\xc3\xa9");
  EXPECT_TRUE(v->find("o")->is_object());
  auto bad = io::parse_json("{\"a\": [1, 2}\n");
  ASSERT_FALSE(bad.ok());
  EXPECT_TRUE(contains(bad.status().message(), "line 1")) << bad.status().message();
  EXPECT_FALSE(io::parse_json("{\"a\": 1} x").ok());
  // strtod's extensions and out-of-range values are not JSON numbers.
  for (const char* num : {"-inf", "-nan", "0x10", "1e999", "-", "-.5"}) {
    auto r = io::parse_json(std::string("{\"fl_x\": ") + num + "}");
    EXPECT_FALSE(r.ok()) << num;
  }
  EXPECT_DOUBLE_EQ(io::parse_json("[-0.5e-3]")->array[0].number, -0.5e-3);
}

TEST(Json, UnicodeEscapesAreStrictAndSurrogatePairsAreOneCodePoint) {
  // U+1F600 as its UTF-16 pair: one 4-byte UTF-8 sequence; U+20AC (3 bytes); upper-case hex.
  auto v = io::parse_json(R"(["\uD83D\ude00", "\u20AC", "\u00E9x"])");
  ASSERT_TRUE(v.ok()) << v.status().message();
  EXPECT_EQ(v->array[0].string, "\xF0\x9F\x98\x80");
  EXPECT_EQ(v->array[1].string, "\xE2\x82\xAC");
  EXPECT_EQ(v->array[2].string, "\xC3\xA9x");
  for (const char* bad : {R"(["\u12G4"])", R"(["\u12"])", R"(["\u-123"])", R"(["\uD83D"])",
                          R"(["\uD83Dx"])", R"(["\uD83D\u0041"])", R"(["\uDE00"])"}) {
    auto r = io::parse_json(bad);
    ASSERT_FALSE(r.ok()) << bad;
    EXPECT_TRUE(contains(r.status().message(), "\\u escape")) << r.status().message();
  }
}

TEST(Npy, ParsesHeaderAndRejectsTruncation) {
  const std::string bytes = npy_bytes({1, 2, 3, 4, 5, 6}, 2, 3);
  auto a = io::parse_npy(bytes, "x.npy");
  ASSERT_TRUE(a.ok()) << a.status().message();
  EXPECT_EQ(a->shape, (std::vector<int64_t>{2, 3}));
  EXPECT_EQ(a->data[5], 6.0);
  auto cut = io::parse_npy(bytes.substr(0, bytes.size() - 1), "x.npy");
  ASSERT_FALSE(cut.ok());
  EXPECT_TRUE(contains(cut.status().message(), "x.npy") &&
              contains(cut.status().message(), "truncated"));
  EXPECT_FALSE(io::parse_npy("garbage", "x.npy").ok());
  std::string f4 = bytes;
  f4.replace(f4.find("<f8"), 3, "<i8");
  EXPECT_FALSE(io::parse_npy(f4, "x.npy").ok());
  // A shape whose byte count overflows size_t (2^61 · 8 = 2^64 wraps to 0).
  std::string huge = bytes;
  huge.replace(huge.find("(2, 3)"), 6, "(2305843009213693952,)");
  auto h = io::parse_npy(huge, "x.npy");
  ASSERT_FALSE(h.ok());
  EXPECT_TRUE(contains(h.status().message(), "too large")) << h.status().message();
}

class Llff : public ::testing::Test {
 protected:
  void SetUp() override {
    root_ = test::fresh_dir();
    fs::create_directories(root_ / "images");
    for (int i = 0; i < 2; ++i) {
      rot_[i] =
          Eigen::AngleAxisd(0.3 + i, Eigen::Vector3d(1, 2, 3).normalized()).toRotationMatrix();
      center_[i] = Eigen::Vector3d(1, -2, 0.5 + i);
      ASSERT_TRUE(save_png(test::random_image(32, 24, 3, unsigned(i)),
                           (root_ / "images" / ("im" + std::to_string(i) + ".png")).string())
                      .ok());
    }
    write(2);
  }
  // LLFF rows: 3x5 [down | right | back | centre | (H, W, f)] flattened, then near, far.
  void write(int rows) {
    std::vector<double> d;
    for (int i = 0; i < rows; ++i) {
      Eigen::Matrix<double, 3, 5> m;
      m.col(0) = rot_[i].col(1);
      m.col(1) = rot_[i].col(0);
      m.col(2) = -rot_[i].col(2);
      m.col(3) = center_[i];
      m.col(4) = Eigen::Vector3d(48, 64, 40);
      for (int r = 0; r < 3; ++r)
        for (int c = 0; c < 5; ++c) d.push_back(m(r, c));
      d.push_back(0.5);
      d.push_back(10);
    }
    test::write_bytes(root_ / "poses_bounds.npy", npy_bytes(d, rows, 17));
  }
  fs::path root_;
  Eigen::Matrix3d rot_[2];
  Eigen::Vector3d center_[2];
};

TEST_F(Llff, AxesConvertedAndHwfRescaled) {
  DatasetOptions o;
  o.path = root_.string();
  o.test_every = 0;
  auto ds = load_dataset(o);
  ASSERT_TRUE(ds.ok()) << ds.status().message();
  EXPECT_EQ(ds->format, "llff");
  ASSERT_EQ(ds->train.size(), 2u);
  for (int i = 0; i < 2; ++i) {
    const Camera& c = ds->train[size_t(i)].camera;
    EXPECT_LT((c.R - rot_[i].transpose()).norm(), 1e-12);
    EXPECT_LT((c.center() - center_[i]).norm(), 1e-12);
    EXPECT_DOUBLE_EQ(c.fx, 20.0);  // 40 at 64 px wide -> 32 px
    EXPECT_DOUBLE_EQ(c.cx, 16.0);
    EXPECT_DOUBLE_EQ(c.cy, 12.0);
    // A point 1 unit ahead, 0.2 right and 0.1 down of the camera.
    double z = 0;
    const Eigen::Vector2d p = project(c, center_[i] + rot_[i] * Eigen::Vector3d(0.2, 0.1, 1), &z);
    EXPECT_NEAR(p.x(), 20.0, 1e-9);
    EXPECT_NEAR(p.y(), 14.0, 1e-9);
    EXPECT_NEAR(z, 1.0, 1e-12);
  }
  bool warned = false;
  for (const auto& w : ds->warnings) warned |= contains(w, "no points3D");
  EXPECT_TRUE(warned);
}

TEST_F(Llff, PoseCountMismatchAndTruncationAreErrors) {
  write(1);
  DatasetOptions o;
  o.path = root_.string();
  auto ds = load_dataset(o);
  ASSERT_FALSE(ds.ok());
  EXPECT_TRUE(contains(ds.status().message(), "1 poses but")) << ds.status().message();
  const std::string bytes = test::read_bytes(root_ / "poses_bounds.npy");
  test::write_bytes(root_ / "poses_bounds.npy", bytes.substr(0, bytes.size() - 8));
  ds = load_dataset(o);
  ASSERT_FALSE(ds.ok());
  EXPECT_TRUE(contains(ds.status().message(), "poses_bounds.npy")) << ds.status().message();
}

TEST(InstantNgp, NonFiniteIntrinsicsAndAbsurdSizesAreRefused) {
  const fs::path root = test::fresh_dir();
  ASSERT_TRUE(save_png(test::random_image(32, 24, 3, 1), (root / "f0.png").string()).ok());
  const std::string frame =
      "\"frames\": [{\"file_path\": \"f0.png\", \"transform_matrix\": "
      "[[1,0,0,0],[0,1,0,0],[0,0,1,0],[0,0,0,1]]}]}";
  DatasetOptions o;
  o.path = root.string();
  o.test_every = 0;
  // camera_angle_x = 0: fx = 16 / tan(0) = inf.
  test::write_bytes(root / "transforms.json", "{\"camera_angle_x\": 0, " + frame);
  auto ds = load_dataset(o);
  ASSERT_FALSE(ds.ok());
  EXPECT_TRUE(contains(ds.status().message(), "not finite")) << ds.status().message();
  test::write_bytes(root / "transforms.json", "{\"fl_x\": 30, \"w\": 1e12, \"h\": 24, " + frame);
  ds = load_dataset(o);
  ASSERT_FALSE(ds.ok());
  EXPECT_TRUE(contains(ds.status().message(), "bad camera size")) << ds.status().message();
  test::write_bytes(root / "transforms.json", "{\"fl_x\": 30, " + frame);
  ds = load_dataset(o);
  EXPECT_TRUE(ds.ok()) << ds.status().message();
}

TEST(InstantNgp, IntrinsicsFromFieldsOpenGlConvertedAndEveryEighthIsTest) {
  const fs::path root = test::fresh_dir();
  std::string frames;
  for (int i = 8; i >= 0; --i) {  // reverse order on purpose: views are sorted by name
    const std::string name = "images/f" + std::to_string(i) + ".png";
    ASSERT_TRUE(save_png(test::random_image(32, 24, 3, unsigned(i)), (root / name).string()).ok());
    frames += std::string(frames.empty() ? "" : ",") + "\n\t{\"file_path\": \"" + name +
              "\", \"transform_matrix\": [[1,0,0," + std::to_string(i) +
              "],[0,1,0,0],[0,0,1,0],[0,0,0,1]]}";
  }
  test::write_bytes(root / "transforms.json",
                    "{\"fl_x\": 30, \"fl_y\": 31, \"cx\": 15, \"cy\": 11, \"w\": 32, "
                    "\"h\": 24, \"k1\": 0.1, \"frames\": [" +
                        frames + "]}");
  DatasetOptions o;
  o.path = root.string();
  auto ds = load_dataset(o);
  ASSERT_TRUE(ds.ok()) << ds.status().message();
  EXPECT_EQ(ds->format, "instant_ngp");
  ASSERT_EQ(ds->test.size(), 2u);  // f0 and f8 (sorted by name: f0..f8)
  ASSERT_EQ(ds->train.size(), 7u);
  EXPECT_EQ(ds->test[0].camera.name, "f0.png");
  EXPECT_EQ(ds->test[1].camera.name, "f8.png");
  // OpenGL camera at the origin looking down -z, y up: (0.5, 0.5, -2) is right and *up*.
  const Camera& c = ds->test[0].camera;
  double z = 0;
  const Eigen::Vector2d p = project(c, Eigen::Vector3d(0.5, 0.5, -2), &z);
  EXPECT_NEAR(z, 2.0, 1e-12);
  EXPECT_NEAR(p.x(), 15 + 30 * 0.25, 1e-9);
  EXPECT_NEAR(p.y(), 11 - 31 * 0.25, 1e-9);
  EXPECT_LT((ds->test[1].camera.center() - Eigen::Vector3d(8, 0, 0)).norm(), 1e-12);
  ASSERT_FALSE(ds->warnings.empty());
  EXPECT_TRUE(contains(ds->warnings[0], "k1=")) << ds->warnings[0];
}

// nerfstudio's transforms.json: its split lists (test from val when test is empty; frames in no
// list are left out), its initial points (ply_file_path, read by draco's PLY reader) and its
// camera model (pinhole ones only).
TEST(Nerfstudio, SplitListsInitialPointsAndCameraModel) {
  const fs::path root = test::fresh_dir();
  std::string frames;
  for (int i = 0; i < 6; ++i) {
    const std::string name = "images/frame_" + std::to_string(i) + ".png";
    ASSERT_TRUE(save_png(test::random_image(32, 24, 3, unsigned(i)), (root / name).string()).ok());
    frames += std::string(frames.empty() ? "" : ",") + "{\"file_path\": \"" + name +
              "\", \"transform_matrix\": [[1,0,0," + std::to_string(i) +
              "],[0,1,0,0],[0,0,1,0],[0,0,0,1]]}";
  }
  test::write_bytes(root / "sparse_pc.ply",
                    "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float "
                    "y\nproperty float z\nproperty uchar red\nproperty uchar green\nproperty "
                    "uchar blue\nend_header\n0 0 -1 255 0 0\n1 0 -2 0 255 0\n0 1 -3 0 0 255\n");
  auto write = [&](const std::string& model, const std::string& lists) {
    test::write_bytes(root / "transforms.json",
                      "{\"camera_model\": \"" + model +
                          "\", \"fl_x\": 30, \"fl_y\": 30, \"cx\": 16, \"cy\": 12, \"w\": 32, "
                          "\"h\": 24, \"k1\": 0.01, \"ply_file_path\": \"sparse_pc.ply\", " +
                          lists + "\"frames\": [" + frames + "]}");
  };
  write("OPENCV",
        "\"train_filenames\": [\"images/frame_0.png\", \"images/frame_1.png\", "
        "\"images/frame_2.png\", \"images/frame_3.png\"], \"val_filenames\": "
        "[\"images/frame_4.png\"], \"test_filenames\": [], ");
  DatasetOptions o;
  o.path = root.string();
  auto ds = load_dataset(o);
  ASSERT_TRUE(ds.ok()) << ds.status().message();
  ASSERT_EQ(ds->train.size(), 4u);
  ASSERT_EQ(ds->test.size(), 1u);  // val, test_filenames being empty; frame_5 in no list
  EXPECT_EQ(ds->test[0].camera.name, "frame_4.png");
  ASSERT_EQ(ds->points.size(), 3u);
  EXPECT_NEAR(ds->points[2].z(), -3.f, 1e-6);
  ASSERT_EQ(ds->point_colors.size(), 3u);
  EXPECT_NEAR(ds->point_colors[1].y(), 1.f, 1e-6);
  EXPECT_NEAR(ds->point_colors[1].x(), 0.f, 1e-6);
  EXPECT_TRUE(std::any_of(ds->warnings.begin(), ds->warnings.end(),
                          [](const std::string& w) { return contains(w, "k1="); }));

  // Without lists: every eighth frame is a test view, as for instant-ngp.
  write("PINHOLE", "");
  ds = load_dataset(o);
  ASSERT_TRUE(ds.ok()) << ds.status().message();
  EXPECT_EQ(ds->train.size() + ds->test.size(), 6u);

  write("OPENCV_FISHEYE", "");
  ds = load_dataset(o);
  ASSERT_FALSE(ds.ok());
  EXPECT_TRUE(contains(ds.status().message(), "camera_model OPENCV_FISHEYE is not a pinhole"))
      << ds.status().message();
  write("OPENCV", "\"train_filenames\": [\"images/frame_0.png\", \"images/missing.png\"], ");
  ds = load_dataset(o);
  ASSERT_FALSE(ds.ok());
  EXPECT_TRUE(contains(ds.status().message(), "list 2 images, 1 of them among the frames"))
      << ds.status().message();
  std::filesystem::remove(root / "sparse_pc.ply");
  write("OPENCV", "");
  ds = load_dataset(o);
  ASSERT_FALSE(ds.ok());
  EXPECT_TRUE(contains(ds.status().message(), "sparse_pc.ply")) << ds.status().message();
}

TEST(NerfSynthetic, RgbaCompositedFovIntrinsicsAndValAsTestWhenTestImagesAbsent) {
  const fs::path root = test::fresh_dir();
  for (const char* split : {"train", "val"}) {
    Image im = Image::zeros(16, 16, 4);
    for (int y = 0; y < 16; ++y)
      for (int x = 0; x < 16; ++x) {
        im.at(y, x, 0) = 0.2f;
        im.at(y, x, 3) = x < 8 ? 0.f : 1.f;  // left half transparent
      }
    ASSERT_TRUE(save_png(im, (root / split / "r_0.png").string()).ok());
  }
  const std::string frame =
      "{\"file_path\": \"./%s/r_0\", \"transform_matrix\": "
      "[[1,0,0,0],[0,1,0,0],[0,0,1,4],[0,0,0,1]]}";
  for (const char* split : {"train", "val", "test"}) {
    char buf[256];
    std::snprintf(buf, sizeof buf, frame.c_str(), split);
    test::write_bytes(root / (std::string("transforms_") + split + ".json"),
                      std::string("{\"camera_angle_x\": 0.8, \"frames\": [") + buf + "]}");
  }
  DatasetOptions o;
  o.path = root.string();
  o.background = {1, 1, 1};
  auto ds = load_dataset(o);
  ASSERT_TRUE(ds.ok()) << ds.status().message();
  EXPECT_EQ(ds->format, "nerf_synthetic");
  ASSERT_EQ(ds->train.size(), 1u);
  ASSERT_EQ(ds->test.size(), 1u);
  EXPECT_EQ(ds->test[0].index, 1);
  ASSERT_EQ(ds->warnings.size(), 1u);
  EXPECT_TRUE(contains(ds->warnings[0], "val")) << ds->warnings[0];
  const View& v = ds->train[0];
  ASSERT_EQ(v.image.channels, 3);
  EXPECT_FLOAT_EQ(v.image.at(0, 0, 0), 1.f);  // transparent -> background
  EXPECT_NEAR(v.image.at(0, 15, 0), 0.2f, 1e-6);
  EXPECT_NEAR(v.image.at(0, 15, 1), 0.f, 1e-6);
  EXPECT_NEAR(v.camera.fx, 0.5 * 16 / std::tan(0.4), 1e-9);
  EXPECT_NEAR(v.camera.fy, v.camera.fx, 1e-12);
  // Camera at z = 4 looking down -z (OpenGL): the origin projects to the image centre in front.
  double z = 0;
  const Eigen::Vector2d p = project(v.camera, Eigen::Vector3d::Zero(), &z);
  EXPECT_NEAR(z, 4.0, 1e-12);
  EXPECT_NEAR(p.x(), 8.0, 1e-9);
  EXPECT_NEAR(p.y(), 8.0, 1e-9);
  // World +x is image right and world +y (OpenGL up) is image up, i.e. smaller v.
  const Eigen::Vector2d q = project(v.camera, Eigen::Vector3d(1, 1, 0));
  EXPECT_NEAR(q.x(), 8.0 + v.camera.fx / 4, 1e-9);
  EXPECT_NEAR(q.y(), 8.0 - v.camera.fy / 4, 1e-9);
  EXPECT_NEAR(v.camera.R.determinant(), 1.0, 1e-12);

  // Some but not all test images present: an error, not a silent fallback.
  test::write_bytes(
      root / "transforms_test.json",
      "{\"camera_angle_x\": 0.8, \"frames\": [{\"file_path\": \"./val/r_0\", \"transform_matrix\": "
      "[[1,0,0,0],[0,1,0,0],[0,0,1,4],[0,0,0,1]]}, {\"file_path\": \"./test/r_9\", "
      "\"transform_matrix\": [[1,0,0,0],[0,1,0,0],[0,0,1,4],[0,0,0,1]]}]}");
  auto partial = load_dataset(o);
  ASSERT_FALSE(partial.ok());
  EXPECT_TRUE(contains(partial.status().message(), "r_9")) << partial.status().message();
}

}  // namespace
}  // namespace crpgs
