/// @file sections.cpp
/// @brief Schemas of the core (non-component) config sections: dataset, scene, model, train,
/// rate.
/// Torch-free (part of crpgs_base) so `crpgs config check` validates without building anything.
#include "crpgs/config.h"

namespace crpgs {
namespace {

ParamSpec P(const char* key, ParamType type, YAML::Node def, const char* doc) {
  ParamSpec p;
  p.key = key;
  p.type = type;
  p.default_value = def;
  p.doc = doc;
  return p;
}
ParamSpec range(ParamSpec p, std::optional<double> lo, std::optional<double> hi) {
  p.min = lo;
  p.max = hi;
  return p;
}
ParamSpec choice(ParamSpec p, std::vector<std::string> choices) {
  p.type = ParamType::kChoice;
  p.choices = std::move(choices);
  return p;
}

}  // namespace

const std::vector<CoreSection>& core_sections() {
  using T = ParamType;
  static const std::vector<CoreSection> sections = {
      {"dataset",
       Schema({
           P("path", T::kString, YAML::Node(""),
             "dataset root; empty = the built-in synthetic scene"),
           choice(P("format", T::kChoice, YAML::Node("auto"), "dataset format"),
                  {"auto", "colmap", "nerf_synthetic", "instant_ngp", "llff", "synthetic"}),
           P("images", T::kString, YAML::Node(""), "image folder; empty = format default"),
           range(P("downscale", T::kInt, YAML::Node(1), "integer downscale factor on load"), 1, 64),
           range(P("max_width", T::kInt, YAML::Node(0), ">0: downscale so width <= this"), 0, 1e5),
           range(
               P("test_every", T::kInt, YAML::Node(8), "every Nth image is a test view; 0 = none"),
               0, 1e6),
           range(P("max_images", T::kInt, YAML::Node(0),
                   ">0: load at most this many views per split"),
                 0, 1e6),
           range(P("synthetic_width", T::kInt, YAML::Node(128), "synthetic scene: image width"), 8,
                 4096),
           range(P("synthetic_height", T::kInt, YAML::Node(96), "synthetic scene: image height"), 8,
                 4096),
           range(P("synthetic_views", T::kInt, YAML::Node(32),
                   "synthetic scene: cameras on the ring"),
                 2, 1000),
           range(P("synthetic_points", T::kInt, YAML::Node(3000),
                   "synthetic scene: SfM-like points (0 = random init)"),
                 0, 1e7),
           range(P("synthetic_seed", T::kInt, YAML::Node(1), "synthetic scene: random seed"), 0,
                 1e9),
       })},
      {"scene",
       Schema({
           P("view_dependent", T::kBool, YAML::Node(true), "view direction is an MLP input"),
           P("distance_input", T::kBool, YAML::Node(true), "camera distance is an MLP input"),
           range(P("appearance_dim", T::kInt, YAML::Node(0),
                   "per-image appearance embedding width fed to the colour MLP; 0 = off"),
                 0, 256),
           range(P("background", T::kFloatList, YAML::Load("[0, 0, 0]"), "background RGB in [0,1]"),
                 0, 1),
       })},
      {"model",
       Schema({
           range(P("feature_dim", T::kInt, YAML::Node(50), "anchor feature width seen by the MLPs"),
                 1, 1024),
           range(P("n_offsets", T::kInt, YAML::Node(10), "neural Gaussians per anchor (K)"), 1, 64),
           range(P("hidden_dim", T::kInt, YAML::Node(50), "hidden width of the three MLPs"), 1,
                 1024),
           P("voxel_size", T::kFloat, YAML::Node(0.01),
             "anchor voxel size; <= 0 = median squared 3-NN distance of the SfM points"),
           range(P("update_init_factor", T::kInt, YAML::Node(16), "growing: coarsest cell / voxel"),
                 1, 1024),
           range(P("update_hierarchy_factor", T::kInt, YAML::Node(4),
                   "growing: cell ratio per level"),
                 2, 64),
           range(P("update_depth", T::kInt, YAML::Node(3), "growing: number of levels"), 1, 8),
           range(P("densify_grad_threshold", T::kFloat, YAML::Node(0.0002),
                   "growing: mean screen-space gradient threshold (NDC units)"),
                 0, 1),
           range(P("min_opacity", T::kFloat, YAML::Node(0.005), "pruning: mean opacity threshold"),
                 0, 1),
           range(P("success_threshold", T::kFloat, YAML::Node(0.8),
                   "growing/pruning: fraction of the interval an anchor must be seen"),
                 0, 1),
           P("use_offset_mask", T::kBool, YAML::Node(true),
             "multiply opacities by the offset mask"),
           range(P("mask_threshold", T::kFloat, YAML::Node(0.01), "offset mask: sigmoid threshold"),
                 0, 1),
           range(P("random_init_points", T::kInt, YAML::Node(20000),
                   "points drawn inside the camera bounds, where a training view sees them, when "
                   "the dataset has none"),
                 1, 1e8),
       })},
      {"train",
       Schema({
           choice(P("schedule", T::kChoice, YAML::Node("full"),
                    "full: HAC's 30k schedule; fast: every phase boundary x fast_factor"),
                  {"full", "fast"}),
           range(P("fast_factor", T::kFloat, YAML::Node(0.1), "scale of the fast schedule"), 0, 1),
           range(P("iterations", T::kInt, YAML::Node(0), ">0: override the schedule's length"), 0,
                 1e8),
           range(P("full_iterations", T::kInt, YAML::Node(30000),
                   "length of the full schedule (HAC 30000, CRP-GS 40000); `fast` scales it"),
                 1, 1e8),
           P("link_builds", T::kIntList, YAML::Load("[30000, 33000, 36000]"),
             "iterations of the full schedule at which anchor links are (re)built from scratch "
             "(only with a `links` component; `fast` scales them)"),
           range(P("seed", T::kInt, YAML::Node(0), "random seed (init, growing, view order)"), 0,
                 1e9),
           range(P("lambda_dssim", T::kFloat, YAML::Node(0.2), "weight of 1 - SSIM"), 0, 1),
           range(P("lambda_scaling", T::kFloat, YAML::Node(0.01), "scale regulariser weight"), 0,
                 1e3),
           range(P("eval_interval", T::kInt, YAML::Node(1000),
                   "held-out PSNR every N iterations; 0 = never"),
                 0, 1e8),
           range(P("checkpoint_interval", T::kInt, YAML::Node(5000),
                   "checkpoint every N iterations; 0 = only at the end / on request (and by "
                   "checkpoint_minutes)"),
                 0, 1e8),
           range(
               P("checkpoint_minutes", T::kFloat, YAML::Node(15),
                 "also checkpoint after this many minutes of training since the last one; 0 = off"),
               0, 1e6),
           range(P("threads", T::kInt, YAML::Node(0), "CPU threads; 0 = all cores"), 0, 1024),
           choice(P("device", T::kChoice, YAML::Node("cpu"),
                    "where the model's tensors live: cpu, or cuda (a GPU; needs the cuda "
                    "rasterizer and a CUDA-enabled libtorch)"),
                  {"cpu", "cuda"}),
           range(P("lr_offset", T::kFloat, YAML::Node(0.01), "offset lr (x spatial scale)"), 0, 10),
           range(P("lr_offset_final", T::kFloat, YAML::Node(0.0001), "final offset lr"), 0, 10),
           range(P("lr_mask", T::kFloat, YAML::Node(0.01), "mask lr (x spatial scale)"), 0, 10),
           range(P("lr_mask_final", T::kFloat, YAML::Node(0.0001), "final mask lr"), 0, 10),
           range(P("lr_feature", T::kFloat, YAML::Node(0.0075), "anchor feature lr"), 0, 10),
           range(P("lr_scaling", T::kFloat, YAML::Node(0.007), "anchor scaling lr"), 0, 10),
           range(P("lr_mlp_opacity", T::kFloat, YAML::Node(0.002), "opacity MLP lr"), 0, 10),
           range(P("lr_mlp_opacity_final", T::kFloat, YAML::Node(0.00002), "final opacity MLP lr"),
                 0, 10),
           range(P("lr_mlp_cov", T::kFloat, YAML::Node(0.004), "covariance MLP lr"), 0, 10),
           range(P("lr_mlp_cov_final", T::kFloat, YAML::Node(0.004), "final covariance MLP lr"), 0,
                 10),
           range(P("lr_mlp_color", T::kFloat, YAML::Node(0.008), "colour MLP lr"), 0, 10),
           range(P("lr_mlp_color_final", T::kFloat, YAML::Node(0.00005), "final colour MLP lr"), 0,
                 10),
           range(P("lr_appearance", T::kFloat, YAML::Node(0.05), "appearance embedding lr"), 0, 10),
           range(P("lr_appearance_final", T::kFloat, YAML::Node(0.0005), "final appearance lr"), 0,
                 10),
           choice(P("feature_model_start", T::kChoice, YAML::Node("start"),
                    "when the feature model (SFA's shared grid) starts to learn at its full lr: "
                    "start, rate_start (when the rate phase begins), growing_end (after anchor "
                    "growing and pruning) or auto (growing_end where the anchors start from "
                    "random points, the scene having no SfM points; else start); before then it "
                    "learns at feature_model_hold_lr_scale times its lr"),
                  {"start", "rate_start", "growing_end", "auto"}),
           range(P("feature_model_hold_lr_scale", T::kFloat, YAML::Node(0.0),
                   "the feature model's lr factor before feature_model_start (0: it keeps its "
                   "initial state until then)"),
                 0, 1),
           range(P("lr_feature_model", T::kFloat, YAML::Node(0.005),
                   "feature-model parameters lr (e.g. SFA's grid)"),
                 0, 10),
           range(P("lr_feature_model_final", T::kFloat, YAML::Node(0.00001),
                   "final feature-model lr"),
                 0, 10),
       })},
      {"rate",
       Schema({
           range(P("lambda", T::kFloat, YAML::Node(0.001),
                   "rate weight: lambda * (bits per parameter + hash bits share); used only "
                   "with a `context` and an `entropy` component"),
                 0, 1),
           range(P("mask_lambda", T::kFloat, YAML::Node(0.0005),
                   "offset-mask loss weight (mean sigmoid of the mask logits)"),
                 0, 1),
           range(P("subset", T::kFloat, YAML::Node(0.05),
                   "fraction of the visible active anchors the rate is measured on"),
                 1e-6, 1),
           range(P("q0_feature", T::kFloat, YAML::Node(1.0),
                   "initial quantisation step Q0, features"),
                 1e-9, 1e3),
           range(P("q0_scaling", T::kFloat, YAML::Node(0.001),
                   "initial quantisation step Q0, activated scaling"),
                 1e-9, 1e3),
           range(
               P("q0_offset", T::kFloat, YAML::Node(0.2), "initial quantisation step Q0, offsets"),
               1e-9, 1e3),
           range(P("leaf_hidden", T::kInt, YAML::Node(60), "hidden width of the leaf MLP (COHS)"),
                 1, 4096),
           range(P("lr_leaf", T::kFloat, YAML::Node(0.005),
                   "leaf MLP lr, log-linear from the first link build to the end"),
                 0, 10),
           range(P("lr_leaf_final", T::kFloat, YAML::Node(0.00005), "final leaf MLP lr"), 0, 10),
           P("leaf_residual", T::kBool, YAML::Node(false),
             "leaf mean = base mean + MLP (last layer zero-initialised)"),
           choice(P("geometry", T::kChoice, YAML::Node("draco"),
                    "anchor positions in the bitstream: draco (lossless point-cloud codec) or "
                    "raw (fixed-width voxel integers, HAC's 16 bits per axis)"),
                  {"draco", "raw"}),
           choice(P("link_coding", T::kChoice, YAML::Node("compact"),
                    "COHS links in the bitstream: compact (leaf flags + each root's rank among "
                    "the free roots) or paper (active-anchor mask + ceil(log2(N+1)) bits per "
                    "anchor, docs/method.md §7.11)"),
                  {"compact", "paper"}),
           P("prune_links", T::kBool, YAML::Node(true),
             "with compact link coding, the encoder drops every link whose leaf saves fewer "
             "estimated feature bits than the link costs (the leaf is coded as a free anchor)"),
           P("recompute_bounds", T::kBool, YAML::Node(true),
             "recompute the anchor bounds at rate_start (HAC); false keeps the initial ones"),
           range(
               P("lr_context", T::kFloat, YAML::Node(0.005), "context grid lr (HAC encoding_xyz)"),
               0, 10),
           range(P("lr_context_final", T::kFloat, YAML::Node(0.00001), "final context grid lr"), 0,
                 10),
           range(P("lr_context_mlp", T::kFloat, YAML::Node(0.005), "context MLP lr (HAC mlp_grid)"),
                 0, 10),
           range(P("lr_context_mlp_final", T::kFloat, YAML::Node(0.00001), "final context MLP lr"),
                 0, 10),
       })},
  };
  return sections;
}

}  // namespace crpgs
