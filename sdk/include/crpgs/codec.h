/// @file codec.h
/// @brief The anchor-model bitstream (method.md §2.7, design.md "The bitstream"): what a
/// quantised anchor model is on disk, and its exact inverse.
///
/// Layout (a versioned container, every section with its component id, version, length, CRC):
///   CONF  the resolved config (rebuilds every component on the decoder side)
///   HEAD  counts, voxel size, bounds, Q0s, chunk size
///   GEOM  anchor voxels, Draco kd-tree, lossless; every per-anchor stream follows the canonical
///         Morton order of these integers, which both sides derive from the decoded voxels
///   OMSK  offset masks [N, K], one global Bernoulli
///   CTXS  the context component's state (binary hash grid + mlp_grid)
///   FTRS  the feature model's state (e.g. SFA's shared grid); absent when it has none
///   MLPS  the Gaussian-generation MLPs (and appearance embedding), float32
///   FEAT / SCAL / OFFS  feature, scaling, offset symbols, entropy-coded in chunks of
///         `chunk` anchors; each chunk's (μ, σ, Q) are predicted from the decoded positions with
///         predict_entropy_params on exactly that chunk, on both sides
/// Offsets are coded only where their mask is on. Decoding refuses anything malformed with a
/// message; it never trusts a count it has not checked against the bytes present.
#pragma once

#include <map>
#include <memory>
#include <string>
#include <vector>

#include <torch/types.h>

#include "crpgs/anchor_model.h"
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
};

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

/// Entropy parameters of every anchor of `m`, computed chunk by chunk in canonical order exactly
/// as the decoder will (the encoder uses them to code, the trainer to evaluate the quantised
/// model).
EntropyParams coded_entropy_params(const CodedModel& m, ContextModel& context, int64_t coded_dim);

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
StatusOr<CodedModel> coded_model_from(const AnchorModel& model, QuantizedAttributes* q = nullptr);
/// The components a trained model is coded with.
CodecComponents codec_components_of(const AnchorModel& model);

/// A render-ready model from a decoded bitstream (dequantised: symbol · step).
StatusOr<std::unique_ptr<AnchorModel>> model_from_decoded(const DecodeResult& decoded,
                                                          const AnchorModelOptions& options);

/// Section id -> report category ("geometry", "features", "scaling", "offsets", "masks",
/// "links", "hash_grids", "mlps", "other").
const char* section_category(const std::string& id);

}  // namespace crpgs
