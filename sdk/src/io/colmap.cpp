/// @file colmap.cpp
/// @brief COLMAP model I/O. Binary layout as in COLMAP's src/colmap/scene/reconstruction_io
/// (little-endian; ids int32 for cameras/images, uint64 for points).
#include "io/colmap.h"

#include <algorithm>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <iomanip>
#include <sstream>

#include <Eigen/Geometry>

#include "crpgs/atomic_file.h"
#include "crpgs/image.h"

namespace crpgs::io {
namespace fs = std::filesystem;
namespace {

struct ModelInfo {
  const char* name;
  int num_params;
};
// Index = COLMAP model id.
constexpr ModelInfo kModels[] = {{"SIMPLE_PINHOLE", 3},
                                 {"PINHOLE", 4},
                                 {"SIMPLE_RADIAL", 4},
                                 {"RADIAL", 5},
                                 {"OPENCV", 8},
                                 {"OPENCV_FISHEYE", 8},
                                 {"FULL_OPENCV", 12},
                                 {"FOV", 5},
                                 {"SIMPLE_RADIAL_FISHEYE", 4},
                                 {"RADIAL_FISHEYE", 5},
                                 {"THIN_PRISM_FISHEYE", 12}};
constexpr int kNumModels = int(sizeof(kModels) / sizeof(kModels[0]));

Status read_whole(const std::string& path, std::string& out) {
  std::ifstream in(path, std::ios::binary);
  if (!in) return Status(StatusCode::kNotFound, "cannot open " + path);
  std::stringstream ss;
  ss << in.rdbuf();
  out = ss.str();
  return OkStatus();
}

// Bounds-checked little-endian reader over a whole file.
class BinReader {
 public:
  BinReader(const std::string& path, const std::string& data) : path_(path), data_(data) {}
  template <typename T>
  Status read(T& v, const char* what) {
    if (pos_ + sizeof(T) > data_.size()) return truncated(what);
    std::memcpy(&v, data_.data() + pos_, sizeof(T));
    pos_ += sizeof(T);
    return OkStatus();
  }
  Status read_cstring(std::string& s, const char* what) {
    const size_t end = data_.find('\0', pos_);
    if (end == std::string::npos) return truncated(what);
    s = data_.substr(pos_, end - pos_);
    pos_ = end + 1;
    return OkStatus();
  }
  // Guards reserve() against absurd counts from corrupt files.
  Status check_count(uint64_t count, size_t min_bytes_each, const char* what) {
    if (count > (data_.size() - pos_) / std::max<size_t>(1, min_bytes_each)) return truncated(what);
    return OkStatus();
  }
  Status truncated(const char* what) const {
    return Status(StatusCode::kIoError, path_ + ": truncated or corrupt (reading " + what +
                                            " at byte " + std::to_string(pos_) + " of " +
                                            std::to_string(data_.size()) + ")");
  }
  bool at_end() const { return pos_ == data_.size(); }

 private:
  const std::string& path_;
  const std::string& data_;
  size_t pos_ = 0;
};

template <typename T>
void put(std::string& out, T v) {
  out.append(reinterpret_cast<const char*>(&v), sizeof(T));
}

std::string fmt(double v) {
  std::ostringstream os;
  os << std::setprecision(17) << v;
  return os.str();
}

Status parse_error(const std::string& path, int line, const std::string& what) {
  return Status(StatusCode::kIoError, path + ":" + std::to_string(line) + ": " + what);
}

// Next non-comment, non-empty line; false at EOF.
bool next_data_line(std::istream& in, std::string& line, int& line_no) {
  while (std::getline(in, line)) {
    ++line_no;
    const size_t p = line.find_first_not_of(" \t\r");
    if (p == std::string::npos || line[p] == '#') continue;
    return true;
  }
  return false;
}

Status read_cameras_bin(const std::string& path, ColmapModel& m) {
  std::string data;
  CRPGS_RETURN_IF_ERROR(read_whole(path, data));
  BinReader r(path, data);
  uint64_t n = 0;
  CRPGS_RETURN_IF_ERROR(r.read(n, "camera count"));
  CRPGS_RETURN_IF_ERROR(r.check_count(n, 24, "cameras"));
  for (uint64_t i = 0; i < n; ++i) {
    ColmapCamera c;
    int32_t id = 0, model = 0;
    CRPGS_RETURN_IF_ERROR(r.read(id, "camera_id"));
    CRPGS_RETURN_IF_ERROR(r.read(model, "camera model_id"));
    CRPGS_RETURN_IF_ERROR(r.read(c.width, "camera width"));
    CRPGS_RETURN_IF_ERROR(r.read(c.height, "camera height"));
    c.id = id;
    c.model_id = model;
    const int np = colmap_model_num_params(model);
    if (np == 0)
      return Status(StatusCode::kIoError, path + ": camera " + std::to_string(id) +
                                              " has unknown model id " + std::to_string(model));
    c.params.resize(size_t(np));
    for (double& p : c.params) CRPGS_RETURN_IF_ERROR(r.read(p, "camera params"));
    m.cameras[c.id] = c;
  }
  return OkStatus();
}

Status read_images_bin(const std::string& path, ColmapModel& m) {
  std::string data;
  CRPGS_RETURN_IF_ERROR(read_whole(path, data));
  BinReader r(path, data);
  uint64_t n = 0;
  CRPGS_RETURN_IF_ERROR(r.read(n, "image count"));
  CRPGS_RETURN_IF_ERROR(r.check_count(n, 4 + 56 + 4 + 1 + 8, "images"));
  m.images.reserve(size_t(n));
  for (uint64_t i = 0; i < n; ++i) {
    ColmapImage im;
    int32_t id = 0, cam = 0;
    CRPGS_RETURN_IF_ERROR(r.read(id, "image_id"));
    for (int k = 0; k < 4; ++k) CRPGS_RETURN_IF_ERROR(r.read(im.qvec[k], "qvec"));
    for (int k = 0; k < 3; ++k) CRPGS_RETURN_IF_ERROR(r.read(im.tvec[k], "tvec"));
    CRPGS_RETURN_IF_ERROR(r.read(cam, "image camera_id"));
    CRPGS_RETURN_IF_ERROR(r.read_cstring(im.name, "image name"));
    im.id = id;
    im.camera_id = cam;
    uint64_t np = 0;
    CRPGS_RETURN_IF_ERROR(r.read(np, "num_points2D"));
    CRPGS_RETURN_IF_ERROR(r.check_count(np, 24, "points2D"));
    im.xys.resize(size_t(np));
    im.point3d_ids.resize(size_t(np));
    for (uint64_t k = 0; k < np; ++k) {
      CRPGS_RETURN_IF_ERROR(r.read(im.xys[k].x(), "points2D x"));
      CRPGS_RETURN_IF_ERROR(r.read(im.xys[k].y(), "points2D y"));
      CRPGS_RETURN_IF_ERROR(r.read(im.point3d_ids[k], "points2D point3D_id"));
    }
    m.images.push_back(std::move(im));
  }
  return OkStatus();
}

Status read_points_bin(const std::string& path, ColmapModel& m) {
  std::string data;
  CRPGS_RETURN_IF_ERROR(read_whole(path, data));
  BinReader r(path, data);
  uint64_t n = 0;
  CRPGS_RETURN_IF_ERROR(r.read(n, "point count"));
  CRPGS_RETURN_IF_ERROR(r.check_count(n, 8 + 24 + 3 + 8 + 8, "points3D"));
  m.points.reserve(size_t(n));
  for (uint64_t i = 0; i < n; ++i) {
    ColmapPoint p;
    CRPGS_RETURN_IF_ERROR(r.read(p.id, "point3D_id"));
    for (int k = 0; k < 3; ++k) CRPGS_RETURN_IF_ERROR(r.read(p.xyz[k], "point xyz"));
    for (int k = 0; k < 3; ++k) CRPGS_RETURN_IF_ERROR(r.read(p.rgb[size_t(k)], "point rgb"));
    CRPGS_RETURN_IF_ERROR(r.read(p.error, "point error"));
    uint64_t len = 0;
    CRPGS_RETURN_IF_ERROR(r.read(len, "track_length"));
    CRPGS_RETURN_IF_ERROR(r.check_count(len, 8, "track"));
    p.track.resize(size_t(len));
    for (auto& t : p.track) {
      int32_t a = 0, b = 0;
      CRPGS_RETURN_IF_ERROR(r.read(a, "track image_id"));
      CRPGS_RETURN_IF_ERROR(r.read(b, "track point2D_idx"));
      t = {a, b};
    }
    m.points.push_back(std::move(p));
  }
  return OkStatus();
}

Status read_cameras_txt(const std::string& path, ColmapModel& m) {
  std::ifstream in(path);
  if (!in) return Status(StatusCode::kNotFound, "cannot open " + path);
  std::string line;
  int ln = 0;
  while (next_data_line(in, line, ln)) {
    std::istringstream ss(line);
    ColmapCamera c;
    std::string model;
    if (!(ss >> c.id >> model >> c.width >> c.height))
      return parse_error(path, ln, "expected CAMERA_ID MODEL WIDTH HEIGHT PARAMS[]");
    c.model_id = colmap_model_id(model);
    if (c.model_id < 0) return parse_error(path, ln, "unknown camera model '" + model + "'");
    double p;
    while (ss >> p) c.params.push_back(p);
    if (int(c.params.size()) != colmap_model_num_params(c.model_id))
      return parse_error(path, ln,
                         model + " needs " + std::to_string(colmap_model_num_params(c.model_id)) +
                             " parameters, got " + std::to_string(c.params.size()));
    m.cameras[c.id] = c;
  }
  return OkStatus();
}

Status read_images_txt(const std::string& path, ColmapModel& m) {
  std::ifstream in(path);
  if (!in) return Status(StatusCode::kNotFound, "cannot open " + path);
  std::string line;
  int ln = 0;
  while (next_data_line(in, line, ln)) {
    std::istringstream ss(line);
    ColmapImage im;
    if (!(ss >> im.id >> im.qvec[0] >> im.qvec[1] >> im.qvec[2] >> im.qvec[3] >> im.tvec[0] >>
          im.tvec[1] >> im.tvec[2] >> im.camera_id))
      return parse_error(path, ln, "expected IMAGE_ID QW QX QY QZ TX TY TZ CAMERA_ID NAME");
    std::getline(ss >> std::ws, im.name);
    while (!im.name.empty() && (im.name.back() == '\r' || im.name.back() == ' '))
      im.name.pop_back();
    if (im.name.empty()) return parse_error(path, ln, "image without a NAME");
    // The POINTS2D line always follows (possibly empty), as COLMAP writes it.
    std::string pts;
    if (std::getline(in, pts)) {
      ++ln;
      std::istringstream ps(pts);
      double x, y;
      int64_t pid;
      while (ps >> x >> y >> pid) {
        im.xys.emplace_back(x, y);
        im.point3d_ids.push_back(pid);
      }
      // Anything else (e.g. the next image's line: a POINTS2D line was left out) would drop
      // every other image without a word.
      if (!ps.eof())
        return parse_error(path, ln,
                           "expected this image's POINTS2D line (X Y POINT3D_ID triples, "
                           "possibly empty) after its image line");
    }
    m.images.push_back(std::move(im));
  }
  return OkStatus();
}

Status read_points_txt(const std::string& path, ColmapModel& m) {
  std::ifstream in(path);
  if (!in) return Status(StatusCode::kNotFound, "cannot open " + path);
  std::string line;
  int ln = 0;
  while (next_data_line(in, line, ln)) {
    std::istringstream ss(line);
    ColmapPoint p;
    int r, g, b;
    if (!(ss >> p.id >> p.xyz[0] >> p.xyz[1] >> p.xyz[2] >> r >> g >> b >> p.error))
      return parse_error(path, ln, "expected POINT3D_ID X Y Z R G B ERROR TRACK[]");
    p.rgb = {uint8_t(std::clamp(r, 0, 255)), uint8_t(std::clamp(g, 0, 255)),
             uint8_t(std::clamp(b, 0, 255))};
    int a, k;
    while (ss >> a >> k) p.track.emplace_back(a, k);
    m.points.push_back(std::move(p));
  }
  return OkStatus();
}

Status check_model(const std::string& dir, const ColmapModel& m) {
  for (const ColmapImage& im : m.images)
    if (!m.cameras.count(im.camera_id))
      return Status(StatusCode::kIoError, dir + ": image '" + im.name + "' references camera " +
                                              std::to_string(im.camera_id) +
                                              ", which is not in the cameras file");
  return OkStatus();
}

}  // namespace

int colmap_model_id(const std::string& name) {
  for (int i = 0; i < kNumModels; ++i)
    if (name == kModels[i].name) return i;
  return -1;
}
const char* colmap_model_name(int id) {
  return id >= 0 && id < kNumModels ? kModels[id].name : "UNKNOWN";
}
int colmap_model_num_params(int id) {
  return id >= 0 && id < kNumModels ? kModels[id].num_params : 0;
}

std::string find_colmap_model_dir(const std::string& dir) {
  for (const fs::path& p :
       {fs::path(dir) / "sparse" / "0", fs::path(dir) / "sparse", fs::path(dir)}) {
    std::error_code ec;
    if (fs::exists(p / "cameras.bin", ec) || fs::exists(p / "cameras.txt", ec)) return p.string();
  }
  return "";
}

namespace {
using ColmapReader = Status (*)(const std::string& path, ColmapModel& m);

/// cameras + images are required; points3D is optional (no points: random initialisation).
StatusOr<ColmapModel> read_colmap_files(const std::string& dir, const char* ext,
                                        ColmapReader cameras, ColmapReader images,
                                        ColmapReader points) {
  ColmapModel m;
  const fs::path d(dir);
  CRPGS_RETURN_IF_ERROR(cameras((d / (std::string("cameras") + ext)).string(), m));
  CRPGS_RETURN_IF_ERROR(images((d / (std::string("images") + ext)).string(), m));
  const fs::path pts = d / (std::string("points3D") + ext);
  std::error_code ec;
  if (fs::exists(pts, ec)) {
    m.has_points_file = true;
    CRPGS_RETURN_IF_ERROR(points(pts.string(), m));
  }
  CRPGS_RETURN_IF_ERROR(check_model(dir, m));
  return m;
}
}  // namespace

StatusOr<ColmapModel> read_colmap_binary(const std::string& dir) {
  return read_colmap_files(dir, ".bin", read_cameras_bin, read_images_bin, read_points_bin);
}

StatusOr<ColmapModel> read_colmap_text(const std::string& dir) {
  return read_colmap_files(dir, ".txt", read_cameras_txt, read_images_txt, read_points_txt);
}

StatusOr<ColmapModel> read_colmap_model(const std::string& dir) {
  std::error_code ec;
  if (fs::exists(fs::path(dir) / "cameras.bin", ec)) return read_colmap_binary(dir);
  if (fs::exists(fs::path(dir) / "cameras.txt", ec)) return read_colmap_text(dir);
  return Status(StatusCode::kNotFound,
                dir + ": no cameras.bin or cameras.txt (not a COLMAP model)");
}

StatusOr<std::vector<ColmapPoint>> read_colmap_points(const std::string& dir) {
  ColmapModel m;
  const fs::path d(dir);
  std::error_code ec;
  if (fs::exists(d / "points3D.bin", ec)) {
    CRPGS_RETURN_IF_ERROR(read_points_bin((d / "points3D.bin").string(), m));
  } else if (fs::exists(d / "points3D.txt", ec)) {
    CRPGS_RETURN_IF_ERROR(read_points_txt((d / "points3D.txt").string(), m));
  } else {
    return Status(StatusCode::kNotFound, dir + ": no points3D.bin or points3D.txt");
  }
  return std::move(m.points);
}

Status write_colmap_binary(const ColmapModel& m, const std::string& dir) {
  const fs::path d(dir);
  std::string cams;
  put<uint64_t>(cams, m.cameras.size());
  for (const auto& [id, c] : m.cameras) {
    put<int32_t>(cams, id);
    put<int32_t>(cams, c.model_id);
    put<uint64_t>(cams, c.width);
    put<uint64_t>(cams, c.height);
    for (double p : c.params) put<double>(cams, p);
  }
  CRPGS_RETURN_IF_ERROR(write_file_atomic((d / "cameras.bin").string(), cams));
  std::string ims;
  put<uint64_t>(ims, m.images.size());
  for (const ColmapImage& im : m.images) {
    put<int32_t>(ims, im.id);
    for (int k = 0; k < 4; ++k) put<double>(ims, im.qvec[k]);
    for (int k = 0; k < 3; ++k) put<double>(ims, im.tvec[k]);
    put<int32_t>(ims, im.camera_id);
    ims.append(im.name);
    ims.push_back('\0');
    put<uint64_t>(ims, im.xys.size());
    for (size_t k = 0; k < im.xys.size(); ++k) {
      put<double>(ims, im.xys[k].x());
      put<double>(ims, im.xys[k].y());
      put<int64_t>(ims, k < im.point3d_ids.size() ? im.point3d_ids[k] : -1);
    }
  }
  CRPGS_RETURN_IF_ERROR(write_file_atomic((d / "images.bin").string(), ims));
  if (!m.has_points_file && m.points.empty()) return OkStatus();
  std::string pts;
  put<uint64_t>(pts, m.points.size());
  for (const ColmapPoint& p : m.points) {
    put<uint64_t>(pts, p.id);
    for (int k = 0; k < 3; ++k) put<double>(pts, p.xyz[k]);
    for (int k = 0; k < 3; ++k) put<uint8_t>(pts, p.rgb[size_t(k)]);
    put<double>(pts, p.error);
    put<uint64_t>(pts, p.track.size());
    for (const auto& [a, b] : p.track) {
      put<int32_t>(pts, a);
      put<int32_t>(pts, b);
    }
  }
  return write_file_atomic((d / "points3D.bin").string(), pts);
}

Status write_colmap_text(const ColmapModel& m, const std::string& dir) {
  const fs::path d(dir);
  std::string cams =
      "# Camera list with one line of data per camera:\n"
      "#   CAMERA_ID, MODEL, WIDTH, HEIGHT, PARAMS[]\n";
  for (const auto& [id, c] : m.cameras) {
    cams += std::to_string(id) + " " + colmap_model_name(c.model_id) + " " +
            std::to_string(c.width) + " " + std::to_string(c.height);
    for (double p : c.params) cams += " " + fmt(p);
    cams += "\n";
  }
  CRPGS_RETURN_IF_ERROR(write_file_atomic((d / "cameras.txt").string(), cams));
  std::string ims =
      "# Image list with two lines of data per image:\n"
      "#   IMAGE_ID, QW, QX, QY, QZ, TX, TY, TZ, CAMERA_ID, NAME\n"
      "#   POINTS2D[] as (X, Y, POINT3D_ID)\n";
  for (const ColmapImage& im : m.images) {
    ims += std::to_string(im.id);
    for (int k = 0; k < 4; ++k) ims += " " + fmt(im.qvec[k]);
    for (int k = 0; k < 3; ++k) ims += " " + fmt(im.tvec[k]);
    ims += " " + std::to_string(im.camera_id) + " " + im.name + "\n";
    for (size_t k = 0; k < im.xys.size(); ++k)
      ims += (k ? " " : "") + fmt(im.xys[k].x()) + " " + fmt(im.xys[k].y()) + " " +
             std::to_string(k < im.point3d_ids.size() ? im.point3d_ids[k] : -1);
    ims += "\n";
  }
  CRPGS_RETURN_IF_ERROR(write_file_atomic((d / "images.txt").string(), ims));
  if (!m.has_points_file && m.points.empty()) return OkStatus();
  std::string pts =
      "# 3D point list with one line of data per point:\n"
      "#   POINT3D_ID, X, Y, Z, R, G, B, ERROR, TRACK[] as (IMAGE_ID, POINT2D_IDX)\n";
  for (const ColmapPoint& p : m.points) {
    pts += std::to_string(p.id);
    for (int k = 0; k < 3; ++k) pts += " " + fmt(p.xyz[k]);
    for (int k = 0; k < 3; ++k) pts += " " + std::to_string(int(p.rgb[size_t(k)]));
    pts += " " + fmt(p.error);
    for (const auto& [a, b] : p.track) pts += " " + std::to_string(a) + " " + std::to_string(b);
    pts += "\n";
  }
  return write_file_atomic((d / "points3D.txt").string(), pts);
}

StatusOr<Camera> colmap_camera(const ColmapCamera& c, const ColmapImage& im,
                               std::vector<std::string>* warnings) {
  if (c.width < 1 || c.width > uint64_t(kMaxImageSide) || c.height < 1 ||
      c.height > uint64_t(kMaxImageSide))
    return Status(StatusCode::kInvalidArgument,
                  "camera " + std::to_string(c.id) + " is " + std::to_string(c.width) + "x" +
                      std::to_string(c.height) + " pixels, outside [1, " +
                      std::to_string(kMaxImageSide) + "] per side");
  Camera cam;
  cam.width = int(c.width);
  cam.height = int(c.height);
  cam.name = im.name;
  const std::vector<double>& p = c.params;
  const std::string model = colmap_model_name(c.model_id);
  std::string ignored;
  switch (c.model_id) {
    case 0:  // SIMPLE_PINHOLE f cx cy
      cam.fx = cam.fy = p[0], cam.cx = p[1], cam.cy = p[2];
      break;
    case 1:  // PINHOLE fx fy cx cy
      cam.fx = p[0], cam.fy = p[1], cam.cx = p[2], cam.cy = p[3];
      break;
    case 2:  // SIMPLE_RADIAL f cx cy k
      cam.fx = cam.fy = p[0], cam.cx = p[1], cam.cy = p[2];
      ignored = "k=" + fmt(p[3]);
      break;
    case 3:  // RADIAL f cx cy k1 k2
      cam.fx = cam.fy = p[0], cam.cx = p[1], cam.cy = p[2];
      ignored = "k1=" + fmt(p[3]) + " k2=" + fmt(p[4]);
      break;
    case 4:  // OPENCV fx fy cx cy k1 k2 p1 p2
    case 6:  // FULL_OPENCV fx fy cx cy k1 k2 p1 p2 k3 k4 k5 k6
    {
      cam.fx = p[0], cam.fy = p[1], cam.cx = p[2], cam.cy = p[3];
      static const char* names[] = {"k1", "k2", "p1", "p2", "k3", "k4", "k5", "k6"};
      for (size_t i = 4; i < p.size(); ++i)
        ignored += std::string(i > 4 ? " " : "") + names[i - 4] + "=" + fmt(p[i]);
      break;
    }
    default:
      return Status(
          StatusCode::kInvalidArgument,
          "camera " + std::to_string(c.id) + " uses the " + model +
              " model, which is not supported (use PINHOLE, SIMPLE_PINHOLE, SIMPLE_RADIAL, "
              "RADIAL, OPENCV or FULL_OPENCV, or undistort the images with COLMAP first)");
  }
  if (!ignored.empty() && warnings) {
    const std::string w = "camera " + std::to_string(c.id) + " (" + model +
                          "): distortion ignored, treated as pinhole (" + ignored + ")";
    if (std::find(warnings->begin(), warnings->end(), w) == warnings->end()) warnings->push_back(w);
  }
  const double qn = im.qvec.norm();
  if (!(qn > 1e-12))
    return Status(StatusCode::kInvalidArgument, "image '" + im.name + "' has a zero quaternion");
  cam.R = Eigen::Quaterniond(im.qvec[0], im.qvec[1], im.qvec[2], im.qvec[3])
              .normalized()
              .toRotationMatrix();
  cam.t = im.tvec;
  return cam;
}

}  // namespace crpgs::io
