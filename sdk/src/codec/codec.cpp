/// @file codec.cpp
/// @brief encode_model / decode_model: the anchor-model bitstream described in codec.h.
#include "crpgs/codec.h"

#include <dlfcn.h>

#include <torch/torch.h>

#include "crpgs/coding/bitstream.h"
#include "crpgs/coding/geometry.h"
#include "crpgs/coding/range_coder.h"
#include "crpgs/components.h"

namespace crpgs {
namespace {

using coding::ByteReader;
using coding::Bytes;
using coding::ByteSpan;
using coding::ByteWriter;

constexpr const char* kComponent = "org.crpgs.codec.anchor_model";
constexpr uint16_t kMajor = 1, kMinor = 0;
// Sanity limits for counts read from a file (refused before anything is allocated).
constexpr uint64_t kMaxOffsets = 64, kMaxCodedDim = 4096, kMaxChunk = 1 << 20;

/// Entropy parameters must come out bit-identical in encoder and decoder: predict them with one
/// thread in torch and in OpenBLAS (whose small-matrix kernels may otherwise differ by shape).
class SingleThreaded {
 public:
  SingleThreaded() : torch_threads_(at::get_num_threads()) {
    at::set_num_threads(1);
    blas_set_ = reinterpret_cast<void (*)(int)>(dlsym(RTLD_DEFAULT, "openblas_set_num_threads"));
    auto get = reinterpret_cast<int (*)()>(dlsym(RTLD_DEFAULT, "openblas_get_num_threads"));
    if (blas_set_ && get) {
      blas_threads_ = get();
      blas_set_(1);
    }
  }
  ~SingleThreaded() {
    at::set_num_threads(torch_threads_);
    if (blas_set_ && blas_threads_ > 0) blas_set_(blas_threads_);
  }

 private:
  int torch_threads_;
  void (*blas_set_)(int) = nullptr;
  int blas_threads_ = 0;
};

Status corrupt(const std::string& msg) {
  return Status(StatusCode::kCorruptBitstream, "bitstream: " + msg);
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

}  // namespace

torch::Tensor voxel_positions(const torch::Tensor& voxels, double voxel_size) {
  return voxels.to(torch::kFloat) * static_cast<float>(voxel_size);
}

torch::Tensor normalize_positions(const torch::Tensor& positions, const torch::Tensor& bounds) {
  const auto lo = bounds[0].to(torch::kFloat), hi = bounds[1].to(torch::kFloat);
  return (positions - lo) / (hi - lo).clamp_min(1e-9);  // as AnchorModel::quantize
}

EntropyParams coded_entropy_params(const CodedModel& m, ContextModel& context, int64_t coded_dim) {
  torch::NoGradGuard no_grad;
  SingleThreaded one_thread;
  const auto pos01 = normalize_positions(voxel_positions(m.voxels, m.voxel_size), m.bounds);
  const EntropyParamLayout layout{coded_dim, m.offset_masks.size(1)};
  return predict_entropy_params(context, pos01, layout, m.q0, m.chunk);
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

StatusOr<EncodeResult> encode_model(const CodedModel& m, const Config& config,
                                    const CodecComponents& c) {
  auto bad = [](const std::string& msg) {
    return Status(StatusCode::kInvalidArgument, "encode: " + msg);
  };
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
  const auto vox = m.voxels.to(torch::kInt).contiguous();
  std::vector<coding::Voxel> points(static_cast<size_t>(N));
  for (int64_t i = 0; i < N; ++i)
    for (int a = 0; a < 3; ++a) points[size_t(i)][size_t(a)] = vox[i][a].item<int32_t>();
  const auto order = coding::morton_order(points);
  for (size_t i = 0; i < order.size(); ++i)
    if (order[i] != i) return bad("anchors are not in canonical (Morton) order");
  CRPGS_ASSIGN_OR_RETURN(Bytes geometry, coding::encode_positions(points));

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
  for (int i = 0; i < 6; ++i) head.put_f32(b.view(-1)[i].item<float>());
  head.put_f64(m.q0.feature);
  head.put_f64(m.q0.scaling);
  head.put_f64(m.q0.offset);
  CRPGS_RETURN_IF_ERROR(w.add_section("HEAD", kComponent, kMajor, kMinor, head.take()));
  CRPGS_RETURN_IF_ERROR(
      w.add_section("GEOM", "org.crpgs.geometry.draco", 1, 0, std::move(geometry)));

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
  const EntropyParams p = coded_entropy_params(m, *c.context, Dc);
  std::array<ByteWriter, 3> streams;
  torch::NoGradGuard no_grad;
  for (int64_t s = 0; s < N; s += m.chunk) {
    const int64_t e = std::min(N, s + m.chunk);
    EntropyParams pc{p.mu_f.slice(0, s, e),    p.sigma_f.slice(0, s, e), p.mu_s.slice(0, s, e),
                     p.sigma_s.slice(0, s, e), p.mu_o.slice(0, s, e),    p.sigma_o.slice(0, s, e),
                     p.q_f.slice(0, s, e),     p.q_s.slice(0, s, e),     p.q_o.slice(0, s, e)};
    const auto args = stream_args(pc, m.feature_sym.slice(0, s, e), m.scaling_sym.slice(0, s, e),
                                  m.offset_sym.slice(0, s, e), masks.slice(0, s, e), K);
    for (int k = 0; k < 3; ++k) {
      const auto& a = args[size_t(k)];
      const auto sym = a.symbols.to(torch::kInt).contiguous();
      const auto bytes =
          c.entropy->compress(sym, a.mean.contiguous(), a.scale.contiguous(), a.q.contiguous());
      streams[size_t(k)].put_varint(bytes.size());
      streams[size_t(k)].put_bytes(bytes);
    }
  }
  const auto estimated = estimated_stream_bits(m, p, *c.entropy);
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
StatusOr<DecodeResult> decode_model_unchecked(const std::vector<uint8_t>& bytes,
                                              const ComponentRegistry& registry) {
  CRPGS_ASSIGN_OR_RETURN(coding::Container ct, coding::ContainerReader::parse(ByteSpan(bytes)));
  auto section = [&](const char* id) -> StatusOr<const coding::Section*> {
    const coding::Section* s = ct.find(id);
    if (!s) return corrupt(std::string("missing section ") + id);
    if (s->component_id == kComponent && s->component_major != kMajor)
      return Status(StatusCode::kUnsupportedVersion,
                    std::string("bitstream: section ") + id + " has version " +
                        std::to_string(s->component_major) + ", this decoder reads " +
                        std::to_string(kMajor));
    return s;
  };
  DecodeResult out;
  for (const auto& s : ct.sections) out.sections.push_back({s.id, s.component_id, s.file_size});

  // 1. Config -> components (a plugin the file needs but this machine lacks is named here).
  CRPGS_ASSIGN_OR_RETURN(const coding::Section* conf, section("CONF"));
  CRPGS_ASSIGN_OR_RETURN(
      Config raw, Config::from_string(std::string(conf->payload.begin(), conf->payload.end()),
                                      "<bitstream config>"));
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
  if (K == 0 || K > kMaxOffsets) return corrupt("HEAD: offsets per anchor " + std::to_string(K));
  if (Dc == 0 || Dc > kMaxCodedDim) return corrupt("HEAD: feature width " + std::to_string(Dc));
  if (uint64_t(c.features->coded_dim()) != Dc || uint64_t(args.n_offsets) != K)
    return corrupt("HEAD: feature width/offsets disagree with the stored config");
  if (chunk == 0 || chunk > kMaxChunk) return corrupt("HEAD: chunk size " + std::to_string(chunk));
  if (!(m.voxel_size > 0) || !std::isfinite(m.voxel_size)) return corrupt("HEAD: bad voxel size");
  for (int a = 0; a < 3; ++a)
    if (!(bounds[3 + a] > bounds[a])) return corrupt("HEAD: empty bounds");
  m.chunk = int64_t(chunk);
  m.bounds = torch::from_blob(bounds, {2, 3}, torch::kFloat).clone();

  // 3. Geometry: its decoded count is the only trusted N.
  CRPGS_ASSIGN_OR_RETURN(const coding::Section* gs, section("GEOM"));
  CRPGS_ASSIGN_OR_RETURN(std::vector<coding::Voxel> points,
                         coding::decode_positions(ByteSpan(gs->payload)));
  if (points.size() != N)
    return corrupt("GEOM holds " + std::to_string(points.size()) + " anchors, HEAD claims " +
                   std::to_string(N));
  m.voxels = torch::empty({int64_t(N), 3}, torch::kInt);
  for (size_t i = 0; i < points.size(); ++i)
    for (int a = 0; a < 3; ++a) m.voxels[int64_t(i)][a] = points[i][size_t(a)];

  CRPGS_ASSIGN_OR_RETURN(const coding::Section* ms, section("OMSK"));
  CRPGS_ASSIGN_OR_RETURN(std::vector<uint8_t> bits,
                         coding::decode_bernoulli(ByteSpan(ms->payload), size_t(N * K)));
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

  // 5. Symbol streams, chunk by chunk, with the parameters the encoder used.
  out.params = coded_entropy_params(m, *c.context, int64_t(Dc));
  const EntropyParams& p = out.params;
  std::vector<ByteReader> readers;
  for (const char* id : kStreamIds) {
    CRPGS_ASSIGN_OR_RETURN(const coding::Section* ss, section(id));
    readers.emplace_back(ByteSpan(ss->payload), id);
  }
  const int64_t n = int64_t(N);
  m.feature_sym = torch::zeros({n, int64_t(Dc)}, torch::kInt);
  m.scaling_sym = torch::zeros({n, 6}, torch::kInt);
  m.offset_sym = torch::zeros({n, int64_t(K), 3}, torch::kInt);
  torch::NoGradGuard no_grad;
  for (int64_t s = 0; s < n; s += m.chunk) {
    const int64_t e = std::min(n, s + m.chunk);
    EntropyParams pc{p.mu_f.slice(0, s, e),    p.sigma_f.slice(0, s, e), p.mu_s.slice(0, s, e),
                     p.sigma_s.slice(0, s, e), p.mu_o.slice(0, s, e),    p.sigma_o.slice(0, s, e),
                     p.q_f.slice(0, s, e),     p.q_s.slice(0, s, e),     p.q_o.slice(0, s, e)};
    const auto masks = m.offset_masks.slice(0, s, e);
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
                       err);
    }
    m.feature_sym.slice(0, s, e).copy_(decoded[0].view({e - s, int64_t(Dc)}));
    m.scaling_sym.slice(0, s, e).copy_(decoded[1].view({e - s, 6}));
    const auto sel = masks.unsqueeze(2).expand({e - s, int64_t(K), 3});
    auto block = torch::zeros({e - s, int64_t(K), 3}, torch::kInt);
    block.masked_scatter_(sel, decoded[2].to(torch::kInt));
    m.offset_sym.slice(0, s, e).copy_(block);
  }
  for (int k = 0; k < 3; ++k)
    if (!readers[size_t(k)].at_end()) return readers[size_t(k)].error("trailing bytes");
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

StatusOr<CodedModel> coded_model_from(const AnchorModel& model, QuantizedAttributes* q_out) {
  if (!model.has_rate())
    return Status(StatusCode::kInvalidArgument,
                  "encode: the model has no rate path (config needs `context` and `entropy`)");
  torch::NoGradGuard no_grad;
  const auto idx = model.active_anchors().nonzero().view(-1);
  const float v = static_cast<float>(model.voxel_size());
  const auto vox =
      torch::round(model.anchors().detach().index({idx}) / v).to(torch::kInt).contiguous();
  std::vector<coding::Voxel> points(static_cast<size_t>(vox.size(0)));
  const int32_t* vp = vox.data_ptr<int32_t>();
  for (size_t i = 0; i < points.size(); ++i) points[i] = {vp[3 * i], vp[3 * i + 1], vp[3 * i + 2]};
  const auto order = coding::morton_order(points);
  for (size_t i = 1; i < order.size(); ++i)
    if (points[order[i]] == points[order[i - 1]])
      return Status(StatusCode::kInternal, "encode: two active anchors share a voxel");
  const auto perm =
      torch::from_blob(const_cast<uint32_t*>(order.data()), {int64_t(order.size())}, torch::kInt)
          .to(torch::kLong);
  QuantizedAttributes q = model.quantize(idx.index({perm}));
  CodedModel m;
  m.voxel_size = model.voxel_size();
  m.bounds = q.bounds.to(torch::kFloat);
  m.voxels = vox.index({perm}).contiguous();
  m.offset_masks = q.offset_masks;
  m.feature_sym = q.feature_symbols;
  m.scaling_sym = q.scaling_symbols;
  m.offset_sym = q.offset_symbols;
  m.mlps = model.mlp_tensors();
  m.q0 = model.rate_options().q0;
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
