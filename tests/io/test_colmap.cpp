/// @file test_colmap.cpp
/// @brief COLMAP loading on small synthetic models: exact projection, text/binary round trip,
/// split, downscaling, and the bad-dataset errors.
#include <gtest/gtest.h>

#include <Eigen/Geometry>
#include <cstring>
#include <filesystem>

#include "cli_output.h"
#include "crpgs/dataset.h"
#include "crpgs/ply.h"
#include "io/colmap.h"
#include "io_test_util.h"

namespace crpgs {
namespace {

namespace fs = std::filesystem;

bool contains(const std::string& s, const std::string& part) {
  return s.find(part) != std::string::npos;
}

Eigen::Vector2d project(const Camera& c, const Eigen::Vector3d& x) {
  const Eigen::Vector3d p = c.R * x + c.t;
  return {c.fx * p.x() / p.z() + c.cx, c.fy * p.y() / p.z() + c.cy};
}

void write_images(const fs::path& dir, const std::vector<std::string>& names, int w, int h) {
  for (size_t i = 0; i < names.size(); ++i)
    ASSERT_TRUE(save_png(test::random_image(w, h, 3, unsigned(i)), (dir / names[i]).string()).ok());
}

// Three images (names deliberately unsorted), PINHOLE and SIMPLE_RADIAL cameras, two points.
io::ColmapModel synthetic_model() {
  io::ColmapModel m;
  m.cameras[1] = {1, 1, 64, 48, {50, 52, 31.5, 24.25}};
  m.cameras[2] = {2, 2, 64, 48, {55, 32, 24, 0.05}};
  const char* names[] = {"c.png", "a.png", "b.png"};
  for (int i = 0; i < 3; ++i) {
    io::ColmapImage im;
    im.id = i + 1;
    const Eigen::Quaterniond q(
        Eigen::AngleAxisd(0.1 * i, Eigen::Vector3d(0.3, 1, 0.2).normalized()));
    im.qvec = {q.w(), q.x(), q.y(), q.z()};
    im.tvec = {0.1 * i, -0.2, 2 + 0.1 * i};
    im.camera_id = i == 2 ? 2 : 1;
    im.name = names[i];
    m.images.push_back(im);
  }
  m.has_points_file = true;
  m.points.push_back({7, {0.1, 0.2, 0.3}, {255, 0, 51}, 0.5, {{1, 0}, {2, 0}}});
  m.points.push_back({9, {-0.1, 0.0, 0.5}, {0, 255, 0}, 0.25, {{3, 1}}});
  return m;
}

StatusOr<Dataset> load(const fs::path& root, DatasetOptions o = {}) {
  o.path = root.string();
  return load_dataset(o);
}

// A hand-written text model in root/sparse/0.
void write_text_model(const fs::path& root, const std::string& cameras, const std::string& images) {
  fs::create_directories(root / "sparse" / "0");
  test::write_bytes(root / "sparse/0/cameras.txt", cameras);
  test::write_bytes(root / "sparse/0/images.txt", images);
}

TEST(Colmap, HandWrittenTextModelProjectsToTheKnownPixel) {
  const fs::path root = test::fresh_dir();
  // Image 1: identity rotation, t = (0.1, -0.2, 2). Image 2: 90° about y (qw = qy = √½), t =
  // (0,0,2).
  write_text_model(root, "# comment\n1 PINHOLE 64 48 50 52 31.5 24.25\n",
                   "# IMAGE_ID QW QX QY QZ TX TY TZ CAMERA_ID NAME\n"
                   "1 1 0 0 0 0.1 -0.2 2 1 one.png\n"
                   "\n"
                   "2 0.70710678118654752 0 0.70710678118654752 0 0 0 2 1 two.png\n"
                   "10 20 1\n");
  test::write_bytes(root / "sparse/0/points3D.txt", "1 0.3 0.4 1.0 255 128 0 0.1 2 0\n");
  fs::create_directories(root / "images");
  write_images(root / "images", {"one.png", "two.png"}, 64, 48);
  DatasetOptions o;
  o.test_every = 0;
  auto ds = load(root, o);
  ASSERT_TRUE(ds.ok()) << ds.status().message();
  ASSERT_EQ(ds->train.size(), 2u);
  ASSERT_EQ(ds->points.size(), 1u);
  EXPECT_NEAR(ds->point_colors[0].y(), 128 / 255.f, 1e-6);
  const Eigen::Vector3d X = ds->points[0].cast<double>();
  // By hand: cam = (0.4, 0.2, 3) -> u = 50·0.4/3 + 31.5, v = 52·0.2/3 + 24.25.
  const Eigen::Vector2d p1 = project(ds->train[0].camera, X);
  EXPECT_NEAR(p1.x(), 38.1666667, 1e-5);
  EXPECT_NEAR(p1.y(), 27.7166667, 1e-5);
  // R_y(90°) X = (1.0, 0.4, -0.3) + t -> (1, 0.4, 1.7): u = 50/1.7 + 31.5, v = 52·0.4/1.7 + 24.25.
  const Eigen::Vector2d p2 = project(ds->train[1].camera, X);
  EXPECT_NEAR(p2.x(), 60.9117647, 1e-5);
  EXPECT_NEAR(p2.y(), 36.4852941, 1e-5);
  // The keypoint line of image 2 is kept by the reader.
  auto model = io::read_colmap_text((root / "sparse/0").string());
  ASSERT_TRUE(model.ok());
  ASSERT_EQ(model->images[1].xys.size(), 1u);
  EXPECT_EQ(model->images[1].point3d_ids[0], 1);
  EXPECT_TRUE(model->images[0].xys.empty());

  // Downscaled by 2 on load: the same point lands on half the pixel coordinate, within 1 px.
  o.downscale = 2;
  auto half = load(root, o);
  ASSERT_TRUE(half.ok());
  EXPECT_EQ(half->train[0].image.width, 32);
  EXPECT_EQ(half->train[0].image.height, 24);
  const Eigen::Vector2d q1 = project(half->train[0].camera, X);
  EXPECT_NEAR(q1.x(), 38.1666667 / 2, 1e-5);
  EXPECT_NEAR(q1.y(), 27.7166667 / 2, 1e-5);
}

TEST(Colmap, TextModelsWithoutPointsLinesOrWithAbsurdSizesAreRefused) {
  const fs::path root = test::fresh_dir();
  // No POINTS2D line after each image line: every other image would be read as keypoints.
  write_text_model(root, "1 PINHOLE 64 48 50 52 31.5 24.25\n",
                   "1 1 0 0 0 0.1 -0.2 2 1 one.png\n"
                   "2 1 0 0 0 0.2 -0.2 2 1 two.png\n");
  auto m = io::read_colmap_text((root / "sparse/0").string());
  ASSERT_FALSE(m.ok());
  EXPECT_TRUE(contains(m.status().message(), "POINTS2D line")) << m.status().message();
  // A width beyond int: it used to wrap to 640.
  write_text_model(root, "1 PINHOLE 4294967936 48 50 52 31.5 24.25\n",
                   "1 1 0 0 0 0.1 -0.2 2 1 one.png\n\n");
  fs::create_directories(root / "images");
  write_images(root / "images", {"one.png"}, 64, 48);
  auto ds = load(root);
  ASSERT_FALSE(ds.ok());
  EXPECT_TRUE(contains(ds.status().message(), "4294967936x48")) << ds.status().message();
}

// The dataset's warnings reach the user: `crpgs import` (any command that loads a dataset)
// prints them. synthetic_model's camera 2 is SIMPLE_RADIAL, whose k is ignored.
TEST(Colmap, TheCliPrintsTheDatasetsWarnings) {
#ifndef CRPGS_CLI_PATH
  GTEST_SKIP() << "this build has no crpgs executable";
#else
  const fs::path root = test::fresh_dir();
  fs::create_directories(root / "sparse/0");
  ASSERT_TRUE(io::write_colmap_binary(synthetic_model(), (root / "sparse/0").string()).ok());
  write_images(root / "images", {"a.png", "b.png", "c.png"}, 16, 12);
  PlyGaussians g;
  g.means = {0, 0, 2};
  g.sh_dc = {0.1f, 0.2f, 0.3f};
  g.opacity = {0};
  g.log_scales = {-2, -2, -2};
  g.rotations = {1, 0, 0, 0};
  ASSERT_TRUE(write_ply((root / "one.ply").string(), g).ok());
  test::write_bytes(root / "cfg.yaml", "dataset: {path: '" + root.string() +
                                           "', format: colmap, test_every: 2}\n"
                                           "train: {threads: 1}\n");
  int rc = -1;
  const std::string out = test::crpgs_output(
      "import '" + (root / "one.ply").string() + "' -c '" + (root / "cfg.yaml").string() + "'",
      &rc);
  EXPECT_EQ(rc, 0) << out;
  EXPECT_TRUE(contains(out, "warning: camera 2 (SIMPLE_RADIAL): distortion ignored")) << out;
#endif
}

TEST(Colmap, TextAndBinaryWritersRoundTripToTheSameCameras) {
  const io::ColmapModel m = synthetic_model();
  const fs::path bin = test::fresh_dir("_bin"), txt = test::fresh_dir("_txt");
  for (const fs::path& root : {bin, txt}) {
    fs::create_directories(root / "sparse" / "0");
    fs::create_directories(root / "images");
    write_images(root / "images", {"a.png", "b.png", "c.png"}, 64, 48);
  }
  ASSERT_TRUE(io::write_colmap_binary(m, (bin / "sparse/0").string()).ok());
  ASSERT_TRUE(io::write_colmap_text(m, (txt / "sparse/0").string()).ok());
  EXPECT_TRUE(fs::exists(bin / "sparse/0/images.bin"));
  EXPECT_TRUE(fs::exists(txt / "sparse/0/images.txt"));

  // Readers give the written model back.
  for (auto rd : {io::read_colmap_binary((bin / "sparse/0").string()),
                  io::read_colmap_text((txt / "sparse/0").string())}) {
    ASSERT_TRUE(rd.ok()) << rd.status().message();
    ASSERT_EQ(rd->images.size(), 3u);
    ASSERT_EQ(rd->cameras.size(), 2u);
    EXPECT_EQ(rd->cameras.at(2).params, m.cameras.at(2).params);
    for (size_t i = 0; i < 3; ++i) {
      EXPECT_EQ(rd->images[i].name, m.images[i].name);
      EXPECT_EQ(rd->images[i].qvec, m.images[i].qvec);
      EXPECT_EQ(rd->images[i].tvec, m.images[i].tvec);
    }
    ASSERT_EQ(rd->points.size(), 2u);
    EXPECT_EQ(rd->points[1].track, m.points[1].track);
    EXPECT_EQ(rd->points[0].rgb, m.points[0].rgb);
  }

  DatasetOptions o;
  o.test_every = 2;
  auto a = load(bin, o), b = load(txt, o);
  ASSERT_TRUE(a.ok()) << a.status().message();
  ASSERT_TRUE(b.ok()) << b.status().message();
  ASSERT_EQ(a->train.size(), 1u);
  ASSERT_EQ(a->test.size(), 2u);
  // Sorted by name: a (test, idx 0), b (train, idx 1), c (test, idx 2).
  EXPECT_EQ(a->test[0].camera.name, "a.png");
  EXPECT_EQ(a->train[0].camera.name, "b.png");
  EXPECT_EQ(a->test[1].camera.name, "c.png");
  EXPECT_EQ(a->train[0].index, 1);
  EXPECT_EQ(a->test[1].index, 2);
  for (size_t i = 0; i < 2; ++i) {
    const Camera &x = a->test[i].camera, &y = b->test[i].camera;
    EXPECT_EQ(x.name, y.name);
    EXPECT_DOUBLE_EQ(x.fx, y.fx);
    EXPECT_DOUBLE_EQ(x.cy, y.cy);
    EXPECT_LT((x.R - y.R).norm(), 1e-15);
    EXPECT_LT((x.t - y.t).norm(), 1e-15);
  }
  // b.png uses the SIMPLE_RADIAL camera: f for both axes, and a warning naming k.
  EXPECT_DOUBLE_EQ(a->train[0].camera.fx, 55);
  EXPECT_DOUBLE_EQ(a->train[0].camera.fy, 55);
  ASSERT_EQ(a->warnings.size(), 1u);
  EXPECT_TRUE(contains(a->warnings[0], "SIMPLE_RADIAL") && contains(a->warnings[0], "k=0.05"))
      << a->warnings[0];
  EXPECT_EQ(a->points.size(), 2u);
  EXPECT_EQ(a->format, "colmap");
}

TEST(Colmap, DownscaleMaxWidthAndMaxImagesRescaleIntrinsics) {
  const fs::path root = test::fresh_dir();
  fs::create_directories(root / "sparse/0");
  ASSERT_TRUE(io::write_colmap_binary(synthetic_model(), (root / "sparse/0").string()).ok());
  write_images(root / "images", {"a.png", "b.png", "c.png"}, 64, 48);
  DatasetOptions o;
  o.test_every = 0;
  o.downscale = 5;  // 12.8 x 9.6 -> 13 x 10 via area resize
  auto d = load(root, o);
  ASSERT_TRUE(d.ok()) << d.status().message();
  const View& v = d->train[2];  // c.png, camera 1
  EXPECT_EQ(v.image.width, 13);
  EXPECT_EQ(v.image.height, 10);
  EXPECT_EQ(v.camera.width, 13);
  EXPECT_DOUBLE_EQ(v.camera.fx, 50.0 * 13 / 64);
  EXPECT_DOUBLE_EQ(v.camera.cy, 24.25 * 10 / 48);

  o.downscale = 2;
  o.max_width = 16;  // 32 -> 16
  o.max_images = 2;
  auto m = load(root, o);
  ASSERT_TRUE(m.ok());
  ASSERT_EQ(m->train.size(), 2u);
  EXPECT_EQ(m->train[0].image.width, 16);
  EXPECT_EQ(m->train[0].image.height, 12);
  EXPECT_DOUBLE_EQ(m->train[1].camera.fx, 55.0 / 4);

  // Cameras only: same intrinsics, no pixels.
  o.load_images = false;
  auto c = load(root, o);
  ASSERT_TRUE(c.ok());
  EXPECT_TRUE(c->train[0].image.empty());
  EXPECT_EQ(c->train[0].camera.width, 16);
  EXPECT_DOUBLE_EQ(c->train[1].camera.fx, 55.0 / 4);
}

class ColmapErrors : public ::testing::Test {
 protected:
  void SetUp() override {
    root_ = test::fresh_dir();
    fs::create_directories(root_ / "sparse/0");
    ASSERT_TRUE(io::write_colmap_binary(synthetic_model(), model_dir()).ok());
    write_images(root_ / "images", {"a.png", "b.png", "c.png"}, 16, 12);
  }
  std::string model_dir() const { return (root_ / "sparse/0").string(); }
  fs::path root_;
};

TEST_F(ColmapErrors, MissingImageNamesThePath) {
  fs::remove(root_ / "images/b.png");
  auto ds = load(root_);
  ASSERT_FALSE(ds.ok());
  EXPECT_EQ(ds.status().code(), StatusCode::kNotFound);
  EXPECT_TRUE(contains(ds.status().message(), "b.png")) << ds.status().message();
  EXPECT_TRUE(contains(ds.status().message(), "images.bin")) << ds.status().message();
}

TEST_F(ColmapErrors, ImagesBinReferencingMoreImagesThanOnDisk) {
  io::ColmapModel m = synthetic_model();
  io::ColmapImage ghost = m.images[0];
  ghost.id = 4;
  ghost.name = "ghost.png";
  m.images.push_back(ghost);
  ASSERT_TRUE(io::write_colmap_binary(m, model_dir()).ok());
  auto ds = load(root_);
  ASSERT_FALSE(ds.ok());
  EXPECT_TRUE(contains(ds.status().message(), "lists 4 images but 1 are missing"))
      << ds.status().message();
  EXPECT_TRUE(contains(ds.status().message(), "ghost.png"));
}

TEST_F(ColmapErrors, ImageReferencingUnknownCamera) {
  io::ColmapModel m = synthetic_model();
  m.images[1].camera_id = 42;
  ASSERT_TRUE(io::write_colmap_binary(m, model_dir()).ok());
  auto ds = load(root_);
  ASSERT_FALSE(ds.ok());
  EXPECT_TRUE(contains(ds.status().message(), "camera 42")) << ds.status().message();
}

TEST_F(ColmapErrors, CorruptPngNamesThePath) {
  test::write_bytes(root_ / "images/c.png", "not a png at all");
  auto ds = load(root_);
  ASSERT_FALSE(ds.ok());
  EXPECT_EQ(ds.status().code(), StatusCode::kIoError);
  EXPECT_TRUE(contains(ds.status().message(), "c.png")) << ds.status().message();
}

TEST_F(ColmapErrors, EveryTruncationOfEachBinaryFileIsReported) {
  for (const char* name : {"cameras.bin", "images.bin", "points3D.bin"}) {
    const fs::path file = root_ / "sparse/0" / name;
    const std::string full = test::read_bytes(file);
    for (size_t len = 0; len < full.size(); ++len) {
      test::write_bytes(file, full.substr(0, len));
      auto m = io::read_colmap_binary(model_dir());
      ASSERT_FALSE(m.ok()) << name << " cut to " << len << " bytes was accepted";
      EXPECT_EQ(m.status().code(), StatusCode::kIoError);
      EXPECT_TRUE(contains(m.status().message(), name)) << m.status().message();
    }
    test::write_bytes(file, full.substr(0, full.size() / 2));
    auto ds = load(root_);
    ASSERT_FALSE(ds.ok());
    EXPECT_TRUE(contains(ds.status().message(), "truncated")) << ds.status().message();
    test::write_bytes(file, full);
  }
  EXPECT_TRUE(load(root_).ok());
}

TEST_F(ColmapErrors, HugeCountInCorruptHeaderIsRejectedNotAllocated) {
  std::string bytes = test::read_bytes(root_ / "sparse/0/points3D.bin");
  const uint64_t huge = uint64_t(1) << 60;
  std::memcpy(&bytes[0], &huge, 8);
  test::write_bytes(root_ / "sparse/0/points3D.bin", bytes);
  auto m = io::read_colmap_binary(model_dir());
  ASSERT_FALSE(m.ok());
  EXPECT_TRUE(contains(m.status().message(), "points3D.bin"));
}

TEST_F(ColmapErrors, EmptyOrMissingPoints3DGivesNoPointsAndAWarning) {
  io::ColmapModel m = synthetic_model();
  m.points.clear();
  ASSERT_TRUE(io::write_colmap_binary(m, model_dir()).ok());
  auto ds = load(root_);
  ASSERT_TRUE(ds.ok()) << ds.status().message();
  EXPECT_TRUE(ds->points.empty());
  bool warned = false;
  for (const auto& w : ds->warnings) warned |= contains(w, "points3D.bin is empty");
  EXPECT_TRUE(warned);
  fs::remove(root_ / "sparse/0/points3D.bin");
  auto none = load(root_);
  ASSERT_TRUE(none.ok());
  EXPECT_TRUE(none->points.empty());
  warned = false;
  for (const auto& w : none->warnings) warned |= contains(w, "does not exist");
  EXPECT_TRUE(warned);
}

TEST_F(ColmapErrors, UnsupportedCameraModelIsRejected) {
  io::ColmapModel m = synthetic_model();
  m.cameras[1] = {1, 5, 16, 12, {10, 10, 8, 6, 0.1, 0, 0, 0}};  // OPENCV_FISHEYE
  ASSERT_TRUE(io::write_colmap_binary(m, model_dir()).ok());
  auto ds = load(root_);
  ASSERT_FALSE(ds.ok());
  EXPECT_EQ(ds.status().code(), StatusCode::kInvalidArgument);
  EXPECT_TRUE(contains(ds.status().message(), "OPENCV_FISHEYE")) << ds.status().message();
}

TEST_F(ColmapErrors, WrongAspectRatioImageIsRejected) {
  ASSERT_TRUE(save_png(test::random_image(16, 16, 3, 0), (root_ / "images/a.png").string()).ok());
  auto ds = load(root_);
  ASSERT_FALSE(ds.ok());
  EXPECT_TRUE(contains(ds.status().message(), "aspect")) << ds.status().message();
}

TEST(DatasetFormat, UnknownFormatAndMissingPathAreClear) {
  const fs::path root = test::fresh_dir();
  auto ds = load(root);
  ASSERT_FALSE(ds.ok());
  EXPECT_TRUE(contains(ds.status().message(), "accepted formats")) << ds.status().message();
  EXPECT_TRUE(contains(ds.status().message(), "poses_bounds.npy"));
  DatasetOptions o;
  o.format = "blender";
  auto bad = load(root, o);
  ASSERT_FALSE(bad.ok());
  EXPECT_EQ(bad.status().code(), StatusCode::kInvalidArgument);
  EXPECT_FALSE(load(root / "nowhere").ok());
  o.format = "auto";
  o.downscale = 0;
  EXPECT_EQ(load(root, o).status().code(), StatusCode::kInvalidArgument);
}

TEST(DatasetFormat, MissingImageFolderListsCandidates) {
  const fs::path root = test::fresh_dir();
  fs::create_directories(root / "sparse/0");
  ASSERT_TRUE(io::write_colmap_binary(synthetic_model(), (root / "sparse/0").string()).ok());
  write_images(root / "images_2", {"a.png", "b.png", "c.png"}, 32, 24);
  auto ds = load(root);
  ASSERT_FALSE(ds.ok());
  EXPECT_TRUE(contains(ds.status().message(), "images_2")) << ds.status().message();
  DatasetOptions o;
  o.images = "images_2";
  auto ok = load(root, o);
  ASSERT_TRUE(ok.ok()) << ok.status().message();
  EXPECT_DOUBLE_EQ(ok->train[0].camera.fx, 55.0 / 2);  // b.png, SIMPLE_RADIAL f = 55 at 64 px
}

}  // namespace
}  // namespace crpgs
