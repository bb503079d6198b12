// CRP-GS links in the rate path (docs/method.md §6.2-§6.4, §7.6-§7.13): links built on the
// schedule, the leaf model and its fallback, sanitising at encode time, and a bitstream with links
// that decodes (another thread count) to exactly the training-side quantised model.
#include <gtest/gtest.h>
#include <torch/torch.h>

#include <cmath>
#include <filesystem>

#include "crpgs/codec.h"
#include "crpgs/components.h"
#include "crpgs/link_report.h"
#include "crpgs/scene_generator.h"
#include "crpgs/trainer.h"
#include "raster/cpu_rasterizer.h"
#include "train/rate_test_util.h"

namespace crpgs {
namespace {

constexpr const char* kCodecYaml =
    "context: {type: hash_grid, log2_hashmap_size: 10, log2_hashmap_size_2d: 10}\n"
    "entropy: {type: gaussian}\nmodel: {feature_dim: 50, n_offsets: 10}\n";

/// Pairs consecutive active anchors (2j -> 2j+1 in active order): a deterministic strategy that
/// does not depend on the link plugins. `chain` makes a root a leaf too (must be refused).
class PairLinks final : public ContextModel {
 public:
  explicit PairLinks(bool chain = false) : chain_(chain) {}
  std::string type_name() const override { return "pair_test"; }
  YAML::Node hyperparams() const override { return YAML::Node(); }
  torch::Tensor build_links(const LinkInputs& in) override {
    ++builds;
    auto links = torch::full({in.features.size(0)}, -1, torch::kLong);
    auto act = in.active.nonzero().view(-1);
    for (int64_t j = 0; j + 1 < act.size(0); j += 2)
      links[act[j + 1].item<int64_t>()] = act[j].item<int64_t>();
    if (chain_ && act.size(0) >= 3) links[act[0].item<int64_t>()] = act[2].item<int64_t>();
    return links;
  }

  int builds = 0;  ///< how often the trainer asked for links

 private:
  bool chain_;
};

// Noise from 10, rate from 22, growth stops at 20, links built at 24 and 27.
std::unique_ptr<Trainer> links_trainer(const Dataset& ds, std::shared_ptr<ContextModel> links,
                                       bool prune_links = false) {
  at::set_num_threads(1);
  torch::manual_seed(1);
  TrainOptions to;
  to.schedule = Schedule::scaled(0.01);
  to.schedule.iterations = 30;
  to.schedule.update_interval = 5;
  to.schedule.update_until = 20;
  to.schedule.quant_start = 10;
  to.schedule.rate_start = 22;
  to.schedule.link_builds = {24, 27};
  to.eval_interval = 0;
  to.seed = 3;
  AnchorModelOptions mo;
  mo.voxel_size = 0.08;
  mo.lr.max_steps = 30;
  RateOptions ro;
  ro.prune_links = prune_links;
  RateSetup rs = test::make_rate_setup(50, 10, ro);
  rs.links = std::move(links);
  rs.link_options.lr_start = 24;
  rs.link_options.lr_end = 30;
  auto t = make_trainer(to, mo, ds, std::make_shared<raster::CpuRasterizer>(1),
                        identity_feature_model(50), rs);
  if (!t.ok()) throw StatusError(t.status());
  return std::move(t).value();
}

#define SKIP_WITHOUT_PLUGINS()                            \
  do {                                                    \
    const std::string why = test::rate_plugins_missing(); \
    if (!why.empty()) GTEST_SKIP() << why;                \
  } while (0)

TEST(LinksTraining, BuiltOnScheduleAndDecodedExactly) {
  SKIP_WITHOUT_PLUGINS();
  Dataset ds = test::tiny_scene();
  auto pairs = std::make_shared<PairLinks>();
  auto t = links_trainer(ds, pairs);
  ASSERT_TRUE(t->model().has_links());
  for (int it = 1; it <= 30; ++it) {
    ASSERT_TRUE(t->step().ok()) << "iteration " << it;
    // Built at 24 and rebuilt from scratch at 27 (link_builds), and at no other iteration.
    EXPECT_EQ(pairs->builds, it < 24 ? 0 : it < 27 ? 1 : 2) << "iteration " << it;
    if (it < 24) {
      EXPECT_FALSE(t->model().links().defined()) << "iteration " << it;
      EXPECT_EQ(t->last_rate().leaves, 0);
    }
  }
  ASSERT_TRUE(t->model().links().defined());
  EXPECT_GT(t->last_rate().leaves, 0);
  EXPECT_GT(t->model().learning_rate("leaf_mlp"), 0);
  EXPECT_EQ(t->model().mlp_tensors().count("leaf_mlp.w1"), 1u);

  QuantizedAttributes q;
  auto coded = coded_model_from(t->model(), &q);
  ASSERT_TRUE(coded.ok()) << coded.status().to_string();
  ASSERT_TRUE(coded->links.defined());
  const LinkCounts lc = count_links(coded->links);
  EXPECT_GT(lc.leaves, 0);
  EXPECT_EQ(lc.roots, lc.leaves);  // one-to-one
  EXPECT_EQ(lc.roots + lc.leaves + lc.free, coded->voxels.size(0));
  EXPECT_EQ(coded->anchor_mask.sum().item<int64_t>(), coded->voxels.size(0));

  auto cfg = Config::from_string(kCodecYaml, "links_test.yaml");
  ASSERT_TRUE(cfg.ok());
  auto resolved = cfg->resolve(test::rate_registry());
  ASSERT_TRUE(resolved.ok()) << resolved.status().to_string();
  auto enc = encode_model(coded.value(), resolved.value(), codec_components_of(t->model()));
  ASSERT_TRUE(enc.ok()) << enc.status().to_string();
  // The default link coding is compact: a LINK section and no active-anchor mask.
  const auto has_section = [](const EncodeResult& e, const char* id) {
    for (const auto& s : e.sections)
      if (s.id == id) return true;
    return false;
  };
  EXPECT_TRUE(has_section(enc.value(), "LINK"));
  EXPECT_FALSE(has_section(enc.value(), "AMSK"));
  // The paper's coding writes the mask too, and decodes to the same links.
  CodedModel paper = coded.value();
  paper.link_coding = "paper";
  EXPECT_EQ(encode_model(paper, resolved.value(), codec_components_of(t->model())).status().code(),
            StatusCode::kInvalidArgument);  // the config says compact
  auto paper_cfg = Config::from_string(std::string(kCodecYaml) + "rate: {link_coding: paper}\n",
                                       "links_test_paper.yaml");
  ASSERT_TRUE(paper_cfg.ok());
  auto paper_resolved = paper_cfg->resolve(test::rate_registry());
  ASSERT_TRUE(paper_resolved.ok()) << paper_resolved.status().to_string();
  auto enc_paper = encode_model(paper, paper_resolved.value(), codec_components_of(t->model()));
  ASSERT_TRUE(enc_paper.ok()) << enc_paper.status().to_string();
  EXPECT_TRUE(has_section(enc_paper.value(), "LINK") && has_section(enc_paper.value(), "AMSK"));
  EXPECT_GT(enc_paper->bytes.size(), enc->bytes.size());
  auto dec_paper = decode_model(enc_paper->bytes, test::rate_registry());
  ASSERT_TRUE(dec_paper.ok()) << dec_paper.status().to_string();
  EXPECT_EQ(dec_paper->model.link_coding, "paper");
  EXPECT_TRUE(torch::equal(dec_paper->model.links, coded->links));
  EXPECT_TRUE(torch::equal(dec_paper->model.anchor_mask, coded->anchor_mask));

  at::set_num_threads(2);  // a different thread count than the encoder's
  auto dec = decode_model(enc->bytes, test::rate_registry());
  at::set_num_threads(1);
  ASSERT_TRUE(dec.ok()) << dec.status().to_string();
  EXPECT_TRUE(torch::equal(dec->model.links, coded->links));
  EXPECT_TRUE(torch::equal(dec->model.feature_sym, coded->feature_sym));
  EXPECT_TRUE(torch::equal(dec->model.scaling_sym, coded->scaling_sym));
  EXPECT_TRUE(torch::equal(dec->model.offset_sym, coded->offset_sym));
  EXPECT_TRUE(torch::equal(dec->params.q_f, q.params.q_f));
  // The leaves were coded with the leaf model's means, not the base model's.
  const auto leaves = (coded->links >= 0).nonzero().view(-1);
  EXPECT_TRUE(torch::equal(dec->params.mu_f,
                           coded_entropy_params(coded.value(), *t->model().context(), 50).mu_f));
  EXPECT_FALSE(torch::equal(dec->params.mu_f.index_select(0, leaves),
                            q.params.mu_f.index_select(0, leaves)));
  const auto free_rows = (coded->links < 0).nonzero().view(-1);
  EXPECT_TRUE(torch::equal(dec->params.mu_f.index_select(0, free_rows),
                           q.params.mu_f.index_select(0, free_rows)));

  // The COHS report splits exactly the FEAT estimate, and prices the leaves under both means.
  auto lr =
      link_rate_report(dec->model, dec->params, *dec->components.context, *dec->components.entropy);
  ASSERT_TRUE(lr.ok()) << lr.status().to_string();
  EXPECT_EQ(lr->counts.leaves, lc.leaves);
  EXPECT_EQ(lr->counts.roots, lc.roots);
  const double feat =
      estimated_stream_bits(dec->model, dec->params, *dec->components.entropy).at("FEAT");
  EXPECT_NEAR(lr->root_bits + lr->free_bits + lr->leaf_bits, feat, 1e-6 * feat);
  EXPECT_GT(lr->leaf_bits, 0);
  EXPECT_GT(lr->leaf_bits_base, 0);
  EXPECT_NE(lr->leaf_bits, lr->leaf_bits_base);
  EXPECT_GE(lr->mean_leaf_root_cosine, -1.0);
  EXPECT_LE(lr->mean_leaf_root_cosine, 1.0);
  CodedModel unlinked = dec->model;
  unlinked.links = torch::Tensor();
  EXPECT_EQ(
      link_rate_report(unlinked, dec->params, *dec->components.context, *dec->components.entropy)
          .status()
          .code(),
      StatusCode::kInvalidArgument);

  auto decoded = model_from_decoded(dec.value(), t->model().options());
  ASSERT_TRUE(decoded.ok()) << decoded.status().to_string();
  const auto img =
      test::render_quantised_and_decoded(t->model(), q, *decoded.value(), ds.test.at(0).camera);
  EXPECT_GT(img.gaussians, 0);
  EXPECT_TRUE(torch::equal(img.quantised, img.decoded))
      << "max diff " << (img.quantised - img.decoded).abs().max().item<float>();
}

TEST(LinksTraining, LeafOfAMaskedRootFallsBackToTheBaseModel) {
  SKIP_WITHOUT_PLUGINS();
  Dataset ds = test::tiny_scene();
  auto t = links_trainer(ds, std::make_shared<PairLinks>());
  AnchorModel& m = t->model();
  ASSERT_TRUE(m.rebuild_links(0).ok());
  const auto links = m.links();
  const auto leaves = (links >= 0).nonzero().view(-1);
  ASSERT_GE(leaves.size(0), 2);
  const int64_t leaf0 = leaves[0].item<int64_t>(), leaf1 = leaves[1].item<int64_t>();
  const int64_t root0 = links[leaf0].item<int64_t>();
  const auto rows = torch::tensor({leaf0, leaf1});
  const auto base = torch::zeros({2, 50});
  {
    torch::NoGradGuard ng;
    auto mu = m.feature_means(rows, base);
    EXPECT_GT(mu[0].abs().sum().item<double>(), 0) << "an active root: the leaf model";
    m.mask_logits()[root0].fill_(-20.f);  // root 0 becomes inactive
    mu = m.feature_means(rows, base);
    EXPECT_TRUE(torch::equal(mu[0], base[0])) << "inactive root: the base model";
    EXPECT_GT(mu[1].abs().sum().item<double>(), 0);
  }
  // Encoding drops the link of the now inactive root (docs/method.md §7.10).
  auto coded = coded_model_from(m);
  ASSERT_TRUE(coded.ok()) << coded.status().to_string();
  EXPECT_EQ(count_links(coded->links).leaves, leaves.size(0) - 1);
  // A rebuild follows the masks: no link touches the inactive anchor.
  ASSERT_TRUE(m.rebuild_links(1).ok());
  EXPECT_EQ(m.links()[root0].item<int64_t>(), -1);
  EXPECT_FALSE((m.links() == root0).any().item<bool>());
}

// A root whose adaptive step saturates (q = 0: a = −1e4) is coded as 0 (quantize); the leaf model
// sees the same 0, not 0/0. A tiny step clamps the coded feature about the features' mean, and
// the leaf model sees the clamped value too.
TEST(LinksTraining, ARootWithASaturatedStepGivesFiniteLeafMeans) {
  SKIP_WITHOUT_PLUGINS();
  Dataset ds = test::tiny_scene();
  auto t = links_trainer(ds, std::make_shared<PairLinks>());
  AnchorModel& m = t->model();
  ASSERT_TRUE(m.rebuild_links(0).ok());
  const auto leaves = (m.links() >= 0).nonzero().view(-1);
  ASSERT_GE(leaves.size(0), 1);
  {
    torch::NoGradGuard ng;
    m.features().normal_();  // roots with non-zero features: x / 0 would be infinite
    // The context's output layer (hash_grid: table, l1 w/b, l2 w/b): its last three outputs are
    // the step pre-activations; drive them to -1e4 for every anchor.
    auto params = m.context()->parameters();
    ASSERT_EQ(params.size(), 5u);
    const int64_t width = params[4].size(0);
    params[3].narrow(0, width - 3, 3).zero_();
    params[4].narrow(0, width - 3, 3).fill_(-1e4f);
    const auto mu = m.feature_means(leaves, torch::zeros({leaves.size(0), 50}));
    EXPECT_TRUE(torch::isfinite(mu).all().item<bool>());
  }
  QuantizedAttributes q;
  ASSERT_TRUE(coded_model_from(m, &q).ok());
  EXPECT_EQ(q.features.abs().max().item<float>(), 0.f);  // every feature coded as 0
  {
    torch::NoGradGuard ng;
    // a = −8: q = Q0·2/(1 + e^16) ≈ 2.3e-7, so the codec keeps features within mean ± 3.4e-3.
    auto params = m.context()->parameters();
    params[4].narrow(0, params[4].size(0) - 3, 3).fill_(-8.f);
    // ±100, half of each in every row: the features' mean is exactly 0 before and after doubling.
    auto f = m.features();
    f.copy_((torch::arange(f.size(1)) % 2 * 2 - 1).to(torch::kFloat).expand_as(f) * 100);
    const auto mu1 = m.feature_means(leaves, torch::zeros({leaves.size(0), 50}));
    f.mul_(2);
    const auto mu2 = m.feature_means(leaves, torch::zeros({leaves.size(0), 50}));
    EXPECT_TRUE(torch::isfinite(mu1).all().item<bool>());
    EXPECT_TRUE(torch::equal(mu1, mu2)) << "the leaf model saw features the codec cannot store";
  }
}

TEST(LinksTraining, ChainsAndBadShapesAreRefused) {
  SKIP_WITHOUT_PLUGINS();
  Dataset ds = test::tiny_scene();
  auto t = links_trainer(ds, std::make_shared<PairLinks>(/*chain=*/true));
  auto st = t->model().rebuild_links(0);
  ASSERT_FALSE(st.ok());
  EXPECT_NE(st.status().message().find("one-hop"), std::string::npos) << st.status().message();
  EXPECT_FALSE(t->model().links().defined());
  // Links without the rate path are refused.
  auto plain = make_trainer(TrainOptions(), AnchorModelOptions(), ds,
                            std::make_shared<raster::CpuRasterizer>(1), identity_feature_model(50));
  ASSERT_TRUE(plain.ok());
  EXPECT_FALSE(
      plain.value()->model().attach_links(std::make_shared<PairLinks>(), LinkOptions(), {}).ok());
}

TEST(LinksTraining, EncoderDropsExactlyTheLinksThatCostMoreThanTheySave) {
  SKIP_WITHOUT_PLUGINS();
  Dataset ds = test::tiny_scene();
  // The same training twice (deterministic); pruning changes only what is coded.
  auto kept = links_trainer(ds, std::make_shared<PairLinks>(), false);
  auto pruned = links_trainer(ds, std::make_shared<PairLinks>(), true);
  for (int it = 0; it < 30; ++it) {
    ASSERT_TRUE(kept->step().ok());
    ASSERT_TRUE(pruned->step().ok());
  }
  auto all = coded_model_from(kept->model());
  ASSERT_TRUE(all.ok()) << all.status().to_string();
  ASSERT_TRUE(all->links.defined());
  const auto params = coded_entropy_params(all.value(), *kept->model().context(), 50);
  const auto bits =
      feature_row_bits(all.value(), params, *kept->model().context(), *kept->model().entropy());
  const auto is_leaf = all->links >= 0;
  const double cost = compact_link_bits(is_leaf.logical_not().sum().item<int64_t>());
  const auto drop = is_leaf.logical_and((bits.base - bits.coded) < cost);
  const int64_t dropped = drop.sum().item<int64_t>();
  // Pair links on a tiny scene: some leaves pay for their link and some do not.
  ASSERT_GT(dropped, 0);
  ASSERT_LT(dropped, is_leaf.sum().item<int64_t>());

  auto some = coded_model_from(pruned->model());
  ASSERT_TRUE(some.ok()) << some.status().to_string();
  ASSERT_TRUE(some->links.defined());
  EXPECT_TRUE(
      torch::equal(some->links, torch::where(drop, torch::full_like(all->links, -1), all->links)));
  EXPECT_TRUE(torch::equal(some->feature_sym, all->feature_sym));

  auto cfg = Config::from_string(kCodecYaml, "links_prune_test.yaml");
  ASSERT_TRUE(cfg.ok());
  auto resolved = cfg->resolve(test::rate_registry());
  ASSERT_TRUE(resolved.ok());
  auto enc = encode_model(some.value(), resolved.value(), codec_components_of(pruned->model()));
  ASSERT_TRUE(enc.ok()) << enc.status().to_string();
  auto dec = decode_model(enc->bytes, test::rate_registry());
  ASSERT_TRUE(dec.ok()) << dec.status().to_string();
  EXPECT_TRUE(torch::equal(dec->model.links, some->links));
  EXPECT_TRUE(torch::equal(dec->model.feature_sym, some->feature_sym));

  // Two leaves on one root break docs/method.md §6.2's one-to-one rule: not encoded.
  CodedModel shared = some.value();
  const auto leaves = (shared.links >= 0).nonzero().view(-1);
  ASSERT_GE(leaves.size(0), 2);
  shared.links = shared.links.clone();
  shared.links[leaves[1].item<int64_t>()] = shared.links[leaves[0].item<int64_t>()].item<int64_t>();
  auto refused = encode_model(shared, resolved.value(), codec_components_of(pruned->model()));
  ASSERT_FALSE(refused.ok());
  EXPECT_NE(refused.status().message().find("has two leaves"), std::string::npos)
      << refused.status().message();
}

TEST(LinksTraining, CheckpointKeepsTheLinks) {
  SKIP_WITHOUT_PLUGINS();
  Dataset ds = test::tiny_scene();
  auto t = links_trainer(ds, std::make_shared<PairLinks>());
  // A state saved before the link build restores into a model that has links since (the
  // trainer's roll-back to its last good state): the links go with it.
  const std::string before = testing::TempDir() + "crpgs_links_before.pt";
  ASSERT_TRUE(t->save_checkpoint(before).ok());
  ASSERT_TRUE(t->model().rebuild_links(0).ok());
  ASSERT_TRUE(t->model().links().defined());
  {
    auto back = links_trainer(ds, std::make_shared<PairLinks>());
    ASSERT_TRUE(back->model().rebuild_links(0).ok());
    Status st = back->load_checkpoint(before);
    ASSERT_TRUE(st.ok()) << st.to_string();
    EXPECT_FALSE(back->model().links().defined());
  }
  std::filesystem::remove(before);
  const auto state = t->model().state_dict();
  auto u = links_trainer(ds, std::make_shared<PairLinks>());
  ASSERT_TRUE(u->model().load_state_dict(state).ok());
  ASSERT_TRUE(u->model().links().defined());
  EXPECT_TRUE(torch::equal(u->model().links(), t->model().links()));
  // And through a checkpoint file, as `--resume` reads it into a trainer with no links yet.
  const std::string path = testing::TempDir() + "crpgs_links_checkpoint.pt";
  ASSERT_TRUE(t->save_checkpoint(path).ok());
  auto v = links_trainer(ds, std::make_shared<PairLinks>());
  ASSERT_FALSE(v->model().links().defined());
  ASSERT_TRUE(v->load_checkpoint(path).ok());
  ASSERT_TRUE(v->model().links().defined());
  EXPECT_TRUE(torch::equal(v->model().links(), t->model().links()));
  std::filesystem::remove(path);
  // A checkpoint whose links form a chain is refused on load, not at the end of the run.
  auto broken = state;
  auto l = broken.at("links").clone();
  const auto linked = (l >= 0).nonzero().view(-1);
  ASSERT_GE(linked.size(0), 2);
  l[l[linked[0].item<int64_t>()].item<int64_t>()] = linked[1].item<int64_t>();  // a root, a leaf
  broken["links"] = l;
  auto w = links_trainer(ds, std::make_shared<PairLinks>());
  auto w_before = w->model().state_dict();
  for (auto& kv : w_before) kv.second = kv.second.clone();
  Status st = w->model().load_state_dict(broken);
  ASSERT_FALSE(st.ok());
  EXPECT_NE(st.message().find("checkpoint links:"), std::string::npos) << st.message();
  // So is a link vector of another length, and neither refusal changes the model.
  auto short_links = state;
  short_links["links"] = state.at("links").slice(0, 1);
  EXPECT_FALSE(w->model().load_state_dict(short_links).ok());
  const auto w_after = w->model().state_dict();
  ASSERT_EQ(w_after.size(), w_before.size());
  for (const auto& kv : w_before)
    EXPECT_TRUE(torch::equal(kv.second, w_after.at(kv.first))) << kv.first;
  // A model without a link strategy has no leaf model for them: refused, not a crash later.
  auto none = links_trainer(ds, nullptr);
  Status refused = none->model().load_state_dict(state);
  ASSERT_FALSE(refused.ok());
  EXPECT_NE(refused.message().find("holds anchor links but this model has none"), std::string::npos)
      << refused.message();
}

}  // namespace
}  // namespace crpgs

namespace crpgs {
namespace {

// A shared feature (SFA) with bounds recomputed at rate_start is allowed but flagged before
// training reaches it; frozen bounds or no shared part are not.
TEST(ShippedConfigs, SharedFeatureWithRecomputedBoundsIsFlagged) {
  const auto& reg = test::rate_registry();
  if (!reg.find(CRPGS_KIND_FEATURES, "sfa"))
    GTEST_SKIP() << "the sfa plugin is not built in " << CRPGS_PLUGIN_BUILD_DIR;
  SKIP_WITHOUT_PLUGINS();
  auto warnings = [&](const std::string& extra) {
    auto cfg = Config::from_string(
        "dataset: {format: synthetic, synthetic_width: 32, synthetic_height: 24, "
        "synthetic_views: 6, synthetic_points: 300}\n"
        "context: {type: hash_grid, n_levels: 2, resolutions: [8, 16], log2_hashmap_size: 8, "
        "n_levels_2d: 1, resolutions_2d: [16], log2_hashmap_size_2d: 8, hidden_dim: 16}\n"
        "entropy: {type: gaussian}\n"
        "train: {schedule: fast, fast_factor: 0.01, iterations: 20, threads: 1}\n" +
            extra,
        "sfa_bounds.yaml");
    if (!cfg.ok()) throw StatusError(cfg.status());
    auto r = cfg->resolve(reg);
    if (!r.ok()) throw StatusError(r.status());
    auto t = setup_training(r.value(), reg, SetupOptions{});
    if (!t.ok()) throw StatusError(t.status());
    return t.value()->setting_warnings();
  };
  const auto flagged = warnings("features: {type: sfa, ratio: 0.4}\n");
  ASSERT_EQ(flagged.size(), 1u);
  EXPECT_NE(flagged[0].find("recompute_bounds"), std::string::npos) << flagged[0];
  EXPECT_NE(flagged[0].find("sfa"), std::string::npos) << flagged[0];
  EXPECT_TRUE(
      warnings("features: {type: sfa, ratio: 0.4}\nrate: {recompute_bounds: false}\n").empty());
  EXPECT_TRUE(warnings("features: {type: sfa, ratio: 0}\n").empty());
  EXPECT_TRUE(warnings("").empty());
}

// Every shipped config validates against the schemas of the built components, and the CRP-GS
// configs say what docs/method.md §6-§7 prescribes.
TEST(ShippedConfigs, ResolveAndFollowTheMethod) {
  const auto& reg = test::rate_registry();
  for (const char* type : {"link_cohs", "link_random", "link_distance", "link_none"})
    if (!reg.find(CRPGS_KIND_CONTEXT, type))
      GTEST_SKIP() << "link plugin '" << type << "' is not built in " << CRPGS_PLUGIN_BUILD_DIR;
  if (!reg.find(CRPGS_KIND_FEATURES, "sfa"))
    GTEST_SKIP() << "the sfa plugin is not built in " << CRPGS_PLUGIN_BUILD_DIR;
  SKIP_WITHOUT_PLUGINS();
  const std::string root = std::string(CRPGS_SOURCE_DIR) + "/configs";
  int checked = 0;
  for (const char* dir : {"", "/ablations"}) {
    for (const auto& e : std::filesystem::directory_iterator(root + dir)) {
      if (e.path().extension() != ".yaml") continue;
      auto cfg = Config::load_file(e.path().string());
      ASSERT_TRUE(cfg.ok()) << cfg.status().to_string();
      auto r = cfg->resolve(reg);
      ASSERT_TRUE(r.ok()) << r.status().to_string();
      ASSERT_TRUE(train_options_from_config(r.value()).ok()) << e.path();
      ASSERT_TRUE(rate_options_from_config(r.value()).ok()) << e.path();
      ++checked;
    }
  }
  EXPECT_GE(checked, 15);
  auto cfg = Config::load_file(root + "/crpgs.yaml");
  ASSERT_TRUE(cfg.ok());
  auto r = cfg->resolve(reg);
  ASSERT_TRUE(r.ok());
  EXPECT_EQ(r->section("links")["type"].as<std::string>(), "link_cohs");
  EXPECT_EQ(r->section("features")["type"].as<std::string>(), "sfa");
  EXPECT_DOUBLE_EQ(r->section("features")["ratio"].as<double>(), 0.4);
  auto to = train_options_from_config(r.value());
  ASSERT_TRUE(to.ok());
  EXPECT_EQ(to->schedule.iterations, 40000);
  EXPECT_EQ(to->schedule.lr_steps, 30000);  // HAC's schedules, clamped after 30k (§7.7)
  EXPECT_EQ(to->schedule.link_builds, (std::vector<int>{30000, 33000, 36000}));
  auto lo = link_options_from_config(r.value(), to->schedule);
  ASSERT_TRUE(lo.ok());
  EXPECT_EQ(lo->lr_start, 30000);
  EXPECT_EQ(lo->lr_end, 40000);
  EXPECT_EQ(lo->leaf_hidden, 60);
  EXPECT_FALSE(rate_options_from_config(r.value())->recompute_bounds);
  // The fast schedule scales the link builds with everything else.
  ASSERT_TRUE(cfg->apply_override("train.schedule=fast").ok());
  auto fast = train_options_from_config(cfg->resolve(reg).value());
  ASSERT_TRUE(fast.ok());
  EXPECT_EQ(fast->schedule.iterations, 4000);
  EXPECT_EQ(fast->schedule.link_builds, (std::vector<int>{3000, 3300, 3600}));
  EXPECT_DOUBLE_EQ(fast->checkpoint_minutes, 15);
  ASSERT_TRUE(cfg->apply_override("train.checkpoint_minutes=2.5").ok());
  EXPECT_DOUBLE_EQ(train_options_from_config(cfg->resolve(reg).value())->checkpoint_minutes, 2.5);
  // A link build inside growing and pruning (which clear the links) or after the last iteration
  // would leave the run without links and without a word: refused.
  for (const char* builds : {"[30000, 1000]", "[30000, 50000]"}) {
    auto c = Config::load_file(root + "/crpgs.yaml");
    ASSERT_TRUE(c->apply_override(std::string("train.link_builds=") + builds).ok());
    auto rr = c->resolve(reg);
    ASSERT_TRUE(rr.ok()) << rr.status().to_string();
    auto bad =
        link_options_from_config(rr.value(), train_options_from_config(rr.value())->schedule);
    ASSERT_FALSE(bad.ok()) << builds;
    EXPECT_NE(bad.status().message().find("is outside [15000, 40000]"), std::string::npos)
        << bad.status().message();
  }
}

// SFA with train.feature_model_start: growing_end and features.zero_init: f_s = 0 and the shared
// grid and its Linear as initialised (lr 0) while anchors grow and are pruned, learning after
// (crpgs.yaml's setting: shared features must not decide which anchors are pruned).
TEST(SharedFeatures, HeldAtZeroUntilGrowingAndPruningEnd) {
  const auto& reg = test::rate_registry();
  if (!reg.find(CRPGS_KIND_FEATURES, "sfa") || !reg.find(CRPGS_KIND_CONTEXT, "hash_grid"))
    GTEST_SKIP() << "the sfa/hash_grid plugins are not built in " << CRPGS_PLUGIN_BUILD_DIR;
  SKIP_WITHOUT_PLUGINS();
  // update_until is 15 at fast_factor 0.001.
  auto trained = [&](int iterations) {
    auto raw = Config::from_string(
        R"yaml(
dataset: {format: synthetic, synthetic_width: 48, synthetic_height: 32, synthetic_views: 12,
          synthetic_points: 1000}
context: {type: hash_grid, n_levels: 4, resolutions: [8, 16, 32, 64], log2_hashmap_size: 10,
          n_levels_2d: 2, resolutions_2d: [32, 64], log2_hashmap_size_2d: 10, hidden_dim: 32}
features: {type: sfa, ratio: 0.4, n_levels: 3, resolutions: [8, 16, 32], log2_hashmap_size: 9,
           n_levels_2d: 0, resolutions_2d: [], zero_init: true}
entropy: {type: gaussian}
rate: {lambda: 0.002, recompute_bounds: false}
rasterizer: {type: cpu, threads: 1}
train: {schedule: fast, fast_factor: 0.001, eval_interval: 0, checkpoint_interval: 0,
        threads: 1, feature_model_start: growing_end}
)yaml",
        "held_sfa.yaml");
    EXPECT_TRUE(raw.ok()) << raw.status().to_string();
    EXPECT_TRUE(raw->apply_override("train.iterations=" + std::to_string(iterations)).ok());
    auto cfg = raw->resolve(reg);
    EXPECT_TRUE(cfg.ok()) << cfg.status().to_string();
    auto t = setup_training(cfg.value(), reg, SetupOptions{});
    EXPECT_TRUE(t.ok()) << t.status().to_string();
    if (iterations > 0) {
      EXPECT_TRUE(t.value()->train().ok());
    }
    return std::move(t).value();
  };
  const auto fresh = trained(0);
  const auto held = trained(12);
  const auto learning = trained(20);
  const auto p0 = fresh->model().feature_model()->parameters();
  const auto p12 = held->model().feature_model()->parameters();
  const auto p20 = learning->model().feature_model()->parameters();
  ASSERT_EQ(p0.size(), 3u);
  EXPECT_EQ(p0[1].abs().max().item<float>(), 0.f);  // Linear weight and bias start at zero
  EXPECT_EQ(p0[2].abs().max().item<float>(), 0.f);
  for (size_t i = 0; i < p0.size(); ++i) EXPECT_TRUE(torch::equal(p0[i], p12[i])) << i;
  EXPECT_EQ(held->model().learning_rate("feature_model"), 0.0);
  EXPECT_GT(learning->model().learning_rate("feature_model"), 0.0);
  EXPECT_GT(p20[1].abs().max().item<float>(), 0.f);  // it learns after growing ends
  // The shipped method holds SFA until the full schedule's growing ends (15k; 1.5k when fast).
  const std::string root = std::string(CRPGS_SOURCE_DIR) + "/configs";
  auto shipped = Config::load_file(root + "/crpgs.yaml");
  ASSERT_TRUE(shipped.ok());
  auto r = shipped->resolve(reg);
  ASSERT_TRUE(r.ok()) << r.status().to_string();
  EXPECT_TRUE(r->section("features")["zero_init"].as<bool>());
  auto mo = model_options_from_config(r.value());
  ASSERT_TRUE(mo.ok()) << mo.status().to_string();
  EXPECT_EQ(mo->lr.feature_model_start, 15000);
  auto hac = Config::load_file(root + "/hac.yaml");
  ASSERT_TRUE(hac.ok());
  auto hac_mo = model_options_from_config(hac->resolve(reg).value());
  ASSERT_TRUE(hac_mo.ok());
  EXPECT_EQ(hac_mo->lr.feature_model_start, 0);
}

// The feature model's lr after two iterations of a small SFA training: from `sfm_points` SfM
// points (0: random init) with `train_keys` added to its train section (update_until is 15).
double feature_lr_after_two_iterations(int sfm_points, const std::string& train_keys) {
  const auto& reg = test::rate_registry();
  auto raw = Config::from_string(
      "dataset: {format: synthetic, synthetic_width: 32, synthetic_height: 24, "
      "synthetic_views: 8, synthetic_points: " +
          std::to_string(sfm_points) +
          "}\n"
          "model: {random_init_points: 500}\n"
          "context: {type: hash_grid, log2_hashmap_size: 10, log2_hashmap_size_2d: 10}\n"
          "features: {type: sfa, ratio: 0.4, n_levels: 2, resolutions: [8, 16], "
          "log2_hashmap_size: 9, n_levels_2d: 0, resolutions_2d: [], zero_init: true}\n"
          "entropy: {type: gaussian}\n"
          "rasterizer: {type: cpu, threads: 1}\n"
          "train: {schedule: fast, fast_factor: 0.001, eval_interval: 0, "
          "checkpoint_interval: 0, threads: 1, iterations: 2, " +
          train_keys + "}\n",
      "sfa_hold.yaml");
  EXPECT_TRUE(raw.ok()) << raw.status().to_string();
  auto cfg = raw->resolve(reg);
  EXPECT_TRUE(cfg.ok()) << cfg.status().to_string();
  auto t = setup_training(cfg.value(), reg, SetupOptions{});
  EXPECT_TRUE(t.ok()) << t.status().to_string();
  EXPECT_TRUE(t.value()->train().ok());
  return t.value()->model().learning_rate("feature_model");
}

bool sfa_plugins_built() {
  const auto& reg = test::rate_registry();
  return reg.find(CRPGS_KIND_FEATURES, "sfa") && reg.find(CRPGS_KIND_CONTEXT, "hash_grid");
}

// feature_model_start: auto holds SFA where anchors start from random points and not where they
// start from SfM points.
TEST(SharedFeatures, AutoHoldsOnlyWhereAnchorsStartFromRandomPoints) {
  SKIP_WITHOUT_PLUGINS();
  if (!sfa_plugins_built())
    GTEST_SKIP() << "the sfa/hash_grid plugins are not built in " << CRPGS_PLUGIN_BUILD_DIR;
  const std::string keys = "feature_model_start: auto";
  EXPECT_EQ(feature_lr_after_two_iterations(0, keys), 0.0);    // random init: held (until 15)
  EXPECT_GT(feature_lr_after_two_iterations(300, keys), 0.0);  // SfM points: learning
}

// A softer, shorter hold: before feature_model_start SFA learns at a fraction of its lr.
TEST(SharedFeatures, HoldLrScaleAppliesUntilFeatureModelStart) {
  SKIP_WITHOUT_PLUGINS();
  auto raw = Config::from_string(
      "train: {schedule: fast, feature_model_start: rate_start, feature_model_hold_lr_scale: "
      "0.1}\n",
      "soft_hold.yaml");
  ASSERT_TRUE(raw.ok()) << raw.status().to_string();
  auto mo = model_options_from_config(raw->resolve(test::rate_registry()).value());
  ASSERT_TRUE(mo.ok()) << mo.status().to_string();
  EXPECT_EQ(mo->lr.feature_model_start, 1000);  // the fast schedule's rate_start
  EXPECT_DOUBLE_EQ(mo->lr.feature_model_hold_scale, 0.1);
  auto bad = Config::from_string("train: {feature_model_hold_lr_scale: 2}\n", "bad_hold.yaml");
  ASSERT_TRUE(bad.ok());
  auto rejected = bad->resolve(test::rate_registry());
  ASSERT_FALSE(rejected.ok());
  EXPECT_NE(rejected.status().message().find("feature_model_hold_lr_scale"), std::string::npos)
      << rejected.status().message();
  // What training applies: during the hold a tenth of the lr it has learning from the start.
  if (!sfa_plugins_built())
    GTEST_SKIP() << "the sfa/hash_grid plugins are not built in " << CRPGS_PLUGIN_BUILD_DIR;
  const double full = feature_lr_after_two_iterations(0, "feature_model_start: start");
  ASSERT_GT(full, 0.0);
  EXPECT_NEAR(feature_lr_after_two_iterations(
                  0, "feature_model_start: growing_end, feature_model_hold_lr_scale: 0.1"),
              0.1 * full, 1e-12 * full);
}

}  // namespace
}  // namespace crpgs
