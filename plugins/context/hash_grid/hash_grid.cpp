/// @file hash_grid.cpp
/// @brief Context plugin `hash_grid`: HAC's binary multi-resolution hash grid (xyz grid + xy, xz,
/// yz planes, sign-binarised with a straight-through gradient) followed by the context MLP
/// `mlp_grid` that predicts the entropy parameters (method.md §2.1, §2.2, §2.5).
#include <cstring>
#include <stdexcept>

#include <torch/torch.h>

#include "crpgs/coding/bitstream.h"
#include "crpgs/coding/range_coder.h"
#include "crpgs/context_model.h"
#include "crpgs/entropy_model.h"
#include "crpgs/plugin.h"
#include "hash_grid_kernels.h"

namespace crpgs {
namespace {

constexpr const char* kSchema = R"yaml(
- {key: n_levels, type: int, default: 12, min: 0, max: 64, doc: "levels of the 3D (xyz) grid; must equal the length of resolutions"}
- {key: resolutions, type: int_list, default: [18, 24, 33, 44, 59, 80, 108, 148, 201, 275, 376, 514], min: 3, max: 65536, doc: "xyz grid resolution per level (effective resolution is res - 2)"}
- {key: log2_hashmap_size, type: int, default: 13, min: 3, max: 30, doc: "log2 of the xyz grid's table entries per level"}
- {key: n_levels_2d, type: int, default: 4, min: 0, max: 64, doc: "levels of each of the xy, xz, yz planes; must equal the length of resolutions_2d"}
- {key: resolutions_2d, type: int_list, default: [130, 258, 514, 1026], min: 3, max: 65536, doc: "plane resolution per level"}
- {key: log2_hashmap_size_2d, type: int, default: 15, min: 3, max: 30, doc: "log2 of each plane's table entries per level"}
- {key: n_features_per_level, type: int, default: 4, min: 1, max: 8, doc: "features per level"}
- {key: hidden_dim, type: int, default: 100, min: 1, max: 4096, doc: "hidden width of the context MLP mlp_grid"}
- {key: binarize, type: bool, default: true, doc: "sign-binarise the grid (HAC); false keeps float parameters (stored as float32)"}
)yaml";

constexpr uint8_t kStateMagic[4] = {'H', 'G', 'R', 'D'};
constexpr uint16_t kStateVersion = 1;

using hash_grid::GridSpec;

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
    return hash_grid::grid_forward(*spec, positions, table, binarize);
  }
  static torch::autograd::tensor_list backward(torch::autograd::AutogradContext* ctx,
                                               torch::autograd::tensor_list grads) {
    const auto saved = ctx->get_saved_variables();
    const auto* spec =
        reinterpret_cast<const GridSpec*>(static_cast<intptr_t>(ctx->saved_data["spec"].toInt()));
    const bool binarize = ctx->saved_data["binarize"].toBool();
    auto grad = hash_grid::grid_backward(*spec, saved[0], saved[1], grads[0], binarize);
    return {torch::Tensor(), grad, torch::Tensor(), torch::Tensor()};
  }
};

class HashGridContext final : public ContextModel {
 public:
  HashGridContext(const YAML::Node& c, const crpgs_create_args& args)
      : res3_(int_list(c["resolutions"])),
        res2_(int_list(c["resolutions_2d"])),
        log2_3_(c["log2_hashmap_size"].as<int>()),
        log2_2_(c["log2_hashmap_size_2d"].as<int>()),
        features_(c["n_features_per_level"].as<int64_t>()),
        hidden_(c["hidden_dim"].as<int64_t>()),
        binarize_(c["binarize"].as<bool>()) {
    if (c["n_levels"].as<size_t>() != res3_.size())
      throw std::invalid_argument("hash_grid: n_levels is " + c["n_levels"].as<std::string>() +
                                  " but resolutions lists " + std::to_string(res3_.size()));
    if (c["n_levels_2d"].as<size_t>() != res2_.size())
      throw std::invalid_argument("hash_grid: n_levels_2d is " +
                                  c["n_levels_2d"].as<std::string>() +
                                  " but resolutions_2d lists " + std::to_string(res2_.size()));
    if (res3_.empty() && res2_.empty())
      throw std::invalid_argument("hash_grid: no levels (n_levels and n_levels_2d are both 0)");
    spec_ = hash_grid::make_grid_spec(res3_, log2_3_, res2_, log2_2_, features_);
    const int64_t coded = args.coded_dim > 0 ? args.coded_dim : args.feature_dim;
    width_ = EntropyParamLayout{coded, args.n_offsets}.width();
    if (coded < 1 || args.n_offsets < 1)
      throw std::invalid_argument("hash_grid: feature_dim/coded_dim and n_offsets must be >= 1");
    const auto device = args.device_cuda ? torch::Device(torch::kCUDA) : torch::Device(torch::kCPU);
    {
      torch::NoGradGuard no_grad;
      table_ = torch::empty({spec_.n_entries, features_}).uniform_(-1e-4, 1e-4).to(device);
    }
    table_.set_requires_grad(true);
    l1_ = torch::nn::Linear(spec_.output_dim(), hidden_);
    l2_ = torch::nn::Linear(hidden_, width_);
    l1_->to(device);
    l2_->to(device);
  }

  std::string type_name() const override { return "hash_grid"; }
  YAML::Node hyperparams() const override {
    YAML::Node n;
    n["type"] = type_name();
    n["n_levels"] = int64_t(res3_.size());
    n["resolutions"] = res3_;
    n["log2_hashmap_size"] = log2_3_;
    n["n_levels_2d"] = int64_t(res2_.size());
    n["resolutions_2d"] = res2_;
    n["log2_hashmap_size_2d"] = log2_2_;
    n["n_features_per_level"] = features_;
    n["hidden_dim"] = hidden_;
    n["binarize"] = binarize_;
    return n;
  }

  /// Order: the grid table [n_entries, n_features_per_level] (all levels of the xyz grid and the
  /// three planes), then mlp_grid's weight1 [hidden, in], bias1, weight2 [width, hidden], bias2.
  std::vector<torch::Tensor> parameters() override {
    return {table_, l1_->weight, l1_->bias, l2_->weight, l2_->bias};
  }

  int64_t output_dim() const override { return width_; }

  torch::Tensor forward(const torch::Tensor& positions01) override {
    TORCH_CHECK(positions01.dim() == 2 && positions01.size(1) == 3,
                "hash_grid: positions must be [N, 3], got ", positions01.sizes());
    const auto pos = positions01.to(table_.device(), table_.scalar_type());
    torch::Tensor feat;  // [N, output_dim of the grid]
    if (table_.device().is_cpu())
      feat = GridFunction::apply(pos, table_, &spec_, binarize_);
    else
      feat = hash_grid::grid_forward_reference(spec_, pos, table_, binarize_);
    return l2_->forward(torch::relu(l1_->forward(feat)));
  }

  /// HAC's B_h over the whole table, differentiable through the straight-through estimator;
  /// float tables (binarize off) count 32 bits per value. MLP weights are not included.
  torch::Tensor parameter_bits() override {
    if (!binarize_) return torch::full({}, double(table_.numel()) * 32.0);
    const auto mask = table_.detach().abs().le(1).to(table_.scalar_type());
    const auto b = hash_grid::binarize_values(table_.detach()) + (table_ - table_.detach()) * mask;
    const double n = double(b.numel());
    const auto n_pos = ((b + 1) * 0.5).sum();
    const auto p = torch::clamp(n_pos / n, 1e-6, 1 - 1e-6);
    return n_pos * -torch::log2(p) + (n - n_pos) * -torch::log2(1 - p) + 32.0;
  }

  std::vector<uint8_t> save_state() const override {
    coding::ByteWriter w;
    for (uint8_t m : kStateMagic) w.put_u8(m);
    w.put_u16(kStateVersion);
    w.put_u8(binarize_ ? 1 : 0);
    w.put_varint(uint64_t(spec_.n_entries));
    w.put_varint(uint64_t(features_));
    w.put_varint(uint64_t(spec_.output_dim()));
    w.put_varint(uint64_t(hidden_));
    w.put_varint(uint64_t(width_));
    const auto table = table_.detach().to(torch::kCPU, torch::kFloat).contiguous();
    const float* t = table.data_ptr<float>();
    const size_t n = size_t(table.numel());
    if (binarize_) {
      std::vector<uint8_t> bits(n);
      for (size_t i = 0; i < n; ++i) bits[i] = t[i] >= 0.f ? 1 : 0;
      auto coded = coding::encode_bernoulli(bits);
      TORCH_CHECK(coded.ok(), "hash_grid: ", coded.status().to_string());
      w.put_varint(coded->size());
      w.put_bytes(*coded);
    } else {
      for (size_t i = 0; i < n; ++i) w.put_f32(t[i]);
    }
    for (const auto& p : mlp_tensors()) {
      const auto c = p.detach().to(torch::kCPU, torch::kFloat).contiguous();
      const float* d = c.data_ptr<float>();
      for (int64_t i = 0; i < c.numel(); ++i) w.put_f32(d[i]);
    }
    return w.take();
  }

  bool load_state(const std::vector<uint8_t>& bytes, std::string* error) override {
    const Status st = load(bytes);
    if (!st.ok() && error) *error = "hash_grid state: " + st.message();
    return st.ok();
  }

 private:
  std::vector<torch::Tensor> mlp_tensors() const {
    return {l1_->weight, l1_->bias, l2_->weight, l2_->bias};
  }

  Status load(const std::vector<uint8_t>& bytes) {
    coding::ByteReader r(coding::ByteSpan(bytes), "hash_grid state");
    uint8_t magic[4];
    for (auto& m : magic) CRPGS_RETURN_IF_ERROR(r.read_u8(&m));
    if (std::memcmp(magic, kStateMagic, 4) != 0)
      return r.error("bad magic (not a hash_grid state)");
    uint16_t version = 0;
    CRPGS_RETURN_IF_ERROR(r.read_u16(&version));
    if (version != kStateVersion)
      return Status(StatusCode::kUnsupportedVersion, "version " + std::to_string(version) +
                                                         ", this build reads " +
                                                         std::to_string(kStateVersion));
    uint8_t bin = 0;
    CRPGS_RETURN_IF_ERROR(r.read_u8(&bin));
    if (bin != (binarize_ ? 1 : 0))
      return r.error(std::string("stored ") + (bin ? "binary" : "float") +
                     " parameters, the configured grid is " + (binarize_ ? "binary" : "float"));
    const uint64_t expect[5] = {uint64_t(spec_.n_entries), uint64_t(features_),
                                uint64_t(spec_.output_dim()), uint64_t(hidden_), uint64_t(width_)};
    const char* names[5] = {"table entries", "features per level", "MLP input width",
                            "MLP hidden width", "MLP output width"};
    for (int i = 0; i < 5; ++i) {
      uint64_t v = 0;
      CRPGS_RETURN_IF_ERROR(r.read_varint(&v));
      if (v != expect[i])
        return r.error(std::string(names[i]) + " " + std::to_string(v) +
                       " does not match the configured " + std::to_string(expect[i]));
    }
    const size_t n = size_t(spec_.n_entries * features_);
    auto table = torch::empty({spec_.n_entries, features_}, torch::kFloat);
    float* t = table.data_ptr<float>();
    if (binarize_) {
      uint64_t len = 0;
      CRPGS_RETURN_IF_ERROR(r.read_varint(&len));
      if (len > r.remaining()) return r.error("grid bits longer than the state");
      coding::ByteSpan span;
      CRPGS_RETURN_IF_ERROR(r.read_span(size_t(len), &span));
      CRPGS_ASSIGN_OR_RETURN(std::vector<uint8_t> bits, coding::decode_bernoulli(span, n));
      for (size_t i = 0; i < n; ++i) t[i] = bits[i] ? 1.f : -1.f;
    } else {
      if (r.remaining() < n * 4) return r.error("truncated grid parameters");
      for (size_t i = 0; i < n; ++i) CRPGS_RETURN_IF_ERROR(r.read_f32(&t[i]));
    }
    std::vector<torch::Tensor> mlp;
    for (const auto& p : mlp_tensors()) {
      auto c = torch::empty(p.sizes(), torch::kFloat);
      float* d = c.data_ptr<float>();
      if (r.remaining() < size_t(c.numel()) * 4) return r.error("truncated MLP weights");
      for (int64_t i = 0; i < c.numel(); ++i) CRPGS_RETURN_IF_ERROR(r.read_f32(&d[i]));
      mlp.push_back(c);
    }
    if (!r.at_end()) return r.error(std::to_string(r.remaining()) + " trailing bytes");
    torch::NoGradGuard no_grad;
    table_.copy_(table);
    const auto targets = mlp_tensors();
    for (size_t i = 0; i < targets.size(); ++i) targets[i].copy_(mlp[i]);
    return OkStatus();
  }

  std::vector<int64_t> res3_, res2_;
  int log2_3_, log2_2_;
  int64_t features_, hidden_, width_ = 0;
  bool binarize_;
  GridSpec spec_;
  torch::Tensor table_;  // [n_entries, features]
  torch::nn::Linear l1_{nullptr}, l2_{nullptr};
};

}  // namespace
}  // namespace crpgs

CRPGS_PLUGIN(CRPGS_KIND_CONTEXT, crpgs::ContextModel, crpgs::HashGridContext,
             "org.crpgs.context.hash_grid", "hash_grid", 1, 0, crpgs::kSchema)
