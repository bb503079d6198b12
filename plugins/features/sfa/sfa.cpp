/// @file sfa.cpp
/// @brief Feature plugin `sfa`: CRP-GS's Shared Feature Aggregation (docs/method.md §6.1, §7 items
/// 2-4). f_s = Linear(96 -> D_s)(binary hash grid H_s at the clamped anchor position) is
/// concatenated before the coded individual feature f_i: f_a = [f_s, f_i]. ratio 0 is plain HAC.
#include <cmath>
#include <stdexcept>

#include <torch/torch.h>

#include "crpgs/coding/bitstream.h"
#include "crpgs/feature_model.h"
#include "crpgs/plugin.h"
#include "hash_grid/binary_grid.h"

namespace crpgs {
namespace {

/// ratio, then the grid's keys and `binarize` exactly as `hash_grid` has them.
const char* schema() {
  static const std::string s =
      R"yaml(
- {key: ratio, type: float, default: 0.4, min: 0, max: 1, doc: "fraction rho of the feature taken from the shared grid: D_s = round(rho D_0), the coded D_i = D_0 - D_s; 0 is plain HAC (no grid)"}
- {key: zero_init, type: bool, default: false, doc: "start the Linear(grid -> D_s) at zero, so that f_s = 0 as HAC's features are until it learns (with train.feature_model_start: growing_end, training is HAC's until anchor growing and pruning end); false: libtorch's default uniform init"}
)yaml" +
      hash_grid::grid_schema_yaml() + hash_grid::binarize_schema_yaml();
  return s.c_str();
}

using hash_grid::GridSpec;

class SharedFeatureAggregation final : public FeatureModel {
 public:
  SharedFeatureAggregation(const YAML::Node& c, const crpgs_create_args& args)
      : ratio_(c["ratio"].as<double>()),
        zero_init_(c["zero_init"].as<bool>()),
        grid_(hash_grid::GridConfig::from_yaml(c, "sfa")),
        feature_dim_(args.feature_dim) {
    if (feature_dim_ < 1) throw std::invalid_argument("sfa: feature_dim must be positive");
    if (!(ratio_ >= 0 && ratio_ <= 1)) throw std::invalid_argument("sfa: ratio must be in [0, 1]");
    shared_dim_ = int64_t(std::llround(ratio_ * double(feature_dim_)));
    if (shared_dim_ >= feature_dim_)
      throw std::invalid_argument("sfa: ratio " + std::to_string(ratio_) + " leaves no coded " +
                                  "feature (D_s = " + std::to_string(shared_dim_) +
                                  " of D_0 = " + std::to_string(feature_dim_) + ")");
    if (shared_dim_ == 0) return;  // plain HAC: no grid, no parameters, no state
    spec_ = grid_.spec();
    table_ = hash_grid::init_table(spec_, args.device_cuda != 0);
    linear_ = torch::nn::Linear(spec_.output_dim(), shared_dim_);
    if (zero_init_) {
      torch::NoGradGuard no_grad;
      linear_->weight.zero_();
      linear_->bias.zero_();
    }
    linear_->to(table_.device());
  }

  std::string type_name() const override { return "sfa"; }
  YAML::Node hyperparams() const override {
    YAML::Node n;
    n["type"] = type_name();
    n["ratio"] = ratio_;
    n["zero_init"] = zero_init_;
    grid_.write_yaml(n);
    n["binarize"] = grid_.binarize;
    return n;
  }

  int64_t coded_dim() const override { return feature_dim_ - shared_dim_; }
  int64_t feature_dim() const override { return feature_dim_; }

  /// coded [N, D_i], positions01 [N, 3] -> [N, D_0] = [f_s (D_s), coded (D_i)].
  torch::Tensor forward(const torch::Tensor& coded, const torch::Tensor& positions01) override {
    if (shared_dim_ == 0) return coded;
    TORCH_CHECK(coded.dim() == 2 && coded.size(1) == coded_dim(), "sfa: coded must be [N, ",
                coded_dim(), "], got ", coded.sizes());
    TORCH_CHECK(
        positions01.dim() == 2 && positions01.size(1) == 3 && positions01.size(0) == coded.size(0),
        "sfa: positions must be [N, 3] with N = ", coded.size(0), ", got ", positions01.sizes());
    // Anchors grown outside the frozen bounds would read 0 from every level (§7 item 4).
    const auto pos = positions01.detach().clamp(0.0, 1.0);                         // [N, 3]
    const auto grid = hash_grid::grid_lookup(spec_, pos, table_, grid_.binarize);  // [N, 96]
    const auto shared = linear_->forward(grid);                                    // [N, D_s]
    return torch::cat({shared, coded}, 1);
  }

  /// The table first (the `feature_model` lr schedule covers all three), then the Linear.
  std::vector<torch::Tensor> parameters() override {
    if (shared_dim_ == 0) return {};
    return {table_, linear_->weight, linear_->bias};
  }

  /// B_h of the grid (as `hash_grid`); the Linear is a constant numel·32 bits, not included.
  torch::Tensor parameter_bits() override {
    if (shared_dim_ == 0) return torch::zeros({});
    return hash_grid::table_bits(table_, grid_.binarize);
  }

  /// Layout (little-endian): "SFAG" | u16 version (1) | u8 binarize | varint n_entries |
  /// varint n_features | varint grid output width | varint D_s | varint D_i | table (as
  /// hash_grid's) | Linear weight [D_s, 96], bias [D_s] as float32. Empty for ratio 0.
  std::vector<uint8_t> save_state() const override {
    if (shared_dim_ == 0) return {};
    coding::ByteWriter w;
    hash_grid::write_state_header(w, state_header());
    hash_grid::write_table(w, table_, grid_.binarize);
    hash_grid::write_f32_tensors(w, linear_tensors());
    return w.take();
  }

  bool load_state(const std::vector<uint8_t>& bytes, std::string* error) override {
    if (shared_dim_ == 0) return FeatureModel::load_state(bytes, error);
    const Status st = load(bytes);
    if (!st.ok() && error) *error = "sfa state: " + st.message();
    return st.ok();
  }

 private:
  hash_grid::StateHeader state_header() const {
    return {{'S', 'F', 'A', 'G'},
            1,
            grid_.binarize,
            {uint64_t(spec_.n_entries), uint64_t(spec_.n_features), uint64_t(spec_.output_dim()),
             uint64_t(shared_dim_), uint64_t(coded_dim())},
            {"table entries", "features per level", "grid output width", "shared width D_s",
             "coded width D_i"},
            "sfa"};
  }
  std::vector<torch::Tensor> linear_tensors() const { return {linear_->weight, linear_->bias}; }

  Status load(const std::vector<uint8_t>& bytes) {
    coding::ByteReader r(coding::ByteSpan(bytes), "sfa state");
    CRPGS_RETURN_IF_ERROR(hash_grid::read_state_header(r, state_header()));
    torch::Tensor table;
    CRPGS_RETURN_IF_ERROR(
        hash_grid::read_table(r, spec_.n_entries, spec_.n_features, grid_.binarize, &table));
    std::vector<torch::Tensor> linear;
    CRPGS_RETURN_IF_ERROR(
        hash_grid::read_f32_tensors(r, linear_tensors(), "Linear weights", &linear));
    if (!r.at_end()) return r.error(std::to_string(r.remaining()) + " trailing bytes");
    torch::NoGradGuard no_grad;
    table_.copy_(table);
    const auto targets = linear_tensors();
    for (size_t i = 0; i < targets.size(); ++i) targets[i].copy_(linear[i]);
    return OkStatus();
  }

  double ratio_;
  bool zero_init_;
  hash_grid::GridConfig grid_;
  int64_t feature_dim_, shared_dim_ = 0;
  GridSpec spec_;
  torch::Tensor table_;  // [n_entries, n_features_per_level]; undefined for ratio 0
  torch::nn::Linear linear_{nullptr};
};

}  // namespace
}  // namespace crpgs

CRPGS_PLUGIN(CRPGS_KIND_FEATURES, crpgs::FeatureModel, crpgs::SharedFeatureAggregation,
             "org.crpgs.features.sfa", "sfa", 1, 0, crpgs::schema())
