/// @file test_decode_cli.cpp
/// @brief `crpgs decode` and `crpgs render` in fresh processes: a small trained model is encoded
/// here; two processes with 1 and 2 threads decode it to identical symbols (equal to the
/// encoder's) and identical dequantised tensors, as does a third with other BLAS kernels; renders
/// of the bitstream, of the decode directory and of the training run's quantised model are
/// pixel-identical. CRP-GS's parts (SFA's shared grid, links) through rate, file, decode and
/// `crpgs info`; `crpgs demo` runs configs/crpgs.yaml's method.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <filesystem>
#include <map>
#include <regex>

#include "cli_test_util.h"
#include "crpgs/atomic_file.h"
#include "crpgs/codec.h"
#include "crpgs/experiments/run_metrics.h"
#include "crpgs/experiments/sweep.h"
#include "crpgs/gaussian_export.h"
#include "crpgs/image.h"
#include "crpgs/trainer.h"
#include "crpgs/version.h"
#include "test_registry.h"
#include "train/rate_test_util.h"

namespace crpgs {
namespace {
namespace fs = std::filesystem;

// tests/data/tiny_rate.yaml: a small synthetic scene through every phase in 12 iterations.
const std::string kConfigFile = std::string(CRPGS_SOURCE_DIR) + "/tests/data/tiny_rate.yaml";

using test::read_archive;
using test::run_cli;

/// kConfigFile trained in this process into DIR/run, a fresh directory holding its config as
/// `crpgs train` leaves a run.
struct SmallRun {
  Config config;
  std::unique_ptr<Trainer> trainer;
};
StatusOr<SmallRun> train_small_run(const fs::path& dir, const ComponentRegistry& reg) {
  fs::remove_all(dir);
  fs::create_directories(dir / "run");
  CRPGS_ASSIGN_OR_RETURN(Config raw, Config::load_file(kConfigFile));
  SmallRun r;
  CRPGS_ASSIGN_OR_RETURN(r.config, raw.resolve(reg));
  CRPGS_RETURN_IF_ERROR(r.config.save((dir / "run" / "config.yaml").string()));
  CRPGS_ASSIGN_OR_RETURN(
      r.trainer, setup_training(r.config, reg, SetupOptions{(dir / "run").string(), false}));
  CRPGS_RETURN_IF_ERROR(r.trainer->train());
  return r;
}

std::vector<fs::path> pngs_in(const fs::path& dir) {
  std::vector<fs::path> out;
  if (fs::is_directory(dir))
    for (const auto& e : fs::directory_iterator(dir))
      if (e.path().extension() == ".png") out.push_back(e.path().filename());
  std::sort(out.begin(), out.end());
  return out;
}

TEST(DecodeCli, BitExactAcrossProcessesAndThreadCounts) {
#ifndef CRPGS_CLI_PATH
  GTEST_SKIP() << "built without the crpgs CLI (CRPGS_BUILD_APPS=OFF)";
#else
  if (!fs::exists(CRPGS_CLI_PATH))
    GTEST_SKIP() << "the crpgs CLI is not built yet: " << CRPGS_CLI_PATH;
  const ComponentRegistry& reg = test::test_registry();
  if (!reg.find(CRPGS_KIND_CONTEXT, "hash_grid") || !reg.find(CRPGS_KIND_ENTROPY, "gaussian"))
    GTEST_SKIP() << "hash_grid/gaussian plugins not built in " << CRPGS_PLUGIN_BUILD_DIR;
  const fs::path dir = fs::path(CRPGS_TEST_TMP_DIR) / "decode_cli";

  // 1. Train and encode in this process; keep the encoder's symbols and quantised attributes.
  auto small = train_small_run(dir, reg);
  ASSERT_TRUE(small.ok()) << small.status().to_string();
  const Config& cfg = small->config;
  Trainer& t = *small->trainer;
  QuantizedAttributes q;
  auto coded = coded_model_from(t.model(), &q);
  ASSERT_TRUE(coded.ok()) << coded.status().to_string();
  ASSERT_GT(coded->voxels.size(0), 10);
  auto enc = encode_model(coded.value(), cfg, codec_components_of(t.model()));
  ASSERT_TRUE(enc.ok()) << enc.status().to_string();
  const std::string file = (dir / "scene.crpgs").string();
  ASSERT_TRUE(write_file_atomic(file, enc->bytes).ok());

  // 2. Fresh processes decode it with different thread counts, and with OpenBLAS's generic SSE3
  // kernels (another summation order than this process's): the entropy parameters are portable.
  std::string log;
  const char* coretype = std::getenv("OPENBLAS_CORETYPE");
  const std::string saved_coretype = coretype ? coretype : "";
  for (int run : {1, 2, 3}) {
    const int threads = std::min(run, 2);
    if (run == 3) setenv("OPENBLAS_CORETYPE", "Prescott", 1);
    const std::string out = (dir / ("dec" + std::to_string(run))).string();
    const int rc =
        run_cli("decode '" + file + "' -o '" + out + "' --threads " + std::to_string(threads),
                dir / "log.txt", &log);
    if (run == 3) {
      if (coretype)
        setenv("OPENBLAS_CORETYPE", saved_coretype.c_str(), 1);
      else
        unsetenv("OPENBLAS_CORETYPE");
    }
    ASSERT_EQ(rc, 0) << log;
    EXPECT_NE(log.find("decoded in"), std::string::npos) << log;
    // The third decode really ran other kernels (OpenBLAS honours OPENBLAS_CORETYPE).
    if (run == 3) {
      EXPECT_NE(log.find("BLAS kernels OpenBLAS Prescott"), std::string::npos) << log;
    }
    EXPECT_TRUE(fs::exists(fs::path(out) / "config.yaml"));
  }
  const auto a = read_archive(dir / "dec1" / "decoded.pt");
  ASSERT_FALSE(a.empty());
  for (const char* other : {"dec2", "dec3"}) {
    const auto b = read_archive(dir / other / "decoded.pt");
    ASSERT_EQ(a.size(), b.size()) << other;
    for (const auto& [k, v] : a) {
      ASSERT_TRUE(b.count(k)) << other << " " << k;
      EXPECT_TRUE(v.dtype() == b.at(k).dtype() && torch::equal(v, b.at(k))) << other << " " << k;
    }
  }
  // Equal to what the encoder coded and to the training-side quantised attributes.
  EXPECT_TRUE(torch::equal(a.at("voxels"), coded->voxels));
  EXPECT_TRUE(torch::equal(a.at("offset_masks"), coded->offset_masks));
  EXPECT_TRUE(torch::equal(a.at("feature_symbols"), coded->feature_sym));
  EXPECT_TRUE(torch::equal(a.at("scaling_symbols"), coded->scaling_sym));
  EXPECT_TRUE(torch::equal(a.at("offset_symbols"), coded->offset_sym));
  EXPECT_TRUE(torch::equal(a.at("bounds"), coded->bounds));
  EXPECT_EQ(a.at("voxel_size").item<double>(), coded->voxel_size);
  EXPECT_TRUE(torch::equal(a.at("positions"), q.positions));
  EXPECT_TRUE(torch::equal(a.at("features"), q.features));
  EXPECT_TRUE(torch::equal(a.at("scaling"), q.scaling));
  EXPECT_TRUE(torch::equal(a.at("offsets"), q.offsets));

  // 3. Renders from the decode directory, the bitstream and the run's quantised model.
  const std::vector<std::pair<std::string, std::string> > renders = {
      {(dir / "dec1").string(), "1"}, {file, "2"}, {(dir / "run").string(), "2"}};
  for (size_t i = 0; i < renders.size(); ++i) {
    const std::string out = (dir / ("render" + std::to_string(i))).string();
    ASSERT_EQ(
        run_cli("render '" + renders[i].first + "' -o '" + out + "' --threads " + renders[i].second,
                dir / "log.txt", &log),
        0)
        << log;
    EXPECT_NE(log.find("ms/view"), std::string::npos) << log;
  }
  const auto names = pngs_in(dir / "render0");
  ASSERT_EQ(names.size(), t.dataset().test.size());
  for (size_t i = 1; i < renders.size(); ++i)
    EXPECT_EQ(pngs_in(dir / ("render" + std::to_string(i))), names);
  for (const auto& n : names) {
    auto ref = load_image((dir / "render0" / n).string());
    ASSERT_TRUE(ref.ok()) << ref.status().to_string();
    for (size_t i = 1; i < renders.size(); ++i) {
      auto other = load_image((dir / ("render" + std::to_string(i)) / n).string());
      ASSERT_TRUE(other.ok()) << other.status().to_string();
      EXPECT_EQ(other->width, ref->width);
      EXPECT_TRUE(other->pixels == ref->pixels) << n << " differs: " << renders[i].first;
    }
  }

  // 3b. A train view renders with its own appearance embedding, as in training (not the mean).
  const std::string train_out = (dir / "render_train").string();
  ASSERT_EQ(run_cli("render '" + (dir / "run").string() + "' -o '" + train_out +
                        "' --views train --threads 1",
                    dir / "log.txt", &log),
            0)
      << log;
  {
    torch::NoGradGuard ng;
    t.model().set_quantized(q);
    RenderSettings st;
    st.background = t.model().options().effects.background;
    const View& v = t.dataset().train[1];
    auto render = [&](int camera_index) {
      auto g = t.model().generate(v.camera, camera_index, t.rasterizer(), st, false);
      return quantize_8bit(tensor_to_image(t.rasterizer().render(g.batch, v.camera, st).image));
    };
    const Image own = render(1), mean = render(-1);
    ASSERT_FALSE(own.pixels == mean.pixels) << "the embedding makes no difference here";
    auto cli = load_image((fs::path(train_out) / "train_00001.png").string());
    ASSERT_TRUE(cli.ok()) << cli.status().to_string();
    EXPECT_TRUE(cli->pixels == own.pixels);
    // With another split a train index may name another view than in training (not train view 1
    // here: view 2 of 12 under test_every 8 and 3 alike), so every train view takes the mean
    // embedding, with a note.
    const std::string resplit_out = (dir / "render_resplit").string();
    ASSERT_EQ(run_cli("render '" + file + "' -o '" + resplit_out +
                          "' --views train --threads 1 --set dataset.test_every=3",
                      dir / "log.txt", &log),
              0)
        << log;
    EXPECT_NE(log.find("mean appearance embedding"), std::string::npos) << log;
    auto resplit = load_image((fs::path(resplit_out) / "train_00001.png").string());
    ASSERT_TRUE(resplit.ok()) << resplit.status().to_string();
    EXPECT_TRUE(resplit->pixels == mean.pixels);
  }

  // 3c. `crpgs export --refine 0` of the run bakes what bake_gaussians bakes with the options it
  // was given.
  {
    const std::string ply = (dir / "scene.ply").string();
    ASSERT_EQ(run_cli("export '" + (dir / "run").string() + "' -o '" + ply +
                          "' --sh-degree 1 --view-weight 0.5 --refine 0 --threads 1",
                      dir / "log.txt", &log),
              0)
        << log;
    EXPECT_NE(log.find("view weight 0.50"), std::string::npos) << log;
    EXPECT_NE(log.find("EXPORTED PSNR"), std::string::npos) << log;
    auto cli = read_ply(ply);
    ASSERT_TRUE(cli.ok()) << cli.status().to_string();
    BakeOptions opt;
    opt.sh_degree = 1;
    for (const auto& v : t.dataset().train) opt.camera_centers.push_back(v.camera.center());
    for (double w : {0.5, 0.0}) {
      opt.view_weight = w;
      auto baked = bake_gaussians(t.model(), opt, &q);
      ASSERT_TRUE(baked.ok()) << baked.status().to_string();
      ASSERT_EQ(baked->size(), cli->size());
      EXPECT_EQ(baked->means, cli->means);
      float diff = 0;
      for (size_t i = 0; i < cli->sh_rest.size(); ++i)
        diff = std::max(diff, std::abs(baked->sh_rest[i] - cli->sh_rest[i]));
      if (w == 0.5)
        EXPECT_LT(diff, 1e-5f);
      else
        EXPECT_GT(diff, 1e-3f) << "the view weight made no difference";
    }
    // --refine moves the same Gaussians (refine_gaussians is tested in test_gaussian_export).
    const std::string refined = (dir / "refined.ply").string();
    ASSERT_EQ(run_cli("export '" + (dir / "run").string() + "' -o '" + refined +
                          "' --sh-degree 1 --view-weight 0.5 --refine 4 --threads 1",
                      dir / "log.txt", &log),
              0)
        << log;
    EXPECT_NE(log.find("training views: 4 iterations"), std::string::npos) << log;
    auto r = read_ply(refined);
    ASSERT_TRUE(r.ok()) << r.status().to_string();
    ASSERT_EQ(r->size(), cli->size());
    EXPECT_NE(r->means, cli->means);
    EXPECT_NE(r->opacity, cli->opacity);
  }

  // 3d. Outputs that would replace an input are refused, and nothing is written.
  const auto run_bytes = test::read_text(dir / "run" / "checkpoint.pt");
  for (const auto& [cmd, why] : std::vector<std::pair<std::string, std::string> >{
           {"export '" + file + "' -o '" + file + "'", "is the input itself"},
           {"encode '" + (dir / "run").string() + "' -o '" +
                (dir / "run" / "checkpoint.pt").string() + "'",
            "would replace the checkpoint.pt of"},
           {"decode '" + file + "' -o '" + (dir / "run").string() + "'",
            "holds a training run (checkpoint.pt)"}}) {
    EXPECT_NE(run_cli(cmd, dir / "log.txt", &log), 0) << cmd;
    EXPECT_NE(log.find(why), std::string::npos) << cmd << "\n" << log;
  }
  EXPECT_EQ(test::read_text(dir / "run" / "checkpoint.pt"), run_bytes);
  ASSERT_TRUE(read_file_bytes(file).ok());
  EXPECT_EQ(read_file_bytes(file)->size(), enc->bytes.size());
  // ... but encode refreshes the run's own bitstream in place.
  ASSERT_EQ(run_cli("encode '" + (dir / "run").string() + "' -o '" +
                        (dir / "run" / "scene.crpgs").string() + "'",
                    dir / "log.txt", &log),
            0)
      << log;
  EXPECT_TRUE(fs::exists(dir / "run" / "scene.crpgs"));
  // eval takes a decode directory too.
  ASSERT_EQ(run_cli("eval '" + (dir / "dec1").string() + "'", dir / "log.txt", &log), 0) << log;
  EXPECT_NE(log.find("decode directory"), std::string::npos) << log;
  EXPECT_NE(log.find("mean"), std::string::npos) << log;

  // 4. A model whose dataset is absent is refused with a message that says so.
  EXPECT_NE(run_cli("render '" + (dir / "dec1").string() + "' -o '" + (dir / "none").string() +
                        "' --set dataset.format=colmap --set dataset.path=" +
                        (dir / "no_such_dataset").string(),
                    dir / "log.txt", &log),
            0);
  EXPECT_NE(log.find("is absent"), std::string::npos) << log;

  // 5. A bitstream or decode directory fixes its model: a --set that the model would ignore
  // while the dataset followed it is refused; the thread count, the rasterizer and a --set
  // that changes nothing (compared by value) are accepted; a misspelt section is named.
  EXPECT_NE(run_cli("eval '" + file + "' --set sceen.background=[1,1,1]", dir / "log.txt", &log),
            0);
  EXPECT_NE(log.find("did you mean 'scene'"), std::string::npos) << log;
  for (const std::string& src : {file, (dir / "dec1").string()}) {
    EXPECT_NE(run_cli("eval '" + src + "' --set scene.background=[1,1,1]", dir / "log.txt", &log),
              0);
    EXPECT_NE(log.find("--set scene.background: a "), std::string::npos) << log;
    EXPECT_NE(log.find("fixes the model it holds"), std::string::npos) << log;
  }
  ASSERT_EQ(run_cli("eval '" + file + "' --set train.threads=1 --set rasterizer.threads=1 " +
                        "--set scene.background=[0.0,0,0]",
                    dir / "log.txt", &log),
            0)
      << log;
#endif
}

// CRP-GS's two parts through the whole path on a small scene: SFA's shared grid is in the
// trained rate and in the file (FTRS), a file with links and a shared grid decodes (another
// thread count) to the training-side quantised model, and `crpgs info` reports the COHS side
// information and the anchor partition. link_random with unpruned links: the partition must be
// non-trivial whatever the few iterations make of the features.
const char* kCrpgsConfig = R"yaml(
dataset: {format: synthetic, synthetic_width: 48, synthetic_height: 32, synthetic_views: 12,
          synthetic_points: 1000}
context: {type: hash_grid, n_levels: 4, resolutions: [8, 16, 32, 64], log2_hashmap_size: 10,
          n_levels_2d: 2, resolutions_2d: [32, 64], log2_hashmap_size_2d: 10, hidden_dim: 32}
features: {type: sfa, ratio: 0.4, n_levels: 3, resolutions: [8, 16, 32], log2_hashmap_size: 9,
           n_levels_2d: 1, resolutions_2d: [32], log2_hashmap_size_2d: 9}
links: {type: link_random}
entropy: {type: gaussian}
scene: {appearance_dim: 4}
rate: {lambda: 0.002, recompute_bounds: false, prune_links: false}
rasterizer: {type: cpu, threads: 1}
train: {schedule: fast, fast_factor: 0.001, iterations: 20, link_builds: [16000, 18000],
        eval_interval: 0, checkpoint_interval: 0, threads: 1}
)yaml";

/// A feature model that counts its forward passes and otherwise is the one it wraps.
class CountingFeatures final : public FeatureModel {
 public:
  explicit CountingFeatures(std::shared_ptr<FeatureModel> inner) : inner_(std::move(inner)) {}
  std::string type_name() const override { return inner_->type_name(); }
  YAML::Node hyperparams() const override { return inner_->hyperparams(); }
  int64_t coded_dim() const override { return inner_->coded_dim(); }
  int64_t feature_dim() const override { return inner_->feature_dim(); }
  torch::Tensor forward(const torch::Tensor& coded, const torch::Tensor& positions01) override {
    ++forwards;
    return inner_->forward(coded, positions01);
  }
  int forwards = 0;

 private:
  std::shared_ptr<FeatureModel> inner_;
};

#ifdef CRPGS_CLI_PATH
/// "" when the CLI and CRP-GS's plugins (with the link strategy `links`) are built, else why not.
std::string crpgs_parts_missing(const ComponentRegistry& reg, const char* links) {
  if (!fs::exists(CRPGS_CLI_PATH))
    return std::string("the crpgs CLI is not built yet: ") + CRPGS_CLI_PATH;
  for (const auto& [kind, type] :
       {std::pair{CRPGS_KIND_CONTEXT, "hash_grid"}, std::pair{CRPGS_KIND_ENTROPY, "gaussian"},
        std::pair{CRPGS_KIND_FEATURES, "sfa"}, std::pair{CRPGS_KIND_CONTEXT, links}})
    if (!reg.find(kind, type))
      return std::string("the ") + type + " plugin is not built in " + CRPGS_PLUGIN_BUILD_DIR;
  return "";
}
#endif

TEST(DecodeCli, SharedGridAndLinksAreRatedCodedDecodedAndReported) {
#ifndef CRPGS_CLI_PATH
  GTEST_SKIP() << "built without the crpgs CLI (CRPGS_BUILD_APPS=OFF)";
#else
  const ComponentRegistry& reg = test::test_registry();
  if (const std::string why = crpgs_parts_missing(reg, "link_random"); !why.empty())
    GTEST_SKIP() << why;
  const fs::path dir = fs::path(CRPGS_TEST_TMP_DIR) / "decode_cli_crpgs";
  fs::remove_all(dir);
  fs::create_directories(dir);

  auto raw = Config::from_string(kCrpgsConfig, "decode_cli_crpgs.yaml");
  ASSERT_TRUE(raw.ok()) << raw.status().to_string();
  auto cfg = raw->resolve(reg);
  ASSERT_TRUE(cfg.ok()) << cfg.status().to_string();
  auto trainer = setup_training(cfg.value(), reg, SetupOptions{});
  ASSERT_TRUE(trainer.ok()) << trainer.status().to_string();
  Trainer& t = *trainer.value();
  FeatureModel& sfa = *t.model().feature_model();
  ASSERT_EQ(sfa.type_name(), "sfa");
  EXPECT_EQ(sfa.coded_dim(), 30);  // 50 - round(0.4 * 50)
  for (int it = 1; it <= 20; ++it) {
    // The rate term prices both binary grids as they are when the step starts: the context's
    // and the shared one.
    const double context_bits = t.model().context()->parameter_bits().item<double>();
    const double shared_bits = sfa.parameter_bits().item<double>();
    ASSERT_TRUE(t.step().ok()) << "iteration " << it;
    if (!t.last_rate().on) continue;
    EXPECT_GT(shared_bits, 0) << "iteration " << it;
    EXPECT_NEAR(t.last_rate().hash_bits, context_bits + shared_bits,
                1e-6 * (context_bits + shared_bits))
        << "iteration " << it;
  }
  ASSERT_TRUE(t.last_rate().on) << "the rate phase never started";

  QuantizedAttributes q;
  auto coded = coded_model_from(t.model(), &q);
  ASSERT_TRUE(coded.ok()) << coded.status().to_string();
  ASSERT_TRUE(coded->links.defined());
  const LinkCounts lc = count_links(coded->links);
  ASSERT_GT(lc.leaves, 0);
  auto enc = encode_model(coded.value(), cfg.value(), codec_components_of(t.model()));
  ASSERT_TRUE(enc.ok()) << enc.status().to_string();
  uint64_t ftrs = 0;
  for (const auto& sec : enc->sections)
    if (sec.id == "FTRS") ftrs = sec.bytes;
  // The file carries the shared table at about its rate estimate, plus the Linear's floats.
  EXPECT_GE(8.0 * double(ftrs), 0.95 * sfa.parameter_bits().item<double>());
  const std::string file = (dir / "scene.crpgs").string();
  ASSERT_TRUE(write_file_atomic(file, enc->bytes).ok());

  at::set_num_threads(2);  // a different thread count than the encoder's
  auto dec = decode_model(enc->bytes, reg);
  at::set_num_threads(1);
  ASSERT_TRUE(dec.ok()) << dec.status().to_string();
  EXPECT_EQ(dec->components.features->type_name(), "sfa");
  EXPECT_TRUE(torch::equal(dec->model.links, coded->links));
  EXPECT_TRUE(torch::equal(dec->model.feature_sym, coded->feature_sym));
  EXPECT_EQ(dec->components.features->save_state(), sfa.save_state());
  // The decoded model computes f_s once per anchor, not once per rendered view.
  DecodeResult counted = dec.value();
  auto counter = std::make_shared<CountingFeatures>(counted.components.features);
  counted.components.features = counter;
  auto decoded = model_from_decoded(counted, t.model().options());
  ASSERT_TRUE(decoded.ok()) << decoded.status().to_string();
  EXPECT_EQ(counter->forwards, 1);
  for (const View& v : t.dataset().test) {
    const auto img = test::render_quantised_and_decoded(t.model(), q, *decoded.value(), v.camera);
    EXPECT_GT(img.gaussians, 0);
    EXPECT_TRUE(torch::equal(img.quantised, img.decoded))
        << "max diff " << (img.quantised - img.decoded).abs().max().item<float>();
  }
  EXPECT_EQ(counter->forwards, 1) << "f_s recomputed while rendering";

  std::string log;
  ASSERT_EQ(run_cli("info '" + file + "'", dir / "log.txt", &log), 0) << log;
  EXPECT_NE(log.find("FTRS"), std::string::npos) << log;
  EXPECT_NE(log.find("COHS side information (compact coding): link vector"), std::string::npos)
      << log;
  EXPECT_NE(log.find("anchors: " + std::to_string(lc.roots) + " roots, " +
                     std::to_string(lc.leaves) + " leaves, " + std::to_string(lc.free) + " free"),
            std::string::npos)
      << log;
#endif
}

// `crpgs demo` is CRP-GS as configs/crpgs.yaml has it, on the embedded scene: the method's
// sections of the run's resolved config equal crpgs.yaml's (all but rate.lambda), and it ends with
// a bitstream decoded and evaluated. Shortened here (a small scene, 40 iterations).
TEST(DecodeCli, DemoRunsCrpgsYamlOnTheEmbeddedScene) {
#ifndef CRPGS_CLI_PATH
  GTEST_SKIP() << "built without the crpgs CLI (CRPGS_BUILD_APPS=OFF)";
#else
  const ComponentRegistry& reg = test::test_registry();
  if (const std::string why = crpgs_parts_missing(reg, "link_cohs"); !why.empty())
    GTEST_SKIP() << why;
  const fs::path dir = fs::path(CRPGS_TEST_TMP_DIR) / "demo_cli";
  fs::remove_all(dir);
  fs::create_directories(dir);
  std::string log;
  ASSERT_EQ(run_cli("demo -o '" + (dir / "run").string() +
                        "' --set dataset.synthetic_width=48 --set dataset.synthetic_height=32"
                        " --set dataset.synthetic_views=12 --set dataset.synthetic_points=1000"
                        " --set train.fast_factor=0.001 --set train.iterations=40"
                        " --set train.eval_interval=0 --set train.threads=1"
                        " --set rasterizer.threads=1",
                    dir / "log.txt", &log),
            0)
      << log;
  EXPECT_NE(log.find("decoded from the file"), std::string::npos) << log;
  EXPECT_TRUE(fs::exists(dir / "run" / "metrics.json")) << log;
  // The three phases' speeds, their iterations adding up to the run's.
  std::smatch phases;
  ASSERT_TRUE(std::regex_search(log, phases,
                                std::regex("speed by phase: raw attributes ([0-9]+) it at [0-9.]+ "
                                           "it/s; fixed noise ([0-9]+) it at [0-9.]+ it/s; rate "
                                           "phase ([0-9]+) it at [0-9.]+ it/s")))
      << log;
  EXPECT_EQ(std::stoi(phases[1]) + std::stoi(phases[2]) + std::stoi(phases[3]), 40) << log;
  // Where the result came from.
  auto metrics = experiments::read_run_metrics((dir / "run" / "metrics.json").string());
  ASSERT_TRUE(metrics.ok()) << metrics.status().to_string();
  EXPECT_EQ(metrics->provenance.version, build_info().version);
  EXPECT_EQ(metrics->provenance.commit, build_info().git_commit);
  EXPECT_EQ(metrics->provenance.threads, 1);
  EXPECT_EQ(metrics->provenance.device, "cpu");
  EXPECT_EQ(metrics->provenance.seed, 0);

  // A fine-tune: --from continues the trained state under another λ, up to a later
  // train.iterations; an end at or before the checkpoint's iteration is refused, leaving nothing.
  const std::string ft = (dir / "fine_tune").string();
  const std::string from = "train -c '" + (dir / "run" / "config.yaml").string() + "' -o '" + ft +
                           "' --from '" + (dir / "run").string() + "' --set rate.lambda=0.004";
  EXPECT_EQ(run_cli(from, dir / "log.txt", &log), 1) << log;
  EXPECT_NE(log.find("is at iteration 40, and this run ends at train.iterations 40"),
            std::string::npos)
      << log;
  EXPECT_FALSE(fs::exists(ft));
  ASSERT_EQ(run_cli(from + " --set train.iterations=50", dir / "log.txt", &log), 0) << log;
  EXPECT_NE(log.find("continues " + (dir / "run").string() + "/checkpoint.pt at iteration 40"),
            std::string::npos)
      << log;
  auto tuned = experiments::read_run_metrics(ft + "/metrics.json");
  ASSERT_TRUE(tuned.ok()) << tuned.status().to_string();
  EXPECT_EQ(tuned->lambda, 0.004);

  auto saved = Config::load_file((dir / "run" / "config.yaml").string());
  ASSERT_TRUE(saved.ok()) << saved.status().to_string();
  auto demo = saved->resolve(reg);  // canonical values, as the shipped config's below
  ASSERT_TRUE(demo.ok()) << demo.status().to_string();
  auto shipped = Config::load_file(std::string(CRPGS_SOURCE_DIR) + "/configs/crpgs.yaml");
  ASSERT_TRUE(shipped.ok()) << shipped.status().to_string();
  auto method = shipped->resolve(reg);
  ASSERT_TRUE(method.ok()) << method.status().to_string();
  const auto dumped = [](const Config& c, const std::string& section, const char* drop) {
    YAML::Node n = YAML::Clone(c.section(section));
    if (drop) n.remove(drop);
    return YAML::Dump(n);
  };
  ASSERT_NE(dumped(method.value(), "features", nullptr).find("type: sfa"), std::string::npos);
  ASSERT_NE(dumped(method.value(), "links", nullptr).find("type: link_cohs"), std::string::npos);
  for (const char* section : {"features", "context", "entropy", "links"})
    EXPECT_EQ(dumped(demo.value(), section, nullptr), dumped(method.value(), section, nullptr))
        << section;
  EXPECT_EQ(dumped(demo.value(), "rate", "lambda"), dumped(method.value(), "rate", "lambda"));
  for (const char* key : {"full_iterations", "link_builds"})
    EXPECT_EQ(YAML::Dump(demo->section("train")[key]), YAML::Dump(method->section("train")[key]))
        << key;
#endif
}

// One trained model, many rates: `crpgs encode --rate-scale` writes smaller files of coarser
// steps that decode bit-exactly in fresh processes on other thread counts (the encoder's symbols);
// `--target-size` lands at or under each target, within 3 % for targets the model reaches; an
// unreachable target is refused with a message; every rate's file is refused when truncated.
TEST(DecodeCli, RatesFromOneTrainedModel) {
#ifndef CRPGS_CLI_PATH
  GTEST_SKIP() << "built without the crpgs CLI (CRPGS_BUILD_APPS=OFF)";
#else
  const ComponentRegistry& reg = test::test_registry();
  if (!reg.find(CRPGS_KIND_CONTEXT, "hash_grid") || !reg.find(CRPGS_KIND_ENTROPY, "gaussian"))
    GTEST_SKIP() << "hash_grid/gaussian plugins not built in " << CRPGS_PLUGIN_BUILD_DIR;
  const fs::path dir = fs::path(CRPGS_TEST_TMP_DIR) / "decode_cli_rates";
  auto small = train_small_run(dir, reg);
  ASSERT_TRUE(small.ok()) << small.status().to_string();
  const std::string run = (dir / "run").string();

  std::string log;
  auto size_of = [](const fs::path& p) { return uint64_t(fs::file_size(p)); };
  // Scale 1 is the training's own file; larger scales give smaller files.
  std::map<double, uint64_t> sizes;
  for (double scale : {1.0, 1.5, 3.0, 8.0}) {
    const fs::path file = dir / ("s" + std::to_string(scale).substr(0, 3) + ".crpgs");
    ASSERT_EQ(run_cli("encode '" + run + "' -o '" + file.string() + "' --rate-scale " +
                          std::to_string(scale),
                      dir / "log.txt", &log),
              0)
        << log;
    EXPECT_NE(log.find("decoded from the file"), std::string::npos) << log;
    sizes[scale] = size_of(file);
  }
  EXPECT_LT(sizes[1.5], sizes[1.0]);
  EXPECT_LT(sizes[3.0], sizes[1.5]);
  EXPECT_LT(sizes[8.0], sizes[3.0]);

  // Bit-exact at a scaled rate: two fresh processes (1 and 2 threads) decode the encoder's
  // symbols.
  const fs::path scaled = dir / "s3.0.crpgs";
  for (int threads : {1, 2})
    ASSERT_EQ(run_cli("decode '" + scaled.string() + "' -o '" +
                          (dir / ("dec" + std::to_string(threads))).string() + "' --threads " +
                          std::to_string(threads),
                      dir / "log.txt", &log),
              0)
        << log;
  {
    QuantizedAttributes q;
    auto coded = coded_model_from(small->trainer->model(), &q, 3.0);
    ASSERT_TRUE(coded.ok()) << coded.status().to_string();
    const auto a = read_archive(dir / "dec1" / "decoded.pt");
    const auto b = read_archive(dir / "dec2" / "decoded.pt");
    ASSERT_FALSE(a.empty());
    for (const auto& [k, v] : a) EXPECT_TRUE(torch::equal(v, b.at(k))) << k;
    EXPECT_TRUE(torch::equal(a.at("feature_symbols"), coded->feature_sym));
    EXPECT_TRUE(torch::equal(a.at("scaling_symbols"), coded->scaling_sym));
    EXPECT_TRUE(torch::equal(a.at("offset_symbols"), coded->offset_sym));
    EXPECT_TRUE(torch::equal(a.at("features"), q.features));
    EXPECT_TRUE(torch::equal(a.at("offsets"), q.offsets));
  }

  // Target sizes: each at or under its target; within 3 % where the target is a size the model
  // reaches (the size at a scale), as the scale is searched finely.
  for (uint64_t target : {sizes[1.5], sizes[3.0], (sizes[1.0] + sizes[8.0]) / 2}) {
    const fs::path file = dir / ("t" + std::to_string(target) + ".crpgs");
    ASSERT_EQ(run_cli("encode '" + run + "' -o '" + file.string() + "' --target-size " +
                          std::to_string(target),
                      dir / "log.txt", &log),
              0)
        << log;
    EXPECT_NE(log.find("% under it) at rate scale"), std::string::npos) << log;
    EXPECT_LE(size_of(file), target) << log;
    if (target == sizes[1.5] || target == sizes[3.0]) {
      EXPECT_GE(double(size_of(file)), 0.97 * double(target)) << log;
    }
  }
  const fs::path unreachable = dir / "too_small.crpgs";
  EXPECT_NE(run_cli("encode '" + run + "' -o '" + unreachable.string() + "' --target-size 2KiB",
                    dir / "log.txt", &log),
            0);
  EXPECT_NE(log.find("--target-size 2048 B is below what this model reaches"), std::string::npos)
      << log;
  EXPECT_FALSE(fs::exists(unreachable));

  // A one-model curve: the run's files at several scales, each with its metrics.json, beside
  // the run (what `crpgs report` reads); the scale-1 file is the training's own.
  experiments::RunMetrics finished;
  finished.method = "small";
  finished.dataset = "synthetic";
  finished.lambda = 1e-3;
  finished.size_bytes = sizes[1.0];
  finished.psnr_mean = 20;
  finished.train_seconds = 12.5;
  ASSERT_TRUE(experiments::write_run_metrics(run + "/metrics.json", finished).ok());
  ASSERT_EQ(run_cli("encode '" + run + "' --rate-scales 1,3", dir / "log.txt", &log), 0) << log;
  for (double scale : {1.0, 3.0}) {
    const std::string at = experiments::rate_scale_dir(run, scale);
    auto m = experiments::read_run_metrics(at + "/metrics.json");
    ASSERT_TRUE(m.ok()) << m.status().to_string() << log;
    EXPECT_EQ(m->method, "small (one model)");
    EXPECT_EQ(m->base_method, "small");
    EXPECT_EQ(m->rate_scale, scale);
    EXPECT_EQ(m->train_seconds, 12.5);  // the one training every scale shares
    EXPECT_EQ(m->size_bytes, sizes[scale]);
    EXPECT_EQ(m->size_bytes, size_of(at + "/scene.crpgs"));
    EXPECT_FALSE(m->views.empty());
  }
  EXPECT_EQ(read_file_bytes(experiments::rate_scale_dir(run, 1) + "/scene.crpgs").value(),
            read_file_bytes((dir / "s1.0.crpgs").string()).value());
  ASSERT_EQ(run_cli("encode '" + run + "' --rate-scales 3", dir / "log.txt", &log), 0) << log;
  EXPECT_NE(log.find("rate scale 3: done before"), std::string::npos) << log;
  // One output or many, not both; and one of them.
  EXPECT_EQ(run_cli("encode '" + run + "' -o x.crpgs --rate-scales 2", dir / "log.txt", &log), 2)
      << log;
  EXPECT_EQ(run_cli("encode '" + run + "'", dir / "log.txt", &log), 2) << log;

  // Every rate's file, truncated, is refused with a message.
  for (const auto& [scale, size] : sizes) {
    const fs::path file = dir / ("s" + std::to_string(scale).substr(0, 3) + ".crpgs");
    auto bytes = read_file_bytes(file.string());
    ASSERT_TRUE(bytes.ok());
    for (size_t len : {size_t(0), size_t(16), bytes->size() / 2, bytes->size() - 1}) {
      std::vector<uint8_t> cut(bytes->begin(), bytes->begin() + long(len));
      auto dec = decode_model(cut, reg);
      EXPECT_FALSE(dec.ok()) << "scale " << scale << " truncated to " << len;
      if (!dec.ok()) {
        EXPECT_FALSE(dec.status().message().empty());
      }
    }
  }
#endif
}

}  // namespace
}  // namespace crpgs
