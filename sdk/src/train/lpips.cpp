/// @file lpips.cpp
/// @brief The TorchScript LPIPS module (crpgs/lpips.h); the only translation unit that includes
/// libtorch's TorchScript headers.
#include "crpgs/lpips.h"

#include <cmath>

#include <torch/script.h>

namespace crpgs {

struct Lpips::Module {
  torch::jit::script::Module module;
};

Lpips::Lpips(std::string path, std::unique_ptr<Module> module)
    : path_(std::move(path)), module_(std::move(module)) {}
Lpips::~Lpips() = default;

namespace {

/// [1, 3, H, W] in [-1, 1], LPIPS's input convention.
torch::Tensor lpips_input(const Image& im) {
  auto t = torch::from_blob(const_cast<float*>(im.pixels.data()), {im.height, im.width, 3},
                            torch::kFloat);
  return (t.permute({2, 0, 1}).unsqueeze(0) * 2.0 - 1.0).contiguous();
}

StatusOr<double> run(torch::jit::script::Module& m, const torch::Tensor& x, const torch::Tensor& y,
                     const std::string& path) {
  torch::NoGradGuard no_grad;
  try {
    const torch::IValue out = m.forward({x, y});
    if (!out.isTensor())
      return Status(StatusCode::kInvalidArgument,
                    path +
                        ": forward(x, y) returned no tensor (an LPIPS module returns the "
                        "distance; docs/lpips.md)");
    const torch::Tensor d = out.toTensor();
    if (d.numel() != 1)
      return Status(StatusCode::kInvalidArgument,
                    path + ": forward(x, y) returned " + std::to_string(d.numel()) +
                        " values, expected one distance (reduce with .mean(); docs/lpips.md)");
    const double v = d.item<double>();
    if (!std::isfinite(v))
      return Status(StatusCode::kInvalidArgument, path +
                                                      ": forward(x, y) returned a non-finite "
                                                      "distance");
    return v;
  } catch (const c10::Error& e) {
    return Status(StatusCode::kInvalidArgument,
                  path + ": forward(x, y) failed: " + e.what_without_backtrace());
  }
}

}  // namespace

StatusOr<std::shared_ptr<Lpips>> Lpips::load(const std::string& path) {
  auto m = std::make_unique<Module>();
  try {
    m->module = torch::jit::load(path, torch::kCPU);
  } catch (const c10::Error& e) {
    return Status(StatusCode::kInvalidArgument,
                  path +
                      ": not a TorchScript module (save one with torch.jit.save; "
                      "docs/lpips.md): " +
                      e.what_without_backtrace());
  }
  m->module.eval();
  // A pair of small images: a module with another signature fails here, not after a render.
  Image a = Image::zeros(32, 32, 3), b = Image::zeros(32, 32, 3);
  for (size_t i = 0; i < b.pixels.size(); ++i) b.pixels[i] = float(i % 7) / 6.f;
  CRPGS_RETURN_IF_ERROR(run(m->module, lpips_input(a), lpips_input(b), path).status());
  return std::shared_ptr<Lpips>(new Lpips(path, std::move(m)));
}

StatusOr<double> Lpips::distance(const Image& a, const Image& b) const {
  if (a.channels != 3 || b.channels != 3 || a.width != b.width || a.height != b.height)
    return Status(StatusCode::kInvalidArgument, "LPIPS: two RGB images of one size expected");
  return run(module_->module, lpips_input(a), lpips_input(b), path_);
}

}  // namespace crpgs
