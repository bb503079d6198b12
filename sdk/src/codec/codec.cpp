/// @file codec.cpp
/// @brief encode_model / decode_model: the anchor-model bitstream described in codec.h.
#include "crpgs/codec.h"

#include <algorithm>
#include <cmath>
#include <functional>
#include <optional>

#include <torch/torch.h>

#include "crpgs/coding/bit_packing.h"
#include "crpgs/coding/bitstream.h"
#include "crpgs/coding/geometry.h"
#include "crpgs/coding/range_coder.h"
#include "crpgs/components.h"
#include "crpgs/link_report.h"
#include "crpgs/links.h"
#include "crpgs/runtime.h"

namespace crpgs {
namespace {

using coding::ByteReader;
using coding::Bytes;
using coding::ByteSpan;
using coding::ByteWriter;

constexpr const char* kComponent = "org.crpgs.codec.anchor_model";
// Minor 1: entropy parameters in portable arithmetic (CodedModel::arithmetic). Minor 2: steps
// by StepForm::kTwoSigmoid (CodedModel::steps). set_format_math says what each minor computes.
constexpr uint16_t kMajor = 1, kMinor = 2;
constexpr const char* kCompactLinks = "org.crpgs.links.compact";  // LINK, compact coding
// Sanity limits for counts read from a file (refused before anything is allocated).
constexpr uint64_t kMaxOffsets = 64, kMaxCodedDim = 4096, kMaxChunk = 1 << 20;

Status corrupt(const std::string& msg) {
  return Status(StatusCode::kCorruptBitstream, "bitstream: " + msg);
}

/// A coding-layer result with the failing section named in its message.
template <typename T>
StatusOr<T> in_section(const char* id, StatusOr<T> r) {
  if (r.ok()) return r;
  return Status(r.status().code(),
                std::string("bitstream: section ") + id + ": " + r.status().message());
}

Bytes to_bytes(const std::vector<uint8_t>& v) {
  return Bytes(v.begin(), v.end());
}

void put_tensor(ByteWriter& w, const std::string& name, const torch::Tensor& t) {
  const auto c = t.detach().to(torch::kFloat).contiguous().cpu();
  w.put_string(name);
  w.put_varint(uint64_t(c.dim()));
  for (int64_t d : c.sizes()) w.put_varint(uint64_t(d));
  const float* p = c.data_ptr<float>();
  for (int64_t i = 0; i < c.numel(); ++i) w.put_f32(p[i]);
}

Status get_tensor(ByteReader& r, std::string* name, torch::Tensor* out) {
  CRPGS_RETURN_IF_ERROR(r.read_string(name, 256));
  uint64_t ndim = 0;
  CRPGS_RETURN_IF_ERROR(r.read_varint(&ndim));
  if (ndim > 4) return r.error("tensor '" + *name + "' has " + std::to_string(ndim) + " dims");
  std::vector<int64_t> dims;
  uint64_t numel = 1;
  for (uint64_t i = 0; i < ndim; ++i) {
    uint64_t d = 0;
    CRPGS_RETURN_IF_ERROR(r.read_varint(&d));
    if (d > r.remaining() || (d && numel > r.remaining() / d))
      return r.error("tensor '" + *name + "' larger than the section");
    numel *= d;
    dims.push_back(int64_t(d));
  }
  if (numel * 4 > r.remaining()) return r.error("tensor '" + *name + "' truncated");
  *out = torch::empty(dims, torch::kFloat);
  float* p = out->data_ptr<float>();
  for (uint64_t i = 0; i < numel; ++i) CRPGS_RETURN_IF_ERROR(r.read_f32(&p[i]));
  return OkStatus();
}

/// One chunk's symbol stream of one attribute: the tensors compress() needs, flattened.
struct StreamArgs {
  torch::Tensor symbols, mean, scale, q;  // [M]
};

/// The three streams of anchors [s, e) given their entropy parameters (already sliced).
std::array<StreamArgs, 3> stream_args(const EntropyParams& p, const torch::Tensor& feat_sym,
                                      const torch::Tensor& scal_sym, const torch::Tensor& off_sym,
                                      const torch::Tensor& masks, int64_t K) {
  std::array<StreamArgs, 3> a;
  const int64_t n = p.mu_f.size(0);
  auto flat = [](const torch::Tensor& t) { return t.defined() ? t.reshape(-1) : t; };
  a[0] = {flat(feat_sym), p.mu_f.reshape(-1), p.sigma_f.reshape(-1),
          p.q_f.expand_as(p.mu_f).reshape(-1)};
  a[1] = {flat(scal_sym), p.mu_s.reshape(-1), p.sigma_s.reshape(-1),
          p.q_s.expand_as(p.mu_s).reshape(-1)};
  const auto sel = masks.unsqueeze(2).expand({n, K, 3}).reshape(-1);
  a[2] = {off_sym.defined() ? off_sym.reshape(-1).index({sel}) : torch::Tensor(),
          p.mu_o.reshape(-1).index({sel}), p.sigma_o.reshape(-1).index({sel}),
          p.q_o.expand_as(p.mu_o).reshape(-1).index({sel})};
  return a;
}

constexpr const char* kStreamIds[3] = {"FEAT", "SCAL", "OFFS"};

/// Where the anchors go in the symbol streams (codec.h): coding position -> canonical index,
/// the chunks (ranges of coding positions, never straddling a group), and for the leaves (the
/// last group) the coding position of their root.
struct CodingPlan {
  torch::Tensor order;  // [N] int64
  std::vector<std::pair<int64_t, int64_t>> chunks;
  int64_t leaf_begin = 0;   // first leaf's coding position (N without links)
  torch::Tensor root_slot;  // [N - leaf_begin] int64
};

CodingPlan make_plan(const torch::Tensor& links, int64_t n, int64_t chunk) {
  CodingPlan plan;
  plan.order = coding_order(links, n);
  plan.leaf_begin = n;
  std::vector<int64_t> bounds{0};
  if (links.defined()) {
    const auto c = count_links(links);
    bounds.push_back(c.roots);
    bounds.push_back(c.roots + c.free);
    plan.leaf_begin = c.roots + c.free;
    auto slot = torch::empty({n}, torch::kLong);
    slot.index_put_({plan.order}, torch::arange(n, torch::kLong));
    plan.root_slot =
        slot.index_select(0, links.index_select(0, plan.order.slice(0, plan.leaf_begin, n)));
  }
  bounds.push_back(n);
  for (size_t g = 0; g + 1 < bounds.size(); ++g)
    for (int64_t s = bounds[g]; s < bounds[g + 1]; s += chunk)
      plan.chunks.emplace_back(s, std::min(bounds[g + 1], s + chunk));
  return plan;
}

EntropyParams map_params(const EntropyParams& p,
                         const std::function<torch::Tensor(const torch::Tensor&)>& f) {
  return {f(p.mu_f),    f(p.sigma_f), f(p.mu_s), f(p.sigma_s), f(p.mu_o),
          f(p.sigma_o), f(p.q_f),     f(p.q_s),  f(p.q_o)};
}

/// Base-model parameters of every anchor in coding order (chunked as predict_entropy_params).
EntropyParams base_params(const CodedModel& m, const CodingPlan& plan, ContextModel& context,
                          int64_t coded_dim) {
  torch::NoGradGuard no_grad;
  const auto pos01 = normalize_positions(voxel_positions(m.voxels, m.voxel_size), m.bounds)
                         .index_select(0, plan.order);
  const EntropyParamLayout layout{coded_dim, m.offset_masks.size(1)};
  return map_params(
      predict_entropy_params(context, pos01, layout, m.q0, m.chunk, m.arithmetic, m.steps),
      [](const torch::Tensor& t) { return t.contiguous(); });
}

/// Replaces the leaves' μ_f (coding positions >= leaf_begin) with the leaf model, given the
/// feature symbols of the roots (in coding order; only rows < leaf_begin are read).
Status apply_leaf_means(const CodedModel& m, const CodingPlan& plan, const LeafMlp& mlp,
                        const torch::Tensor& feature_sym_coded, EntropyParams* p) {
  const int64_t n = plan.order.size(0), leaves = n - plan.leaf_begin;
  if (leaves == 0) return OkStatus();
  if (!mlp.defined()) return corrupt("the model has leaves but no leaf MLP");
  torch::NoGradGuard no_grad;
  std::optional<ScopedComputeThreads> one_thread;  // as in predict_entropy_params
  if (m.arithmetic == Arithmetic::kFast) one_thread.emplace(1);
  const auto pos01 = normalize_positions(voxel_positions(m.voxels, m.voxel_size), m.bounds)
                         .index_select(0, plan.order);
  for (int64_t s = 0; s < leaves; s += m.chunk) {
    const int64_t e = std::min(leaves, s + m.chunk);
    const auto roots = plan.root_slot.slice(0, s, e);
    const auto root_feat =
        feature_sym_coded.index_select(0, roots).to(torch::kFloat) * p->q_f.index_select(0, roots);
    const auto rows = torch::arange(plan.leaf_begin + s, plan.leaf_begin + e, torch::kLong);
    const auto mu =
        leaf_feature_mean(mlp, root_feat, pos01.index_select(0, roots), pos01.index_select(0, rows),
                          p->mu_f.index_select(0, rows), m.arithmetic);
    p->mu_f.slice(0, plan.leaf_begin + s, plan.leaf_begin + e).copy_(mu);
  }
  return OkStatus();
}

/// Rows of coding-order tensors back in canonical order.
torch::Tensor to_canonical(const torch::Tensor& t, const CodingPlan& plan) {
  auto out = torch::empty_like(t);
  out.index_copy_(0, plan.order, t);
  return out;
}

bool leaf_residual_of(const Config& config) {
  const YAML::Node r = config.section("rate");
  return r && r["leaf_residual"] && r["leaf_residual"].as<bool>();
}

/// rate.link_coding; a file's config without the key predates the option: paper.
std::string link_coding_of(const Config& config) {
  const YAML::Node r = config.section("rate");
  return r && r["link_coding"] ? r["link_coding"].as<std::string>() : std::string("paper");
}

/// With the compact coding every model whose config has a link strategy carries a LINK section
/// (a few bytes without leaves), so a file that lost it is refused instead of decoding the
/// streams in the wrong order.
bool always_writes_links(const Config& config) {
  const YAML::Node l = config.section("links");
  return link_coding_of(config) == "compact" && l && l.IsMap() && l["type"];
}

}  // namespace

LinkCounts count_links(const torch::Tensor& links) {
  LinkCounts c;
  if (!links.defined() || links.numel() == 0) return c;
  const auto l = links.to(torch::kLong);
  const auto is_leaf = l >= 0;
  auto is_root = torch::zeros_like(is_leaf);
  if (is_leaf.any().item<bool>()) is_root.index_fill_(0, l.masked_select(is_leaf), true);
  c.leaves = is_leaf.sum().item<int64_t>();
  c.roots = is_root.sum().item<int64_t>();
  c.free = l.size(0) - c.leaves - c.roots;
  return c;
}

torch::Tensor coding_order(const torch::Tensor& links, int64_t n) {
  if (!links.defined()) return torch::arange(n, torch::kLong);
  const auto l = links.to(torch::kLong);
  const auto is_leaf = l >= 0;
  auto is_root = torch::zeros_like(is_leaf);
  if (is_leaf.any().item<bool>()) is_root.index_fill_(0, l.masked_select(is_leaf), true);
  const auto is_free = ~is_leaf & ~is_root;
  return torch::cat(
      {is_root.nonzero().view(-1), is_free.nonzero().view(-1), is_leaf.nonzero().view(-1)});
}

torch::Tensor voxel_positions(const torch::Tensor& voxels, double voxel_size) {
  return voxels.to(torch::kFloat) * static_cast<float>(voxel_size);
}

torch::Tensor normalize_positions(const torch::Tensor& positions, const torch::Tensor& bounds) {
  const auto lo = bounds[0].to(torch::kFloat), hi = bounds[1].to(torch::kFloat);
  return (positions - lo) / (hi - lo).clamp_min(1e-9);  // as AnchorModel::quantize
}

EntropyParams coded_entropy_params(const CodedModel& m, ContextModel& context, int64_t coded_dim) {
  const CodingPlan plan = make_plan(m.links, m.voxels.size(0), m.chunk);
  EntropyParams p = base_params(m, plan, context, coded_dim);
  auto mlp = leaf_mlp_from(m.mlps, coded_dim, m.leaf_residual);
  TORCH_CHECK(mlp.ok(), mlp.status().to_string());
  const Status st = apply_leaf_means(m, plan, *mlp, m.feature_sym.index_select(0, plan.order), &p);
  TORCH_CHECK(st.ok(), st.to_string());
  return map_params(p, [&](const torch::Tensor& t) { return to_canonical(t, plan); });
}

std::map<std::string, double> estimated_stream_bits(const CodedModel& m, const EntropyParams& p,
                                                    EntropyModel& entropy) {
  torch::NoGradGuard no_grad;
  const auto masks = m.offset_masks.to(torch::kBool);
  const auto a =
      stream_args(p, m.feature_sym, m.scaling_sym, m.offset_sym, masks, m.offset_masks.size(1));
  std::map<std::string, double> out;
  for (int k = 0; k < 3; ++k) {
    const auto& s = a[size_t(k)];
    out[kStreamIds[k]] = s.symbols.numel()
                             ? entropy.bits(s.symbols.to(torch::kFloat) * s.q, s.mean, s.scale, s.q)
                                   .sum()
                                   .item<double>()
                             : 0.0;
  }
  return out;
}

double compact_link_bits(int64_t non_leaves) {
  return std::log2(std::max(2.0, double(non_leaves))) + 1.0;
}

StatusOr<std::vector<int32_t>> link_vector_of(const coding::Section& s) {
  if (s.component_id == kCompactLinks)
    return in_section("LINK", coding::decode_links_compact(ByteSpan(s.payload)));
  if (s.component_id == kComponent)
    return in_section("LINK", coding::unpack_links(ByteSpan(s.payload)));
  return corrupt("LINK: unknown link coding '" + s.component_id + "'");
}

void set_format_math(uint16_t minor, CodedModel* m) {
  m->arithmetic = minor >= 1 ? Arithmetic::kPortable : Arithmetic::kFast;
  m->steps = minor >= 2 ? StepForm::kTwoSigmoid : StepForm::kOnePlusTanh;
}

const char* section_category(const std::string& id) {
  if (id == "GEOM") return "geometry";
  if (id == "FEAT") return "features";
  if (id == "SCAL") return "scaling";
  if (id == "OFFS") return "offsets";
  if (id == "OMSK" || id == "AMSK") return "masks";
  if (id == "LINK") return "links";
  if (id == "CTXS" || id == "FTRS") return "hash_grids";
  if (id == "MLPS") return "mlps";
  return "other";
}

namespace {
// [N, 3] CPU tensor of integral values -> voxels.
std::vector<coding::Voxel> voxels_of(const torch::Tensor& t) {
  const auto vox = t.to(torch::kInt).contiguous();
  std::vector<coding::Voxel> points(static_cast<size_t>(vox.size(0)));
  const int32_t* vp = vox.data_ptr<int32_t>();
  for (size_t i = 0; i < points.size(); ++i) points[i] = {vp[3 * i], vp[3 * i + 1], vp[3 * i + 2]};
  return points;
}

// What HEAD's bounds must be for the decoder to accept them (checked on both sides, so that no
// file is written that cannot be read back).
bool bounds_decodable(const float lo_hi[6]) {
  for (int a = 0; a < 3; ++a)
    if (!(lo_hi[3 + a] > lo_hi[a]) || !std::isfinite(lo_hi[3 + a] - lo_hi[a])) return false;
  return true;
}
}  // namespace

StatusOr<EncodeResult> encode_model(const CodedModel& model, const Config& config,
                                    const CodecComponents& c) {
  CodedModel m = model;  // shares the tensors
  set_format_math(kMinor, &m);
  auto bad = [](const std::string& msg) {
    return Status(StatusCode::kInvalidArgument, "encode: " + msg);
  };
  // The coder reads the symbols through host pointers.
  for (const torch::Tensor* t : {&m.bounds, &m.voxels, &m.offset_masks, &m.feature_sym,
                                 &m.scaling_sym, &m.offset_sym, &m.links, &m.anchor_mask})
    if (t->defined() && !t->device().is_cpu())
      return bad("the coded model's tensors are on " + t->device().str() + ", not the CPU");
  if (!c.context || !c.entropy || !c.features)
    return bad("context, entropy and features are required");
  if (!c.entropy->supports_coding())
    return bad("entropy model '" + c.entropy->type_name() + "' cannot code bitstreams");
  const int64_t N = m.voxels.size(0), K = m.offset_masks.size(1), Dc = m.feature_sym.size(1);
  if (m.voxels.dim() != 2 || m.voxels.size(1) != 3 || m.offset_masks.size(0) != N ||
      m.feature_sym.size(0) != N || m.scaling_sym.sizes() != torch::IntArrayRef({N, 6}) ||
      m.offset_sym.sizes() != torch::IntArrayRef({N, K, 3}) || Dc != c.features->coded_dim())
    return bad("inconsistent tensor shapes in the coded model");

  // Geometry first: it fixes the canonical order everything else must already follow.
  const std::vector<coding::Voxel> points = voxels_of(m.voxels);
  const auto order = coding::morton_order(points);
  for (size_t i = 0; i < order.size(); ++i)
    if (order[i] != i) return bad("anchors are not in canonical (Morton) order");
  if (m.geometry != "draco" && m.geometry != "raw")
    return bad("unknown geometry coding '" + m.geometry + "' (draco, raw)");
  CRPGS_ASSIGN_OR_RETURN(Bytes geometry, m.geometry == "raw" ? coding::encode_voxels_raw(points)
                                                             : coding::encode_positions(points));
  if (m.link_coding != link_coding_of(config))
    return bad("the link coding '" + m.link_coding + "' disagrees with the config's '" +
               link_coding_of(config) + "' (rate.link_coding)");
  if (m.leaf_residual != leaf_residual_of(config))
    return bad("the leaf MLP form disagrees with the config's rate.leaf_residual");
  std::vector<int32_t> links;
  if (m.links.defined()) {
    if (m.links.dim() != 1 || m.links.size(0) != N) return bad("links must be [N]");
    const auto l = m.links.to(torch::kLong).contiguous();
    // In range, one hop, one leaf per root (docs/method.md §6.2): what the decoder accepts.
    if (Status st = check_links(l, {}); !st.ok()) return bad(st.message());
    const int64_t* lp = l.data_ptr<int64_t>();
    for (int64_t i = 0; i < N; ++i) links.push_back(int32_t(lp[i]));
  }

  coding::ContainerWriter w(config.hash());
  const std::string conf = config.dump();
  CRPGS_RETURN_IF_ERROR(
      w.add_section("CONF", kComponent, kMajor, kMinor, Bytes(conf.begin(), conf.end())));
  ByteWriter head;
  head.put_varint(uint64_t(N));
  head.put_varint(uint64_t(K));
  head.put_varint(uint64_t(Dc));
  head.put_varint(uint64_t(m.chunk));
  head.put_f64(m.voxel_size);
  const auto b = m.bounds.to(torch::kFloat).contiguous();
  if (b.numel() != 6) return bad("bounds must be [2, 3]");
  float lo_hi[6];
  for (int i = 0; i < 6; ++i) lo_hi[i] = b.view(-1)[i].item<float>();
  if (!bounds_decodable(lo_hi))
    return bad("the anchor bounds are empty or non-finite on an axis (recompute_bounds)");
  for (float v : lo_hi) head.put_f32(v);
  head.put_f64(m.q0.feature);
  head.put_f64(m.q0.scaling);
  head.put_f64(m.q0.offset);
  CRPGS_RETURN_IF_ERROR(w.add_section("HEAD", kComponent, kMajor, kMinor, head.take()));
  CRPGS_RETURN_IF_ERROR(
      w.add_section("GEOM", "org.crpgs.geometry." + m.geometry, 1, 0, std::move(geometry)));
  if (m.link_coding == "compact" && (m.links.defined() || always_writes_links(config))) {
    if (!m.links.defined()) links.assign(size_t(N), coding::kNoRoot);
    CRPGS_ASSIGN_OR_RETURN(Bytes link_bytes, coding::encode_links_compact(links));
    CRPGS_RETURN_IF_ERROR(w.add_section("LINK", kCompactLinks, 1, 0, std::move(link_bytes)));
  } else if (m.links.defined()) {
    // The active-anchor mask is redundant for decoding (docs/method.md §7.11); written so the size
    // accounting matches the paper's side information.
    if (!m.anchor_mask.defined() || m.anchor_mask.sum().item<int64_t>() != N)
      return bad("the anchor mask must mark exactly the N coded anchors");
    const auto am = m.anchor_mask.to(torch::kBool).contiguous();
    std::vector<uint8_t> am_bits(size_t(am.numel()));
    for (size_t i = 0; i < am_bits.size(); ++i) am_bits[i] = am.data_ptr<bool>()[i] ? 1 : 0;
    ByteWriter amsk;
    amsk.put_varint(am_bits.size());
    CRPGS_ASSIGN_OR_RETURN(Bytes am_coded, coding::encode_bernoulli(am_bits));
    amsk.put_bytes(am_coded);
    CRPGS_RETURN_IF_ERROR(w.add_section("AMSK", kComponent, kMajor, kMinor, amsk.take()));
    CRPGS_ASSIGN_OR_RETURN(Bytes link_bytes, coding::pack_links(links));
    CRPGS_RETURN_IF_ERROR(w.add_section("LINK", kComponent, kMajor, kMinor, std::move(link_bytes)));
  }

  const auto masks = m.offset_masks.to(torch::kBool).contiguous();
  std::vector<uint8_t> bits(size_t(N * K));
  const bool* mp = masks.data_ptr<bool>();
  for (size_t i = 0; i < bits.size(); ++i) bits[i] = mp[i] ? 1 : 0;
  CRPGS_ASSIGN_OR_RETURN(Bytes mask_bytes, coding::encode_bernoulli(bits));
  CRPGS_RETURN_IF_ERROR(w.add_section("OMSK", kComponent, kMajor, kMinor, std::move(mask_bytes)));

  CRPGS_RETURN_IF_ERROR(w.add_section("CTXS", "org.crpgs.context." + c.context->type_name(), 1, 0,
                                      to_bytes(c.context->save_state())));
  const auto fstate = c.features->save_state();
  if (!fstate.empty())
    CRPGS_RETURN_IF_ERROR(w.add_section("FTRS", "org.crpgs.features." + c.features->type_name(), 1,
                                        0, to_bytes(fstate)));
  ByteWriter mlps;
  mlps.put_varint(m.mlps.size());
  for (const auto& [name, t] : m.mlps) put_tensor(mlps, name, t);
  CRPGS_RETURN_IF_ERROR(w.add_section("MLPS", kComponent, kMajor, kMinor, mlps.take()));

  EncodeResult result;
  const CodingPlan plan = make_plan(m.links, N, m.chunk);
  EntropyParams p = base_params(m, plan, *c.context, Dc);
  CRPGS_ASSIGN_OR_RETURN(LeafMlp leaf, leaf_mlp_from(m.mlps, Dc, m.leaf_residual));
  const auto feat_c = m.feature_sym.index_select(0, plan.order);
  CRPGS_RETURN_IF_ERROR(apply_leaf_means(m, plan, leaf, feat_c, &p));
  const auto scal_c = m.scaling_sym.index_select(0, plan.order);
  const auto offs_c = m.offset_sym.index_select(0, plan.order);
  const auto masks_c = masks.index_select(0, plan.order);
  std::array<ByteWriter, 3> streams;
  torch::NoGradGuard no_grad;
  for (const auto& [s, e] : plan.chunks) {
    const EntropyParams pc =
        map_params(p, [s = s, e = e](const torch::Tensor& t) { return t.slice(0, s, e); });
    const auto args = stream_args(pc, feat_c.slice(0, s, e), scal_c.slice(0, s, e),
                                  offs_c.slice(0, s, e), masks_c.slice(0, s, e), K);
    for (int k = 0; k < 3; ++k) {
      const auto& a = args[size_t(k)];
      const auto sym = a.symbols.to(torch::kInt).contiguous();
      const auto bytes =
          c.entropy->compress(sym, a.mean.contiguous(), a.scale.contiguous(), a.q.contiguous());
      streams[size_t(k)].put_varint(bytes.size());
      streams[size_t(k)].put_bytes(bytes);
    }
  }
  const auto estimated = estimated_stream_bits(
      m, map_params(p, [&](const torch::Tensor& t) { return to_canonical(t, plan); }), *c.entropy);
  for (int k = 0; k < 3; ++k) {
    Bytes payload = streams[size_t(k)].take();
    result.estimated_vs_coded_bits[kStreamIds[k]] = {estimated.at(kStreamIds[k]),
                                                     8.0 * payload.size()};
    CRPGS_RETURN_IF_ERROR(w.add_section(
        kStreamIds[k], "org.crpgs.entropy." + c.entropy->type_name(), 1, 0, std::move(payload)));
  }
  result.bytes = w.finish();
  // Sizes as the reader sees them (headers included), from the bytes just written.
  auto parsed = coding::ContainerReader::parse(ByteSpan(result.bytes));
  if (!parsed.ok()) return parsed.status();
  for (const auto& s : parsed->sections)
    result.sections.push_back({s.id, s.component_id, s.file_size});
  return result;
}

namespace {
/// The rasterizer and train.device are the encoding machine's choices, not the model's: a file
/// trained on a GPU decodes where this build lacks its rasterizer, rendering with the CPU's.
Status use_the_cpu_where_the_rasterizer_is_missing(Config* c, const ComponentRegistry& registry) {
  const YAML::Node r = c->section("rasterizer");
  if (!r.IsMap() || !r["type"].IsScalar() ||
      registry.find(CRPGS_KIND_RASTERIZER, r["type"].Scalar()))
    return OkStatus();
  YAML::Node cpu(YAML::NodeType::Map);
  cpu["type"] = "cpu";
  CRPGS_RETURN_IF_ERROR(c->set("rasterizer", cpu));
  const YAML::Node t = c->section("train");
  if (t.IsMap() && t["device"]) CRPGS_RETURN_IF_ERROR(c->set("train.device", YAML::Node("cpu")));
  return OkStatus();
}

StatusOr<DecodeResult> decode_model_unchecked(const std::vector<uint8_t>& bytes,
                                              const ComponentRegistry& registry) {
  CRPGS_ASSIGN_OR_RETURN(coding::Container ct, coding::ContainerReader::parse(ByteSpan(bytes)));
  auto section = [&](const char* id) -> StatusOr<const coding::Section*> {
    const coding::Section* s = ct.find(id);
    if (!s) return corrupt(std::string("missing section ") + id);
    return s;
  };
  DecodeResult out;
  for (const auto& s : ct.sections) {
    // Every section this codec writes is version 1.x; another major has another layout.
    if (s.component_major != kMajor)
      return Status(StatusCode::kUnsupportedVersion,
                    "bitstream: section " + s.id + " (" + s.component_id + ") has version " +
                        std::to_string(s.component_major) + "." +
                        std::to_string(s.component_minor) + ", this decoder reads " +
                        std::to_string(kMajor) + ".x");
    // A later minor of this codec may compute the entropy parameters differently (1.2 did):
    // decoding it with this version's arithmetic would fail or, worse, not.
    if (s.component_id == kComponent && s.component_minor > kMinor)
      return Status(StatusCode::kUnsupportedVersion,
                    "bitstream: section " + s.id + " (" + s.component_id + ") has version " +
                        std::to_string(s.component_major) + "." +
                        std::to_string(s.component_minor) +
                        ", written by a newer crpgs; this decoder reads up to " +
                        std::to_string(kMajor) + "." + std::to_string(kMinor));
    out.sections.push_back({s.id, s.component_id, s.file_size});
  }

  // 1. Config -> components (a plugin the file needs but this machine lacks is named here).
  CRPGS_ASSIGN_OR_RETURN(const coding::Section* conf, section("CONF"));
  CRPGS_ASSIGN_OR_RETURN(
      Config raw, Config::from_string(std::string(conf->payload.begin(), conf->payload.end()),
                                      "<bitstream config>"));
  CRPGS_RETURN_IF_ERROR(use_the_cpu_where_the_rasterizer_is_missing(&raw, registry));
  CRPGS_ASSIGN_OR_RETURN(out.config, raw.resolve(registry));
  crpgs_create_args args = create_args_for(out.config);
  auto& c = out.components;
  CRPGS_ASSIGN_OR_RETURN(
      c.features, create_component<FeatureModel>(registry, out.config.section("features"), args));
  args.coded_dim = int32_t(c.features->coded_dim());
  if (!out.config.section("context") || !out.config.section("entropy"))
    return corrupt("its config has no context/entropy component");
  CRPGS_ASSIGN_OR_RETURN(
      c.context, create_component<ContextModel>(registry, out.config.section("context"), args));
  CRPGS_ASSIGN_OR_RETURN(
      c.entropy, create_component<EntropyModel>(registry, out.config.section("entropy"), args));

  // 2. Header, with every count checked before use.
  CRPGS_ASSIGN_OR_RETURN(const coding::Section* hs, section("HEAD"));
  ByteReader head(ByteSpan(hs->payload), "HEAD");
  uint64_t N = 0, K = 0, Dc = 0, chunk = 0;
  CodedModel& m = out.model;
  CRPGS_RETURN_IF_ERROR(head.read_varint(&N));
  CRPGS_RETURN_IF_ERROR(head.read_varint(&K));
  CRPGS_RETURN_IF_ERROR(head.read_varint(&Dc));
  CRPGS_RETURN_IF_ERROR(head.read_varint(&chunk));
  CRPGS_RETURN_IF_ERROR(head.read_f64(&m.voxel_size));
  float bounds[6];
  for (float& v : bounds) CRPGS_RETURN_IF_ERROR(head.read_f32(&v));
  CRPGS_RETURN_IF_ERROR(head.read_f64(&m.q0.feature));
  CRPGS_RETURN_IF_ERROR(head.read_f64(&m.q0.scaling));
  CRPGS_RETURN_IF_ERROR(head.read_f64(&m.q0.offset));
  if (!head.at_end()) return head.error("trailing bytes");
  set_format_math(hs->component_minor, &m);
  if (K == 0 || K > kMaxOffsets) return corrupt("HEAD: offsets per anchor " + std::to_string(K));
  if (Dc == 0 || Dc > kMaxCodedDim) return corrupt("HEAD: feature width " + std::to_string(Dc));
  if (uint64_t(c.features->coded_dim()) != Dc || uint64_t(args.n_offsets) != K)
    return corrupt("HEAD: feature width/offsets disagree with the stored config");
  if (chunk == 0 || chunk > kMaxChunk) return corrupt("HEAD: chunk size " + std::to_string(chunk));
  if (!(m.voxel_size > 0) || !std::isfinite(m.voxel_size)) return corrupt("HEAD: bad voxel size");
  if (!bounds_decodable(bounds)) return corrupt("HEAD: empty or non-finite bounds");
  for (double q : {m.q0.feature, m.q0.scaling, m.q0.offset})
    if (!(q > 0) || !std::isfinite(q)) return corrupt("HEAD: bad quantisation step Q0");
  m.chunk = int64_t(chunk);
  m.bounds = torch::from_blob(bounds, {2, 3}, torch::kFloat).clone();

  // 3. Geometry: its decoded count is the only trusted N.
  CRPGS_ASSIGN_OR_RETURN(const coding::Section* gs, section("GEOM"));
  std::vector<coding::Voxel> points;
  if (gs->component_id == "org.crpgs.geometry.raw") {
    m.geometry = "raw";
    CRPGS_ASSIGN_OR_RETURN(points,
                           in_section("GEOM", coding::decode_voxels_raw(ByteSpan(gs->payload))));
  } else if (gs->component_id == "org.crpgs.geometry.draco") {
    CRPGS_ASSIGN_OR_RETURN(points,
                           in_section("GEOM", coding::decode_positions(ByteSpan(gs->payload))));
  } else {
    return corrupt("GEOM: unknown geometry coding '" + gs->component_id + "'");
  }
  if (points.size() != N)
    return corrupt("GEOM holds " + std::to_string(points.size()) + " anchors, HEAD claims " +
                   std::to_string(N));
  static_assert(sizeof(coding::Voxel) == 3 * sizeof(int32_t), "Voxel must be 3 packed int32");
  m.voxels = N ? torch::from_blob(points.data(), {int64_t(N), 3}, torch::kInt).clone()
               : torch::empty({0, 3}, torch::kInt);

  // Links (CRP-GS): the link vector, and with the paper's coding the active-anchor mask
  // (checked, not needed).
  m.leaf_residual = leaf_residual_of(out.config);
  const coding::Section* link_section = ct.find("LINK");
  const bool has_amsk = ct.find("AMSK") != nullptr;
  m.link_coding = link_coding_of(out.config);
  if (link_section && (link_section->component_id == kCompactLinks) != (m.link_coding == "compact"))
    return corrupt("LINK is coded as " + link_section->component_id +
                   ", the config says rate.link_coding: " + m.link_coding);
  if (!link_section && always_writes_links(out.config))
    return corrupt("missing section LINK (the config has a link strategy)");
  if (has_amsk != (link_section && m.link_coding == "paper"))
    return corrupt(has_amsk ? "AMSK without a LINK section in the paper's coding"
                            : "missing section AMSK (written with the paper's link coding)");
  if (const coding::Section* as = ct.find("AMSK")) {
    ByteReader ar(ByteSpan(as->payload), "AMSK");
    uint64_t n0 = 0;
    CRPGS_RETURN_IF_ERROR(ar.read_varint(&n0));
    if (n0 < N || n0 > (uint64_t(1) << 32))
      return corrupt("AMSK: " + std::to_string(n0) + " anchors");
    coding::ByteSpan rest;
    CRPGS_RETURN_IF_ERROR(ar.read_span(ar.remaining(), &rest));
    CRPGS_ASSIGN_OR_RETURN(std::vector<uint8_t> am,
                           in_section("AMSK", coding::decode_bernoulli(rest, size_t(n0))));
    uint64_t on = 0;
    for (uint8_t b : am) on += b;
    if (on != N)
      return corrupt("AMSK marks " + std::to_string(on) + " anchors, GEOM holds " +
                     std::to_string(N));
    m.anchor_mask = torch::from_blob(am.data(), {int64_t(n0)}, torch::kUInt8).to(torch::kBool);
  }
  if (link_section) {
    CRPGS_ASSIGN_OR_RETURN(std::vector<int32_t> links, link_vector_of(*link_section));
    if (links.size() != N)
      return corrupt("LINK holds " + std::to_string(links.size()) + " entries for " +
                     std::to_string(N) + " anchors");
    bool any_leaf = false;
    for (int32_t r : links) any_leaf |= r >= 0;
    if (Status st = check_links(
            torch::from_blob(links.data(), {int64_t(N)}, torch::kInt).to(torch::kLong), {});
        !st.ok())
      return corrupt("LINK: " + st.message());
    // No leaves (a compact LINK written for a link strategy that linked nothing): no links.
    if (any_leaf)
      m.links = torch::from_blob(links.data(), {int64_t(N)}, torch::kInt).to(torch::kLong);
  }

  CRPGS_ASSIGN_OR_RETURN(const coding::Section* ms, section("OMSK"));
  CRPGS_ASSIGN_OR_RETURN(
      std::vector<uint8_t> bits,
      in_section("OMSK", coding::decode_bernoulli(ByteSpan(ms->payload), size_t(N * K))));
  m.offset_masks =
      torch::from_blob(bits.data(), {int64_t(N), int64_t(K)}, torch::kUInt8).to(torch::kBool);

  // 4. Component states and MLPs.
  std::string err;
  CRPGS_ASSIGN_OR_RETURN(const coding::Section* cs, section("CTXS"));
  if (!c.context->load_state(std::vector<uint8_t>(cs->payload.begin(), cs->payload.end()), &err))
    return corrupt("CTXS: " + err);
  if (const coding::Section* fs = ct.find("FTRS")) {
    if (!c.features->load_state(std::vector<uint8_t>(fs->payload.begin(), fs->payload.end()), &err))
      return corrupt("FTRS: " + err);
  } else if (!c.features->save_state().empty()) {
    return corrupt("missing section FTRS (the feature model '" + c.features->type_name() +
                   "' has a state)");
  }
  CRPGS_ASSIGN_OR_RETURN(const coding::Section* mls, section("MLPS"));
  ByteReader mr(ByteSpan(mls->payload), "MLPS");
  uint64_t n_mlps = 0;
  CRPGS_RETURN_IF_ERROR(mr.read_varint(&n_mlps));
  if (n_mlps > 64) return corrupt("MLPS: " + std::to_string(n_mlps) + " tensors");
  for (uint64_t i = 0; i < n_mlps; ++i) {
    std::string name;
    torch::Tensor t;
    CRPGS_RETURN_IF_ERROR(get_tensor(mr, &name, &t));
    m.mlps[name] = t;
  }
  if (!mr.at_end()) return mr.error("trailing bytes");

  // 5. Symbol streams, chunk by chunk in coding order, with the parameters the encoder used;
  // the leaves' means once every root is decoded.
  const CodingPlan plan = make_plan(m.links, int64_t(N), m.chunk);
  EntropyParams p = base_params(m, plan, *c.context, int64_t(Dc));
  CRPGS_ASSIGN_OR_RETURN(LeafMlp leaf, leaf_mlp_from(m.mlps, int64_t(Dc), m.leaf_residual));
  const auto masks_c = m.offset_masks.index_select(0, plan.order);
  std::vector<ByteReader> readers;
  for (const char* id : kStreamIds) {
    CRPGS_ASSIGN_OR_RETURN(const coding::Section* ss, section(id));
    readers.emplace_back(ByteSpan(ss->payload), id);
  }
  const int64_t n = int64_t(N);
  auto feat_c = torch::zeros({n, int64_t(Dc)}, torch::kInt);
  auto scal_c = torch::zeros({n, 6}, torch::kInt);
  auto offs_c = torch::zeros({n, int64_t(K), 3}, torch::kInt);
  torch::NoGradGuard no_grad;
  bool leaves_ready = false;
  for (const auto& [s, e] : plan.chunks) {
    if (s >= plan.leaf_begin && !leaves_ready) {
      CRPGS_RETURN_IF_ERROR(apply_leaf_means(m, plan, leaf, feat_c, &p));
      leaves_ready = true;
    }
    const EntropyParams pc =
        map_params(p, [s = s, e = e](const torch::Tensor& t) { return t.slice(0, s, e); });
    const auto masks = masks_c.slice(0, s, e);
    const auto a =
        stream_args(pc, torch::Tensor(), torch::Tensor(), torch::Tensor(), masks, int64_t(K));
    std::array<torch::Tensor, 3> decoded;
    for (int k = 0; k < 3; ++k) {
      ByteReader& r = readers[size_t(k)];
      uint64_t len = 0;
      CRPGS_RETURN_IF_ERROR(r.read_varint(&len));
      Bytes chunk_bytes;
      CRPGS_RETURN_IF_ERROR(r.read_bytes(size_t(len), &chunk_bytes));
      const auto& sa = a[size_t(k)];
      decoded[size_t(k)] = c.entropy->decompress(chunk_bytes, sa.mean.contiguous(),
                                                 sa.scale.contiguous(), sa.q.contiguous(), &err);
      if (!decoded[size_t(k)].defined())
        return corrupt(std::string(kStreamIds[k]) + " chunk at anchor " + std::to_string(s) + ": " +
                       err +
                       (m.arithmetic == Arithmetic::kFast
                            ? " (a format 1.0 file decodes only where the BLAS kernels that "
                              "encoded it run; re-encode its run with this version)"
                            : ""));
    }
    feat_c.slice(0, s, e).copy_(decoded[0].view({e - s, int64_t(Dc)}));
    scal_c.slice(0, s, e).copy_(decoded[1].view({e - s, 6}));
    const auto sel = masks.unsqueeze(2).expand({e - s, int64_t(K), 3});
    auto block = torch::zeros({e - s, int64_t(K), 3}, torch::kInt);
    block.masked_scatter_(sel, decoded[2].to(torch::kInt));
    offs_c.slice(0, s, e).copy_(block);
  }
  for (int k = 0; k < 3; ++k)
    if (!readers[size_t(k)].at_end()) return readers[size_t(k)].error("trailing bytes");
  m.feature_sym = to_canonical(feat_c, plan);
  m.scaling_sym = to_canonical(scal_c, plan);
  m.offset_sym = to_canonical(offs_c, plan);
  out.params = map_params(p, [&](const torch::Tensor& t) { return to_canonical(t, plan); });
  return out;
}

}  // namespace

StatusOr<DecodeResult> decode_model(const std::vector<uint8_t>& bytes,
                                    const ComponentRegistry& registry) {
  // Every check above returns a Status; this is the last line of defence for untrusted input.
  try {
    return decode_model_unchecked(bytes, registry);
  } catch (const std::exception& e) {
    return corrupt(std::string("cannot be decoded: ") + e.what());
  }
}

StatusOr<CodedModel> coded_model_from(const AnchorModel& model, QuantizedAttributes* q_out,
                                      double rate_scale) {
  if (!model.has_rate())
    return Status(StatusCode::kInvalidArgument,
                  "encode: the model has no rate path (config needs `context` and `entropy`)");
  if (!(rate_scale > 0) || !std::isfinite(rate_scale))
    return Status(StatusCode::kInvalidArgument,
                  "encode: the rate scale must be a finite number > 0 (got " +
                      std::to_string(rate_scale) + ")");
  if (!model.device().is_cpu())
    return Status(StatusCode::kInvalidArgument,
                  "encode: the model is on " + model.device().str() +
                      "; move it to the CPU first (AnchorModel::to(torch::kCPU))");
  torch::NoGradGuard no_grad;
  const auto idx = model.active_anchors().nonzero().view(-1);
  const float v = static_cast<float>(model.voxel_size());
  const auto vox =
      torch::round(model.anchors().detach().index({idx}) / v).to(torch::kInt).contiguous();
  const std::vector<coding::Voxel> points = voxels_of(vox);
  const auto order = coding::morton_order(points);
  for (size_t i = 1; i < order.size(); ++i)
    if (points[order[i]] == points[order[i - 1]])
      return Status(StatusCode::kInternal, "encode: two active anchors share a voxel");
  const auto perm =
      torch::from_blob(const_cast<uint32_t*>(order.data()), {int64_t(order.size())}, torch::kInt)
          .to(torch::kLong);
  const auto canon = idx.index({perm});  // model index of each canonical anchor
  const int64_t n = canon.size(0);
  CodedModel m;
  if (model.has_links()) {
    // Sanitise (docs/method.md §7.10): a link whose leaf or root is not coded is dropped; the rest
    // are remapped to canonical indices. Links never built: every anchor is free.
    m.links = torch::full({n}, -1, torch::kLong);
    if (model.links().defined()) {
      auto rank = torch::full({model.num_anchors()}, -1, torch::kLong);
      rank.index_put_({canon}, torch::arange(n, torch::kLong));
      const auto root = model.links().index_select(0, canon);  // [n] model index or -1
      m.links = torch::where(root >= 0, rank.index_select(0, root.clamp_min(0)), m.links);
    }
    m.anchor_mask = model.active_anchors();
    m.leaf_residual = model.leaf_mlp().residual;
    if (!(m.links >= 0).any().item<bool>()) {  // no leaves: HAC's stream, no side information
      m.links = torch::Tensor();
      m.anchor_mask = torch::Tensor();
    }
  }
  m.geometry = model.rate_options().geometry;
  m.link_coding = model.rate_options().link_coding;
  m.voxel_size = model.voxel_size();
  m.voxels = vox.index({perm}).contiguous();
  m.mlps = model.mlp_tensors();
  m.q0 = model.rate_options().q0;
  for (double* q0 : {&m.q0.feature, &m.q0.scaling, &m.q0.offset}) *q0 *= rate_scale;
  QuantizedAttributes q;
  auto quantise = [&] {
    // In coding order, so the steps come from the same context chunks as the decoder's.
    const auto coded_order = coding_order(m.links, n);
    q = model.quantize(*model.context(), m.q0, canon.index_select(0, coded_order));
    auto back = torch::empty_like(coded_order);
    back.index_put_({coded_order}, torch::arange(n, torch::kLong));
    auto rows = [&](torch::Tensor& t) { t = t.index_select(0, back); };
    for (torch::Tensor* t :
         {&q.index, &q.positions, &q.positions01, &q.params.mu_f, &q.params.sigma_f, &q.params.mu_s,
          &q.params.sigma_s, &q.params.mu_o, &q.params.sigma_o, &q.params.q_f, &q.params.q_s,
          &q.params.q_o, &q.feature_symbols, &q.scaling_symbols, &q.offset_symbols, &q.features,
          &q.scaling, &q.offsets, &q.offset_masks})
      rows(*t);
    m.bounds = q.bounds.to(torch::kFloat);
    m.offset_masks = q.offset_masks;
    m.feature_sym = q.feature_symbols;
    m.scaling_sym = q.scaling_symbols;
    m.offset_sym = q.offset_symbols;
  };
  quantise();
  if (m.links.defined() && m.link_coding == "compact" && model.rate_options().prune_links) {
    // A link pays only when its leaf saves more FEAT bits than the link costs in the compact
    // LINK section: about log2 of the roots to choose from, plus the leaf flag. Leaves that save
    // less are coded as free anchors (their features are the same; the partition changes).
    // q.params hold the base means; the coded parameters add the leaf model's.
    const EntropyParams p = coded_entropy_params(m, *model.context(), m.feature_sym.size(1));
    const FeatureRowBits b = feature_row_bits(m, p, *model.context(), *model.entropy());
    const auto is_leaf = m.links >= 0;
    const double link_bits = compact_link_bits(is_leaf.logical_not().sum().item<int64_t>());
    const auto drop = is_leaf.logical_and((b.base - b.coded) < link_bits);
    if (drop.any().item<bool>()) {
      m.links = torch::where(drop, torch::full_like(m.links, -1), m.links);
      if (!(m.links >= 0).any().item<bool>()) {
        m.links = torch::Tensor();
        m.anchor_mask = torch::Tensor();
      }
      quantise();
    }
  }
  if (q_out) *q_out = std::move(q);
  return m;
}

CodecComponents codec_components_of(const AnchorModel& model) {
  // The model owns its context/entropy; these non-owning handles live no longer than it.
  auto none = [](auto*) {};
  return {std::shared_ptr<ContextModel>(model.context(), none),
          std::shared_ptr<EntropyModel>(model.entropy(), none), model.feature_model()};
}

StatusOr<std::unique_ptr<AnchorModel>> model_from_decoded(const DecodeResult& d,
                                                          const AnchorModelOptions& options) {
  const CodedModel& m = d.model;
  const EntropyParams& p = d.params;
  const int64_t n = m.voxels.size(0), K = m.offset_masks.size(1);
  const auto features = m.feature_sym.to(torch::kFloat) * p.q_f;
  const auto scaling = m.scaling_sym.to(torch::kFloat) * p.q_s;
  const auto offsets = m.offset_sym.to(torch::kFloat) * p.q_o.view({n, 1, 1});
  (void)K;
  return AnchorModel::from_decoded(options, d.components.features,
                                   voxel_positions(m.voxels, m.voxel_size), features, scaling,
                                   offsets, m.offset_masks, m.mlps, m.bounds, m.voxel_size);
}

}  // namespace crpgs
