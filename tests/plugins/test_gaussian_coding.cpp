/// @file test_gaussian_coding.cpp
/// @brief The `gaussian` entropy model: its deterministic Φ and tables, coding round trips
/// (random, escape, empty, single, corrupt input, thread counts), coded size against the
/// training-time bits estimate, and the numerical-stability cases of issue 5.
#include <gtest/gtest.h>

#include <cmath>
#include <limits>
#include <random>

#include <ATen/Parallel.h>
#include <torch/torch.h>

#include "../plugins/entropy/gaussian/gaussian_coding.h"
#include "crpgs/entropy_model.h"
#include "plugins/plugin_test_util.h"

namespace crpgs {
namespace {

namespace gc = gaussian_coding;

std::shared_ptr<EntropyModel> make_gaussian() {
  return test::make_plugin<EntropyModel>("entropy", "{type: gaussian}");
}

/// Symbols drawn from the model itself: x ~ N(mu, sigma), k = round(x / q).
struct Data {
  torch::Tensor symbols, mean, scale, q;  // [M]
};

Data realistic(int64_t m, uint64_t seed) {
  torch::manual_seed(seed);
  Data d;
  d.q = 0.2 * (1 + torch::tanh(torch::randn({m})));  // (0, 0.4)
  d.mean = torch::randn({m}) * 3;
  d.scale = torch::exp(torch::rand({m}) * 6 - 3.5) * d.q.max();  // σ/q spans ~0.05 .. 20+
  const auto x = d.mean + d.scale * torch::randn({m});
  d.symbols = torch::round(x / d.q).to(torch::kInt);
  return d;
}

torch::Tensor roundtrip(EntropyModel& e, const Data& d, std::vector<uint8_t>* bytes = nullptr) {
  const auto b = e.compress(d.symbols, d.mean, d.scale, d.q);
  if (bytes) *bytes = b;
  std::string error;
  auto out = e.decompress(b, d.mean, d.scale, d.q, &error);
  EXPECT_TRUE(out.defined()) << error;
  return out;
}

TEST(GaussianCodingMath, DeterministicPhiMatchesLibm) {
  for (double x = -8; x <= 30; x += 0.01) {
    const double ref = 0.5 * std::erfc(x / std::sqrt(2.0));
    const double got = gc::normal_upper_tail(x);
    ASSERT_NEAR(got, ref, std::abs(ref) * 1e-10 + 1e-300) << x;
  }
  EXPECT_NEAR(gc::normal_interval(-0.5, 0.5), 0.38292492254802624, 1e-15);
}

TEST(GaussianCodingMath, ScaleLevelsAreLogSpacedAndTotal) {
  EXPECT_NEAR(gc::scale_level_value(0), std::pow(2.0, -26.0 / 8), 1e-15);
  EXPECT_NEAR(gc::scale_level_value(gc::kScaleLevels - 1), 1024.0, 1e-9);
  for (int k = 1; k < gc::kScaleLevels; ++k)
    EXPECT_NEAR(gc::scale_level_value(k) / gc::scale_level_value(k - 1), std::pow(2.0, 0.125),
                1e-12);
  EXPECT_EQ(gc::scale_level(0.0), 0);
  EXPECT_EQ(gc::scale_level(1e-30), 0);
  EXPECT_EQ(gc::scale_level(1.0), 26);
  EXPECT_EQ(gc::scale_level(1e9), gc::kScaleLevels - 1);
  EXPECT_EQ(gc::scale_level(std::numeric_limits<double>::quiet_NaN()), gc::kScaleLevels - 1);
  int64_t center = 0;
  // mean 2.3 steps: c = floor(2.3 * 32 + 0.5) = 74 → center 2, bin 10.
  const uint32_t key = gc::element_key(0.23f, 0.1f, 0.1f, 1e-9, &center);
  EXPECT_EQ(center, 2);
  EXPECT_EQ(key % gc::kMeanBins, 10u);
  EXPECT_EQ(key / gc::kMeanBins, 26u);
  gc::element_key(-0.01f, 0.1f, 0.1f, 1e-9, &center);  // -0.1 steps → c = -3 → center -1
  EXPECT_EQ(center, -1);
}

TEST(GaussianCodingTables, EverySymbolCodableAndTinyScaleIsAlmostOneSymbol) {
  for (uint32_t key : {0u, 16u, 31u, 26u * 32u + 5u, gc::kNumKeys - 1}) {
    auto t = gc::table_for_key(key);
    ASSERT_TRUE(t.ok()) << t.status().to_string();
    EXPECT_TRUE(coding::validate_cdf(t->cdf, gc::kPrecision).ok()) << key;
  }
  // Level 0 (σ ≈ 0.105 steps), mean bin 0: symbol 0 carries nearly all 2^20 counts.
  auto t = gc::table_for_key(0);
  ASSERT_TRUE(t.ok());
  const auto& cdf = t->cdf;
  const size_t zero = size_t(-t->offset);
  EXPECT_GT(cdf[zero + 1] - cdf[zero], (1u << gc::kPrecision) - 16);
  for (size_t i = 0; i + 1 < cdf.size(); ++i) EXPECT_GE(cdf[i + 1] - cdf[i], 1u);
  EXPECT_FALSE(gc::table_for_key(gc::kNumKeys).ok());
}

TEST(GaussianCoding, RandomRoundTripAcrossChunks) {
  auto e = make_gaussian();
  ASSERT_TRUE(e);
  ASSERT_TRUE(e->supports_coding());
  const Data d = realistic(25001, 1);  // three chunks of 10000, the last partial
  std::vector<uint8_t> bytes;
  const auto out = roundtrip(*e, d, &bytes);
  ASSERT_TRUE(out.defined());
  EXPECT_EQ(out.scalar_type(), torch::kInt);
  EXPECT_TRUE(torch::equal(out, d.symbols));
  EXPECT_EQ(bytes[0], gc::kFormatVersion);
  // Deterministic: the same input gives the same bytes.
  EXPECT_EQ(e->compress(d.symbols, d.mean, d.scale, d.q), bytes);
}

TEST(GaussianCoding, CodedSizeAgreesWithTheBitsEstimate) {
  auto e = make_gaussian();
  ASSERT_TRUE(e);
  const Data d = realistic(200000, 2);
  const auto bytes = e->compress(d.symbols, d.mean, d.scale, d.q);
  const double est =
      e->bits(d.symbols.to(torch::kFloat) * d.q, d.mean, d.scale, d.q).sum().item<double>();
  const double coded = 8.0 * double(bytes.size());
  EXPECT_NEAR(coded / est, 1.0, 0.03) << "coded " << coded << " bits, estimate " << est;
  std::string error;
  EXPECT_TRUE(torch::equal(e->decompress(bytes, d.mean, d.scale, d.q, &error), d.symbols)) << error;
}

TEST(GaussianCoding, EscapesAndExtremeParameters) {
  auto e = make_gaussian();
  ASSERT_TRUE(e);
  const float nan = std::numeric_limits<float>::quiet_NaN();
  const float inf = std::numeric_limits<float>::infinity();
  const int32_t lo = std::numeric_limits<int32_t>::min(), hi = std::numeric_limits<int32_t>::max();
  // Scales 0, negative, 1e-12, 1e6, NaN; steps 0, negative, tiny, NaN; means huge, inf, NaN.
  const std::vector<int32_t> sym = {0, 1, -1, 1000000, -1000000, hi, lo, 7, 3, 0, -5, 12, 40, 2};
  const std::vector<float> mean = {0, 0.5f, 1e9f, 0, 0, 0, 0, 3e38f, -inf, nan, 0, 0.3f, 0, 2};
  const std::vector<float> scale = {0, -1, 1e-12f, 1e6f, 1e-12f, 1, 1, 1, 1, 1, nan, 1, inf, 0};
  const std::vector<float> q = {1, 1, 1, 1, 1, 1, 1e-30f, 1, 1, 0, 1, -1, 1, nan};
  Data d{torch::tensor(sym, torch::kInt), torch::tensor(mean), torch::tensor(scale),
         torch::tensor(q)};
  const auto out = roundtrip(*e, d);
  ASSERT_TRUE(out.defined());
  EXPECT_TRUE(torch::equal(out, d.symbols)) << out;
}

TEST(GaussianCoding, TinyScaleCostsAlmostNothingAndFarSymbolsEscape) {
  auto e = make_gaussian();
  ASSERT_TRUE(e);
  const int64_t m = 50000;
  Data d{torch::zeros({m}, torch::kInt), torch::zeros({m}), torch::full({m}, 1e-12f),
         torch::ones({m})};
  const auto bytes = e->compress(d.symbols, d.mean, d.scale, d.q);
  EXPECT_LT(bytes.size(), 100u);  // ~1e-5 bit per symbol plus headers
  d.symbols[123] = 100000;        // far outside every table: escape-coded
  d.symbols[m - 1] = -3;
  const auto out = roundtrip(*e, d);
  ASSERT_TRUE(out.defined());
  EXPECT_TRUE(torch::equal(out, d.symbols));
}

TEST(GaussianCoding, EmptyAndSingleElement) {
  auto e = make_gaussian();
  ASSERT_TRUE(e);
  const auto empty_i = torch::zeros({0}, torch::kInt);
  const auto empty_f = torch::zeros({0});
  const auto bytes = e->compress(empty_i, empty_f, empty_f, empty_f);
  EXPECT_FALSE(bytes.empty());
  std::string error;
  const auto out = e->decompress(bytes, empty_f, empty_f, empty_f, &error);
  ASSERT_TRUE(out.defined()) << error;
  EXPECT_EQ(out.numel(), 0);
  Data one{torch::tensor({-42}, torch::kInt), torch::tensor({-4.0f}), torch::tensor({0.5f}),
           torch::tensor({0.1f})};
  const auto o1 = roundtrip(*e, one);
  ASSERT_TRUE(o1.defined());
  EXPECT_TRUE(torch::equal(o1, one.symbols));
}

TEST(GaussianCoding, CorruptOrMismatchedInputIsRefusedWithAMessage) {
  auto e = make_gaussian();
  ASSERT_TRUE(e);
  const Data d = realistic(12000, 3);
  const auto bytes = e->compress(d.symbols, d.mean, d.scale, d.q);
  std::string error;
  EXPECT_FALSE(e->decompress({}, d.mean, d.scale, d.q, &error).defined());
  EXPECT_FALSE(error.empty());
  auto wrong_version = bytes;
  wrong_version[0] = 99;
  EXPECT_FALSE(e->decompress(wrong_version, d.mean, d.scale, d.q, &error).defined());
  EXPECT_NE(error.find("version"), std::string::npos) << error;
  for (size_t cut : {size_t(1), size_t(5), bytes.size() / 2, bytes.size() - 1}) {
    error.clear();
    const std::vector<uint8_t> part(bytes.begin(), bytes.begin() + cut);
    EXPECT_FALSE(e->decompress(part, d.mean, d.scale, d.q, &error).defined()) << cut;
    EXPECT_FALSE(error.empty());
  }
  // The caller's element count must match the stream's.
  const auto m2 = d.mean.slice(0, 0, 11999);
  EXPECT_FALSE(e->decompress(bytes, m2, d.scale.slice(0, 0, 11999), d.q.slice(0, 0, 11999), &error)
                   .defined());
  EXPECT_NE(error.find("11999"), std::string::npos) << error;
  EXPECT_FALSE(e->decompress(bytes, d.mean, d.scale.slice(0, 0, 5), d.q, &error).defined());
  // Flipped bytes: refused or decoded to something, never a crash.
  std::mt19937 rng(7);
  int refused = 0;
  for (int i = 0; i < 200; ++i) {
    auto b = bytes;
    b[1 + rng() % (b.size() - 1)] ^= uint8_t(1 + rng() % 255);
    error.clear();
    const auto out = e->decompress(b, d.mean, d.scale, d.q, &error);
    if (!out.defined()) {
      ++refused;
      EXPECT_FALSE(error.empty());
    }
  }
  EXPECT_GT(refused, 150);  // rANS final-state checks catch nearly every flip
  // Compressing with mismatched sizes is a caller bug: it throws, it does not write garbage.
  EXPECT_THROW(e->compress(d.symbols, m2, d.scale, d.q), c10::Error);
}

TEST(GaussianCoding, DecodeDoesNotDependOnThreadCount) {
  auto e = make_gaussian();
  ASSERT_TRUE(e);
  const Data d = realistic(45000, 4);
  const int before = at::get_num_threads();
  at::set_num_threads(1);
  const auto b1 = e->compress(d.symbols, d.mean, d.scale, d.q);
  std::string error;
  const auto o1 = e->decompress(b1, d.mean, d.scale, d.q, &error);
  at::set_num_threads(2);
  const auto b2 = e->compress(d.symbols, d.mean, d.scale, d.q);
  const auto o2 = e->decompress(b1, d.mean, d.scale, d.q, &error);
  at::set_num_threads(before);
  EXPECT_EQ(b1, b2);
  ASSERT_TRUE(o1.defined() && o2.defined()) << error;
  EXPECT_TRUE(torch::equal(o1, d.symbols));
  EXPECT_TRUE(torch::equal(o2, d.symbols));
}

// ---- numerical stability of the training path (issue 5) ------------------------------------

TEST(GaussianStability, FarTailsReachTheFloorWithFiniteGradients) {
  auto e = make_gaussian();
  ASSERT_TRUE(e);
  auto mean = torch::zeros({4}, torch::requires_grad());
  auto scale = torch::ones({4}, torch::requires_grad());
  auto x = torch::tensor({1e4f, -1e4f, 5e3f, 0.f}, torch::requires_grad());
  const auto bits = e->bits(x, mean, scale, torch::ones({4}));
  const double floor_bits = -std::log2(1e-6);
  EXPECT_NEAR(bits[0].item<double>(), floor_bits, 1e-4);
  EXPECT_NEAR(bits[1].item<double>(), floor_bits, 1e-4);
  EXPECT_NEAR(bits[2].item<double>(), floor_bits, 1e-4);
  EXPECT_NEAR(bits[3].item<double>(), -std::log2(0.38292492254802624), 1e-4);
  bits.sum().backward();
  for (const auto& g : {x.grad(), mean.grad(), scale.grad()}) {
    ASSERT_TRUE(g.defined());
    EXPECT_TRUE(torch::isfinite(g).all().item<bool>()) << g;
  }
}

TEST(GaussianStability, DegenerateScalePredictionsStayFinite) {
  auto e = make_gaussian();
  ASSERT_TRUE(e);
  auto scale = torch::tensor({0.f, -1.f, 1e-12f, 1e6f}, torch::requires_grad());
  auto mean = torch::full({4}, 0.3f, torch::requires_grad());
  const auto x = torch::tensor({0.f, 1.f, 0.f, 2.f});
  const auto bits = e->bits(x, mean, scale, torch::ones({4}));
  EXPECT_TRUE(torch::isfinite(bits).all().item<bool>()) << bits;
  EXPECT_LE(bits.max().item<float>(), -std::log2(1e-6f) + 1e-3f);
  EXPECT_GT(bits[3].item<float>(), 15.f);   // σ = 1e6: ~log2(1e6 √(2π)) bits
  EXPECT_LT(bits[0].item<float>(), 1e-3f);  // σ clamped to 1e-9, mean 0.3 inside the cell of 0
  bits.sum().backward();
  EXPECT_TRUE(torch::isfinite(scale.grad()).all().item<bool>()) << scale.grad();
  EXPECT_TRUE(torch::isfinite(mean.grad()).all().item<bool>()) << mean.grad();
  // ...and they code.
  Data d{torch::tensor({0, 1, 0, 2}, torch::kInt), mean.detach(), scale.detach(), torch::ones({4})};
  const auto out = roundtrip(*e, d);
  ASSERT_TRUE(out.defined());
  EXPECT_TRUE(torch::equal(out, d.symbols));
}

TEST(GaussianStability, SaturatedStepRefinement) {
  auto e = make_gaussian();
  ASSERT_TRUE(e);
  // q = Q0 (1 + tanh a): a = -20 gives q = 0 in float, a = 20 gives 2 Q0.
  auto a = torch::tensor({-20.f, -9.f, 20.f, 0.f}, torch::requires_grad());
  const auto q = 0.2 * (1 + torch::tanh(a));
  EXPECT_EQ(q[0].item<float>(), 0.f);
  EXPECT_FLOAT_EQ(q[2].item<float>(), 0.4f);
  const auto x = torch::tensor({0.f, 0.1f, 0.4f, 0.2f});
  const auto bits = e->bits(x, torch::zeros({4}), torch::full({4}, 0.1f), q);
  EXPECT_TRUE(torch::isfinite(bits).all().item<bool>()) << bits;
  bits.sum().backward();
  EXPECT_TRUE(torch::isfinite(a.grad()).all().item<bool>()) << a.grad();
  Data d{torch::tensor({0, 1, 1, 1}, torch::kInt), torch::zeros({4}), torch::full({4}, 0.1f),
         q.detach()};
  const auto out = roundtrip(*e, d);
  ASSERT_TRUE(out.defined());
  EXPECT_TRUE(torch::equal(out, d.symbols));
}

}  // namespace
}  // namespace crpgs
