/// @file test_datasets.cpp
/// @brief The shared datasets: fern (COLMAP binary and LLFF) and lego (NeRF-synthetic).
#include <gtest/gtest.h>

#include <Eigen/LU>
#include <cmath>
#include <filesystem>

#include "crpgs/dataset.h"
#include "io_test_util.h"

namespace crpgs {
namespace {

namespace fs = std::filesystem;

bool contains(const std::string& s, const std::string& part) {
  return s.find(part) != std::string::npos;
}

std::vector<const View*> all_views(const Dataset& d) {
  std::vector<const View*> v;
  for (const View& x : d.train) v.push_back(&x);
  for (const View& x : d.test) v.push_back(&x);
  std::sort(v.begin(), v.end(), [](const View* a, const View* b) { return a->index < b->index; });
  return v;
}

class Fern : public ::testing::Test {
 protected:
  void SetUp() override {
    if (!fs::exists(test::shared_data("fern/sparse/0/images.bin")))
      GTEST_SKIP() << "shared dataset fern not found at " << test::shared_data("fern");
  }
  static DatasetOptions options(const std::string& format) {
    DatasetOptions o;
    o.path = test::shared_data("fern");
    o.format = format;
    o.images = "images_8";
    return o;
  }
};

TEST_F(Fern, LoadsAsColmapBinaryWithRescaledIntrinsics) {
  EXPECT_EQ(*detect_dataset_format(test::shared_data("fern")), "colmap");
  auto ds = load_dataset(options("auto"));
  ASSERT_TRUE(ds.ok()) << ds.status().message();
  EXPECT_EQ(ds->format, "colmap");
  EXPECT_EQ(ds->train.size(), 17u);  // 20 views, idx 0, 8, 16 are test
  ASSERT_EQ(ds->test.size(), 3u);
  EXPECT_EQ(ds->test[1].camera.name, "image008.png");
  EXPECT_EQ(ds->test[1].index, 8);
  for (const View* v : all_views(*ds)) {
    EXPECT_EQ(v->image.width, 504);
    EXPECT_EQ(v->image.height, 378);
    EXPECT_EQ(v->image.channels, 3);
    EXPECT_EQ(v->camera.width, 504);
    EXPECT_NEAR(v->camera.fx, 3260.53 / 8, 0.01);
    EXPECT_NEAR(v->camera.fy, 3260.53 / 8, 0.01);
    EXPECT_NEAR(v->camera.cx, 252.0, 1e-9);
    EXPECT_NEAR(v->camera.cy, 189.0, 1e-9);
  }
  EXPECT_EQ(ds->points.size(), 10091u);
  EXPECT_EQ(ds->point_colors.size(), ds->points.size());
  ASSERT_FALSE(ds->warnings.empty());
  EXPECT_TRUE(contains(ds->warnings[0], "SIMPLE_RADIAL") && contains(ds->warnings[0], "k="))
      << ds->warnings[0];
}

TEST_F(Fern, MostSfmPointsProjectIntoEveryViewInFront) {
  DatasetOptions o = options("colmap");
  o.load_images = false;
  auto ds = load_dataset(o);
  ASSERT_TRUE(ds.ok()) << ds.status().message();
  ASSERT_GT(ds->points.size(), 1000u);
  for (const View* v : all_views(*ds)) {
    const Camera& c = v->camera;
    size_t good = 0;
    for (const Eigen::Vector3f& pf : ds->points) {
      const Eigen::Vector3d p = c.R * pf.cast<double>() + c.t;
      if (p.z() <= 0) continue;
      const double u = c.fx * p.x() / p.z() + c.cx, w = c.fy * p.y() / p.z() + c.cy;
      good += u >= 0 && u < c.width && w >= 0 && w < c.height;
    }
    EXPECT_GE(double(good) / ds->points.size(), 0.95) << c.name;
  }
}

TEST_F(Fern, LlffPosesMatchColmapPoses) {
  DatasetOptions oc = options("colmap"), ol = options("llff");
  oc.load_images = ol.load_images = false;
  auto c = load_dataset(oc), l = load_dataset(ol);
  ASSERT_TRUE(c.ok()) << c.status().message();
  ASSERT_TRUE(l.ok()) << l.status().message();
  EXPECT_EQ(l->format, "llff");
  EXPECT_EQ(l->points.size(), c->points.size());  // from sparse/0
  const auto vc = all_views(*c), vl = all_views(*l);
  ASSERT_EQ(vc.size(), 20u);
  ASSERT_EQ(vl.size(), 20u);
  for (size_t i = 0; i < vc.size(); ++i) {
    const Camera &a = vc[i]->camera, &b = vl[i]->camera;
    EXPECT_EQ(a.name, b.name);
    EXPECT_LT((a.center() - b.center()).norm(), 1e-4) << a.name;
    EXPECT_LT((a.R - b.R).norm(), 1e-4) << a.name;
    EXPECT_NEAR(a.fx, b.fx, 0.01);
    EXPECT_NEAR(a.cx, b.cx, 1e-6);
    EXPECT_EQ(b.width, 504);
    EXPECT_NEAR(b.R.determinant(), 1.0, 1e-6) << b.name;
  }
  // The whole trajectory spans something: the check above is not comparing zeros.
  EXPECT_GT((vc.front()->camera.center() - vc.back()->camera.center()).norm(), 0.1);
}

TEST_F(Fern, Images4FolderGivesDoubleIntrinsics) {
  DatasetOptions o = options("colmap");
  o.images = "images_4";
  o.load_images = false;
  auto ds = load_dataset(o);
  ASSERT_TRUE(ds.ok()) << ds.status().message();
  EXPECT_EQ(ds->train[0].camera.width, 1008);
  EXPECT_NEAR(ds->train[0].camera.fx, 3260.53 / 4, 0.01);
}

TEST(Lego, LoadsTrainAndValAsTestWithFovIntrinsics) {
  const std::string root = test::shared_data("lego");
  if (!fs::exists(fs::path(root) / "transforms_train.json"))
    GTEST_SKIP() << "shared dataset lego not found at " << root;
  // All 200 cameras from the image headers (decoding 200 800x800 RGBA PNGs takes seconds).
  DatasetOptions o;
  o.path = root;
  o.downscale = 4;  // 200x200
  o.background = {1, 1, 1};
  o.load_images = false;
  auto ds = load_dataset(o);
  ASSERT_TRUE(ds.ok()) << ds.status().message();
  EXPECT_EQ(ds->format, "nerf_synthetic");
  EXPECT_EQ(ds->train.size(), 100u);
  EXPECT_EQ(ds->test.size(), 100u);
  bool warned = false;
  for (const auto& w : ds->warnings) warned |= contains(w, "val views as the test split");
  EXPECT_TRUE(warned);
  EXPECT_TRUE(ds->points.empty());
  EXPECT_EQ(ds->train[0].camera.name, "r_0.png");
  EXPECT_EQ(ds->test[0].camera.name, "r_0.png");
  EXPECT_EQ(ds->test[0].index, 100);
  const double angle = 0.6911112070083618;
  for (const View* v : all_views(*ds)) {
    const Camera& c = v->camera;
    EXPECT_EQ(c.width, 200);
    EXPECT_NEAR(c.fx, 0.5 * 200 / std::tan(0.5 * angle), 1e-6);
    EXPECT_NEAR(c.cx, 100.0, 1e-9);
    EXPECT_NEAR(c.center().norm(), 4.0311, 1e-3);
    // A proper rotation (a wrong axis flip would give a reflection, det = -1).
    EXPECT_NEAR(c.R.determinant(), 1.0, 1e-5) << c.name;
    EXPECT_LT((c.R * c.R.transpose() - Eigen::Matrix3d::Identity()).norm(), 1e-5) << c.name;
    // Every camera looks at the object at the origin: it projects near the image centre.
    const Eigen::Vector3d p = c.t;  // R·0 + t
    ASSERT_GT(p.z(), 0) << c.name;
    EXPECT_NEAR(c.fx * p.x() / p.z() + c.cx, 100, 20) << c.name;
    EXPECT_NEAR(c.fy * p.y() / p.z() + c.cy, 100, 20) << c.name;
  }

  // Pixels of a few views per split: RGBA composited onto the white background.
  o.load_images = true;
  o.max_images = 3;
  auto px = load_dataset(o);
  ASSERT_TRUE(px.ok()) << px.status().message();
  ASSERT_EQ(px->train.size(), 3u);
  ASSERT_EQ(px->test.size(), 3u);
  for (const View* v : all_views(*px)) {
    ASSERT_EQ(v->image.width, 200);
    ASSERT_EQ(v->image.channels, 3);
    EXPECT_NEAR(v->image.at(0, 0, 0), 1.f, 1e-6);  // transparent corner
    double mean = 0;
    for (float x : v->image.pixels) mean += x;
    EXPECT_LT(mean / v->image.pixels.size(), 0.95);  // the object is there, not all background
  }
  EXPECT_EQ(px->train[2].camera.name, ds->train[2].camera.name);
  EXPECT_DOUBLE_EQ(px->train[2].camera.fx, ds->train[2].camera.fx);

  o.downscale = 1;
  o.load_images = false;
  o.max_images = 0;
  auto full = load_dataset(o);
  ASSERT_TRUE(full.ok());
  EXPECT_NEAR(full->train[5].camera.fx, 0.5 * 800 / std::tan(0.5 * angle), 1e-6);
  EXPECT_NEAR(full->train[5].camera.fx, 1111.1111, 1e-3);
}

}  // namespace
}  // namespace crpgs
