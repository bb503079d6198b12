/// @file test_sfa.cpp
/// @brief The `sfa` feature model (Shared Feature Aggregation, docs/method.md §6.1): dimensions per
/// ratio, ratio 0 is exactly `identity`, output layout [f_s, coded], clamped positions,
/// gradients (straight-through table, Linear, coded), B_h, save/load, corrupt states, thread
/// independence; all through the registry.
#include <gtest/gtest.h>

#include <cmath>
#include <random>

#include <ATen/Parallel.h>
#include <torch/torch.h>

#include "crpgs/feature_model.h"
#include "hash_grid/hash_grid_kernels.h"
#include "plugins/plugin_test_util.h"

namespace crpgs {
namespace {

/// Dense and hashed levels in 3D and 2D, 9 levels x 3 features = 27 grid columns.
const char* kSmallGrid =
    ", n_levels: 3, resolutions: [6, 18, 40], log2_hashmap_size: 12, n_levels_2d: 2, "
    "resolutions_2d: [18, 70], log2_hashmap_size_2d: 10, n_features_per_level: 3";

hash_grid::GridSpec small_spec() {
  return hash_grid::make_grid_spec({6, 18, 40}, 12, {18, 70}, 10, 3);
}

std::shared_ptr<FeatureModel> make_sfa(const std::string& extra = "") {
  return test::make_plugin<FeatureModel>("features", "{type: sfa" + extra + "}");
}

torch::Tensor random_positions(int64_t n, uint64_t seed) {
  torch::manual_seed(seed);
  return torch::rand({n, 3});
}

TEST(SfaComponent, IsRegisteredAndDefaultsToHacGridWithRatio04) {
  ASSERT_NE(test::plugin_registry().find(CRPGS_KIND_FEATURES, "sfa"), nullptr);
  auto sfa = make_sfa();
  ASSERT_TRUE(sfa);
  EXPECT_EQ(sfa->type_name(), "sfa");
  const auto hp = sfa->hyperparams();
  EXPECT_DOUBLE_EQ(hp["ratio"].as<double>(), 0.4);
  EXPECT_EQ(hp["log2_hashmap_size"].as<int>(), 13);
  EXPECT_EQ(hp["log2_hashmap_size_2d"].as<int>(), 15);
  EXPECT_TRUE(hp["binarize"].as<bool>());
  const auto params = sfa->parameters();
  ASSERT_EQ(params.size(), 3u);
  EXPECT_EQ(params[0].sizes(), torch::IntArrayRef({441568, 4}));  // HAC's table, §2.1
  EXPECT_LE(params[0].abs().max().item<float>(), 1e-4f);
  EXPECT_EQ(params[1].sizes(), torch::IntArrayRef({20, 96}));
  EXPECT_EQ(params[2].sizes(), torch::IntArrayRef({20}));
  for (const auto& p : params) EXPECT_TRUE(p.requires_grad());
}

TEST(SfaComponent, DimensionsFollowTheRatio) {
  const std::vector<std::pair<std::string, int64_t>> cases = {
      {"0", 0}, {"0.2", 10}, {"0.4", 20}, {"0.6", 30}, {"0.8", 40}};
  for (const auto& [ratio, shared] : cases) {
    auto sfa = make_sfa(", ratio: " + ratio + kSmallGrid);
    ASSERT_TRUE(sfa) << ratio;
    EXPECT_EQ(sfa->feature_dim(), 50) << ratio;
    EXPECT_EQ(sfa->coded_dim(), 50 - shared) << ratio;
    const auto coded = torch::randn({7, 50 - shared});
    const auto out = sfa->forward(coded, random_positions(7, 1));
    EXPECT_EQ(out.sizes(), torch::IntArrayRef({7, 50})) << ratio;
    if (shared > 0) {
      EXPECT_EQ(sfa->parameters()[1].size(0), shared) << ratio;
    }
  }
  // D_0 = 20 with rho 0.4: 8 shared + 12 coded.
  auto small = test::make_plugin<FeatureModel>("features", "{type: sfa}",
                                               crpgs_create_args{20, 10, 0, 20, {0, 0, 0, 0}});
  ASSERT_TRUE(small);
  EXPECT_EQ(small->coded_dim(), 12);
}

TEST(SfaComponent, RatioOneLeavesNoCodedFeatureAndIsRefused) {
  auto cfg = Config::from_string("features: {type: sfa, ratio: 1}\n", "t.yaml");
  ASSERT_TRUE(cfg.ok());
  auto resolved = cfg->resolve(test::plugin_registry());
  ASSERT_TRUE(resolved.ok()) << resolved.status().to_string();
  auto c = create_component<FeatureModel>(test::plugin_registry(), resolved->section("features"),
                                          {50, 10, 0, 50, {0, 0, 0, 0}});
  ASSERT_FALSE(c.ok());
  EXPECT_NE(c.status().message().find("no coded"), std::string::npos) << c.status().message();
}

TEST(SfaComponent, RatioZeroIsExactlyIdentity) {
  auto sfa = make_sfa(", ratio: 0");
  auto identity = test::make_plugin<FeatureModel>("features", "{type: identity}");
  ASSERT_TRUE(sfa && identity);
  EXPECT_EQ(sfa->coded_dim(), 50);
  EXPECT_EQ(sfa->feature_dim(), 50);
  const auto coded = torch::randn({64, 50}).requires_grad_(true);
  const auto pos = random_positions(64, 2) * 3 - 1;  // also outside [0, 1]: ignored
  const auto out = sfa->forward(coded, pos);
  EXPECT_TRUE(torch::equal(out, identity->forward(coded, pos)));
  EXPECT_TRUE(torch::equal(out, coded));
  EXPECT_EQ(out.data_ptr(), coded.data_ptr());  // the tensor itself, no copy
  EXPECT_TRUE(sfa->parameters().empty());
  const auto bits = sfa->parameter_bits();
  EXPECT_EQ(bits.dim(), 0);
  EXPECT_EQ(bits.item<double>(), 0.0);
  EXPECT_TRUE(sfa->save_state().empty());
  std::string error;
  EXPECT_TRUE(sfa->load_state({}, &error)) << error;
  EXPECT_FALSE(sfa->load_state({1, 2, 3}, &error));
  EXPECT_NE(error.find("sfa"), std::string::npos) << error;
}

TEST(SfaComponent, OutputIsSharedFeatureThenCodedUnchanged) {
  auto sfa = make_sfa(std::string(kSmallGrid));
  ASSERT_TRUE(sfa);
  ASSERT_EQ(sfa->coded_dim(), 30);
  const auto params = sfa->parameters();
  ASSERT_EQ(params.size(), 3u);
  {
    torch::NoGradGuard g;
    params[0].uniform_(-1, 1);
  }
  const auto coded = torch::randn({200, 30});
  const auto pos = random_positions(200, 3);
  const auto out = sfa->forward(coded, pos);
  ASSERT_EQ(out.sizes(), torch::IntArrayRef({200, 50}));
  EXPECT_TRUE(torch::equal(out.slice(1, 20), coded));
  // f_s = Linear(grid(pos)) with the binarised table.
  const auto grid = hash_grid::grid_forward(small_spec(), pos, params[0].detach(), true);
  ASSERT_EQ(grid.size(1), 27);
  const auto expected = torch::addmm(params[2].detach(), grid, params[1].detach().t());
  const auto shared = out.slice(1, 0, 20).detach();
  EXPECT_LT((shared - expected).abs().max().item<float>(), 1e-5f);
  // f_s depends on the position: not just the bias.
  EXPECT_GT((shared - params[2].detach()).abs().max().item<float>(), 1e-3f);
  EXPECT_GT((shared[0] - shared[1]).abs().max().item<float>(), 0.f);
}

// zero_init: f_s = 0 everywhere at first (as HAC's initial features), whatever the grid holds.
TEST(SfaComponent, ZeroInitStartsTheSharedFeatureAtZero) {
  auto sfa = make_sfa(std::string(kSmallGrid) + ", zero_init: true");
  ASSERT_TRUE(sfa);
  EXPECT_TRUE(sfa->hyperparams()["zero_init"].as<bool>());
  {
    torch::NoGradGuard g;
    sfa->parameters()[0].uniform_(-1, 1);
  }
  const auto out = sfa->forward(torch::randn({100, 30}), random_positions(100, 5));
  EXPECT_EQ(out.slice(1, 0, 20).abs().max().item<float>(), 0.f);
  // The default keeps libtorch's Linear init: f_s varies with the position.
  auto dflt = make_sfa(std::string(kSmallGrid));
  EXPECT_FALSE(dflt->hyperparams()["zero_init"].as<bool>());
  EXPECT_GT(dflt->parameters()[1].abs().max().item<float>(), 0.f);
}

TEST(SfaComponent, PositionsOutsideTheUnitCubeAreClamped) {
  auto sfa = make_sfa(std::string(kSmallGrid));
  ASSERT_TRUE(sfa);
  {
    torch::NoGradGuard g;
    sfa->parameters()[0].uniform_(-1, 1);
  }
  const auto outside = torch::tensor(
      {{-0.3, 0.5, 0.2}, {1.7, 0.4, 0.9}, {0.25, -2.0, 3.0}, {5.0, 5.0, -5.0}}, torch::kFloat);
  const auto clamped = outside.clamp(0, 1);
  const auto coded = torch::randn({4, 30});
  const auto a = sfa->forward(coded, outside);
  const auto b = sfa->forward(coded, clamped);
  EXPECT_TRUE(torch::equal(a, b));
  // Unclamped, every level would read 0 and f_s would be the bias alone.
  const auto bias = sfa->parameters()[2].detach();
  EXPECT_GT((a.slice(1, 0, 20) - bias).abs().sum(1).min().item<float>(), 0.f);
}

TEST(SfaComponent, GradientsReachTableLinearAndCoded) {
  auto sfa = make_sfa(std::string(kSmallGrid));
  ASSERT_TRUE(sfa);
  const auto params = sfa->parameters();
  for (double magnitude : {0.5, 2.0}) {
    {
      torch::NoGradGuard g;
      params[0].copy_(torch::where(torch::rand_like(params[0]) < 0.5, torch::ones_like(params[0]),
                                   -torch::ones_like(params[0])) *
                      magnitude);
      for (const auto& p : params)
        if (p.grad().defined()) p.grad().zero_();
    }
    const auto coded = torch::randn({300, 30}).requires_grad_(true);
    const auto out = sfa->forward(coded, random_positions(300, 4));
    const auto w = torch::randn_like(out);
    (out * w).sum().backward();
    ASSERT_TRUE(coded.grad().defined());
    EXPECT_TRUE(torch::equal(coded.grad(), w.slice(1, 20)));
    ASSERT_TRUE(params[0].grad().defined());
    ASSERT_TRUE(params[1].grad().defined());
    ASSERT_TRUE(params[2].grad().defined());
    EXPECT_GT(params[1].grad().abs().sum().item<float>(), 0.f);
    EXPECT_TRUE(torch::allclose(params[2].grad(), w.slice(1, 0, 20).sum(0), 1e-4, 1e-4));
    // Straight-through: gradient only where |param| <= 1.
    if (magnitude <= 1) {
      EXPECT_GT(params[0].grad().abs().sum().item<float>(), 0.f);
    } else {
      EXPECT_EQ(params[0].grad().abs().max().item<float>(), 0.f);
    }
  }
}

TEST(SfaComponent, ParameterBitsIsHacBhOnAHandCheckedTable) {
  // One dense 3^3 level of one feature: 27 entries, rounded up to 32.
  auto sfa = make_sfa(
      ", n_levels: 1, resolutions: [3], n_levels_2d: 0, resolutions_2d: [], "
      "n_features_per_level: 1");
  ASSERT_TRUE(sfa);
  auto table = sfa->parameters()[0];
  ASSERT_EQ(table.numel(), 32);
  {
    torch::NoGradGuard g;
    table.fill_(-1);
    table.slice(0, 0, 7).fill_(1);
    table.index_put_({7, 0}, 5.0);  // reads +1, outside the straight-through window
  }
  // n = 32, n+ = 8, p = 1/4: 8·2 + 24·(−log2 0.75) + 32.
  const double expected = 16.0 + 24.0 * 0.41503749927884376 + 32.0;
  auto bits = sfa->parameter_bits();
  ASSERT_EQ(bits.dim(), 0);
  EXPECT_NEAR(bits.item<double>(), expected, 1e-4);
  bits.backward();
  ASSERT_TRUE(table.grad().defined());
  // d B_h / d b_i = 0.5 log2((1 − p)/p) = 0.5 log2 3, except where |param| > 1.
  const double slope = 0.5 * std::log2(3.0);
  EXPECT_EQ(table.grad()[7][0].item<float>(), 0.f);
  EXPECT_NEAR(table.grad()[0][0].item<float>(), slope, 1e-5);
  EXPECT_NEAR(table.grad()[20][0].item<float>(), slope, 1e-5);

  auto flt = make_sfa(
      ", n_levels: 1, resolutions: [3], n_levels_2d: 0, resolutions_2d: [], "
      "n_features_per_level: 1, binarize: false");
  ASSERT_TRUE(flt);
  EXPECT_DOUBLE_EQ(flt->parameter_bits().item<double>(), 32.0 * 32);
}

TEST(SfaComponent, SaveLoadRoundTripIsBitIdentical) {
  auto a = make_sfa();
  auto b = make_sfa();
  ASSERT_TRUE(a && b);
  {
    torch::NoGradGuard g;
    a->parameters()[0].uniform_(-1, 1);
  }
  const auto state = a->save_state();
  // About 1 bit per table value plus the float32 Linear.
  EXPECT_LT(state.size(), size_t(441568 * 4 / 8 * 1.01) + (20 * 96 + 20) * 4 + 64);
  std::string error;
  ASSERT_TRUE(b->load_state(state, &error)) << error;
  const auto coded = torch::randn({500, 30});
  const auto pos = random_positions(500, 5);
  EXPECT_TRUE(torch::equal(a->forward(coded, pos), b->forward(coded, pos)));
  EXPECT_EQ(b->save_state(), state);
  EXPECT_TRUE(b->parameters()[0].abs().eq(1).all().item<bool>());

  auto fa = make_sfa(std::string(kSmallGrid) + ", binarize: false");
  auto fb = make_sfa(std::string(kSmallGrid) + ", binarize: false");
  ASSERT_TRUE(fa && fb);
  ASSERT_TRUE(fb->load_state(fa->save_state(), &error)) << error;
  const auto c2 = torch::randn({100, 30});
  const auto p2 = random_positions(100, 6);
  EXPECT_TRUE(torch::equal(fa->forward(c2, p2), fb->forward(c2, p2)));
}

TEST(SfaComponent, MalformedStatesAreRefusedWithAMessage) {
  auto a = make_sfa(kSmallGrid);
  auto b = make_sfa(kSmallGrid);
  auto narrow = make_sfa(std::string(kSmallGrid) + ", ratio: 0.2");
  auto other_grid = make_sfa(", ratio: 0.4");
  auto float_grid = make_sfa(std::string(kSmallGrid) + ", binarize: false");
  auto plain = make_sfa(", ratio: 0");
  ASSERT_TRUE(a && b && narrow && other_grid && float_grid && plain);
  const auto state = a->save_state();
  std::string error;
  EXPECT_FALSE(b->load_state({}, &error));
  EXPECT_FALSE(error.empty());
  for (size_t cut : {size_t(2), size_t(9), state.size() / 2, state.size() - 1}) {
    error.clear();
    EXPECT_FALSE(b->load_state(std::vector<uint8_t>(state.begin(), state.begin() + cut), &error))
        << cut;
    EXPECT_FALSE(error.empty()) << cut;
  }
  auto bad_magic = state;
  bad_magic[0] ^= 0xFF;
  EXPECT_FALSE(b->load_state(bad_magic, &error));
  EXPECT_NE(error.find("magic"), std::string::npos) << error;
  auto bad_version = state;
  bad_version[4] = 9;
  EXPECT_FALSE(b->load_state(bad_version, &error));
  EXPECT_NE(error.find("version"), std::string::npos) << error;
  auto trailing = state;
  trailing.push_back(0);
  EXPECT_FALSE(b->load_state(trailing, &error));
  EXPECT_NE(error.find("trailing"), std::string::npos) << error;
  EXPECT_FALSE(narrow->load_state(state, &error));
  EXPECT_NE(error.find("shared width"), std::string::npos) << error;
  EXPECT_FALSE(other_grid->load_state(state, &error));
  EXPECT_NE(error.find("table entries"), std::string::npos) << error;
  EXPECT_FALSE(float_grid->load_state(state, &error));
  EXPECT_NE(error.find("binary"), std::string::npos) << error;
  EXPECT_FALSE(plain->load_state(state, &error));
  EXPECT_NE(error.find("no state"), std::string::npos) << error;
  // Garbage and random flips never crash (flips inside the bit stream may go undetected).
  std::mt19937 rng(7);
  std::vector<uint8_t> garbage(300);
  for (auto& g : garbage) g = uint8_t(rng());
  EXPECT_FALSE(b->load_state(garbage, &error));
  for (int i = 0; i < 100; ++i) {
    auto s = state;
    s[rng() % s.size()] ^= uint8_t(1 + rng() % 255);
    b->load_state(s, &error);
  }
  // A failed load leaves a usable object that still accepts the good state.
  ASSERT_TRUE(b->load_state(state, &error)) << error;
  const auto coded = torch::randn({50, 30});
  const auto pos = random_positions(50, 8);
  EXPECT_TRUE(torch::equal(a->forward(coded, pos), b->forward(coded, pos)));
}

TEST(SfaComponent, ForwardAndBackwardDoNotDependOnThreadCount) {
  auto sfa = make_sfa();
  ASSERT_TRUE(sfa);
  const auto params = sfa->parameters();
  {
    torch::NoGradGuard g;
    params[0].uniform_(-2, 2);
  }
  const auto coded = torch::randn({5000, 30});
  const auto pos = random_positions(5000, 9);
  const auto w = torch::randn({5000, 50});
  auto run = [&](int threads) {
    at::set_num_threads(threads);
    for (const auto& p : params)
      if (p.grad().defined()) p.grad().zero_();
    const auto out = sfa->forward(coded, pos);
    (out * w).sum().backward();
    return std::vector<torch::Tensor>{out.detach(), params[0].grad().clone(),
                                      params[1].grad().clone()};
  };
  const int before = at::get_num_threads();
  const auto one = run(1);
  const auto two = run(2);
  at::set_num_threads(before);
  for (size_t i = 0; i < one.size(); ++i) EXPECT_TRUE(torch::equal(one[i], two[i])) << i;
  EXPECT_GT(one[1].abs().sum().item<float>(), 0.f);
}

}  // namespace
}  // namespace crpgs
