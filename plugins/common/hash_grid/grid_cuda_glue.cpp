/// @file grid_cuda_glue.cpp
/// @brief grid_lookup_cuda: the CUDA kernels (grid_cuda.h) as an autograd function of the table.
/// Linked into the grid plugins where the CUDA rasterizer is (a CUDA libtorch and nvcc),
/// elsewhere compiled on its own so that a broken glue fails every build.
#include <cstdlib>
#include <cstring>
#include <vector>

#include <torch/torch.h>

#include "grid_cuda.h"
#include "hash_grid_kernels.h"

namespace crpgs::hash_grid {
namespace {

std::vector<cuda_kernels::Level> cuda_levels(const GridSpec& spec) {
  std::vector<cuda_kernels::Level> out;
  for (const GridLevel& lv : spec.levels) {
    cuda_kernels::Level l{};
    l.dim = lv.dim;
    for (int d = 0; d < 3; ++d) l.axes[d] = lv.axes[d];
    l.res = int32_t(lv.res);  // make_grid_spec caps resolutions at 65536
    l.dense = lv.dense ? 1 : 0;
    l.offset = lv.offset;
    l.size = lv.size;
    out.push_back(l);
  }
  return out;
}

void check(const char* error) {
  TORCH_CHECK(error == nullptr, "hash_grid (cuda): ", error);
}

struct GridCudaFunction : torch::autograd::Function<GridCudaFunction> {
  static torch::Tensor forward(torch::autograd::AutogradContext* ctx,
                               const torch::Tensor& positions, const torch::Tensor& table,
                               const GridSpec* spec, bool binarize) {
    const auto pos = positions.contiguous();
    const auto tab = table.contiguous();
    ctx->save_for_backward({pos, tab});
    ctx->saved_data["spec"] = int64_t(reinterpret_cast<intptr_t>(spec));
    ctx->saved_data["binarize"] = binarize;
    const auto levels = cuda_levels(*spec);
    auto out = torch::empty({pos.size(0), spec->output_dim()}, tab.options());
    AT_DISPATCH_FLOATING_TYPES(tab.scalar_type(), "hash_grid_cuda_forward", [&] {
      check(cuda_kernels::forward(levels.data(), int(levels.size()), spec->n_features,
                                  pos.data_ptr<scalar_t>(), tab.data_ptr<scalar_t>(), pos.size(0),
                                  binarize, out.data_ptr<scalar_t>()));
    });
    return out;
  }
  static torch::autograd::tensor_list backward(torch::autograd::AutogradContext* ctx,
                                               torch::autograd::tensor_list grads) {
    const auto saved = ctx->get_saved_variables();
    const auto* spec =
        reinterpret_cast<const GridSpec*>(static_cast<intptr_t>(ctx->saved_data["spec"].toInt()));
    const bool binarize = ctx->saved_data["binarize"].toBool();
    const auto& pos = saved[0];
    const auto& tab = saved[1];
    const auto go = grads[0].to(tab.scalar_type()).contiguous();
    const auto levels = cuda_levels(*spec);
    auto grad = torch::zeros_like(tab);
    AT_DISPATCH_FLOATING_TYPES(tab.scalar_type(), "hash_grid_cuda_backward", [&] {
      check(cuda_kernels::backward(levels.data(), int(levels.size()), spec->n_features,
                                   pos.data_ptr<scalar_t>(), go.data_ptr<scalar_t>(),
                                   tab.data_ptr<scalar_t>(), tab.size(0), pos.size(0), binarize,
                                   grad.data_ptr<scalar_t>()));
    });
    return {torch::Tensor(), grad, torch::Tensor(), torch::Tensor()};
  }
};

}  // namespace

bool grid_cuda_kernels_enabled() {
  const char* v = std::getenv("CRPGS_GRID_CUDA");
  return v == nullptr || std::strcmp(v, "0") != 0;
}

at::Tensor grid_lookup_cuda(const GridSpec& spec, const at::Tensor& positions01,
                            const at::Tensor& table, bool binarize) {
  TORCH_CHECK(table.is_cuda() && positions01.device() == table.device(),
              "hash_grid (cuda): positions and table must be on the same CUDA device");
  check_grid_inputs(spec, positions01, table);
  return GridCudaFunction::apply(positions01.to(table.scalar_type()), table, &spec, binarize);
}

}  // namespace crpgs::hash_grid
