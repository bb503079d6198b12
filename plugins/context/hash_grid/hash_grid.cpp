/// @file hash_grid.cpp
/// @brief Context plugin `hash_grid`: HAC's binary multi-resolution hash grid (xyz grid + xy, xz,
/// yz planes, sign-binarised with a straight-through gradient) followed by the context MLP
/// `mlp_grid` that predicts the entropy parameters (docs/method.md §2.1, §2.2, §2.5).
#include <stdexcept>

#include <torch/torch.h>

#include "crpgs/chunked_mlp.h"
#include "crpgs/coding/bitstream.h"
#include "crpgs/context_model.h"
#include "crpgs/entropy_model.h"
#include "crpgs/plugin.h"
#include "crpgs/portable_math.h"
#include "hash_grid/binary_grid.h"

namespace crpgs {
namespace {

/// The grid's keys (shared with `sfa`), then the context MLP's, then `binarize`.
const char* schema() {
  static const std::string s = hash_grid::grid_schema_yaml() + R"yaml(
- {key: hidden_dim, type: int, default: 100, min: 1, max: 4096, doc: "hidden width of the context MLP mlp_grid"}
)yaml" + hash_grid::binarize_schema_yaml();
  return s.c_str();
}

using hash_grid::GridSpec;

class HashGridContext final : public ContextModel {
 public:
  HashGridContext(const YAML::Node& c, const crpgs_create_args& args)
      : grid_(hash_grid::GridConfig::from_yaml(c, "hash_grid")),
        hidden_(c["hidden_dim"].as<int64_t>()),
        spec_(grid_.spec()) {
    const int64_t coded = args.coded_dim > 0 ? args.coded_dim : args.feature_dim;
    width_ = EntropyParamLayout{coded, args.n_offsets}.width();
    if (coded < 1 || args.n_offsets < 1)
      throw std::invalid_argument("hash_grid: feature_dim/coded_dim and n_offsets must be >= 1");
    table_ = hash_grid::init_table(spec_, args.device_cuda != 0);
    l1_ = torch::nn::Linear(spec_.output_dim(), hidden_);
    l2_ = torch::nn::Linear(hidden_, width_);
    l1_->to(table_.device());
    l2_->to(table_.device());
  }

  std::string type_name() const override { return "hash_grid"; }
  YAML::Node hyperparams() const override {
    YAML::Node n;
    n["type"] = type_name();
    grid_.write_yaml(n);
    n["hidden_dim"] = hidden_;
    n["binarize"] = grid_.binarize;
    return n;
  }

  /// Order: the grid table [n_entries, n_features_per_level] (all levels of the xyz grid and the
  /// three planes), then mlp_grid's weight1 [hidden, in], bias1, weight2 [width, hidden], bias2.
  std::vector<torch::Tensor> parameters() override {
    return {table_, l1_->weight, l1_->bias, l2_->weight, l2_->bias};
  }

  int64_t output_dim() const override { return width_; }

  torch::Tensor forward(const torch::Tensor& positions01) override {
    return l2_->forward(hidden(positions01));
  }

  /// The grid lookup is already portable (hash_grid_kernels.cpp: fixed order, no contraction);
  /// the MLP runs in portable_linear, its ReLU is exact. On the CPU whatever the device.
  torch::Tensor forward_portable(const torch::Tensor& positions01) override {
    torch::NoGradGuard no_grad;
    check_positions(positions01);
    auto cpu = [](const torch::Tensor& t) { return t.detach().to(torch::kCPU); };
    const auto feat = hash_grid::grid_lookup(spec_, cpu(positions01), cpu(table_), grid_.binarize);
    const auto h = torch::relu(portable_linear(feat, cpu(l1_->weight), cpu(l1_->bias)));
    return portable_linear(h, cpu(l2_->weight), cpu(l2_->bias));
  }

  PartialOutput forward_partial(const torch::Tensor& positions01, int64_t tail) override {
    TORCH_CHECK(tail >= 0 && tail <= width_, "hash_grid: tail must be in [0, ", width_, "]");
    check_positions(positions01);
    const auto feat = hash_grid::grid_lookup(spec_, positions01, table_, grid_.binarize);
    const int64_t first = width_ - tail;
    // Every visible anchor's tail (its quantisation steps) in one chunked pass: the [N, hidden]
    // activations, their ReLU, its gradient and the bias sums stay in cache-sized chunks instead
    // of [N, hidden] libtorch temporaries (bench/results/train_fern.md, session 37). The few rows
    // wanted whole (the rate subset) look their grid features up again, so that `feat` has one
    // consumer and no [N, grid width] gradient is zeroed and summed for them.
    auto out_tail = chunked_mlp(feat, l1_->weight, l1_->bias, l2_->weight.slice(0, first),
                                l2_->bias.slice(0, first));
    return {out_tail, [this, positions01](const torch::Tensor& rows) {
              return l2_->forward(hidden(positions01.index_select(0, rows)));
            }};
  }

  /// HAC's B_h over the whole table, differentiable through the straight-through estimator;
  /// float tables (binarize off) count 32 bits per value. MLP weights are not included.
  torch::Tensor parameter_bits() override { return hash_grid::table_bits(table_, grid_.binarize); }

  std::vector<uint8_t> save_state() const override {
    coding::ByteWriter w;
    hash_grid::write_state_header(w, state_header());
    hash_grid::write_table(w, table_, grid_.binarize);
    hash_grid::write_f32_tensors(w, mlp_tensors());
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
  hash_grid::StateHeader state_header() const {
    return {{'H', 'G', 'R', 'D'},
            1,
            grid_.binarize,
            {uint64_t(spec_.n_entries), uint64_t(spec_.n_features), uint64_t(spec_.output_dim()),
             uint64_t(hidden_), uint64_t(width_)},
            {"table entries", "features per level", "MLP input width", "MLP hidden width",
             "MLP output width"},
            "hash_grid"};
  }

  Status load(const std::vector<uint8_t>& bytes) {
    coding::ByteReader r(coding::ByteSpan(bytes), "hash_grid state");
    CRPGS_RETURN_IF_ERROR(hash_grid::read_state_header(r, state_header()));
    torch::Tensor table;
    CRPGS_RETURN_IF_ERROR(
        hash_grid::read_table(r, spec_.n_entries, spec_.n_features, grid_.binarize, &table));
    std::vector<torch::Tensor> mlp;
    CRPGS_RETURN_IF_ERROR(hash_grid::read_f32_tensors(r, mlp_tensors(), "MLP weights", &mlp));
    if (!r.at_end()) return r.error(std::to_string(r.remaining()) + " trailing bytes");
    torch::NoGradGuard no_grad;
    table_.copy_(table);
    const auto targets = mlp_tensors();
    for (size_t i = 0; i < targets.size(); ++i) targets[i].copy_(mlp[i]);
    return OkStatus();
  }

  /// mlp_grid's hidden activations: relu(l1(grid(x))).
  static void check_positions(const torch::Tensor& positions01) {
    TORCH_CHECK(positions01.dim() == 2 && positions01.size(1) == 3,
                "hash_grid: positions must be [N, 3], got ", positions01.sizes());
  }

  torch::Tensor hidden(const torch::Tensor& positions01) {
    check_positions(positions01);
    const auto feat = hash_grid::grid_lookup(spec_, positions01, table_, grid_.binarize);
    return torch::relu(l1_->forward(feat));  // feat: [N, grid output_dim]
  }

  hash_grid::GridConfig grid_;
  int64_t hidden_, width_ = 0;
  GridSpec spec_;
  torch::Tensor table_;  // [n_entries, features]
  torch::nn::Linear l1_{nullptr}, l2_{nullptr};
};

}  // namespace
}  // namespace crpgs

CRPGS_PLUGIN(CRPGS_KIND_CONTEXT, crpgs::ContextModel, crpgs::HashGridContext,
             "org.crpgs.context.hash_grid", "hash_grid", 1, 0, crpgs::schema())
