/// @file test_hash_grid.cpp
/// @brief The binary hash grid: layout counts, CPU kernels against the ATen reference (values and
/// gradients, dense and hashed levels, corners, borders, out-of-bounds), thread-count
/// independence, and the `hash_grid` component (shape, B_h, save/load, corrupt state).
#include <gtest/gtest.h>

#include <cmath>
#include <limits>
#include <random>

#include <ATen/Parallel.h>
#include <torch/torch.h>

#include "crpgs/context_model.h"
#include "crpgs/portable_math.h"
#include "hash_grid/binary_grid.h"
#include "hash_grid/hash_grid_kernels.h"
#include "plugins/plugin_test_util.h"

namespace crpgs {
namespace {

using hash_grid::GridSpec;

GridSpec hac_spec() {
  return hash_grid::make_grid_spec({18, 24, 33, 44, 59, 80, 108, 148, 201, 275, 376, 514}, 13,
                                   {130, 258, 514, 1026}, 15, 4);
}

/// A small spec with dense and hashed levels in 3D and 2D.
GridSpec small_spec() {
  return hash_grid::make_grid_spec({6, 18, 40}, 12, {18, 70}, 10, 3);
}

torch::Tensor random_positions(int64_t n, torch::ScalarType type, uint64_t seed) {
  torch::manual_seed(seed);
  return torch::rand({n, 3}, torch::TensorOptions().dtype(type));
}

TEST(HashGridSpec, MatchesHacLayout) {
  const GridSpec s = hac_spec();
  ASSERT_EQ(s.levels.size(), 24u);
  EXPECT_EQ(s.output_dim(), 96);
  EXPECT_EQ(s.levels[0].size, 5832);  // 18^3, dense
  EXPECT_TRUE(s.levels[0].dense);
  EXPECT_EQ(s.levels[1].size, 8192);
  EXPECT_FALSE(s.levels[1].dense);
  EXPECT_EQ(s.levels[12].size, 16904);  // 130^2 = 16900 rounded up to a multiple of 8
  EXPECT_TRUE(s.levels[12].dense);
  EXPECT_FALSE(s.levels[13].dense);
  EXPECT_EQ(s.n_entries * s.n_features, 1766272);  // docs/method.md §2.1
  // Planes read xy, xz, yz in that order.
  EXPECT_EQ(s.levels[16].axes[0], 0);
  EXPECT_EQ(s.levels[16].axes[1], 2);
  EXPECT_EQ(s.levels[20].axes[0], 1);
  EXPECT_EQ(s.levels[20].axes[1], 2);
  EXPECT_THROW(hash_grid::make_grid_spec({2}, 13, {}, 15, 4), std::invalid_argument);
}

TEST(HashGridKernels, ForwardMatchesReferenceFloat64) {
  const GridSpec s = small_spec();
  const auto pos = random_positions(3000, torch::kDouble, 1);
  const auto table = torch::randn({s.n_entries, s.n_features}, torch::kDouble);
  for (bool binarize : {false, true}) {
    const auto out = hash_grid::grid_forward(s, pos, table, binarize);
    const auto ref = hash_grid::grid_forward_reference(s, pos, table, binarize);
    ASSERT_EQ(out.sizes(), ref.sizes());
    // Bit for bit: the kernel keeps the reference's operation order (built without FMA
    // contraction), which is what makes encoder and decoder agree on any machine.
    EXPECT_TRUE(torch::equal(out, ref))
        << "binarize " << binarize << ", max difference " << (out - ref).abs().max().item<double>();
    EXPECT_GT(out.abs().max().item<double>(), 0.1);
  }
}

TEST(HashGridKernels, ForwardMatchesReferenceFloat32HacLayout) {
  const GridSpec s = hac_spec();
  const auto pos = random_positions(2000, torch::kFloat, 2);
  const auto table = torch::empty({s.n_entries, s.n_features}).uniform_(-1e-4, 1e-4);
  const auto out = hash_grid::grid_forward(s, pos, table, true);
  const auto ref = hash_grid::grid_forward_reference(s, pos, table, true);
  EXPECT_TRUE(torch::equal(out, ref)) << "max difference " << (out - ref).abs().max().item<float>();
  EXPECT_LE(out.abs().max().item<float>(), 1.0f + 1e-5f);  // convex combination of ±1
}

TEST(HashGridKernels, BinarizedForwardEqualsForwardOfTheSignTableBitForBit) {
  // The binarised forward reads packed sign bits; it must round exactly like reading ±1 floats
  // (encoder and decoder of existing files depend on it). Zeros and NaN: HAC's sign is +1 for
  // x >= 0 and -1 otherwise (NaN included).
  const GridSpec s = hac_spec();
  const auto pos = random_positions(2000, torch::kFloat, 3);
  auto table = torch::empty({s.n_entries, s.n_features}).uniform_(-1e-4, 1e-4);
  table.index_put_({torch::indexing::Slice(0, 64)}, 0.0f);
  table.index_put_({torch::indexing::Slice(64, 72)}, std::nanf(""));
  const auto packed = hash_grid::grid_forward(s, pos, table, true);
  const auto floats = hash_grid::grid_forward(s, pos, hash_grid::binarize_values(table), false);
  EXPECT_TRUE(torch::equal(packed, floats));
  EXPECT_GT(packed.abs().max().item<float>(), 0.5f);
}

TEST(HashGridKernels, BackwardMatchesReferenceWithStraightThroughMask) {
  const GridSpec s = small_spec();
  const auto pos = random_positions(2000, torch::kDouble, 3);
  // Values beyond ±1 get no gradient through the straight-through estimator.
  const auto init = torch::randn({s.n_entries, s.n_features}, torch::kDouble) * 1.5;
  const auto grad_out = torch::randn({2000, s.output_dim()}, torch::kDouble);
  for (bool binarize : {false, true}) {
    auto table = init.clone().requires_grad_(true);
    auto ref = hash_grid::grid_forward_reference(s, pos, table, binarize);
    ref.backward(grad_out);
    const auto expected = table.grad();
    const auto got = hash_grid::grid_backward(s, pos, init, grad_out, binarize);
    EXPECT_LT((got - expected).abs().max().item<double>(), 1e-10) << "binarize " << binarize;
    EXPECT_GT(got.abs().max().item<double>(), 0.0);
    if (binarize) {
      const auto outside = init.abs().gt(1);
      ASSERT_GT(outside.sum().item<int64_t>(), 0);
      EXPECT_EQ(got.masked_select(outside).abs().max().item<double>(), 0.0);
    }
  }
}

TEST(HashGridKernels, CornersAndBordersReadTheExpectedVertex) {
  // res 18: res - 2 = 16, so u = (k - 0.5) / 16 lands exactly on vertex k (dense level).
  const GridSpec s = hash_grid::make_grid_spec({18}, 13, {}, 15, 1);
  const int64_t r = 18;
  auto table = torch::arange(s.n_entries, torch::kDouble).unsqueeze(1);
  auto vertex = [&](int64_t x, int64_t y, int64_t z) { return double(x + y * r + z * r * r); };
  struct Case {
    double u[3];
    double expected;
  };
  const std::vector<Case> cases = {
      {{(5 - 0.5) / 16, (7 - 0.5) / 16, (2 - 0.5) / 16}, vertex(5, 7, 2)},  // on a corner
      {{0.0, 0.0, 0.0}, vertex(1, 1, 1)},     // border corners 0 discarded, renormalised
      {{1.0, 1.0, 1.0}, vertex(16, 16, 16)},  // corner res-1 discarded
      {{0.0, (3 - 0.5) / 16, 1.0}, vertex(1, 3, 16)},
  };
  for (const auto& c : cases) {
    const auto pos = torch::tensor({c.u[0], c.u[1], c.u[2]}, torch::kDouble).unsqueeze(0);
    const auto out = hash_grid::grid_forward(s, pos, table, false);
    const auto ref = hash_grid::grid_forward_reference(s, pos, table, false);
    EXPECT_NEAR(out.item<double>(), c.expected, 1e-9) << c.u[0] << " " << c.u[1] << " " << c.u[2];
    EXPECT_NEAR(ref.item<double>(), c.expected, 1e-9);
  }
  // Half-way between two interior vertices along x: the mean of the two.
  const auto mid = torch::tensor({5.0 / 16, (7 - 0.5) / 16, (2 - 0.5) / 16}, torch::kDouble);
  const auto out = hash_grid::grid_forward(s, mid.unsqueeze(0), table, false);
  EXPECT_NEAR(out.item<double>(), 0.5 * (vertex(5, 7, 2) + vertex(6, 7, 2)), 1e-9);
}

TEST(HashGridKernels, OutOfBoundsLevelsReadZeroAndStayFinite) {
  const GridSpec s = small_spec();
  const double nan = std::numeric_limits<double>::quiet_NaN();
  const double inf = std::numeric_limits<double>::infinity();
  // x outside: the 3D levels and the xy, xz planes read 0, the yz plane does not.
  const auto pos = torch::tensor(
      {{-0.1, 0.5, 0.5}, {1.0001, 0.3, 0.7}, {nan, 0.4, 0.2}, {inf, 0.4, 0.2}, {-inf, 0.4, 0.2}},
      torch::kDouble);
  auto table = torch::randn({s.n_entries, s.n_features}, torch::kDouble);
  for (bool binarize : {false, true}) {
    const auto out = hash_grid::grid_forward(s, pos, table, binarize);
    const auto ref = hash_grid::grid_forward_reference(s, pos, table, binarize);
    EXPECT_TRUE(torch::isfinite(out).all().item<bool>());
    EXPECT_TRUE(torch::isfinite(ref).all().item<bool>());
    const int64_t f = s.n_features;
    const int64_t yz_begin = (3 + 2 + 2) * f;  // 3 xyz levels, xy and xz planes of 2 levels
    EXPECT_EQ(out.slice(1, 0, yz_begin).abs().max().item<double>(), 0.0);
    if (!binarize) {  // (binarised ±1 can cancel exactly)
      EXPECT_GT(out.slice(1, yz_begin).abs().sum(1).min().item<double>(), 0.0);
    }
    EXPECT_LT((out - ref).abs().max().item<double>(), 1e-12);
    const auto grad = hash_grid::grid_backward(s, pos, table, torch::ones_like(out), binarize);
    EXPECT_TRUE(torch::isfinite(grad).all().item<bool>());
  }
}

TEST(HashGridKernels, ResultsDoNotDependOnThreadCount) {
  const GridSpec s = hac_spec();
  const auto pos = random_positions(5000, torch::kFloat, 4);
  const auto table = torch::empty({s.n_entries, s.n_features}).uniform_(-2, 2);
  const auto grad_out = torch::randn({5000, s.output_dim()});
  const int before = at::get_num_threads();
  at::set_num_threads(1);
  const auto f1 = hash_grid::grid_forward(s, pos, table, true);
  const auto b1 = hash_grid::grid_backward(s, pos, table, grad_out, true);
  at::set_num_threads(2);
  const auto f2 = hash_grid::grid_forward(s, pos, table, true);
  const auto b2 = hash_grid::grid_backward(s, pos, table, grad_out, true);
  at::set_num_threads(before);
  EXPECT_TRUE(torch::equal(f1, f2));
  EXPECT_TRUE(torch::equal(b1, b2));
  EXPECT_GT(b1.abs().sum().item<float>(), 0.f);
}

// ---- the component, through the registry ---------------------------------------------------

std::shared_ptr<ContextModel> make_grid(const std::string& extra = "") {
  return test::make_plugin<ContextModel>("context", "{type: hash_grid" + extra + "}");
}

TEST(HashGridComponent, OutputsTheEntropyParameterLayout) {
  auto grid = make_grid();
  ASSERT_TRUE(grid);
  EXPECT_EQ(grid->output_dim(), 2 * (50 + 6 + 30) + 3);
  const auto params = grid->parameters();
  ASSERT_EQ(params.size(), 5u);
  EXPECT_EQ(params[0].sizes(), torch::IntArrayRef({441568, 4}));
  EXPECT_LE(params[0].abs().max().item<float>(), 1e-4f);
  EXPECT_EQ(params[1].sizes(), torch::IntArrayRef({100, 96}));
  EXPECT_EQ(params[3].sizes(), torch::IntArrayRef({175, 100}));
  const auto out = grid->forward(random_positions(300, torch::kFloat, 5));
  EXPECT_EQ(out.sizes(), torch::IntArrayRef({300, 175}));
  out.sum().backward();
  ASSERT_TRUE(params[0].grad().defined());
  EXPECT_GT(params[0].grad().abs().sum().item<float>(), 0.f);
  EXPECT_TRUE(params[1].grad().defined());

  // coded_dim narrows the layout (CRP-GS: 2 (30 + 6 + 30) + 3 = 135).
  auto narrow = test::make_plugin<ContextModel>("context", "{type: hash_grid}",
                                                crpgs_create_args{50, 10, 0, 30, {0, 0, 0, 0}});
  ASSERT_TRUE(narrow);
  EXPECT_EQ(narrow->output_dim(), 135);
}

TEST(HashGridComponent, PartialForwardMatchesForward) {
  auto grid = make_grid();
  ASSERT_TRUE(grid);
  const auto pos = random_positions(400, torch::kFloat, 9);
  const auto full = grid->forward(pos).detach();
  const auto part = grid->forward_partial(pos, 3);
  ASSERT_EQ(part.tail.sizes(), torch::IntArrayRef({400, 3}));
  EXPECT_TRUE(torch::allclose(part.tail, full.slice(1, 172), 1e-5, 1e-6));
  const auto rows = torch::tensor({399, 0, 17, 17}, torch::kLong);
  const auto picked = part.rows(rows);
  ASSERT_EQ(picked.sizes(), torch::IntArrayRef({4, 175}));
  EXPECT_TRUE(torch::allclose(picked, full.index_select(0, rows), 1e-5, 1e-6));

  // Both parts reach the grid table and the output layer: the tail through its three rows of
  // weight2, the picked rows through all of them.
  const auto weights = torch::randn({400, 3}, torch::TensorOptions().dtype(torch::kFloat));
  (part.tail * weights).sum().add(picked.sum()).backward();
  const auto params = grid->parameters();
  EXPECT_GT(params[0].grad().abs().sum().item<float>(), 0.f);
  const auto w2_grad = params[3].grad();
  EXPECT_GT(w2_grad.slice(0, 0, 172).abs().sum().item<float>(), 0.f);
  EXPECT_GT(w2_grad.slice(0, 172).abs().sum().item<float>(), 0.f);
  // The same gradients as the whole forward() (the tail runs through chunked_mlp's backward).
  std::vector<torch::Tensor> partial_grads;
  for (auto& p : params) {
    partial_grads.push_back(p.grad().clone());
    p.mutable_grad() = torch::Tensor();
  }
  const auto whole = grid->forward(pos);
  (whole.slice(1, 172) * weights).sum().add(whole.index_select(0, rows).sum()).backward();
  for (size_t i = 0; i < params.size(); ++i)
    EXPECT_TRUE(torch::allclose(partial_grads[i], params[i].grad(), 1e-4, 1e-5))
        << "parameter " << i;
}

// The codec's arithmetic: the grid lookup (portable already) and the MLP as portable_linear,
// bit for bit; the same function as forward() up to rounding.
TEST(HashGridComponent, PortableForwardIsTheFixedOrderMlpBitForBit) {
  auto grid = make_grid(", hidden_dim: 24");
  ASSERT_TRUE(grid);
  const auto params = grid->parameters();
  {
    torch::NoGradGuard no_grad;
    torch::manual_seed(21);
    params[0].uniform_(-1, 1);  // a trained table's signs, not the init's ±1e-4
    for (size_t i = 1; i < params.size(); ++i) params[i].normal_(0, 0.3);
  }
  const auto pos = random_positions(257, torch::kFloat, 13);
  const auto got = grid->forward_portable(pos);
  ASSERT_EQ(got.sizes(), torch::IntArrayRef({257, 175}));
  EXPECT_FALSE(got.requires_grad());
  torch::Tensor want;
  {
    torch::NoGradGuard no_grad;
    const auto feat = hash_grid::grid_lookup(hac_spec(), pos, params[0].detach(), true);
    const auto h = torch::relu(portable_linear(feat, params[1], params[2]));
    want = portable_linear(h, params[3], params[4]);
  }
  EXPECT_TRUE(torch::equal(got, want));
  EXPECT_TRUE(torch::allclose(got, grid->forward(pos).detach(), 1e-4, 1e-4));
}

TEST(ContextModelDefault, PartialForwardSlicesForward) {
  struct Fixed : ContextModel {
    std::string type_name() const override { return "fixed"; }
    YAML::Node hyperparams() const override { return {}; }
    int64_t output_dim() const override { return 4; }
    torch::Tensor forward(const torch::Tensor& p) override {
      return torch::arange(p.size(0) * 4, torch::kFloat).reshape({p.size(0), 4});
    }
  } fixed;
  const auto part = fixed.forward_partial(torch::zeros({3, 3}), 1);
  EXPECT_TRUE(torch::equal(part.tail, torch::tensor({3.f, 7.f, 11.f}).unsqueeze(1)));
  EXPECT_TRUE(torch::equal(part.rows(torch::tensor({2}, torch::kLong)),
                           torch::tensor({8.f, 9.f, 10.f, 11.f}).unsqueeze(0)));
}

TEST(HashGridComponent, LevelCountMustMatchResolutions) {
  auto cfg = Config::from_string("context: {type: hash_grid, n_levels: 3}\n", "t.yaml");
  ASSERT_TRUE(cfg.ok());
  auto resolved = cfg->resolve(test::plugin_registry());
  ASSERT_TRUE(resolved.ok()) << resolved.status().to_string();
  auto c = create_component<ContextModel>(test::plugin_registry(), resolved->section("context"),
                                          {50, 10, 0, 50, {0, 0, 0, 0}});
  ASSERT_FALSE(c.ok());
  EXPECT_NE(c.status().message().find("n_levels"), std::string::npos) << c.status().message();
}

/// table_bits's fused CPU function against the ATen expression evaluated in double (in float,
/// the expression's own rounding of −log2(1 − p) near a clamp is ~1e-3 bits off): value and
/// straight-through gradient, for p inside (0, 1) and clamped at either end, with entries
/// outside |t| <= 1.
TEST(HashGridTableBits, FusedFunctionMatchesTheAtenExpression) {
  struct Case {
    const char* name;
    double positive_share;
    torch::ScalarType type;
  };
  for (const Case c :
       {Case{"p 0.3", 0.3, torch::kFloat}, Case{"p 0.5 double", 0.5, torch::kDouble},
        Case{"all negative", 0.0, torch::kFloat}, Case{"all positive", 1.0, torch::kFloat}}) {
    SCOPED_TRACE(c.name);
    torch::manual_seed(11);
    const auto opts = torch::TensorOptions().dtype(c.type);
    const auto sign = torch::where(torch::rand({20000, 4}, opts) < c.positive_share,
                                   torch::ones({20000, 4}, opts), -torch::ones({20000, 4}, opts));
    const auto values = sign * torch::rand({20000, 4}, opts) * 1.5;  // ~1/3 with |t| > 1
    auto fused = values.clone().requires_grad_(true);
    auto reference = values.to(torch::kDouble).requires_grad_(true);
    const auto bits = hash_grid::table_bits(fused, true);
    const auto expected = hash_grid::table_bits_reference(reference);
    ASSERT_EQ(bits.dim(), 0);
    EXPECT_EQ(bits.scalar_type(), c.type);
    EXPECT_NEAR(bits.item<double>(), expected.item<double>(), 1e-6 * expected.item<double>());
    (bits * 0.37).backward();
    (expected * 0.37).backward();
    ASSERT_TRUE(fused.grad().defined());
    const auto got = fused.grad().to(torch::kDouble), want = reference.grad();
    // Same entries without gradient (|t| > 1), same slope elsewhere.
    EXPECT_TRUE(torch::equal(got.eq(0), want.eq(0)));
    EXPECT_TRUE(torch::allclose(got, want, 1e-6, 1e-12));
    EXPECT_GT(got.ne(0).sum().item<int64_t>(), 0);
  }
}

TEST(HashGridComponent, ParameterBitsIsHacBhAndDifferentiable) {
  auto grid = make_grid();
  ASSERT_TRUE(grid);
  auto table = grid->parameters()[0];
  {
    torch::NoGradGuard g;
    table.copy_(torch::where(torch::rand_like(table) < 0.25, torch::ones_like(table),
                             -torch::ones_like(table)));
    table.index_put_({0, 0}, 5.0);  // binarises to +1 but gets no straight-through gradient
  }
  const double n = double(table.numel());
  const double n_pos = double(table.ge(0).sum().item<int64_t>());
  const double p = n_pos / n;
  const double expected = n_pos * -std::log2(p) + (n - n_pos) * -std::log2(1 - p) + 32;
  auto bits = grid->parameter_bits();
  ASSERT_EQ(bits.dim(), 0);
  EXPECT_NEAR(bits.item<double>(), expected, expected * 1e-4);
  EXPECT_LT(bits.item<double>(), n);  // p ≈ 0.25: well under one bit per parameter
  bits.backward();
  ASSERT_TRUE(table.grad().defined());
  EXPECT_TRUE(torch::isfinite(table.grad()).all().item<bool>());
  EXPECT_EQ(table.grad()[0][0].item<float>(), 0.f);
  // d B_h / d b_i = 0.5 (log2((1-p)/p)) > 0 for p < 0.5: pushing a parameter down saves bits.
  EXPECT_GT(table.grad()[0][1].item<float>(), 0.f);
}

TEST(HashGridComponent, SaveLoadRoundTripIsBitIdentical) {
  auto a = make_grid(", hidden_dim: 16");
  auto b = make_grid(", hidden_dim: 16");
  ASSERT_TRUE(a && b);
  {
    torch::NoGradGuard g;
    a->parameters()[0].uniform_(-1, 1);
  }
  const auto state = a->save_state();
  // Bernoulli-coded ±1 table: about 1 bit per parameter here, plus float32 weights.
  EXPECT_LT(state.size(), size_t(441568 * 4 / 8 * 1.01) + (16 * 96 + 16 + 175 * 16 + 175) * 4 + 64);
  std::string error;
  ASSERT_TRUE(b->load_state(state, &error)) << error;
  const auto pos = random_positions(500, torch::kFloat, 6);
  EXPECT_TRUE(torch::equal(a->forward(pos), b->forward(pos)));
  EXPECT_EQ(b->save_state(), state);
  const auto loaded = b->parameters()[0];
  EXPECT_TRUE(loaded.abs().eq(1).all().item<bool>());
}

TEST(HashGridComponent, FloatGridSaveLoadRoundTrip) {
  auto a = make_grid(", hidden_dim: 8, binarize: false");
  auto b = make_grid(", hidden_dim: 8, binarize: false");
  ASSERT_TRUE(a && b);
  std::string error;
  ASSERT_TRUE(b->load_state(a->save_state(), &error)) << error;
  const auto pos = random_positions(200, torch::kFloat, 7);
  EXPECT_TRUE(torch::equal(a->forward(pos), b->forward(pos)));
  EXPECT_DOUBLE_EQ(a->parameter_bits().item<double>(), 441568.0 * 4 * 32);
}

TEST(HashGridComponent, CorruptStateIsRefusedWithAMessage) {
  auto a = make_grid(", hidden_dim: 8");
  auto b = make_grid(", hidden_dim: 8");
  auto other = make_grid(", hidden_dim: 9");
  ASSERT_TRUE(a && b && other);
  const auto state = a->save_state();
  std::string error;
  EXPECT_FALSE(b->load_state({}, &error));
  EXPECT_FALSE(error.empty());
  for (size_t cut : {size_t(3), size_t(10), state.size() / 2, state.size() - 1}) {
    error.clear();
    EXPECT_FALSE(b->load_state(std::vector<uint8_t>(state.begin(), state.begin() + cut), &error))
        << cut;
    EXPECT_FALSE(error.empty());
  }
  auto bad_magic = state;
  bad_magic[0] ^= 0xFF;
  EXPECT_FALSE(b->load_state(bad_magic, &error));
  EXPECT_NE(error.find("magic"), std::string::npos) << error;
  auto trailing = state;
  trailing.push_back(0);
  EXPECT_FALSE(b->load_state(trailing, &error));
  EXPECT_FALSE(other->load_state(state, &error));
  EXPECT_NE(error.find("hidden"), std::string::npos) << error;
  // Random flips never crash (they may or may not be detected inside the bit stream).
  std::mt19937 rng(1);
  for (int i = 0; i < 50; ++i) {
    auto s = state;
    s[rng() % 64] ^= uint8_t(1 + rng() % 255);
    b->load_state(s, &error);
  }
  // A failed load leaves a usable object that still accepts the good state.
  ASSERT_TRUE(b->load_state(state, &error)) << error;
}

}  // namespace
}  // namespace crpgs
