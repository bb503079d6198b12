/// @file range_coder.h
/// @brief Table-driven entropy coder (CompressAI style): each symbol carries an index into a set
/// of integer CDF tables; values outside a table's range are escape-coded, never lost.
///
/// The coder is rANS with a 64-bit state and 32-bit renormalisation words (state kept in
/// [2^31, 2^63)): one multiply, a table lookup and at most one 4-byte read per decoded symbol,
/// integer-only, so encoder and decoder are bit-exact on every machine. rANS encodes in reverse;
/// the encoder buffers words and writes them in decoding order. A stream is
///   u64 final encoder state | u32 words...
/// and the decoder checks at the end that the state is back at its initial value and that every
/// word was consumed, which catches most corruption on top of the container's CRC. (Escape
/// bypass bits carry no redundancy: a flipped bypass bit changes that value undetected; the
/// container's CRC is the integrity check.)
///
/// Tables: a table with n in-range symbols has n + 2 CDF entries; symbol i (value offset + i)
/// has frequency cdf[i+1] - cdf[i] >= 1, and symbol n is the escape. A value v outside
/// [offset, offset + n) is coded as the escape, then in bypass bits: u = 2(-s) - 1 for
/// s = v - offset < 0, u = 2(s - n) for s >= n; g = u + 1 is written Elias-gamma style as its
/// bit length minus one in 6 bits, then its lower bits in 16-bit groups (low group first).
/// Any int32 value round-trips.
///
/// Failure behaviour: encoding refuses (kInvalidArgument) a table index out of range or a size
/// mismatch. Decoding a corrupt or truncated stream returns kCorruptBitstream; it never reads
/// out of bounds, never loops more than the symbol count, and sizes every allocation from the
/// caller's symbol count or from counts checked against the bytes left.
#pragma once

#include <cstddef>
#include <cstdint>
#include <vector>

#include "crpgs/coding/bitstream.h"
#include "crpgs/status.h"

namespace crpgs::coding {

inline constexpr int kDefaultPrecision = 16;
inline constexpr int kMinPrecision = 12;
inline constexpr int kMaxPrecision = 24;
inline constexpr uint32_t kDefaultChunkSize = 10000;  ///< symbols per chunk, as HAC

/// Integer frequencies from float probabilities: every symbol gets at least one count and the
/// counts sum to exactly 2^precision. Counts are 1 + floor(share of the remaining 2^p - n) with
/// the leftover given to the largest fractional parts (ties to the lower index), so the result
/// depends only on the input doubles. Returns the CDF (n + 1 entries, cdf[0] = 0,
/// cdf[n] = 2^precision). Refuses (kInvalidArgument) an empty pmf, a negative or non-finite
/// entry, an all-zero pmf, more than 2^precision symbols, or a precision outside
/// [kMinPrecision, kMaxPrecision].
StatusOr<std::vector<uint32_t>> quantize_pmf(const std::vector<double>& pmf,
                                             int precision = kDefaultPrecision);

/// Checks an integer CDF: at least 2 entries, cdf[0] = 0, strictly increasing (every symbol has
/// a count), last entry exactly 2^precision. kInvalidArgument naming the first bad entry.
Status validate_cdf(const std::vector<uint32_t>& cdf, int precision = kDefaultPrecision);

/// One coding table: in-range values offset .. offset + n - 1 plus the escape symbol.
struct CdfTable {
  int32_t offset = 0;
  std::vector<uint32_t> cdf;  ///< n + 2 entries (n in-range symbols + escape), see above
  /// Number of in-range symbols n.
  size_t num_symbols() const { return cdf.size() < 2 ? 0 : cdf.size() - 2; }
};

/// A table for values offset .. offset + pmf.size() - 1. The escape symbol gets the mass
/// missing from pmf (1 - sum, or 0 if the pmf sums to >= 1), and like every symbol at least one
/// count; the pmf is not renormalised first, so its tail mass is what escapes cost.
StatusOr<CdfTable> make_cdf_table(const std::vector<double>& pmf, int32_t offset,
                                  int precision = kDefaultPrecision);

/// The immutable table set a stream is coded against, with the decoder's lookup structures.
/// Encoder and decoder must build it from identical integer tables.
class CdfTableSet {
 public:
  CdfTableSet() = default;
  /// Validates every table (validate_cdf, at least one in-range symbol; offset + n must fit
  /// int32) and builds the lookup. kInvalidArgument naming the table on failure.
  static StatusOr<CdfTableSet> create(std::vector<CdfTable> tables,
                                      int precision = kDefaultPrecision);

  int precision() const { return precision_; }
  size_t size() const { return tables_.size(); }
  const CdfTable& table(size_t i) const { return tables_[i]; }

  /// Internal to the coder: per table, the symbol holding the first slot of each of the
  /// 2^bucket_bits() slot buckets, then the last symbol (2^bucket_bits() + 1 entries).
  int bucket_bits() const { return bucket_bits_; }
  const uint32_t* buckets(size_t i) const {
    return buckets_.data() + i * ((size_t(1) << bucket_bits_) + 1);
  }

 private:
  int precision_ = kDefaultPrecision;
  int bucket_bits_ = 0;
  std::vector<CdfTable> tables_;
  std::vector<uint32_t> buckets_;  // [n_tables * (2^bucket_bits + 1)]
};

/// One independent rANS stream of symbols[i] coded with tables.table(indexes[i]).
StatusOr<Bytes> encode_symbols(const int32_t* symbols, const uint32_t* indexes, size_t n,
                               const CdfTableSet& tables);
StatusOr<Bytes> encode_symbols(const std::vector<int32_t>& symbols,
                               const std::vector<uint32_t>& indexes, const CdfTableSet& tables);
/// Decodes exactly n symbols into out[0..n). The whole stream must be consumed.
Status decode_symbols(ByteSpan stream, const uint32_t* indexes, size_t n, const CdfTableSet& tables,
                      int32_t* out);
StatusOr<std::vector<int32_t>> decode_symbols(ByteSpan stream, const std::vector<uint32_t>& indexes,
                                              const CdfTableSet& tables);

/// Header of a chunked stream, with views of each chunk's bytes (into the parsed buffer).
/// Layout: u8 precision | varint n_symbols | varint chunk_size | varint byte length of each of
/// the ceil(n_symbols / chunk_size) chunks | the chunks' rANS streams, concatenated.
struct ChunkedStreamInfo {
  int precision = kDefaultPrecision;
  uint64_t num_symbols = 0;
  uint32_t chunk_size = kDefaultChunkSize;
  std::vector<ByteSpan> chunks;
  /// Bytes of the header (everything before the first chunk).
  size_t header_bytes = 0;
  /// Symbols in chunk k (chunk_size, except possibly the last).
  size_t chunk_symbols(size_t k) const;
};

/// Splits the sequence into chunks of chunk_size symbols coded independently (HAC's
/// sub-streams), so they decode in parallel and any chunk decodes alone.
class ChunkedEncoder {
 public:
  /// chunk_size 0 is treated as kDefaultChunkSize.
  explicit ChunkedEncoder(uint32_t chunk_size = kDefaultChunkSize, int num_threads = 1);
  StatusOr<Bytes> encode(const std::vector<int32_t>& symbols, const std::vector<uint32_t>& indexes,
                         const CdfTableSet& tables) const;
  uint32_t chunk_size() const { return chunk_size_; }

 private:
  uint32_t chunk_size_;
  int num_threads_;
};

class ChunkedDecoder {
 public:
  /// Parses and checks the header only (chunk count and lengths against the bytes present).
  static StatusOr<ChunkedStreamInfo> parse(ByteSpan stream);
  /// Decodes all chunks with up to num_threads threads (<= 0: hardware concurrency). The result
  /// does not depend on the thread count; on failure the error of the lowest failing chunk is
  /// returned. indexes.size() must equal the stream's symbol count (else kCorruptBitstream).
  static StatusOr<std::vector<int32_t>> decode(ByteSpan stream,
                                               const std::vector<uint32_t>& indexes,
                                               const CdfTableSet& tables, int num_threads = 1);
  /// Chunk k alone; chunk_indexes holds the table indexes of that chunk's symbols only.
  static StatusOr<std::vector<int32_t>> decode_chunk(const ChunkedStreamInfo& info, size_t k,
                                                     const std::vector<uint32_t>& chunk_indexes,
                                                     const CdfTableSet& tables);
};

/// Bit vector (one 0/1 byte per bit) coded with a single global probability, as HAC codes
/// masks and binary hash-grid parameters. Layout: varint n | u32 count of ones' frequency
/// f1 in [1, 2^16 - 1] at precision 16 (p(1) = f1 / 2^16, from the empirical rate) | rANS
/// stream (absent when n = 0). Values other than 0/1 are refused (kInvalidArgument).
StatusOr<Bytes> encode_bernoulli(const std::vector<uint8_t>& bits);
/// expected_n: the bit count the caller knows from its header; a stream holding another count,
/// or more bits than its bytes can code at its probability (even a stream of only the likelier
/// bit costs at least -log2(max(f1, 2^16 - f1) / 2^16) bits of rANS state per bit), is refused
/// (kCorruptBitstream) before anything is allocated.
StatusOr<std::vector<uint8_t>> decode_bernoulli(ByteSpan stream, size_t expected_n);

}  // namespace crpgs::coding
