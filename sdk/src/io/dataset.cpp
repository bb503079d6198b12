/// @file dataset.cpp
/// @brief load_dataset: format detection, the four loaders, split, parallel image decoding.
#include "crpgs/dataset.h"

#include <algorithm>
#include <atomic>
#include <cmath>
#include <filesystem>
#include <limits>
#include <set>
#include <thread>

#include <draco/io/ply_decoder.h>
#include <draco/point_cloud/point_cloud.h>
#include <Eigen/Geometry>

#include "io/colmap.h"
#include "io/json.h"
#include "io/npy.h"

namespace crpgs {
namespace fs = std::filesystem;
namespace {

constexpr double kNone = std::numeric_limits<double>::quiet_NaN();

// A view before its image is read. Intrinsics are either complete (`camera` at its native size)
// or given as transforms.json fields resolved against the image size once it is known.
struct Pending {
  Camera camera;
  bool intrinsics_known = false;
  double fl_x = kNone, fl_y = kNone, cx = kNone, cy = kNone, w = kNone, h = kNone;
  double angle_x = kNone, angle_y = kNone;
  std::string path;
  bool test = false;
};

struct Loaded {
  std::vector<Pending> views;  // final order (index = position)
  std::vector<Eigen::Vector3f> points, colors;
};

bool path_exists(const fs::path& p) {
  std::error_code ec;
  return fs::exists(p, ec);
}

Status not_found(const std::string& what) {
  return Status(StatusCode::kNotFound, what);
}
Status invalid(const std::string& what) {
  return Status(StatusCode::kInvalidArgument, what);
}

// An image side a file declares: finite, in [1, kMaxImageSide] (int conversions stay defined).
bool side_ok(double v) {
  return v >= 1 && v <= kMaxImageSide;
}

// Image folder: options.images or "images"; lists the candidates when it is missing.
StatusOr<fs::path> image_dir(const DatasetOptions& o) {
  const std::string name = o.images.empty() ? "images" : o.images;
  const fs::path dir = fs::path(o.path) / name;
  if (fs::is_directory(dir)) return dir;
  std::string found;
  std::error_code ec;
  for (const auto& e : fs::directory_iterator(o.path, ec))
    if (e.is_directory() && e.path().filename().string().rfind("images", 0) == 0)
      found += (found.empty() ? "" : ", ") + e.path().filename().string();
  return not_found(
      "image folder " + dir.string() + " does not exist" +
      (found.empty() ? std::string() : " (found: " + found + "; set the images option)"));
}

void assign_split(std::vector<Pending>& views, int test_every) {
  for (size_t i = 0; i < views.size(); ++i)
    views[i].test = test_every > 0 && i % size_t(test_every) == 0;
}

Camera camera_from_c2w_opencv(const Eigen::Matrix3d& c2w_rot, const Eigen::Vector3d& center) {
  Camera c;
  c.R = c2w_rot.transpose();
  c.t = -c.R * center;
  return c;
}

void add_points(const std::vector<io::ColmapPoint>& pts, Loaded& out) {
  out.points.reserve(pts.size());
  out.colors.reserve(pts.size());
  for (const io::ColmapPoint& p : pts) {
    out.points.push_back(p.xyz.cast<float>());
    out.colors.emplace_back(p.rgb[0] / 255.f, p.rgb[1] / 255.f, p.rgb[2] / 255.f);
  }
}

// ---- COLMAP -------------------------------------------------------------------------------

Status load_colmap(const DatasetOptions& o, Loaded& out, std::vector<std::string>& warnings) {
  const std::string model_dir = io::find_colmap_model_dir(o.path);
  if (model_dir.empty())
    return not_found(
        o.path +
        ": no COLMAP model (looked for sparse/0, sparse and the root for cameras.bin/.txt)");
  const bool binary = path_exists(fs::path(model_dir) / "cameras.bin");
  CRPGS_ASSIGN_OR_RETURN(io::ColmapModel model, io::read_colmap_model(model_dir));
  const std::string images_file =
      (fs::path(model_dir) / (binary ? "images.bin" : "images.txt")).string();
  if (model.images.empty())
    return Status(StatusCode::kIoError, images_file + ": no images in the model");
  CRPGS_ASSIGN_OR_RETURN(const fs::path dir, image_dir(o));
  std::sort(model.images.begin(), model.images.end(),
            [](const io::ColmapImage& a, const io::ColmapImage& b) { return a.name < b.name; });
  size_t missing = 0;
  std::string first_missing;
  for (const io::ColmapImage& im : model.images) {
    Pending v;
    CRPGS_ASSIGN_OR_RETURN(v.camera,
                           io::colmap_camera(model.cameras.at(im.camera_id), im, &warnings));
    v.intrinsics_known = true;
    v.path = (dir / im.name).string();
    if (!path_exists(v.path) && missing++ == 0) first_missing = v.path;
    out.views.push_back(std::move(v));
  }
  if (missing)
    return not_found(images_file + " lists " + std::to_string(model.images.size()) +
                     " images but " + std::to_string(missing) + " are missing from " +
                     dir.string() + " (first: " + first_missing + ")");
  assign_split(out.views, o.test_every);
  const std::string points_file =
      (fs::path(model_dir) / (binary ? "points3D.bin" : "points3D.txt")).string();
  if (!model.has_points_file)
    warnings.push_back(points_file +
                       " does not exist: no SfM points (random initialisation needed)");
  else if (model.points.empty())
    warnings.push_back(points_file + " is empty: no SfM points (random initialisation needed)");
  add_points(model.points, out);
  return OkStatus();
}

// ---- transforms.json (NeRF-synthetic, instant-ngp) ------------------------------------------

double number_or(const io::JsonValue* v, double fallback) {
  return v && v->is_number() ? v->number : fallback;
}

// file_path as written, or with .png/.jpg/.jpeg appended (NeRF-synthetic omits the extension).
std::string resolve_frame_path(const fs::path& root, const std::string& file_path) {
  const fs::path base = root / file_path;
  if (base.has_extension() && path_exists(base)) return base.lexically_normal().string();
  for (const char* ext : {".png", ".jpg", ".jpeg", ".JPG", ".PNG"}) {
    fs::path p = base;
    p += ext;
    if (path_exists(p)) return p.lexically_normal().string();
  }
  if (base.has_extension()) return base.lexically_normal().string();
  fs::path p = base;
  p += ".png";
  return p.lexically_normal().string();
}

// Frames of one transforms file; OpenGL camera-to-world converted to OpenCV world-to-camera.
Status read_transforms(const fs::path& file, const fs::path& root, std::vector<Pending>& views,
                       std::vector<std::string>& warnings) {
  CRPGS_ASSIGN_OR_RETURN(const io::JsonValue doc, io::read_json_file(file.string()));
  const io::JsonValue* frames = doc.find("frames");
  if (!frames || !frames->is_array())
    return Status(StatusCode::kIoError, file.string() + ": no \"frames\" array");
  for (size_t i = 0; i < frames->array.size(); ++i) {
    const io::JsonValue& f = frames->array[i];
    const std::string where = file.string() + ": frame " + std::to_string(i);
    const io::JsonValue* fp = f.find("file_path");
    const io::JsonValue* tm = f.find("transform_matrix");
    if (!fp || !fp->is_string()) return Status(StatusCode::kIoError, where + " has no file_path");
    if (!tm || !tm->is_array() || tm->array.size() < 3)
      return Status(StatusCode::kIoError, where + " has no 4x4 transform_matrix");
    Eigen::Matrix4d c2w = Eigen::Matrix4d::Identity();
    for (int r = 0; r < 3; ++r) {
      const io::JsonValue& row = tm->array[size_t(r)];
      if (!row.is_array() || row.array.size() < 4)
        return Status(StatusCode::kIoError, where + ": bad transform_matrix");
      for (int c = 0; c < 4; ++c) {
        if (!row.array[size_t(c)].is_number())
          return Status(StatusCode::kIoError, where + ": bad transform_matrix");
        c2w(r, c) = row.array[size_t(c)].number;
      }
    }
    // OpenGL (x right, y up, z back) -> OpenCV (x right, y down, z forward): flip y and z axes.
    Eigen::Matrix3d rot = c2w.topLeftCorner<3, 3>();
    rot.col(1) *= -1.0;
    rot.col(2) *= -1.0;
    Pending v;
    v.camera = camera_from_c2w_opencv(rot, c2w.topRightCorner<3, 1>());
    v.path = resolve_frame_path(root, fp->string);
    v.camera.name = fs::path(v.path).filename().string();
    // Per-frame intrinsics override the file-level ones (instant-ngp allows both).
    for (const io::JsonValue* src : {&doc, &f}) {
      v.fl_x = number_or(src->find("fl_x"), v.fl_x);
      v.fl_y = number_or(src->find("fl_y"), v.fl_y);
      v.cx = number_or(src->find("cx"), v.cx);
      v.cy = number_or(src->find("cy"), v.cy);
      v.w = number_or(src->find("w"), v.w);
      v.h = number_or(src->find("h"), v.h);
      v.angle_x = number_or(src->find("camera_angle_x"), v.angle_x);
      v.angle_y = number_or(src->find("camera_angle_y"), v.angle_y);
    }
    if (std::isnan(v.fl_x) && std::isnan(v.angle_x) && std::isnan(v.fl_y))
      return Status(StatusCode::kIoError,
                    where + ": no intrinsics (need fl_x/fl_y or camera_angle_x)");
    views.push_back(std::move(v));
  }
  std::string distortion;
  for (const char* k : {"k1", "k2", "k3", "k4", "p1", "p2"})
    if (const io::JsonValue* d = doc.find(k); d && d->is_number() && d->number != 0)
      distortion +=
          std::string(distortion.empty() ? "" : " ") + k + "=" + std::to_string(d->number);
  if (!distortion.empty())
    warnings.push_back(file.string() + ": distortion ignored, treated as pinhole (" + distortion +
                       ")");
  return OkStatus();
}

Status check_exist(const std::vector<Pending>& views, const std::string& listed_in) {
  size_t missing = 0;
  std::string first;
  for (const Pending& v : views)
    if (!path_exists(v.path) && missing++ == 0) first = v.path;
  if (missing)
    return not_found(listed_in + " lists " + std::to_string(views.size()) + " images but " +
                     std::to_string(missing) + " are missing (first: " + first + ")");
  return OkStatus();
}

size_t count_existing(const std::vector<Pending>& views) {
  return size_t(std::count_if(views.begin(), views.end(),
                              [](const Pending& v) { return path_exists(v.path); }));
}

Status load_nerf_synthetic(const DatasetOptions& o, Loaded& out,
                           std::vector<std::string>& warnings) {
  const fs::path root(o.path);
  std::vector<Pending> train, test, val;
  const fs::path train_file = root / "transforms_train.json",
                 test_file = root / "transforms_test.json", val_file = root / "transforms_val.json";
  CRPGS_RETURN_IF_ERROR(read_transforms(train_file, root, train, warnings));
  CRPGS_RETURN_IF_ERROR(check_exist(train, train_file.string()));
  if (path_exists(test_file))
    CRPGS_RETURN_IF_ERROR(read_transforms(test_file, root, test, warnings));
  if (!test.empty() && count_existing(test) > 0) {
    CRPGS_RETURN_IF_ERROR(check_exist(test, test_file.string()));
  } else {
    if (path_exists(val_file))
      CRPGS_RETURN_IF_ERROR(read_transforms(val_file, root, val, warnings));
    const std::string why = path_exists(test_file)
                                ? "none of the " + std::to_string(test.size()) + " images of " +
                                      test_file.string() + " exist"
                                : test_file.string() + " does not exist";
    if (!val.empty() && count_existing(val) > 0) {
      CRPGS_RETURN_IF_ERROR(check_exist(val, val_file.string()));
      warnings.push_back(why + ": using the " + std::to_string(val.size()) +
                         " val views as the test split");
      test = std::move(val);
    } else {
      warnings.push_back(why + " and there are no val images: the test split is empty");
      test.clear();
    }
  }
  for (Pending& v : train) v.test = false;
  for (Pending& v : test) v.test = true;
  out.views = std::move(train);
  out.views.insert(out.views.end(), test.begin(), test.end());
  return OkStatus();
}

/// nerfstudio's `ply_file_path`: the initial points (x, y, z and, when present, red, green,
/// blue), read with draco's PLY reader.
Status read_point_ply(const fs::path& file, Loaded& out) {
  draco::PointCloud pc;
  draco::PlyDecoder decoder;
  if (const draco::Status st = decoder.DecodeFromFile(file.string(), &pc); !st.ok())
    return Status(StatusCode::kIoError, file.string() + ": " + st.error_msg_string());
  const draco::PointAttribute* pos = pc.GetNamedAttribute(draco::GeometryAttribute::POSITION);
  const draco::PointAttribute* col = pc.GetNamedAttribute(draco::GeometryAttribute::COLOR);
  if (!pos || pos->num_components() != 3)
    return Status(StatusCode::kIoError, file.string() + ": no x, y, z vertex properties");
  for (draco::PointIndex i(0); i < pc.num_points(); ++i) {
    float xyz[3] = {0, 0, 0};
    pos->ConvertValue<float, 3>(pos->mapped_index(i), xyz);
    if (!std::isfinite(xyz[0]) || !std::isfinite(xyz[1]) || !std::isfinite(xyz[2])) continue;
    out.points.emplace_back(xyz[0], xyz[1], xyz[2]);
    uint8_t rgb[3] = {128, 128, 128};
    if (col && col->num_components() >= 3) col->ConvertValue<uint8_t, 3>(col->mapped_index(i), rgb);
    out.colors.emplace_back(rgb[0] / 255.f, rgb[1] / 255.f, rgb[2] / 255.f);
  }
  return OkStatus();
}

const std::string* string_field(const io::JsonValue& doc, const char* key) {
  const io::JsonValue* v = doc.find(key);
  return v && v->is_string() ? &v->string : nullptr;
}

/// transforms.json as instant-ngp and nerfstudio write it. nerfstudio's keys: camera_model (a
/// pinhole model; OPENCV's distortion is ignored with a warning, fisheye and equirectangular
/// are refused), ply_file_path (initial points) and train/val/test_filenames (the split; test
/// from val_filenames when test_filenames is absent or empty).
Status load_instant_ngp(const DatasetOptions& o, Loaded& out, std::vector<std::string>& warnings) {
  const fs::path root(o.path), file = root / "transforms.json";
  CRPGS_ASSIGN_OR_RETURN(const io::JsonValue doc, io::read_json_file(file.string()));
  if (const std::string* model = string_field(doc, "camera_model");
      model && *model != "OPENCV" && *model != "PINHOLE" && *model != "SIMPLE_PINHOLE")
    return Status(StatusCode::kIoError,
                  file.string() + ": camera_model " + *model +
                      " is not a pinhole model (accepted: PINHOLE, SIMPLE_PINHOLE, OPENCV with "
                      "its distortion ignored); undistort the images first");
  CRPGS_RETURN_IF_ERROR(read_transforms(file, o.path, out.views, warnings));
  if (out.views.empty()) return Status(StatusCode::kIoError, file.string() + ": no frames");
  CRPGS_RETURN_IF_ERROR(check_exist(out.views, file.string()));
  std::stable_sort(out.views.begin(), out.views.end(),
                   [](const Pending& a, const Pending& b) { return a.path < b.path; });
  // The split nerfstudio lists, as frame paths.
  auto listed = [&](const char* key) -> StatusOr<std::set<std::string>> {
    std::set<std::string> paths;
    if (const io::JsonValue* l = doc.find(key); l) {
      if (!l->is_array())
        return Status(StatusCode::kIoError, file.string() + ": " + key + " is not a list");
      for (const auto& v : l->array) {
        if (!v.is_string())
          return Status(StatusCode::kIoError, file.string() + ": " + key + " lists a non-string");
        paths.insert(resolve_frame_path(root, v.string));
      }
    }
    return paths;
  };
  CRPGS_ASSIGN_OR_RETURN(const auto train, listed("train_filenames"));
  CRPGS_ASSIGN_OR_RETURN(auto test, listed("test_filenames"));
  if (test.empty()) {
    CRPGS_ASSIGN_OR_RETURN(test, listed("val_filenames"));
  }
  if (train.empty() && test.empty()) {
    assign_split(out.views, o.test_every);
  } else {
    std::vector<Pending> kept;
    for (Pending& v : out.views) {
      const bool in_train = train.count(v.path) > 0, in_test = test.count(v.path) > 0;
      if (!in_train && !in_test) continue;  // a frame the lists leave out: in no split
      v.test = in_test;
      kept.push_back(std::move(v));
    }
    const size_t n_listed = train.size() + test.size();
    if (kept.size() < n_listed)
      return not_found(file.string() + ": train/val/test_filenames list " +
                       std::to_string(n_listed) + " images, " + std::to_string(kept.size()) +
                       " of them among the frames");
    out.views = std::move(kept);
  }
  if (const std::string* ply = string_field(doc, "ply_file_path"))
    CRPGS_RETURN_IF_ERROR(read_point_ply(root / *ply, out));
  return OkStatus();
}

// ---- LLFF ---------------------------------------------------------------------------------

bool is_image_file(const fs::path& p) {
  std::string ext = p.extension().string();
  std::transform(ext.begin(), ext.end(), ext.begin(),
                 [](unsigned char c) { return char(std::tolower(c)); });
  return ext == ".png" || ext == ".jpg" || ext == ".jpeg";
}

Status load_llff(const DatasetOptions& o, Loaded& out, std::vector<std::string>& warnings) {
  const std::string file = (fs::path(o.path) / "poses_bounds.npy").string();
  CRPGS_ASSIGN_OR_RETURN(const io::NpyArray arr, io::read_npy(file));
  if (arr.shape.size() != 2 || arr.shape[1] != 17)
    return Status(StatusCode::kIoError, file + ": expected an N x 17 array");
  const size_t n = size_t(arr.shape[0]);
  CRPGS_ASSIGN_OR_RETURN(const fs::path dir, image_dir(o));
  std::vector<fs::path> files;
  for (const auto& e : fs::directory_iterator(dir))
    if (e.is_regular_file() && is_image_file(e.path())) files.push_back(e.path());
  std::sort(files.begin(), files.end());
  if (files.size() != n)
    return Status(StatusCode::kIoError, file + " has " + std::to_string(n) + " poses but " +
                                            dir.string() + " has " + std::to_string(files.size()) +
                                            " images");
  for (size_t i = 0; i < n; ++i) {
    const double* row = &arr.data[i * 17];
    Eigen::Matrix<double, 3, 5> m;  // [R | t | hwf], rows of 5
    for (int r = 0; r < 3; ++r)
      for (int c = 0; c < 5; ++c) m(r, c) = row[r * 5 + c];
    // LLFF rotation columns are the camera's [down, right, back] axes in world coordinates.
    Eigen::Matrix3d rot;
    rot.col(0) = m.col(1);   // right
    rot.col(1) = m.col(0);   // down
    rot.col(2) = -m.col(2);  // forward
    Pending v;
    v.camera = camera_from_c2w_opencv(rot, m.col(3));
    const double H = m(0, 4), W = m(1, 4), f = m(2, 4);
    if (!(side_ok(H) && side_ok(W) && f > 0 && std::isfinite(f)) || !m.allFinite())
      return Status(StatusCode::kIoError,
                    file + ": row " + std::to_string(i) + " has a bad hwf column");
    v.camera.width = int(std::lround(W));
    v.camera.height = int(std::lround(H));
    v.camera.fx = v.camera.fy = f;
    v.camera.cx = W / 2;
    v.camera.cy = H / 2;
    v.intrinsics_known = true;
    v.path = files[i].string();
    v.camera.name = files[i].filename().string();
    out.views.push_back(std::move(v));
  }
  assign_split(out.views, o.test_every);
  const std::string model_dir = (fs::path(o.path) / "sparse" / "0").string();
  auto pts = io::read_colmap_points(model_dir);
  if (pts.ok()) {
    if (pts->empty()) warnings.push_back(model_dir + ": points3D is empty: no SfM points");
    add_points(*pts, out);
  } else if (pts.status().code() == StatusCode::kNotFound) {
    warnings.push_back(model_dir +
                       " has no points3D: no SfM points (random initialisation needed)");
  } else {
    return pts.status();
  }
  return OkStatus();
}

// ---- image loading ------------------------------------------------------------------------

// Final size after the integer downscale and the max_width cap.
void target_size(int w0, int h0, const DatasetOptions& o, int& w, int& h) {
  w = w0, h = h0;
  if (o.downscale > 1) {
    w = std::max(1, int(std::lround(double(w0) / o.downscale)));
    h = std::max(1, int(std::lround(double(h0) / o.downscale)));
  }
  if (o.max_width > 0 && w > o.max_width) {
    h = std::max(1, int(std::lround(double(h) * o.max_width / w)));
    w = o.max_width;
  }
}

Image resample(Image im, const DatasetOptions& o) {
  int w, h;
  target_size(im.width, im.height, o, w, h);
  if (o.downscale > 1 && im.width % o.downscale == 0 && im.height % o.downscale == 0)
    im = downscale(im, o.downscale);  // exact box filter, the common case
  return resize_area(im, w, h);       // no-op when already the target size
}

Status resolve_camera(Pending& v, int w0, int h0, const std::string& path) {
  if (!v.intrinsics_known) {
    Camera& c = v.camera;
    if ((!std::isnan(v.w) && !side_ok(v.w)) || (!std::isnan(v.h) && !side_ok(v.h)))
      return invalid(path + ": bad camera size (" + std::to_string(v.w) + " x " +
                     std::to_string(v.h) + ")");
    c.width = std::isnan(v.w) ? w0 : int(std::lround(v.w));
    c.height = std::isnan(v.h) ? h0 : int(std::lround(v.h));
    if (!std::isnan(v.fl_x))
      c.fx = v.fl_x;
    else if (!std::isnan(v.angle_x))
      c.fx = 0.5 * c.width / std::tan(0.5 * v.angle_x);
    else
      c.fx = v.fl_y;
    if (!std::isnan(v.fl_y))
      c.fy = v.fl_y;
    else if (!std::isnan(v.angle_y))
      c.fy = 0.5 * c.height / std::tan(0.5 * v.angle_y);
    else
      c.fy = c.fx;
    c.cx = std::isnan(v.cx) ? 0.5 * c.width : v.cx;
    c.cy = std::isnan(v.cy) ? 0.5 * c.height : v.cy;
    v.intrinsics_known = true;
  }
  const Camera& c = v.camera;
  // Non-finite values (e.g. camera_angle_x = 0 gives fx = inf) would reach training as NaN.
  const bool finite = std::isfinite(c.fx) && std::isfinite(c.fy) && std::isfinite(c.cx) &&
                      std::isfinite(c.cy) && c.R.allFinite() && c.t.allFinite();
  if (c.width <= 0 || c.height <= 0 || !(c.fx > 0) || !(c.fy > 0) || !finite)
    return invalid(path + ": bad camera (" + std::to_string(c.width) + "x" +
                   std::to_string(c.height) + ", fx " + std::to_string(c.fx) + ", fy " +
                   std::to_string(c.fy) + ", cx " + std::to_string(c.cx) + ", cy " +
                   std::to_string(c.cy) + (c.R.allFinite() && c.t.allFinite() ? "" : ", pose") +
                   (finite ? ")" : ": not finite)"));
  // The file may be a downscaled copy (images_8 for a 4032-wide model), but not another aspect.
  const double sx = double(w0) / c.width, sy = double(h0) / c.height;
  if (std::abs(sx / sy - 1.0) > 0.01)
    return invalid(path + " is " + std::to_string(w0) + "x" + std::to_string(h0) +
                   " but its camera is " + std::to_string(c.width) + "x" +
                   std::to_string(c.height) + " (different aspect ratio)");
  return OkStatus();
}

// One view: its image decoded (or only sized), its camera resolved and resized.
Status load_view(Pending& p, const DatasetOptions& o, View& view) {
  int w0 = 0, h0 = 0;
  Image im;
  if (o.load_images) {
    CRPGS_ASSIGN_OR_RETURN(im, load_image(p.path));
    w0 = im.width, h0 = im.height;
  } else {
    CRPGS_ASSIGN_OR_RETURN(const ImageInfo info, read_image_info(p.path));
    w0 = info.width, h0 = info.height;
  }
  CRPGS_RETURN_IF_ERROR(resolve_camera(p, w0, h0, p.path));
  int w, h;
  target_size(w0, h0, o, w, h);
  if (o.load_images) {
    im = composite_rgba(im, o.background.data());  // before resampling: average what is seen
    view.image = resample(std::move(im), o);
  }
  view.camera = p.camera.resized(w, h);
  return OkStatus();
}

// Decodes (or, without load_images, only sizes) every view with a few threads; results land at
// their own index, so the order does not depend on scheduling. The first error by index wins.
Status load_views(std::vector<Pending>& pending, const DatasetOptions& o,
                  std::vector<View>& views) {
  views.assign(pending.size(), View());
  std::vector<Status> errors(pending.size());
  std::atomic<size_t> next{0};
  auto work = [&]() {
    for (size_t i = next++; i < pending.size(); i = next++) {
      try {
        errors[i] = load_view(pending[i], o, views[i]);
      } catch (const std::exception& e) {  // e.g. bad_alloc: in a worker it would terminate
        errors[i] = Status(StatusCode::kIoError, pending[i].path + ": " + e.what());
      }
    }
  };
  const int n_threads = std::max(1, std::min<int>(o.threads, int(pending.size())));
  std::vector<std::thread> threads;
  for (int t = 1; t < n_threads; ++t) threads.emplace_back(work);
  work();
  for (std::thread& t : threads) t.join();
  for (const Status& s : errors)
    if (!s.ok()) return s;
  return OkStatus();
}

using Loader = Status (*)(const DatasetOptions&, Loaded&, std::vector<std::string>&);

}  // namespace

StatusOr<std::string> detect_dataset_format(const std::string& path) {
  if (!fs::is_directory(path)) return not_found("dataset path " + path + " is not a directory");
  const fs::path root(path);
  if (!io::find_colmap_model_dir(path).empty()) return std::string("colmap");
  if (path_exists(root / "transforms_train.json")) return std::string("nerf_synthetic");
  if (path_exists(root / "transforms.json")) return std::string("instant_ngp");
  if (path_exists(root / "poses_bounds.npy")) return std::string("llff");
  return not_found("cannot detect the dataset format of " + path +
                   "; accepted formats: colmap (sparse/0/, sparse/ or ./ with cameras.bin|txt + "
                   "images.bin|txt), "
                   "nerf_synthetic (transforms_train.json), instant_ngp (transforms.json), llff "
                   "(poses_bounds.npy)");
}

StatusOr<Dataset> load_dataset(const DatasetOptions& options) {
  if (options.downscale < 1)
    return invalid("downscale must be >= 1, got " + std::to_string(options.downscale));
  if (options.test_every < 0) return invalid("test_every must be >= 0");
  if (options.max_width < 0 || options.max_images < 0)
    return invalid("max_width and max_images must be >= 0");
  std::string format = options.format;
  if (format.empty() || format == "auto") {
    CRPGS_ASSIGN_OR_RETURN(format, detect_dataset_format(options.path));
  } else if (!fs::is_directory(options.path)) {
    return not_found("dataset path " + options.path + " is not a directory");
  }
  Loader loader = nullptr;
  if (format == "colmap")
    loader = &load_colmap;
  else if (format == "nerf_synthetic")
    loader = &load_nerf_synthetic;
  else if (format == "instant_ngp")
    loader = &load_instant_ngp;
  else if (format == "llff")
    loader = &load_llff;
  else
    return invalid("unknown dataset format '" + format +
                   "' (accepted: auto, colmap, nerf_synthetic, instant_ngp, llff)");
  Dataset ds;
  ds.format = format;
  ds.name = fs::path(options.path).lexically_normal().filename().string();
  if (ds.name.empty())
    ds.name = fs::path(options.path).lexically_normal().parent_path().filename().string();
  Loaded loaded;
  CRPGS_RETURN_IF_ERROR(loader(options, loaded, ds.warnings));

  // Keep at most max_images per split, remembering each view's position in the full list.
  std::vector<Pending> pending;
  std::vector<int> index;
  size_t n_train = 0, n_test = 0;
  for (size_t i = 0; i < loaded.views.size(); ++i) {
    size_t& n = loaded.views[i].test ? n_test : n_train;
    if (options.max_images > 0 && n >= size_t(options.max_images)) continue;
    ++n;
    pending.push_back(loaded.views[i]);
    index.push_back(int(i));
  }
  std::vector<View> views;
  CRPGS_RETURN_IF_ERROR(load_views(pending, options, views));
  for (size_t i = 0; i < views.size(); ++i) {
    views[i].index = index[i];
    (pending[i].test ? ds.test : ds.train).push_back(std::move(views[i]));
  }
  ds.points = std::move(loaded.points);
  ds.point_colors = std::move(loaded.colors);
  return ds;
}

}  // namespace crpgs
