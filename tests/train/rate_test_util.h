/// @file rate_test_util.h
/// @brief The rate path's components for tests: the hash_grid context and the gaussian entropy
/// model loaded from the in-tree plugin build (CRPGS_PLUGIN_BUILD_DIR), with small tables.
#pragma once

#include <memory>
#include <string>

#include "crpgs/anchor_model.h"
#include "crpgs/components.h"
#include "crpgs/config.h"
#include "crpgs/scene_generator.h"
#include "crpgs/trainer.h"
#include "raster/cpu_rasterizer.h"
#include "test_registry.h"

namespace crpgs::test {

inline const ComponentRegistry& rate_registry() {
  return test_registry();
}

/// "" when both plugins are loadable, else why not (for GTEST_SKIP).
inline std::string rate_plugins_missing() {
  const auto& r = rate_registry();
  if (!r.find(CRPGS_KIND_CONTEXT, "hash_grid") || !r.find(CRPGS_KIND_ENTROPY, "gaussian"))
    return std::string("the hash_grid/gaussian plugins are not built in ") +
           CRPGS_PLUGIN_BUILD_DIR + " (build crpgs_context_hash_grid crpgs_entropy_gaussian)";
  return "";
}

/// A small binary hash grid (2^10-entry tables) and the gaussian entropy model, built through
/// the registry from a resolved config exactly as setup_training does.
inline RateSetup make_rate_setup(int coded_dim, int n_offsets, const RateOptions& options) {
  auto cfg = Config::from_string(
      "context: {type: hash_grid, log2_hashmap_size: 10, log2_hashmap_size_2d: 10}\n"
      "entropy: {type: gaussian}\n",
      "rate_test.yaml");
  if (!cfg.ok()) throw StatusError(cfg.status());
  auto resolved = cfg->resolve(rate_registry());
  if (!resolved.ok()) throw StatusError(resolved.status());
  crpgs_create_args args{};
  args.feature_dim = coded_dim;
  args.coded_dim = coded_dim;
  args.n_offsets = n_offsets;
  RateSetup s;
  auto c = create_component<ContextModel>(rate_registry(), resolved->section("context"), args);
  if (!c.ok()) throw StatusError(c.status());
  auto e = create_component<EntropyModel>(rate_registry(), resolved->section("entropy"), args);
  if (!e.ok()) throw StatusError(e.status());
  s.context = c.value();
  s.entropy = e.value();
  s.options = options;
  return s;
}

/// Mean bits per coded parameter of the model's quantised attributes under its own entropy
/// parameters (offsets only where their mask is on): what the bitstream would cost.
inline double quantized_bits_per_param(const AnchorModel& m) {
  torch::NoGradGuard ng;
  const QuantizedAttributes q = m.quantize();
  EntropyModel& e = *m.entropy();
  const int64_t A = q.index.size(0), K = m.n_offsets();
  if (A == 0) return 0;
  auto bf = e.bits(q.features, q.params.mu_f, q.params.sigma_f, q.params.q_f).sum();
  auto bs = e.bits(q.scaling, q.params.mu_s, q.params.sigma_s, q.params.q_s).sum();
  auto bo = e.bits(q.offsets.reshape({A, 3 * K}), q.params.mu_o, q.params.sigma_o, q.params.q_o);
  auto mask = q.offset_masks.unsqueeze(2).expand({A, K, 3}).reshape({A, 3 * K});
  bo = (bo * mask.to(bo.dtype())).sum();
  const double n = double(A) * double(q.features.size(1) + 6) + 3.0 * mask.sum().item<double>();
  return (bf + bs + bo).item<double>() / n;
}

/// The tiny generated scene the rate-path tests train on (32x24, 8 views, 1500 SfM points).
inline Dataset tiny_scene() {
  raster::CpuRasterizer r(1);
  SyntheticSceneOptions o;
  o.width = 32;
  o.height = 24;
  o.views = 8;
  o.sfm_points = 1500;
  auto s = generate_scene(o, r);
  if (!s.ok()) throw StatusError(s.status());
  return std::move(s).value();
}

/// Renders `cam` with the training-side model quantised to `q` and with `decoded`; the two must
/// be identical when decoding is bit-exact. Also returns the quantised render's Gaussian count.
struct RenderPair {
  torch::Tensor quantised, decoded;
  int64_t gaussians = 0;
};
inline RenderPair render_quantised_and_decoded(AnchorModel& trained, const QuantizedAttributes& q,
                                               AnchorModel& decoded, const Camera& cam) {
  raster::CpuRasterizer r(1);
  RenderSettings rs;
  torch::NoGradGuard ng;
  trained.set_quantized(q);
  auto a = trained.generate(cam, -1, r, rs, false);
  RenderPair out;
  out.quantised = r.render(a.batch, cam, rs).image;
  out.gaussians = a.batch.means.size(0);
  trained.clear_quantized();
  auto b = decoded.generate(cam, -1, r, rs, false);
  out.decoded = r.render(b.batch, cam, rs).image;
  return out;
}

}  // namespace crpgs::test
