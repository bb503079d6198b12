/// @file codec.h
/// @brief The anchor-model bitstream (docs/method.md §2.7, design.md "The bitstream"): what a
/// quantised anchor model is on disk, and its exact inverse.
///
/// Layout (a versioned container, every section with its component id, version, length, CRC):
///   CONF  the resolved config (rebuilds every component on the decoder side)
///   HEAD  counts, voxel size, bounds, Q0s, chunk size
///   GEOM  anchor voxels, Draco kd-tree, lossless; every per-anchor stream follows the canonical
///         Morton order of these integers, which both sides derive from the decoded voxels
///   AMSK  (with links coded as in the paper) which of the model's N0 anchors are coded, one
///         global Bernoulli; redundant for decoding, written for the paper's side information
///   LINK  (with links) the link vector, in one of two codings (coding/bit_packing.h), chosen by
///         `rate.link_coding` and named by the section's component id:
///         compact (org.crpgs.links.compact): leaf flags + each leaf's root as a rank among the
///         roots still free; paper (org.crpgs.codec.anchor_model): per coded anchor the canonical
///         index of its root or a sentinel, w = ceil(log2(N + 1)) bits each
///   OMSK  offset masks [N, K], one global Bernoulli
///   CTXS  the context component's state (binary hash grid + mlp_grid)
///   FTRS  the feature model's state (e.g. SFA's shared grid); absent when it has none
///   MLPS  the Gaussian-generation MLPs (and appearance embedding), float32
///   FEAT / SCAL / OFFS  feature, scaling, offset symbols, entropy-coded in chunks of
///         `chunk` anchors; each chunk's (μ, σ, Q) are predicted from the decoded positions with
///         predict_entropy_params on exactly that chunk, on both sides
/// With links the streams follow the decode order of docs/method.md §6.4: roots, free anchors, then
/// leaves (each group in canonical order and chunked on its own); a leaf's feature mean comes
/// from the leaf MLP (MLPS) on its root's decoded feature. Without links it is canonical order.
/// GEOM is Draco (component org.crpgs.geometry.draco) or raw fixed-width voxel integers
/// (org.crpgs.geometry.raw, the ablation without a point-cloud codec).
/// Offsets are coded only where their mask is on. Decoding refuses anything malformed with a
/// message; it never trusts a count it has not checked against the bytes present.
#pragma once

#include <map>
#include <memory>
#include <string>
#include <vector>

#include <torch/types.h>

#include "crpgs/anchor_model.h"
#include "crpgs/coding/bitstream.h"
#include "crpgs/config.h"
#include "crpgs/context_model.h"
#include "crpgs/entropy_model.h"
#include "crpgs/entropy_params.h"
#include "crpgs/feature_model.h"
#include "crpgs/registry.h"
#include "crpgs/status.h"

namespace crpgs {

/// The symbols and side information of a quantised anchor model, in canonical order.
struct CodedModel {
  double voxel_size = 0;
  torch::Tensor bounds;        ///< [2, 3] float32: min, max used to normalise positions
  torch::Tensor voxels;        ///< [N, 3] int32, unique, canonical Morton order
  torch::Tensor offset_masks;  ///< [N, K] bool
  torch::Tensor feature_sym;   ///< [N, Dc] int32: round(f / Q_f)
  torch::Tensor scaling_sym;   ///< [N, 6] int32: round(exp(scaling_raw) / Q_s)
  torch::Tensor offset_sym;    ///< [N, K, 3] int32: round(o / Q_o); zero where the mask is off
  std::map<std::string, torch::Tensor> mlps;  ///< float32 tensors by name
  QuantSteps q0;
  int64_t chunk = 3000;
  /// [N] int64: canonical index of each anchor's root, -1 for none (one hop, one-to-one).
  /// Undefined: a model without links or without a single leaf (then no AMSK/LINK sections,
  /// except a compact LINK without leaves when the config has a link strategy).
  torch::Tensor links;
  torch::Tensor anchor_mask;       ///< [N0] bool: which model anchors are coded (paper link coding)
  std::string geometry = "draco";  ///< "draco" or "raw"
  std::string link_coding = "compact";  ///< "compact" or "paper" (the LINK section's coding)
  bool leaf_residual = false;  ///< the leaf MLP's form (from the config `rate.leaf_residual`)
  /// How the entropy parameters are computed (set_format_math): kPortable in files of format 1.1
  /// and later; kFast for 1.0 files, which decode only where the same BLAS kernels run as when
  /// they were encoded.
  Arithmetic arithmetic = Arithmetic::kPortable;
  /// How the adaptive steps are computed: kTwoSigmoid from format 1.2, kOnePlusTanh before.
  StepForm steps = StepForm::kTwoSigmoid;
};

/// Sets m's arithmetic and steps to what a file whose codec sections have minor version `minor`
/// computes (0: kFast, kOnePlusTanh; 1: kPortable, kOnePlusTanh; 2: kPortable, kTwoSigmoid).
/// The encoder writes the newest minor; the decoder refuses a later one (it may compute its
/// entropy parameters differently).
void set_format_math(uint16_t minor, CodedModel* m);

/// Roots, free anchors and leaves of a link vector [N] (counts).
struct LinkCounts {
  int64_t roots = 0, free = 0, leaves = 0;
};
LinkCounts count_links(const torch::Tensor& links);

/// The components a bitstream is coded with (built from its config).
struct CodecComponents {
  std::shared_ptr<ContextModel> context;
  std::shared_ptr<EntropyModel> entropy;
  std::shared_ptr<FeatureModel> features;
};

/// Anchor positions the decoder sees: voxels · voxel_size in float32. [N, 3]
torch::Tensor voxel_positions(const torch::Tensor& voxels, double voxel_size);
/// Positions normalised by the bounds: (p − min) / (max − min), float32. [N, 3]
torch::Tensor normalize_positions(const torch::Tensor& positions, const torch::Tensor& bounds);

/// Entropy parameters of every anchor of `m` (rows in canonical order), computed chunk by chunk
/// in coding order exactly as the decoder will. With links, the leaves' μ_f come from the leaf
/// MLP found in m.mlps on the roots' dequantised feature symbols.
EntropyParams coded_entropy_params(const CodedModel& m, ContextModel& context, int64_t coded_dim);

/// The coding order: canonical indices [N] int64 of roots, free anchors, leaves (identity
/// without links).
torch::Tensor coding_order(const torch::Tensor& links, int64_t n);

/// Training-time rate estimate (Σ −log2 p, the quantity the rate term minimises) of each symbol
/// stream ("FEAT", "SCAL", "OFFS") under the given parameters.
std::map<std::string, double> estimated_stream_bits(const CodedModel& m, const EntropyParams& p,
                                                    EntropyModel& entropy);

/// Per-section sizes, in file order.
struct SectionSize {
  std::string id, component;
  uint64_t bytes = 0;  ///< on disk, header included
};

struct EncodeResult {
  std::vector<uint8_t> bytes;
  std::vector<SectionSize> sections;
  /// Training-time rate estimate (Σ −log2 p under the same μ, σ, Q) vs actual coded bits, per
  /// symbol stream ("FEAT", "SCAL", "OFFS").
  std::map<std::string, std::pair<double, double>> estimated_vs_coded_bits;
};

/// Builds the bitstream. `config` must be the resolved config the components were built from.
StatusOr<EncodeResult> encode_model(const CodedModel& model, const Config& config,
                                    const CodecComponents& components);

struct DecodeResult {
  Config config;
  CodedModel model;
  CodecComponents components;
  EntropyParams params;  ///< what the symbols were coded with (their steps dequantise them)
  std::vector<SectionSize> sections;
};

/// Parses, checks and decodes a bitstream; components are rebuilt from its config through
/// `registry` (a missing plugin is an error naming it).
StatusOr<DecodeResult> decode_model(const std::vector<uint8_t>& bytes,
                                    const ComponentRegistry& registry);

/// The coded form of a trained model with the rate path attached: its active anchors in canonical
/// Morton order, quantised by AnchorModel::quantize (so the steps are the decoder's). `q`
/// (optional) receives the quantised attributes, for evaluating the training-side quantised model.
/// `rate_scale` (> 0) multiplies the base steps Q0 of every attribute, so every step
/// Q = Q0·(1 + tanh a) with it: above 1 a smaller file of coarser values, from the same trained
/// model. Q0 is in the file's HEAD section, so the decoder needs nothing else to follow.
StatusOr<CodedModel> coded_model_from(const AnchorModel& model, QuantizedAttributes* q = nullptr,
                                      double rate_scale = 1.0);
/// The components a trained model is coded with.
CodecComponents codec_components_of(const AnchorModel& model);

/// A render-ready model from a decoded bitstream (dequantised: symbol · step).
StatusOr<std::unique_ptr<AnchorModel>> model_from_decoded(const DecodeResult& decoded,
                                                          const AnchorModelOptions& options);

/// What one more link costs in the compact LINK section, in bits (approximately: the root's rank
/// among `non_leaves` candidates plus the leaf flag). With `rate.prune_links`, coded_model_from
/// drops every link whose leaf saves fewer estimated feature bits than this.
double compact_link_bits(int64_t non_leaves);

/// The link vector [N] (canonical root index or -1) of a LINK section, in either coding.
StatusOr<std::vector<int32_t>> link_vector_of(const coding::Section& link_section);

/// Section id -> report category ("geometry", "features", "scaling", "offsets", "masks",
/// "links", "hash_grids", "mlps", "other").
const char* section_category(const std::string& id);

}  // namespace crpgs
