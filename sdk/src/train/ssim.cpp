/// @file ssim.cpp
/// @brief The training loss's SSIM with a hand-written backward: eight separable blurs in all
/// (five forward, three backward) instead of ten depthwise convolutions and their autograd.
#include <torch/torch.h>

#include <ATen/Parallel.h>

#include <vector>

#include "crpgs/trainer.h"
#include "io/gaussian_blur.h"

namespace crpgs {
namespace {

namespace sw = ssim_window;
using torch::autograd::AutogradContext;
using torch::autograd::variable_list;

constexpr int64_t kRowGrain = 8;          // rows of an image per task
constexpr int64_t kPixelGrain = 1 << 14;  // values per task in the element-wise loops

/// The SSIM window over an [H, W, C] image (channels interleaved). `tmp`: H*W*C scratch.
void blur(const float* in, float* out, float* tmp, int64_t H, int64_t W, int64_t C) {
  at::parallel_for(0, H, kRowGrain,
                   [&](int64_t b, int64_t e) { sw::blur_rows_f32(in, tmp, b, e, W, C); });
  at::parallel_for(0, H, kRowGrain,
                   [&](int64_t b, int64_t e) { sw::blur_columns_f32(tmp, out, b, e, H, W * C); });
}

struct SsimFunction : public torch::autograd::Function<SsimFunction> {
  /// Mean SSIM of x against y (both [H, W, C]); the gradient flows to x only.
  static at::Tensor forward(AutogradContext* ctx, const at::Tensor& x_in, const at::Tensor& y_in) {
    TORCH_CHECK(x_in.dim() == 3 && x_in.sizes() == y_in.sizes(),
                "tensor_ssim: expected two [H, W, C] images of one size");
    TORCH_CHECK(
        x_in.scalar_type() == at::kFloat && y_in.scalar_type() == at::kFloat && x_in.numel() > 0,
        "tensor_ssim: expected non-empty float images");
    TORCH_CHECK(!y_in.requires_grad(), "tensor_ssim: the reference image takes no gradient");
    const at::Tensor x = x_in.contiguous(), y = y_in.contiguous();
    const int64_t H = x.size(0), W = x.size(1), C = x.size(2), n = x.numel(), len = W * C;
    const float* px = x.data_ptr<float>();
    const float* py = y.data_ptr<float>();
    // mx, my, exx, eyy, exy: the blurred x, y, x^2, y^2, xy.
    std::vector<float> maps(static_cast<size_t>(5 * n)), tmp(static_cast<size_t>(n)),
        prod(static_cast<size_t>(n));
    float *mx = maps.data(), *my = mx + n, *exx = my + n, *eyy = exx + n, *exy = eyy + n;
    blur(px, mx, tmp.data(), H, W, C);
    blur(py, my, tmp.data(), H, W, C);
    float* q = prod.data();
    at::parallel_for(0, n, kPixelGrain, [&](int64_t b, int64_t e) {
      for (int64_t i = b; i < e; ++i) q[i] = px[i] * px[i];
    });
    blur(q, exx, tmp.data(), H, W, C);
    at::parallel_for(0, n, kPixelGrain, [&](int64_t b, int64_t e) {
      for (int64_t i = b; i < e; ++i) q[i] = py[i] * py[i];
    });
    blur(q, eyy, tmp.data(), H, W, C);
    at::parallel_for(0, n, kPixelGrain, [&](int64_t b, int64_t e) {
      for (int64_t i = b; i < e; ++i) q[i] = px[i] * py[i];
    });
    blur(q, exy, tmp.data(), H, W, C);

    // The map, and the derivatives of its mean with respect to mx, exy and exx, which the
    // backward blurs (derivation above backward()).
    at::Tensor g_m = at::empty_like(x), g_exy = at::empty_like(x), g_exx = at::empty_like(x);
    float *gm = g_m.data_ptr<float>(), *gxy = g_exy.data_ptr<float>(),
          *gxx = g_exx.data_ptr<float>();
    const float c1 = float(sw::kC1), c2 = float(sw::kC2), inv_n = 1.0f / float(n);
    std::vector<double> row_sum(size_t(H), 0.0);  // per row, summed in order: thread-count free
    at::parallel_for(0, H, kRowGrain, [&](int64_t b, int64_t e) {
      for (int64_t r = b; r < e; ++r) {
        double s = 0;
        for (int64_t i = r * len; i < (r + 1) * len; ++i) {
          const float a1 = 2 * mx[i] * my[i] + c1, a2 = 2 * (exy[i] - mx[i] * my[i]) + c2;
          const float b1 = mx[i] * mx[i] + my[i] * my[i] + c1;
          const float b2 = (exx[i] - mx[i] * mx[i]) + (eyy[i] - my[i] * my[i]) + c2;
          const float inv = 1.0f / (b1 * b2), ssim = a1 * a2 * inv;
          s += ssim;
          gm[i] =
              inv_n * (2 * my[i] * (a2 - a1) * inv + 2 * mx[i] * ssim * (1.0f / b2 - 1.0f / b1));
          gxy[i] = inv_n * 2 * a1 * inv;
          gxx[i] = -inv_n * ssim / b2;
        }
        row_sum[size_t(r)] = s;
      }
    });
    double total = 0;
    for (double s : row_sum) total += s;
    ctx->save_for_backward({x, y, g_m, g_exy, g_exx});
    return at::scalar_tensor(total / double(n), x.options());
  }

  // S = A1 A2 / (B1 B2) per pixel, A1 = 2 mx my + C1, A2 = 2 (exy - mx my) + C2,
  // B1 = mx^2 + my^2 + C1, B2 = (exx - mx^2) + (eyy - my^2) + C2, with mx = B(x), exx = B(x^2),
  // exy = B(xy) for the blur B. The blur is symmetric with zero padding, so B' = B and
  // d mean(S) / dx = B(g_m) + 2 x B(g_exx) + y B(g_exy).
  static variable_list backward(AutogradContext* ctx, variable_list grads) {
    const variable_list saved = ctx->get_saved_variables();
    const at::Tensor &x = saved[0], &y = saved[1];
    const int64_t H = x.size(0), W = x.size(1), C = x.size(2), n = x.numel();
    const float go = grads[0].item<float>();
    std::vector<float> blurred(static_cast<size_t>(3 * n)), tmp(static_cast<size_t>(n));
    float *bm = blurred.data(), *bxy = bm + n, *bxx = bxy + n;
    blur(saved[2].data_ptr<float>(), bm, tmp.data(), H, W, C);
    blur(saved[3].data_ptr<float>(), bxy, tmp.data(), H, W, C);
    blur(saved[4].data_ptr<float>(), bxx, tmp.data(), H, W, C);
    at::Tensor dx = at::empty_like(x);
    float* d = dx.data_ptr<float>();
    const float *px = x.data_ptr<float>(), *py = y.data_ptr<float>();
    at::parallel_for(0, n, kPixelGrain, [&](int64_t b, int64_t e) {
      for (int64_t i = b; i < e; ++i) d[i] = go * (bm[i] + 2 * px[i] * bxx[i] + py[i] * bxy[i]);
    });
    return {dx, at::Tensor()};
  }
};

// The window as two depthwise convolutions over [1, C, H, W] planes (zero padding).
at::Tensor blur_planes(const at::Tensor& planes) {
  const auto g = ssim_window::taps<double>();
  const auto w = torch::tensor(std::vector<double>(g.begin(), g.end())).to(planes.options());
  const int64_t C = planes.size(1), r = ssim_window::kRadius;
  const auto rows = torch::conv2d(planes, w.view({1, 1, 1, -1}).expand({C, 1, 1, w.size(0)}), {}, 1,
                                  at::IntArrayRef({0, r}), 1, C);
  return torch::conv2d(rows, w.view({1, 1, -1, 1}).expand({C, 1, w.size(0), 1}), {}, 1,
                       at::IntArrayRef({r, 0}), 1, C);
}

}  // namespace

torch::Tensor tensor_ssim_reference(const torch::Tensor& a, const torch::Tensor& b) {
  TORCH_CHECK(a.dim() == 3 && a.sizes() == b.sizes() && a.numel() > 0,
              "tensor_ssim: expected two non-empty [H, W, C] images of one size");
  TORCH_CHECK(!b.requires_grad(), "tensor_ssim: the reference image takes no gradient");
  auto planes = [](const torch::Tensor& t) { return t.permute({2, 0, 1}).unsqueeze(0); };
  const auto x = planes(a), y = planes(b.detach());
  // The five blurred maps in one pair of convolutions (their channels side by side): five
  // times fewer kernel launches, what a GPU is bound by at these sizes.
  const auto maps = blur_planes(torch::cat({x, y, x * x, y * y, x * y}, 1)).chunk(5, 1);
  const auto &mx = maps[0], &my = maps[1];
  const auto vx = maps[2] - mx * mx, vy = maps[3] - my * my, cxy = maps[4] - mx * my;
  const double c1 = ssim_window::kC1, c2 = ssim_window::kC2;
  return ((2 * mx * my + c1) * (2 * cxy + c2) / ((mx * mx + my * my + c1) * (vx + vy + c2))).mean();
}

torch::Tensor tensor_ssim(const torch::Tensor& a, const torch::Tensor& b) {
  if (!a.device().is_cpu()) return tensor_ssim_reference(a, b);
  return SsimFunction::apply(a, b);
}

}  // namespace crpgs
