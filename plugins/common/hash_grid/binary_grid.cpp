/// @file binary_grid.cpp
/// @brief The binary hash grid's configuration, autograd lookup, B_h and state coding (shared by
/// the `hash_grid` and `sfa` plugins).
#include "binary_grid.h"

#include <ATen/Parallel.h>

#include <algorithm>
#include <cmath>
#include <functional>
#include <stdexcept>

#include <torch/torch.h>

#include "crpgs/coding/range_coder.h"

namespace crpgs::hash_grid {
namespace {

std::vector<int64_t> int_list(const YAML::Node& n) {
  std::vector<int64_t> out;
  for (const auto& e : n) out.push_back(e.as<int64_t>());
  return out;
}

/// The grid lookup with the CPU kernels; backward w.r.t. the table only.
struct GridFunction : torch::autograd::Function<GridFunction> {
  static torch::Tensor forward(torch::autograd::AutogradContext* ctx,
                               const torch::Tensor& positions, const torch::Tensor& table,
                               const GridSpec* spec, bool binarize) {
    ctx->save_for_backward({positions, table});
    ctx->saved_data["spec"] = int64_t(reinterpret_cast<intptr_t>(spec));
    ctx->saved_data["binarize"] = binarize;
    return grid_forward(*spec, positions, table, binarize);
  }
  static torch::autograd::tensor_list backward(torch::autograd::AutogradContext* ctx,
                                               torch::autograd::tensor_list grads) {
    const auto saved = ctx->get_saved_variables();
    const auto* spec =
        reinterpret_cast<const GridSpec*>(static_cast<intptr_t>(ctx->saved_data["spec"].toInt()));
    const bool binarize = ctx->saved_data["binarize"].toBool();
    auto grad = grid_backward(*spec, saved[0], saved[1], grads[0], binarize);
    return {torch::Tensor(), grad, torch::Tensor(), torch::Tensor()};
  }
};

/// B_h of a binarised CPU table in one counting pass, its gradient in one more: the ATen
/// expression (table_bits_reference) made ~10 passes over the table each way, per grid and
/// iteration of the rate phase. dB_h/dn₊ = log2((1−p)/p) whether or not p is clamped (the terms
/// through p cancel when it is not, vanish when it is), and dn₊/dt = 0.5 · [|t| ≤ 1].
struct TableBitsFunction : torch::autograd::Function<TableBitsFunction> {
  static torch::Tensor forward(torch::autograd::AutogradContext* ctx, const torch::Tensor& table) {
    const auto t = table.contiguous();
    int64_t n_pos = 0;
    AT_DISPATCH_FLOATING_TYPES(t.scalar_type(), "table_bits", [&] {
      const scalar_t* d = t.data_ptr<scalar_t>();
      n_pos = at::parallel_reduce(
          0, t.numel(), 1 << 16, int64_t(0),
          [&](int64_t begin, int64_t end, int64_t acc) {
            for (int64_t i = begin; i < end; ++i) acc += int64_t(d[i] >= scalar_t(0));
            return acc;
          },
          std::plus<int64_t>());
    });
    const double n = double(t.numel()), np = double(n_pos);
    const double p = std::clamp(np / n, 1e-6, 1 - 1e-6);
    ctx->save_for_backward({table});
    ctx->saved_data["slope"] = 0.5 * std::log2((1 - p) / p);
    return torch::full({}, np * -std::log2(p) + (n - np) * -std::log2(1 - p) + 32.0,
                       table.options());
  }
  static torch::autograd::tensor_list backward(torch::autograd::AutogradContext* ctx,
                                               torch::autograd::tensor_list grads) {
    const auto t = ctx->get_saved_variables()[0].contiguous();
    const double coef = grads[0].item<double>() * ctx->saved_data["slope"].toDouble();
    auto grad = torch::empty_like(t, at::MemoryFormat::Contiguous);
    AT_DISPATCH_FLOATING_TYPES(t.scalar_type(), "table_bits_backward", [&] {
      const scalar_t* d = t.data_ptr<scalar_t>();
      scalar_t* g = grad.data_ptr<scalar_t>();
      const auto c = scalar_t(coef);
      at::parallel_for(0, t.numel(), 1 << 16, [&](int64_t begin, int64_t end) {
        for (int64_t i = begin; i < end; ++i) g[i] = std::abs(d[i]) <= scalar_t(1) ? c : 0;
      });
    });
    return {grad};
  }
};

}  // namespace

const std::string& grid_schema_yaml() {
  static const std::string s = R"yaml(
- {key: n_levels, type: int, default: 12, min: 0, max: 64, doc: "levels of the 3D (xyz) grid; must equal the length of resolutions"}
- {key: resolutions, type: int_list, default: [18, 24, 33, 44, 59, 80, 108, 148, 201, 275, 376, 514], min: 3, max: 65536, doc: "xyz grid resolution per level (effective resolution is res - 2)"}
- {key: log2_hashmap_size, type: int, default: 13, min: 3, max: 30, doc: "log2 of the xyz grid's table entries per level"}
- {key: n_levels_2d, type: int, default: 4, min: 0, max: 64, doc: "levels of each of the xy, xz, yz planes; must equal the length of resolutions_2d"}
- {key: resolutions_2d, type: int_list, default: [130, 258, 514, 1026], min: 3, max: 65536, doc: "plane resolution per level"}
- {key: log2_hashmap_size_2d, type: int, default: 15, min: 3, max: 30, doc: "log2 of each plane's table entries per level"}
- {key: n_features_per_level, type: int, default: 4, min: 1, max: 8, doc: "features per level"}
)yaml";
  return s;
}

const std::string& binarize_schema_yaml() {
  static const std::string s = R"yaml(
- {key: binarize, type: bool, default: true, doc: "sign-binarise the grid (HAC); false keeps float parameters (stored as float32)"}
)yaml";
  return s;
}

GridConfig GridConfig::from_yaml(const YAML::Node& c, const std::string& who) {
  GridConfig g;
  g.res3 = int_list(c["resolutions"]);
  g.res2 = int_list(c["resolutions_2d"]);
  g.log2_3 = c["log2_hashmap_size"].as<int>();
  g.log2_2 = c["log2_hashmap_size_2d"].as<int>();
  g.features = c["n_features_per_level"].as<int64_t>();
  g.binarize = c["binarize"].as<bool>();
  if (c["n_levels"].as<size_t>() != g.res3.size())
    throw std::invalid_argument(who + ": n_levels is " + c["n_levels"].as<std::string>() +
                                " but resolutions lists " + std::to_string(g.res3.size()));
  if (c["n_levels_2d"].as<size_t>() != g.res2.size())
    throw std::invalid_argument(who + ": n_levels_2d is " + c["n_levels_2d"].as<std::string>() +
                                " but resolutions_2d lists " + std::to_string(g.res2.size()));
  if (g.res3.empty() && g.res2.empty())
    throw std::invalid_argument(who + ": no levels (n_levels and n_levels_2d are both 0)");
  return g;
}

void GridConfig::write_yaml(YAML::Node& n) const {
  n["n_levels"] = int64_t(res3.size());
  n["resolutions"] = res3;
  n["log2_hashmap_size"] = log2_3;
  n["n_levels_2d"] = int64_t(res2.size());
  n["resolutions_2d"] = res2;
  n["log2_hashmap_size_2d"] = log2_2;
  n["n_features_per_level"] = features;
}

torch::Tensor init_table(const GridSpec& spec, bool cuda) {
  const auto device = cuda ? torch::Device(torch::kCUDA) : torch::Device(torch::kCPU);
  torch::Tensor table;  // [n_entries, n_features]
  {
    torch::NoGradGuard no_grad;
    table = torch::empty({spec.n_entries, spec.n_features}).uniform_(-1e-4, 1e-4).to(device);
  }
  table.set_requires_grad(true);
  return table;
}

torch::Tensor grid_lookup(const GridSpec& spec, const torch::Tensor& positions01,
                          const torch::Tensor& table, bool binarize) {
  const auto pos = positions01.to(table.device(), table.scalar_type());  // [N, 3]
  if (table.device().is_cpu()) return GridFunction::apply(pos, table, &spec, binarize);
#if CRPGS_GRID_CUDA
  if (table.is_cuda() && grid_cuda_kernels_enabled())
    return grid_lookup_cuda(spec, pos, table, binarize);
#endif
  return grid_forward_reference(spec, pos, table, binarize);
}

torch::Tensor table_bits(const torch::Tensor& table, bool binarize) {
  if (!binarize) return torch::full({}, double(table.numel()) * 32.0);
  if (table.device().is_cpu() && table.numel() > 0) return TableBitsFunction::apply(table);
  return table_bits_reference(table);
}

torch::Tensor table_bits_reference(const torch::Tensor& table) {
  const auto mask = table.detach().abs().le(1).to(table.scalar_type());
  const auto b = binarize_values(table.detach()) + (table - table.detach()) * mask;
  const double n = double(b.numel());
  const auto n_pos = ((b + 1) * 0.5).sum();
  const auto p = torch::clamp(n_pos / n, 1e-6, 1 - 1e-6);
  return n_pos * -torch::log2(p) + (n - n_pos) * -torch::log2(1 - p) + 32.0;
}

void write_table(coding::ByteWriter& w, const torch::Tensor& table, bool binarize) {
  const auto t = table.detach().to(torch::kCPU, torch::kFloat).contiguous();
  const float* d = t.data_ptr<float>();
  const size_t n = size_t(t.numel());
  if (binarize) {
    std::vector<uint8_t> bits(n);
    for (size_t i = 0; i < n; ++i) bits[i] = d[i] >= 0.f ? 1 : 0;
    auto coded = coding::encode_bernoulli(bits);
    TORCH_CHECK(coded.ok(), "binary grid: ", coded.status().to_string());
    w.put_varint(coded->size());
    w.put_bytes(*coded);
  } else {
    for (size_t i = 0; i < n; ++i) w.put_f32(d[i]);
  }
}

Status read_table(coding::ByteReader& r, int64_t n_entries, int64_t n_features, bool binarize,
                  torch::Tensor* out) {
  const size_t n = size_t(n_entries * n_features);
  // The stored bits (or floats) are checked against the bytes present before the table is sized.
  std::vector<uint8_t> bits;
  if (binarize) {
    uint64_t len = 0;
    CRPGS_RETURN_IF_ERROR(r.read_varint(&len));
    if (len > r.remaining()) return r.error("grid bits longer than the state");
    coding::ByteSpan span;
    CRPGS_RETURN_IF_ERROR(r.read_span(size_t(len), &span));
    CRPGS_ASSIGN_OR_RETURN(bits, coding::decode_bernoulli(span, n));
  } else if (r.remaining() / 4 < n) {
    return r.error("truncated grid parameters");
  }
  auto table = torch::empty({n_entries, n_features}, torch::kFloat);
  float* t = table.data_ptr<float>();
  if (binarize) {
    for (size_t i = 0; i < n; ++i) t[i] = bits[i] ? 1.f : -1.f;
  } else {
    for (size_t i = 0; i < n; ++i) CRPGS_RETURN_IF_ERROR(r.read_f32(&t[i]));
  }
  *out = table;
  return OkStatus();
}

void write_f32_tensors(coding::ByteWriter& w, const std::vector<torch::Tensor>& tensors) {
  for (const auto& p : tensors) {
    const auto c = p.detach().to(torch::kCPU, torch::kFloat).contiguous();
    const float* d = c.data_ptr<float>();
    for (int64_t i = 0; i < c.numel(); ++i) w.put_f32(d[i]);
  }
}

Status read_f32_tensors(coding::ByteReader& r, const std::vector<torch::Tensor>& like,
                        const std::string& what, std::vector<torch::Tensor>* out) {
  std::vector<torch::Tensor> result;
  for (const auto& p : like) {
    if (r.remaining() / 4 < size_t(p.numel())) return r.error("truncated " + what);
    auto c = torch::empty(p.sizes(), torch::kFloat);
    float* d = c.data_ptr<float>();
    for (int64_t i = 0; i < c.numel(); ++i) CRPGS_RETURN_IF_ERROR(r.read_f32(&d[i]));
    result.push_back(c);
  }
  *out = std::move(result);
  return OkStatus();
}

void write_state_header(coding::ByteWriter& w, const StateHeader& h) {
  for (uint8_t m : h.magic) w.put_u8(m);
  w.put_u16(h.version);
  w.put_u8(h.binarize ? 1 : 0);
  for (uint64_t v : h.dims) w.put_varint(v);
}

Status read_state_header(coding::ByteReader& r, const StateHeader& h) {
  std::array<uint8_t, 4> magic{};
  for (auto& m : magic) CRPGS_RETURN_IF_ERROR(r.read_u8(&m));
  if (magic != h.magic) return r.error(std::string("bad magic (not a ") + h.what + " state)");
  uint16_t version = 0;
  CRPGS_RETURN_IF_ERROR(r.read_u16(&version));
  if (version != h.version)
    return Status(
        StatusCode::kUnsupportedVersion,
        "version " + std::to_string(version) + ", this build reads " + std::to_string(h.version));
  uint8_t bin = 0;
  CRPGS_RETURN_IF_ERROR(r.read_u8(&bin));
  if (bin != (h.binarize ? 1 : 0))
    return r.error(std::string("stored ") + (bin ? "binary" : "float") +
                   " parameters, the configured grid is " + (h.binarize ? "binary" : "float"));
  for (size_t i = 0; i < h.dims.size(); ++i) {
    uint64_t v = 0;
    CRPGS_RETURN_IF_ERROR(r.read_varint(&v));
    if (v != h.dims[i])
      return r.error(std::string(h.dim_names[i]) + " " + std::to_string(v) +
                     " does not match the configured " + std::to_string(h.dims[i]));
  }
  return OkStatus();
}

}  // namespace crpgs::hash_grid
