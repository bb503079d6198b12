/// @file range_coder.cpp
/// @brief rANS (64-bit state, 32-bit words) over integer CDF tables, escape coding, chunking and
/// the Bernoulli bit-vector coder. See range_coder.h for the stream layouts.
#include "crpgs/coding/range_coder.h"

#include <algorithm>
#include <atomic>
#include <cmath>
#include <cstring>
#include <limits>
#include <numeric>
#include <string>
#include <thread>

namespace crpgs::coding {
namespace {

constexpr uint64_t kRansL = 1ull << 31;  // state lower bound; states live in [L, L << 32)
constexpr int kBucketBits = 10;          // decoder lookup: 2^10 slot buckets per table
constexpr int kLinearScanMax = 8;        // wider buckets are searched by bisection
constexpr int kLengthBits = 6;           // escape: bit length of g - 1 (0..34)
constexpr int kBypassGroup = 16;         // escape: raw bits per bypass step
constexpr int kMaxGammaBits = 35;        // g = u + 1 < 2^35 for every int32 value

Status invalid(const std::string& m) {
  return Status(StatusCode::kInvalidArgument, m);
}
Status corrupt(const std::string& m) {
  return Status(StatusCode::kCorruptBitstream, m);
}

// Encoder side: symbols are pushed in reverse decoding order; words come out in reverse too.
class RansWriter {
 public:
  explicit RansWriter(size_t expect_words) { words_.reserve(expect_words); }
  inline void put(uint32_t start, uint32_t freq, int scale_bits) {
    const uint64_t x_max = ((kRansL >> scale_bits) << 32) * freq;
    if (x_ >= x_max) {
      words_.push_back(uint32_t(x_));
      x_ >>= 32;
    }
    x_ = ((x_ / freq) << scale_bits) + (x_ % freq) + start;
  }
  void finish(ByteWriter& w) const {
    w.put_u64(x_);
    for (auto it = words_.rbegin(); it != words_.rend(); ++it) w.put_u32(*it);
  }
  size_t size_bytes() const { return 8 + 4 * words_.size(); }

 private:
  uint64_t x_ = kRansL;
  std::vector<uint32_t> words_;
};

inline uint32_t load_u32(const uint8_t* p) {
  return uint32_t(p[0]) | uint32_t(p[1]) << 8 | uint32_t(p[2]) << 16 | uint32_t(p[3]) << 24;
}

// Decoder state; the hot loops copy x/p into locals.
struct RansReader {
  uint64_t x = 0;
  const uint8_t* p = nullptr;
  const uint8_t* end = nullptr;
  bool truncated = false;

  Status init(ByteSpan s) {
    if (s.size < 8) return corrupt("rANS stream shorter than its 8-byte state");
    if ((s.size - 8) % 4 != 0) return corrupt("rANS stream length is not 8 + 4k bytes");
    x = uint64_t(load_u32(s.data)) | uint64_t(load_u32(s.data + 4)) << 32;
    if (x < kRansL || x >= (kRansL << 32)) return corrupt("rANS initial state out of range");
    p = s.data + 8;
    end = s.data + s.size;
    return OkStatus();
  }
  inline void renorm() {
    if (x < kRansL) {
      if (end - p >= 4) {
        x = (x << 32) | load_u32(p);
        p += 4;
      } else {
        truncated = true;
        x = kRansL;  // keep going safely; the caller reports the error
      }
    }
  }
  inline uint32_t get_bits(int k) {
    const uint32_t v = uint32_t(x) & ((1u << k) - 1);
    x >>= k;  // freq 1: x = (x >> k) + v - v
    renorm();
    return v;
  }
  Status finish(const char* what) const {
    if (truncated) return corrupt(std::string(what) + ": truncated rANS stream");
    if (p != end) return corrupt(std::string(what) + ": rANS stream has unread words");
    if (x != kRansL) return corrupt(std::string(what) + ": rANS final state mismatch");
    return OkStatus();
  }
};

int bit_length(uint64_t v) {
  int n = 0;
  while (v) {
    ++n;
    v >>= 1;
  }
  return n;
}

struct TableRt {
  const uint32_t* cdf;
  const uint32_t* bucket;  // 2^bb + 1 entries
  int32_t offset;
  uint32_t escape;
};

std::vector<TableRt> runtime_tables(const CdfTableSet& set) {
  std::vector<TableRt> rt(set.size());
  for (size_t i = 0; i < set.size(); ++i) {
    const CdfTable& t = set.table(i);
    rt[i] = {t.cdf.data(), set.buckets(i), t.offset, uint32_t(t.num_symbols())};
  }
  return rt;
}

Status check_indexes(const uint32_t* indexes, size_t n, size_t n_tables) {
  for (size_t i = 0; i < n; ++i)
    if (indexes[i] >= n_tables)
      return invalid("table index " + std::to_string(indexes[i]) + " at symbol " +
                     std::to_string(i) + " is out of range (" + std::to_string(n_tables) +
                     " tables)");
  return OkStatus();
}

void encode_range(const int32_t* symbols, const uint32_t* indexes, size_t n,
                  const CdfTableSet& tables, ByteWriter& out) {
  const int prec = tables.precision();
  RansWriter w(n / 4 + 16);
  for (size_t i = n; i-- > 0;) {
    const CdfTable& t = tables.table(indexes[i]);
    const uint32_t* cdf = t.cdf.data();
    const int64_t nsym = int64_t(t.num_symbols());
    const int64_t s = int64_t(symbols[i]) - t.offset;
    if (s >= 0 && s < nsym) {
      w.put(cdf[s], cdf[s + 1] - cdf[s], prec);
      continue;
    }
    // Escape: decoded as [escape][len][group 0 (low bits)]...[group last]; push in reverse.
    const uint64_t u = s < 0 ? uint64_t(-s) * 2 - 1 : uint64_t(s - nsym) * 2;
    const uint64_t g = u + 1;
    const int nb = bit_length(g);
    const int raw_bits = nb - 1;
    const int groups = (raw_bits + kBypassGroup - 1) / kBypassGroup;
    for (int k = groups - 1; k >= 0; --k) {
      const int bits = std::min(kBypassGroup, raw_bits - k * kBypassGroup);
      w.put(uint32_t(g >> (k * kBypassGroup)) & ((1u << bits) - 1), 1, bits);
    }
    w.put(uint32_t(raw_bits), 1, kLengthBits);
    const uint32_t e = uint32_t(nsym);
    w.put(cdf[e], cdf[e + 1] - cdf[e], prec);
  }
  w.finish(out);
}

// Returns false on an invalid escape payload.
inline bool decode_escape(RansReader& r, const TableRt& t, int32_t* out) {
  const int raw_bits = int(r.get_bits(kLengthBits));
  if (raw_bits + 1 > kMaxGammaBits) return false;
  uint64_t g = 0;
  for (int k = 0; k * kBypassGroup < raw_bits; ++k) {
    const int bits = std::min(kBypassGroup, raw_bits - k * kBypassGroup);
    g |= uint64_t(r.get_bits(bits)) << (k * kBypassGroup);
  }
  g |= uint64_t(1) << raw_bits;
  const uint64_t u = g - 1;
  const int64_t s = (u & 1) ? -int64_t((u + 1) / 2) : int64_t(u / 2) + int64_t(t.escape);
  const int64_t v = s + t.offset;
  if (v < std::numeric_limits<int32_t>::min() || v > std::numeric_limits<int32_t>::max())
    return false;
  *out = int32_t(v);
  return true;
}

Status decode_range(ByteSpan stream, const uint32_t* indexes, size_t n, const CdfTableSet& tables,
                    const TableRt* rt, int32_t* out, const char* what) {
  RansReader r;
  CRPGS_RETURN_IF_ERROR(r.init(stream));
  const int prec = tables.precision();
  const uint32_t mask = (1u << prec) - 1;
  const int shift = prec - tables.bucket_bits();
  uint64_t x = r.x;
  for (size_t i = 0; i < n; ++i) {
    const TableRt& t = rt[indexes[i]];
    const uint32_t slot = uint32_t(x) & mask;
    const uint32_t b = slot >> shift;
    uint32_t s = t.bucket[b];
    uint32_t hi = t.bucket[b + 1];
    if (hi - s > uint32_t(kLinearScanMax)) {
      // Largest s in [s, hi] with cdf[s] <= slot.
      while (s < hi) {
        const uint32_t mid = (s + hi + 1) >> 1;
        if (t.cdf[mid] <= slot)
          s = mid;
        else
          hi = mid - 1;
      }
    } else {
      while (t.cdf[s + 1] <= slot) ++s;
    }
    const uint32_t start = t.cdf[s];
    x = uint64_t(t.cdf[s + 1] - start) * (x >> prec) + slot - start;
    if (x < kRansL) {
      if (r.end - r.p >= 4) {
        x = (x << 32) | load_u32(r.p);
        r.p += 4;
      } else {
        r.truncated = true;
        x = kRansL;
      }
    }
    if (s != t.escape) {
      out[i] = t.offset + int32_t(s);
    } else {
      r.x = x;
      if (!decode_escape(r, t, out + i))
        return corrupt(std::string(what) + ": invalid escape value at symbol " + std::to_string(i));
      x = r.x;
    }
  }
  r.x = x;
  return r.finish(what);
}

}  // namespace

// --- Tables ----------------------------------------------------------------------------------

StatusOr<std::vector<uint32_t>> quantize_pmf(const std::vector<double>& pmf, int precision) {
  if (precision < kMinPrecision || precision > kMaxPrecision)
    return invalid("precision " + std::to_string(precision) + " outside [" +
                   std::to_string(kMinPrecision) + ", " + std::to_string(kMaxPrecision) + "]");
  const size_t n = pmf.size();
  const uint64_t total = uint64_t(1) << precision;
  if (n == 0) return invalid("empty pmf");
  if (n > total)
    return invalid(std::to_string(n) + " symbols do not fit precision " +
                   std::to_string(precision));
  double sum = 0;
  for (size_t i = 0; i < n; ++i) {
    if (!std::isfinite(pmf[i]) || pmf[i] < 0)
      return invalid("pmf[" + std::to_string(i) + "] = " + std::to_string(pmf[i]) +
                     " is negative or not finite");
    sum += pmf[i];
  }
  if (!(sum > 0) || !std::isfinite(sum)) return invalid("pmf sums to zero or overflows");
  const uint64_t spare = total - n;
  std::vector<uint64_t> freq(n);
  std::vector<double> frac(n);
  int64_t assigned = 0;
  for (size_t i = 0; i < n; ++i) {
    const double share = std::min(pmf[i] / sum * double(spare), double(spare));
    const double fl = std::floor(share);
    freq[i] = 1 + uint64_t(fl);
    frac[i] = share - fl;
    assigned += int64_t(fl);
  }
  int64_t left = int64_t(spare) - assigned;
  if (left > 0) {
    std::vector<size_t> order(n);
    std::iota(order.begin(), order.end(), size_t(0));
    std::sort(order.begin(), order.end(),
              [&](size_t a, size_t b) { return frac[a] != frac[b] ? frac[a] > frac[b] : a < b; });
    for (size_t k = 0; left > 0; k = (k + 1) % n, --left) ++freq[order[k]];
  }
  while (left < 0) {  // rounding overshoot: take from the largest count (lowest index on ties)
    const size_t i = size_t(std::max_element(freq.begin(), freq.end()) - freq.begin());
    --freq[i];
    ++left;
  }
  std::vector<uint32_t> cdf(n + 1, 0);
  for (size_t i = 0; i < n; ++i) cdf[i + 1] = cdf[i] + uint32_t(freq[i]);
  CRPGS_RETURN_IF_ERROR(validate_cdf(cdf, precision));  // guards the arithmetic above
  return cdf;
}

Status validate_cdf(const std::vector<uint32_t>& cdf, int precision) {
  if (precision < kMinPrecision || precision > kMaxPrecision)
    return invalid("precision " + std::to_string(precision) + " out of range");
  if (cdf.size() < 2) return invalid("CDF needs at least 2 entries");
  if (cdf[0] != 0) return invalid("CDF must start at 0, starts at " + std::to_string(cdf[0]));
  for (size_t i = 1; i < cdf.size(); ++i)
    if (cdf[i] <= cdf[i - 1])
      return invalid("CDF not strictly increasing at entry " + std::to_string(i) + " (" +
                     std::to_string(cdf[i - 1]) + " -> " + std::to_string(cdf[i]) +
                     "): every symbol needs a count");
  if (cdf.back() != (uint32_t(1) << precision))
    return invalid("CDF ends at " + std::to_string(cdf.back()) + ", not 2^" +
                   std::to_string(precision));
  return OkStatus();
}

StatusOr<CdfTable> make_cdf_table(const std::vector<double>& pmf, int32_t offset, int precision) {
  if (pmf.empty()) return invalid("empty pmf");
  if (int64_t(offset) + int64_t(pmf.size()) - 1 > std::numeric_limits<int32_t>::max())
    return invalid("table range offset + size exceeds int32");
  std::vector<double> ext(pmf);
  double sum = 0;
  for (double p : pmf) sum += p;  // non-finite values are refused by quantize_pmf
  ext.push_back(std::isfinite(sum) ? std::max(0.0, 1.0 - sum) : 0.0);
  CdfTable t;
  t.offset = offset;
  CRPGS_ASSIGN_OR_RETURN(t.cdf, quantize_pmf(ext, precision));
  return t;
}

StatusOr<CdfTableSet> CdfTableSet::create(std::vector<CdfTable> tables, int precision) {
  if (precision < kMinPrecision || precision > kMaxPrecision)
    return invalid("precision " + std::to_string(precision) + " outside [" +
                   std::to_string(kMinPrecision) + ", " + std::to_string(kMaxPrecision) + "]");
  if (tables.size() > (size_t(1) << 24)) return invalid("too many tables");
  CdfTableSet set;
  set.precision_ = precision;
  set.bucket_bits_ = std::min(precision, kBucketBits);
  // Per table 2^bb + 1 entries: bucket b spans symbols [bucket[b], bucket[b + 1]].
  const size_t stride = (size_t(1) << set.bucket_bits_) + 1;
  set.buckets_.assign(tables.size() * stride, 0);
  const int shift = precision - set.bucket_bits_;
  for (size_t i = 0; i < tables.size(); ++i) {
    const CdfTable& t = tables[i];
    const Status st = validate_cdf(t.cdf, precision);
    if (!st.ok()) return invalid("table " + std::to_string(i) + ": " + st.message());
    if (t.cdf.size() < 3)
      return invalid("table " + std::to_string(i) + " needs at least one symbol besides escape");
    if (int64_t(t.offset) + int64_t(t.num_symbols()) - 1 > std::numeric_limits<int32_t>::max())
      return invalid("table " + std::to_string(i) + ": offset + size exceeds int32");
    uint32_t s = 0;
    uint32_t* bucket = set.buckets_.data() + i * stride;
    for (size_t b = 0; b + 1 < stride; ++b) {
      const uint32_t slot = uint32_t(b) << shift;
      while (t.cdf[s + 1] <= slot) ++s;
      bucket[b] = s;
    }
    bucket[stride - 1] = uint32_t(t.cdf.size() - 2);  // the last symbol (escape)
  }
  set.tables_ = std::move(tables);
  return set;
}

// --- Plain streams ---------------------------------------------------------------------------

StatusOr<Bytes> encode_symbols(const int32_t* symbols, const uint32_t* indexes, size_t n,
                               const CdfTableSet& tables) {
  CRPGS_RETURN_IF_ERROR(check_indexes(indexes, n, tables.size()));
  ByteWriter w;
  encode_range(symbols, indexes, n, tables, w);
  return w.take();
}

StatusOr<Bytes> encode_symbols(const std::vector<int32_t>& symbols,
                               const std::vector<uint32_t>& indexes, const CdfTableSet& tables) {
  if (symbols.size() != indexes.size())
    return invalid(std::to_string(symbols.size()) + " symbols but " +
                   std::to_string(indexes.size()) + " table indexes");
  return encode_symbols(symbols.data(), indexes.data(), symbols.size(), tables);
}

Status decode_symbols(ByteSpan stream, const uint32_t* indexes, size_t n, const CdfTableSet& tables,
                      int32_t* out) {
  CRPGS_RETURN_IF_ERROR(check_indexes(indexes, n, tables.size()));
  const std::vector<TableRt> rt = runtime_tables(tables);
  return decode_range(stream, indexes, n, tables, rt.data(), out, "symbol stream");
}

StatusOr<std::vector<int32_t>> decode_symbols(ByteSpan stream, const std::vector<uint32_t>& indexes,
                                              const CdfTableSet& tables) {
  std::vector<int32_t> out(indexes.size());
  CRPGS_RETURN_IF_ERROR(decode_symbols(stream, indexes.data(), indexes.size(), tables, out.data()));
  return out;
}

// --- Chunked streams -------------------------------------------------------------------------

size_t ChunkedStreamInfo::chunk_symbols(size_t k) const {
  const uint64_t begin = uint64_t(k) * chunk_size;
  return begin >= num_symbols ? 0 : size_t(std::min<uint64_t>(chunk_size, num_symbols - begin));
}

namespace {
// Runs fn(k) for k in [0, n) on up to num_threads threads (<= 0: hardware concurrency).
template <typename Fn>
void parallel_for(size_t n, int num_threads, Fn fn) {
  size_t t = num_threads > 0 ? size_t(num_threads)
                             : std::max<size_t>(1, std::thread::hardware_concurrency());
  t = std::min(t, n);
  if (t <= 1) {
    for (size_t k = 0; k < n; ++k) fn(k);
    return;
  }
  std::atomic<size_t> next{0};
  std::vector<std::thread> pool;
  pool.reserve(t);
  for (size_t w = 0; w < t; ++w)
    pool.emplace_back([&] {
      for (size_t k = next.fetch_add(1); k < n; k = next.fetch_add(1)) fn(k);
    });
  for (auto& th : pool) th.join();
}
}  // namespace

ChunkedEncoder::ChunkedEncoder(uint32_t chunk_size, int num_threads)
    : chunk_size_(chunk_size ? chunk_size : kDefaultChunkSize), num_threads_(num_threads) {}

StatusOr<Bytes> ChunkedEncoder::encode(const std::vector<int32_t>& symbols,
                                       const std::vector<uint32_t>& indexes,
                                       const CdfTableSet& tables) const {
  if (symbols.size() != indexes.size())
    return invalid(std::to_string(symbols.size()) + " symbols but " +
                   std::to_string(indexes.size()) + " table indexes");
  CRPGS_RETURN_IF_ERROR(check_indexes(indexes.data(), indexes.size(), tables.size()));
  const size_t n = symbols.size();
  const size_t n_chunks = n / chunk_size_ + (n % chunk_size_ != 0);
  std::vector<Bytes> chunks(n_chunks);
  parallel_for(n_chunks, num_threads_, [&](size_t k) {
    const size_t begin = k * chunk_size_;
    const size_t len = std::min<size_t>(chunk_size_, n - begin);
    ByteWriter w;
    encode_range(symbols.data() + begin, indexes.data() + begin, len, tables, w);
    chunks[k] = w.take();
  });
  ByteWriter out;
  out.put_u8(uint8_t(tables.precision()));
  out.put_varint(n);
  out.put_varint(chunk_size_);
  for (const Bytes& c : chunks) out.put_varint(c.size());
  for (const Bytes& c : chunks) out.put_bytes(c);
  return out.take();
}

StatusOr<ChunkedStreamInfo> ChunkedDecoder::parse(ByteSpan stream) {
  ByteReader r(stream, "chunked stream header");
  ChunkedStreamInfo info;
  uint8_t prec = 0;
  uint64_t chunk_size = 0;
  CRPGS_RETURN_IF_ERROR(r.read_u8(&prec));
  if (prec < kMinPrecision || prec > kMaxPrecision)
    return r.error("precision " + std::to_string(prec) + " out of range");
  info.precision = prec;
  CRPGS_RETURN_IF_ERROR(r.read_varint(&info.num_symbols));
  CRPGS_RETURN_IF_ERROR(r.read_varint(&chunk_size));
  if (chunk_size == 0 || chunk_size > std::numeric_limits<uint32_t>::max())
    return r.error("chunk size " + std::to_string(chunk_size) + " out of range");
  info.chunk_size = uint32_t(chunk_size);
  const uint64_t n_chunks = info.num_symbols / chunk_size + (info.num_symbols % chunk_size != 0);
  // Each chunk costs at least a 1-byte length and an 8-byte state: check before allocating.
  if (n_chunks > r.remaining() / 9)
    return r.error(std::to_string(n_chunks) + " chunks cannot fit in " +
                   std::to_string(r.remaining()) + " bytes");
  std::vector<uint64_t> lengths(n_chunks);
  uint64_t total = 0;
  for (uint64_t k = 0; k < n_chunks; ++k) {
    CRPGS_RETURN_IF_ERROR(r.read_varint(&lengths[k]));
    if (lengths[k] < 8 || lengths[k] > r.remaining())
      return r.error("chunk " + std::to_string(k) + " length " + std::to_string(lengths[k]) +
                     " is invalid");
    total += lengths[k];
  }
  info.header_bytes = r.position();
  if (total != r.remaining())
    return r.error("chunks claim " + std::to_string(total) + " bytes, stream has " +
                   std::to_string(r.remaining()));
  info.chunks.resize(n_chunks);
  for (uint64_t k = 0; k < n_chunks; ++k)
    CRPGS_RETURN_IF_ERROR(r.read_span(size_t(lengths[k]), &info.chunks[k]));
  return info;
}

namespace {
Status check_precision(const ChunkedStreamInfo& info, const CdfTableSet& tables) {
  if (info.precision != tables.precision())
    return corrupt("stream was coded at precision " + std::to_string(info.precision) +
                   " but the tables have precision " + std::to_string(tables.precision()));
  return OkStatus();
}
}  // namespace

StatusOr<std::vector<int32_t>> ChunkedDecoder::decode(ByteSpan stream,
                                                      const std::vector<uint32_t>& indexes,
                                                      const CdfTableSet& tables, int num_threads) {
  CRPGS_ASSIGN_OR_RETURN(ChunkedStreamInfo info, parse(stream));
  CRPGS_RETURN_IF_ERROR(check_precision(info, tables));
  if (info.num_symbols != indexes.size())
    return corrupt("chunked stream holds " + std::to_string(info.num_symbols) +
                   " symbols, caller expects " + std::to_string(indexes.size()));
  CRPGS_RETURN_IF_ERROR(check_indexes(indexes.data(), indexes.size(), tables.size()));
  const std::vector<TableRt> rt = runtime_tables(tables);
  std::vector<int32_t> out(indexes.size());
  std::vector<Status> errors(info.chunks.size());
  parallel_for(info.chunks.size(), num_threads, [&](size_t k) {
    const size_t begin = k * size_t(info.chunk_size);
    const std::string what = "chunk " + std::to_string(k);
    errors[k] = decode_range(info.chunks[k], indexes.data() + begin, info.chunk_symbols(k), tables,
                             rt.data(), out.data() + begin, what.c_str());
  });
  for (const Status& e : errors)
    if (!e.ok()) return e;
  return out;
}

StatusOr<std::vector<int32_t>> ChunkedDecoder::decode_chunk(
    const ChunkedStreamInfo& info, size_t k, const std::vector<uint32_t>& chunk_indexes,
    const CdfTableSet& tables) {
  CRPGS_RETURN_IF_ERROR(check_precision(info, tables));
  if (k >= info.chunks.size())
    return invalid("chunk " + std::to_string(k) + " of " + std::to_string(info.chunks.size()));
  if (chunk_indexes.size() != info.chunk_symbols(k))
    return invalid("chunk " + std::to_string(k) + " holds " +
                   std::to_string(info.chunk_symbols(k)) + " symbols, " +
                   std::to_string(chunk_indexes.size()) + " indexes given");
  CRPGS_RETURN_IF_ERROR(check_indexes(chunk_indexes.data(), chunk_indexes.size(), tables.size()));
  const std::vector<TableRt> rt = runtime_tables(tables);
  std::vector<int32_t> out(chunk_indexes.size());
  const std::string what = "chunk " + std::to_string(k);
  CRPGS_RETURN_IF_ERROR(decode_range(info.chunks[k], chunk_indexes.data(), chunk_indexes.size(),
                                     tables, rt.data(), out.data(), what.c_str()));
  return out;
}

// --- Bernoulli -------------------------------------------------------------------------------

namespace {
constexpr int kBernoulliPrecision = 16;
constexpr uint32_t kBernoulliTotal = 1u << kBernoulliPrecision;

/// The most bits a Bernoulli rANS stream of `words` 32-bit words (after its 8-byte state) can
/// hold with p(1) = f1 / 2^16. Before every step the state x is in [2^31, 2^63); decoding a bit of
/// frequency f gives x' = x - (2^16 - f)(x >> 16) - start <= x (1 - (2^16 - f) / (2^16 + 2)), so
/// each bit costs at least delta = -log2(1 - (2^16 - f_max) / (2^16 + 2)) bits of state. The state
/// starts below 2^63, ends at exactly 2^31 and gains at most 32 + log2(1 + 2^-15) bits per word
/// read, so n delta <= 32 + 32.0001 words. A count above this cannot decode: it is refused before
/// anything is sized from it.
uint64_t max_bernoulli_bits(uint32_t f1, size_t words) {
  const uint32_t f_max = std::max(f1, kBernoulliTotal - f1);
  const double d = double(kBernoulliTotal - f_max) / double(kBernoulliTotal + 2);
  const double delta = -std::log1p(-d) / std::log(2.0);
  const double n = (32.0 + 32.0001 * double(words)) / delta + 1.0;
  return n >= 1.8e19 ? std::numeric_limits<uint64_t>::max() : uint64_t(n);
}
}  // namespace

StatusOr<Bytes> encode_bernoulli(const std::vector<uint8_t>& bits) {
  size_t ones = 0;
  for (size_t i = 0; i < bits.size(); ++i) {
    if (bits[i] > 1) return invalid("bit " + std::to_string(i) + " is not 0 or 1");
    ones += bits[i];
  }
  ByteWriter w;
  w.put_varint(bits.size());
  if (bits.empty()) return w.take();
  // p(1) on the 16-bit grid, clamped so both symbols stay codable (HAC clamps p to [1e-6, 1-1e-6]).
  const uint64_t f = (uint64_t(ones) * kBernoulliTotal + bits.size() / 2) / bits.size();
  const uint32_t f1 = uint32_t(std::clamp<uint64_t>(f, 1, kBernoulliTotal - 1));
  const uint32_t f0 = kBernoulliTotal - f1;
  w.put_u32(f1);
  RansWriter rw(bits.size() / 64 + 16);
  for (size_t i = bits.size(); i-- > 0;) {
    if (bits[i])
      rw.put(f0, f1, kBernoulliPrecision);
    else
      rw.put(0, f0, kBernoulliPrecision);
  }
  rw.finish(w);
  return w.take();
}

StatusOr<std::vector<uint8_t>> decode_bernoulli(ByteSpan stream, size_t expected_n) {
  ByteReader r(stream, "bernoulli stream");
  uint64_t n = 0;
  CRPGS_RETURN_IF_ERROR(r.read_varint(&n));
  if (n != expected_n)
    return r.error("holds " + std::to_string(n) + " bits, caller expects " +
                   std::to_string(expected_n));
  if (n == 0) {
    if (!r.at_end()) return r.error("trailing bytes after an empty bit vector");
    return std::vector<uint8_t>();
  }
  uint32_t f1 = 0;
  CRPGS_RETURN_IF_ERROR(r.read_u32(&f1));
  if (f1 == 0 || f1 >= kBernoulliTotal)
    return r.error("probability count " + std::to_string(f1) + " out of range");
  const uint32_t f0 = kBernoulliTotal - f1;
  RansReader rr;
  CRPGS_RETURN_IF_ERROR(rr.init(r.rest()));
  const size_t words = (r.remaining() - 8) / 4;
  const uint64_t most = max_bernoulli_bits(f1, words);
  if (n > most)
    return r.error("claims " + std::to_string(n) + " bits, but " + std::to_string(r.remaining()) +
                   " bytes with p(1) = " + std::to_string(f1) + "/65536 code at most " +
                   std::to_string(most));
  std::vector<uint8_t> out(static_cast<size_t>(n));
  uint64_t x = rr.x;
  for (size_t i = 0; i < out.size(); ++i) {
    const uint32_t slot = uint32_t(x) & (kBernoulliTotal - 1);
    const bool one = slot >= f0;
    out[i] = one;
    x = one ? f1 * (x >> kBernoulliPrecision) + slot - f0 : f0 * (x >> kBernoulliPrecision) + slot;
    if (x < kRansL) {
      if (rr.end - rr.p >= 4) {
        x = (x << 32) | load_u32(rr.p);
        rr.p += 4;
      } else {
        rr.truncated = true;
        break;
      }
    }
  }
  rr.x = x;
  CRPGS_RETURN_IF_ERROR(rr.finish("bernoulli stream"));
  return out;
}

}  // namespace crpgs::coding
