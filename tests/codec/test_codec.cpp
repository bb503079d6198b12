/// @file test_codec.cpp
/// @brief The anchor-model bitstream: bit-exact round trip (every symbol, mask, voxel, MLP and
/// component state), thread-count independence, and refusal of corrupt or truncated files.
#include <gtest/gtest.h>

#include <random>
#include <set>

#include "crpgs/codec.h"
#include "crpgs/coding/bitstream.h"
#include "crpgs/coding/geometry.h"
#include "crpgs/components.h"
#include "test_registry.h"

namespace crpgs {
namespace {

const ComponentRegistry& registry() {
  return test::test_registry();
}

struct Fixture {
  Config config;
  CodecComponents components;
  CodedModel model;
};

/// A small random coded model with the real hash_grid context and gaussian entropy model.
StatusOr<Fixture> make_fixture(int64_t n, uint64_t seed) {
  if (!registry().find(CRPGS_KIND_CONTEXT, "hash_grid") ||
      !registry().find(CRPGS_KIND_ENTROPY, "gaussian"))
    return Status(StatusCode::kNotFound, "hash_grid/gaussian plugins not built");
  auto raw = Config::from_string(
      "context: {type: hash_grid}\nentropy: {type: gaussian}\nmodel: {n_offsets: 4, feature_dim: "
      "8}\n",
      "codec_test.yaml");
  if (!raw.ok()) return raw.status();
  Fixture f;
  CRPGS_ASSIGN_OR_RETURN(f.config, raw->resolve(registry()));
  // The components draw their tables and MLPs from libtorch's global generator, which each
  // process seeds at random: seeded here, a fixture is the same model in every run.
  torch::manual_seed(seed);
  crpgs_create_args args = create_args_for(f.config);
  CRPGS_ASSIGN_OR_RETURN(
      f.components.features,
      create_component<FeatureModel>(registry(), f.config.section("features"), args));
  args.coded_dim = int32_t(f.components.features->coded_dim());
  CRPGS_ASSIGN_OR_RETURN(f.components.context, create_component<ContextModel>(
                                                   registry(), f.config.section("context"), args));
  CRPGS_ASSIGN_OR_RETURN(f.components.entropy, create_component<EntropyModel>(
                                                   registry(), f.config.section("entropy"), args));

  std::mt19937 rng{static_cast<uint32_t>(seed)};
  std::uniform_int_distribution<int32_t> coord(-200, 200);
  std::vector<coding::Voxel> pts;
  std::set<coding::Voxel> seen;
  while (int64_t(pts.size()) < n) {
    coding::Voxel v{coord(rng), coord(rng), coord(rng) / 4};
    if (seen.insert(v).second) pts.push_back(v);
  }
  coding::sort_morton(&pts);
  CodedModel& m = f.model;
  m.voxel_size = 0.01;
  m.chunk = 700;  // several chunks
  m.voxels = torch::empty({n, 3}, torch::kInt);
  for (int64_t i = 0; i < n; ++i)
    for (int a = 0; a < 3; ++a) m.voxels[i][a] = pts[size_t(i)][size_t(a)];
  m.bounds = torch::tensor({{-2.5f, -2.5f, -0.7f}, {2.5f, 2.5f, 0.7f}});
  auto gen = at::detail::createCPUGenerator(seed);
  m.offset_masks = torch::rand({n, 4}, gen) > 0.3;
  m.feature_sym = torch::round(torch::randn({n, 8}, gen) * 3).to(torch::kInt);
  m.scaling_sym = torch::round(torch::rand({n, 6}, gen) * 40 + 1).to(torch::kInt);
  m.offset_sym = (torch::round(torch::randn({n, 4, 3}, gen) * 5) * m.offset_masks.unsqueeze(2))
                     .to(torch::kInt);
  m.mlps["mlp_opacity.w1"] = torch::randn({16, 12}, gen);
  m.mlps["mlp_opacity.b1"] = torch::randn({16}, gen);
  return f;
}

void expect_same(const CodedModel& a, const CodedModel& b) {
  EXPECT_TRUE(torch::equal(a.voxels, b.voxels));
  EXPECT_TRUE(torch::equal(a.offset_masks, b.offset_masks));
  EXPECT_TRUE(torch::equal(a.feature_sym, b.feature_sym));
  EXPECT_TRUE(torch::equal(a.scaling_sym, b.scaling_sym));
  EXPECT_TRUE(torch::equal(a.offset_sym, b.offset_sym));
  EXPECT_TRUE(torch::equal(a.bounds, b.bounds));
  EXPECT_EQ(a.voxel_size, b.voxel_size);
  ASSERT_EQ(a.mlps.size(), b.mlps.size());
  for (const auto& [k, v] : a.mlps) EXPECT_TRUE(torch::equal(v, b.mlps.at(k))) << k;
}

TEST(Codec, RoundTripIsBitExactWithAnyThreadCount) {
  auto f = make_fixture(2500, 7);
  if (!f.ok()) GTEST_SKIP() << f.status().message();
  auto enc = encode_model(f->model, f->config, f->components);
  ASSERT_TRUE(enc.ok()) << enc.status().to_string();
  const int threads = at::get_num_threads();
  for (int t : {1, 2}) {
    at::set_num_threads(t);
    auto dec = decode_model(enc->bytes, registry());
    ASSERT_TRUE(dec.ok()) << dec.status().to_string();
    expect_same(f->model, dec->model);
    // The decoded context predicts exactly what the encoder's did.
    const auto p1 = coded_entropy_params(f->model, *f->components.context, 8);
    const auto p2 = coded_entropy_params(dec->model, *dec->components.context, 8);
    EXPECT_TRUE(torch::equal(p1.mu_f, p2.mu_f));
    EXPECT_TRUE(torch::equal(p1.q_o, p2.q_o));
  }
  at::set_num_threads(threads);
  // Every section is accounted for and the sizes add up to the file.
  uint64_t total = 0;
  for (const auto& s : enc->sections) total += s.bytes;
  EXPECT_LE(total, enc->bytes.size());
  EXPECT_GT(total + 64, enc->bytes.size());
  // All three symbol streams report an estimate and a coded size (their agreement on data that
  // follows the model is tested with the gaussian plugin; these symbols are random).
  EXPECT_EQ(enc->estimated_vs_coded_bits.size(), 3u);
}

// docs/method.md §6.4: roots, then free anchors, then leaves, each group in canonical index order.
TEST(Codec, CodingOrderIsRootsThenFreeThenLeaves) {
  // 7 anchors: leaves 1 -> root 4 and 5 -> root 0; anchors 2, 3, 6 are free.
  const auto links = torch::tensor({-1, 4, -1, -1, -1, 0, -1}, torch::kInt);
  EXPECT_TRUE(
      torch::equal(coding_order(links, 7), torch::tensor({0, 4, 2, 3, 6, 1, 5}, torch::kLong)));
  EXPECT_TRUE(torch::equal(coding_order(torch::full({4}, -1, torch::kInt), 4),
                           torch::arange(4, torch::kLong)));
  EXPECT_TRUE(torch::equal(coding_order(torch::Tensor(), 3), torch::arange(3, torch::kLong)));
}

TEST(Codec, SingleAnchorAndAllMasked) {
  auto f = make_fixture(1, 3);
  if (!f.ok()) GTEST_SKIP() << f.status().message();
  f->model.offset_masks.fill_(false);
  f->model.offset_sym.zero_();
  auto enc = encode_model(f->model, f->config, f->components);
  ASSERT_TRUE(enc.ok()) << enc.status().to_string();
  auto dec = decode_model(enc->bytes, registry());
  ASSERT_TRUE(dec.ok()) << dec.status().to_string();
  expect_same(f->model, dec->model);
}

// The encoder refuses what the decoder would refuse, rather than write a file nobody can read.
TEST(Codec, RefusesBoundsTheDecoderWouldRefuse) {
  auto f = make_fixture(50, 5);
  if (!f.ok()) GTEST_SKIP() << f.status().message();
  f->model.bounds = torch::tensor({{-2.5f, -2.5f, 0.f}, {2.5f, 2.5f, 0.f}});  // flat in z
  auto enc = encode_model(f->model, f->config, f->components);
  ASSERT_FALSE(enc.ok());
  EXPECT_NE(enc.status().message().find("bounds are empty or non-finite"), std::string::npos)
      << enc.status().message();
  f->model.bounds = torch::tensor({{-2.5f, -2.5f, -0.7f}, {2.5f, NAN, 0.7f}});
  EXPECT_FALSE(encode_model(f->model, f->config, f->components).ok());
}

TEST(Codec, RefusesNonCanonicalOrder) {
  auto f = make_fixture(50, 5);
  if (!f.ok()) GTEST_SKIP() << f.status().message();
  f->model.voxels = f->model.voxels.flip(0).contiguous();
  auto enc = encode_model(f->model, f->config, f->components);
  ASSERT_FALSE(enc.ok());
  EXPECT_NE(enc.status().message().find("canonical"), std::string::npos);
}

// A model trained on a GPU must reach the coder on the CPU: refused with a message, not read
// through a device pointer. (The meta device stands in for a GPU on a CPU-only libtorch.)
TEST(Codec, RefusesSymbolsOffTheCpu) {
  auto f = make_fixture(50, 5);
  if (!f.ok()) GTEST_SKIP() << f.status().message();
  f->model.feature_sym = f->model.feature_sym.to(torch::kMeta);
  auto enc = encode_model(f->model, f->config, f->components);
  ASSERT_FALSE(enc.ok());
  EXPECT_NE(enc.status().message().find("on meta, not the CPU"), std::string::npos)
      << enc.status().message();
}

// Truncations and flipped bits anywhere are refused with a message, never a crash.
TEST(Codec, CorruptAndTruncatedFilesAreRefused) {
  auto f = make_fixture(300, 11);
  if (!f.ok()) GTEST_SKIP() << f.status().message();
  auto enc = encode_model(f->model, f->config, f->components);
  ASSERT_TRUE(enc.ok()) << enc.status().to_string();
  const auto& good = enc->bytes;
  for (size_t len :
       {size_t(0), size_t(3), size_t(27), good.size() / 3, good.size() / 2, good.size() - 1}) {
    auto dec =
        decode_model(std::vector<uint8_t>(good.begin(), good.begin() + long(len)), registry());
    EXPECT_FALSE(dec.ok()) << "truncated to " << len;
    EXPECT_FALSE(dec.status().message().empty());
  }
  std::mt19937 rng(1);
  for (int trial = 0; trial < 40; ++trial) {
    auto bad = good;
    const size_t at = rng() % bad.size();
    bad[at] ^= uint8_t(1u << (rng() % 8));
    auto dec = decode_model(bad, registry());
    EXPECT_FALSE(dec.ok()) << "bit flip at byte " << at;
  }
}

// The file rebuilt (valid CRCs) with the codec's sections at `minor` and, with bad_scal, one
// byte of the SCAL stream's data flipped.
coding::Bytes relabelled(const coding::Bytes& file, uint16_t minor, bool bad_scal) {
  auto ct = coding::ContainerReader::parse(file);
  EXPECT_TRUE(ct.ok()) << ct.status().to_string();
  coding::ContainerWriter w(ct->header.config_hash, ct->header.flags);
  for (coding::Section sec : ct->sections) {
    if (sec.component_id == "org.crpgs.codec.anchor_model") sec.component_minor = minor;
    if (bad_scal && sec.id == "SCAL") sec.payload[sec.payload.size() / 2] ^= 0x5a;
    EXPECT_TRUE(w.add_section(std::move(sec)).ok());
  }
  return w.finish();
}

// The rasterizer and train.device are the encoding machine's: a file written where the `cuda`
// rasterizer trained the model decodes in a CPU-only build, with the CPU rasterizer.
TEST(Codec, AFileTrainedOnAGpuDecodesWhereOnlyTheCpuRasterizerIs) {
  auto f = make_fixture(300, 14);
  if (!f.ok()) GTEST_SKIP() << f.status().message();
  if (registry().find(CRPGS_KIND_RASTERIZER, "gpu_only_test_rasterizer"))
    GTEST_SKIP() << "the test's missing rasterizer exists";
  ASSERT_TRUE(f->config.set("train.device", YAML::Node("cuda")).ok());
  auto enc = encode_model(f->model, f->config, f->components);
  ASSERT_TRUE(enc.ok()) << enc.status().to_string();
  auto ct = coding::ContainerReader::parse(enc->bytes);
  ASSERT_TRUE(ct.ok());
  coding::ContainerWriter w(ct->header.config_hash, ct->header.flags);
  for (coding::Section sec : ct->sections) {
    if (sec.id == "CONF") {
      auto conf = Config::from_string(std::string(sec.payload.begin(), sec.payload.end()), "CONF");
      ASSERT_TRUE(conf.ok()) << conf.status().to_string();
      YAML::Node r(YAML::NodeType::Map);
      r["type"] = "gpu_only_test_rasterizer";
      r["device"] = 0;
      ASSERT_TRUE(conf->set("rasterizer", r).ok());
      const std::string text = conf->dump();
      sec.payload.assign(text.begin(), text.end());
    }
    ASSERT_TRUE(w.add_section(std::move(sec)).ok());
  }
  auto dec = decode_model(w.finish(), registry());
  ASSERT_TRUE(dec.ok()) << dec.status().to_string();
  EXPECT_EQ(dec->config.section("rasterizer")["type"].as<std::string>(), "cpu");
  EXPECT_EQ(dec->config.section("train")["device"].as<std::string>(), "cpu");
  expect_same(f->model, dec->model);
}

// Formats from 1.1 compute the entropy parameters portably; a 1.0 file is decoded with the old
// (BLAS) arithmetic, and a stream that fails to decode says why that may be.
TEST(Codec, FormatOneZeroStreamErrorsNameTheKernelDependence) {
  auto f = make_fixture(300, 12);
  if (!f.ok()) GTEST_SKIP() << f.status().message();
  auto enc = encode_model(f->model, f->config, f->components);
  ASSERT_TRUE(enc.ok()) << enc.status().to_string();
  const std::string hint = "format 1.0 file decodes only where the BLAS kernels";
  auto v12 = decode_model(relabelled(enc->bytes, 2, true), registry());
  ASSERT_FALSE(v12.ok());
  EXPECT_NE(v12.status().message().find("SCAL"), std::string::npos) << v12.status().message();
  EXPECT_EQ(v12.status().message().find(hint), std::string::npos) << v12.status().message();
  auto v10 = decode_model(relabelled(enc->bytes, 0, true), registry());
  ASSERT_FALSE(v10.ok());
  EXPECT_NE(v10.status().message().find(hint), std::string::npos) << v10.status().message();
}

// Each minor version keeps the arithmetic it was written with; the encoder writes the newest
// (1.2: steps by 2·sigmoid(2a), which neither cancels nor loses its gradient where a << 0), and a
// later one is refused (tests/data/format_1_1 checks that 1.1 files decode as written).
TEST(Codec, EachFormatMinorDecodesWithItsOwnStepsAndArithmetic) {
  const std::pair<Arithmetic, StepForm> by_minor[] = {
      {Arithmetic::kFast, StepForm::kOnePlusTanh},
      {Arithmetic::kPortable, StepForm::kOnePlusTanh},
      {Arithmetic::kPortable, StepForm::kTwoSigmoid}};
  for (uint16_t minor = 0; minor < 3; ++minor) {
    CodedModel m;
    set_format_math(minor, &m);
    EXPECT_EQ(m.arithmetic, by_minor[minor].first) << minor;
    EXPECT_EQ(m.steps, by_minor[minor].second) << minor;
  }
  auto f = make_fixture(300, 13);
  if (!f.ok()) GTEST_SKIP() << f.status().message();
  f->model.steps = StepForm::kOnePlusTanh;  // the encoder writes 1.2 whatever it is given
  auto enc = encode_model(f->model, f->config, f->components);
  ASSERT_TRUE(enc.ok()) << enc.status().to_string();
  auto ct = coding::ContainerReader::parse(enc->bytes);
  ASSERT_TRUE(ct.ok());
  for (const auto& sec : ct->sections) {
    if (sec.component_id == "org.crpgs.codec.anchor_model") {
      EXPECT_EQ(sec.component_minor, 2) << sec.id;
    }
  }
  auto dec = decode_model(enc->bytes, registry());
  ASSERT_TRUE(dec.ok()) << dec.status().to_string();
  EXPECT_EQ(dec->model.steps, StepForm::kTwoSigmoid);
  f->model.steps = StepForm::kTwoSigmoid;
  expect_same(f->model, dec->model);
  auto later = decode_model(relabelled(enc->bytes, 3, false), registry());
  ASSERT_FALSE(later.ok());
  EXPECT_EQ(later.status().code(), StatusCode::kUnsupportedVersion);
  EXPECT_NE(later.status().message().find("version 1.3, written by a newer crpgs"),
            std::string::npos)
      << later.status().message();
}

}  // namespace
}  // namespace crpgs
