/// @file fuzz_seeds.cpp
#include "fuzz_seeds.h"

#include <random>
#include <set>

#include <torch/torch.h>

#include "crpgs/codec.h"
#include "crpgs/coding/geometry.h"
#include "crpgs/components.h"
#include "crpgs/trainer.h"

namespace crpgs::fuzz {
namespace {

// Small tables and MLPs keep every seed to a few KB.
constexpr const char* kContext =
    "context: {type: hash_grid, n_levels: 1, resolutions: [8], log2_hashmap_size: 4, "
    "n_levels_2d: 1, resolutions_2d: [8], log2_hashmap_size_2d: 4, hidden_dim: 2";
constexpr const char* kModel =
    "entropy: {type: gaussian}\nmodel: {feature_dim: 6, n_offsets: 2, hidden_dim: 2}\n";

struct Variant {
  const char* name;
  std::string yaml;
  int64_t anchors;
  bool links = false;
  bool all_masked = false;
  /// Non-zero: the context's step outputs a are about this (its last bias), so the adaptive
  /// steps are tiny and 1 + tanh a has lost most of its digits in float.
  double step_bias = 0;
};

std::vector<Variant> variants() {
  const std::string ctx = std::string(kContext) + "}\n";
  const std::string plain_scene = "scene: {view_dependent: false, distance_input: false}\n";
  const std::string linked = plain_scene + "links: {type: link_random}\n";
  return {
      {"plain", ctx + kModel + plain_scene, 16},
      {"single", ctx + kModel + plain_scene, 1, false, true},
      {"raw_geometry", ctx + kModel + "rate: {geometry: raw}\n", 12},
      {"links", ctx + kModel + linked, 16, true},
      {"links_residual", ctx + kModel + linked + "rate: {leaf_residual: true}\n", 12, true},
      {"links_paper", ctx + kModel + linked + "rate: {link_coding: paper}\n", 16, true},
      {"sfa",
       ctx + kModel + plain_scene +
           "features: {type: sfa, ratio: 0.5, n_levels: 1, resolutions: [4], log2_hashmap_size: 3, "
           "n_levels_2d: 1, resolutions_2d: [4], log2_hashmap_size_2d: 3}\n",
       12},
      {"float_grid",
       std::string(kContext) + ", binarize: false}\n" + kModel + "scene: {appearance_dim: 2}\n",
       10},
      {"small_steps", ctx + kModel + plain_scene, 12, false, false, -5.0},
  };
}

StatusOr<Seed> make_seed(const Variant& v, const ComponentRegistry& reg, uint32_t seed) {
  torch::manual_seed(seed);  // the components' initial tables and MLPs
  CRPGS_ASSIGN_OR_RETURN(Config raw, Config::from_string(v.yaml, std::string(v.name) + ".yaml"));
  CRPGS_ASSIGN_OR_RETURN(Config config, raw.resolve(reg));
  crpgs_create_args args = create_args_for(config);
  CodecComponents c;
  CRPGS_ASSIGN_OR_RETURN(c.features,
                         create_component<FeatureModel>(reg, config.section("features"), args));
  args.coded_dim = int32_t(c.features->coded_dim());
  CRPGS_ASSIGN_OR_RETURN(c.context,
                         create_component<ContextModel>(reg, config.section("context"), args));
  CRPGS_ASSIGN_OR_RETURN(c.entropy,
                         create_component<EntropyModel>(reg, config.section("entropy"), args));
  CRPGS_ASSIGN_OR_RETURN(AnchorModelOptions o, model_options_from_config(config));
  const int64_t n = v.anchors, K = o.n_offsets, dc = c.features->coded_dim();

  std::mt19937 rng(seed);
  std::uniform_int_distribution<int32_t> coord(-20, 20);
  std::vector<coding::Voxel> pts;
  std::set<coding::Voxel> seen;
  while (int64_t(pts.size()) < n) {
    const coding::Voxel p{coord(rng), coord(rng), coord(rng)};
    if (seen.insert(p).second) pts.push_back(p);
  }
  coding::sort_morton(&pts);

  torch::NoGradGuard no_grad;
  if (v.step_bias != 0) {
    // hash_grid's parameters end with mlp_grid's output bias; its last columns are the steps'.
    const torch::Tensor bias = c.context->parameters().back();
    bias.slice(0, bias.size(0) - EntropyParamLayout::kStepColumns).fill_(v.step_bias);
  }
  auto gen = at::detail::createCPUGenerator(seed);
  CodedModel m;
  m.voxel_size = 0.05;
  m.chunk = 5;  // several chunks per stream
  m.voxels = torch::empty({n, 3}, torch::kInt);
  for (int64_t i = 0; i < n; ++i)
    for (int a = 0; a < 3; ++a) m.voxels[i][a] = pts[size_t(i)][size_t(a)];
  m.bounds = torch::tensor({{-1.5f, -1.5f, -1.5f}, {1.5f, 1.5f, 1.5f}});
  m.offset_masks =
      v.all_masked ? torch::zeros({n, K}, torch::kBool) : torch::rand({n, K}, gen) > 0.3;
  m.feature_sym = torch::round(torch::randn({n, dc}, gen) * 3).to(torch::kInt);
  m.scaling_sym = torch::round(torch::rand({n, 6}, gen) * 40 + 1).to(torch::kInt);
  m.offset_sym = (torch::round(torch::randn({n, K, 3}, gen) * 5) * m.offset_masks.unsqueeze(2))
                     .to(torch::kInt);
  // The render MLPs exactly as AnchorModel::from_decoded expects them.
  const SceneEffects& fx = o.effects;
  const int64_t in =
      c.features->feature_dim() + (fx.view_dependent ? 3 : 0) + (fx.distance_input ? 1 : 0);
  const int64_t H = o.hidden_dim;
  const std::vector<std::tuple<std::string, int64_t, int64_t>> mlps = {
      {"mlp_opacity", in, K}, {"mlp_cov", in, 7 * K}, {"mlp_color", in + fx.appearance_dim, 3 * K}};
  for (const auto& [name, din, dout] : mlps) {
    m.mlps[name + ".w1"] = torch::randn({H, din}, gen) * 0.1;
    m.mlps[name + ".b1"] = torch::randn({H}, gen) * 0.1;
    m.mlps[name + ".w2"] = torch::randn({dout, H}, gen) * 0.1;
    m.mlps[name + ".b2"] = torch::randn({dout}, gen) * 0.1;
  }
  if (fx.appearance_dim > 0) m.mlps["appearance"] = torch::randn({3, fx.appearance_dim}, gen);
  const YAML::Node rate = config.section("rate");
  m.geometry = rate["geometry"].as<std::string>();
  m.leaf_residual = rate["leaf_residual"].as<bool>();
  m.link_coding = rate["link_coding"].as<std::string>();
  if (v.links) {
    // Every third anchor is a leaf of the anchor before it (a root, never itself a leaf).
    m.links = torch::full({n}, -1, torch::kLong);
    for (int64_t i = 1; i < n; i += 3) m.links[i] = i - 1;
    // Five model anchors that are not coded, among the coded ones.
    m.anchor_mask = torch::ones({n + 5}, torch::kBool);
    for (int64_t i = 0; i < 5; ++i) m.anchor_mask[2 + 3 * i] = false;
    const int64_t hl = 3;
    m.mlps["leaf_mlp.w1"] = torch::randn({hl, dc + 6}, gen) * 0.1;
    m.mlps["leaf_mlp.b1"] = torch::randn({hl}, gen) * 0.1;
    m.mlps["leaf_mlp.w2"] = torch::randn({dc, hl}, gen) * 0.1;
    m.mlps["leaf_mlp.b2"] = torch::randn({dc}, gen) * 0.1;
  }
  CRPGS_ASSIGN_OR_RETURN(EncodeResult enc, encode_model(m, config, c));
  return Seed{std::string("seed-") + v.name + ".crpgs", std::move(enc.bytes)};
}

}  // namespace

StatusOr<std::vector<Seed>> make_seeds(const ComponentRegistry& registry) {
  std::vector<Seed> out;
  uint32_t seed = 1;
  for (const Variant& v : variants()) {
    auto s = make_seed(v, registry, seed++);
    if (!s.ok())
      return Status(s.status().code(),
                    std::string("seed '") + v.name + "': " + s.status().message());
    out.push_back(std::move(s).value());
  }
  return out;
}

}  // namespace crpgs::fuzz
