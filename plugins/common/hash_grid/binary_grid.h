/// @file binary_grid.h
/// @brief HAC's binary hash grid as a trainable table (docs/method.md §2.1, §2.5), shared by the
/// `hash_grid` context plugin and the `sfa` feature plugin: its configuration keys, the
/// autograd lookup, the rate estimate B_h and the table's coding in a component state.
#pragma once

#include <array>
#include <cstdint>
#include <string>
#include <vector>

#include <torch/types.h>
#include <yaml-cpp/yaml.h>

#include "crpgs/coding/bitstream.h"
#include "crpgs/status.h"
#include "hash_grid_kernels.h"

namespace crpgs::hash_grid {

/// Schema lines (YAML list items) of the grid's geometry keys: n_levels, resolutions,
/// log2_hashmap_size, n_levels_2d, resolutions_2d, log2_hashmap_size_2d, n_features_per_level.
/// HAC's configuration is the default.
const std::string& grid_schema_yaml();
/// Schema line of the `binarize` key (default true).
const std::string& binarize_schema_yaml();

/// The grid's configuration as read from a resolved block holding the keys above.
struct GridConfig {
  std::vector<int64_t> res3, res2;
  int log2_3 = 13, log2_2 = 15;
  int64_t features = 4;
  bool binarize = true;

  /// Throws std::invalid_argument (prefixed with `who`) when a level count differs from its
  /// resolution list, or when there are no levels.
  static GridConfig from_yaml(const YAML::Node& c, const std::string& who);
  /// Writes the geometry keys (not `binarize`) in schema order.
  void write_yaml(YAML::Node& n) const;
  GridSpec spec() const { return make_grid_spec(res3, log2_3, res2, log2_2, features); }
};

/// A fresh table [n_entries, n_features], U(-1e-4, 1e-4) (HAC's init), requiring grad.
torch::Tensor init_table(const GridSpec& spec, bool cuda);

/// Output [N, output_dim] of positions01 [N, 3] (converted to the table's device and dtype):
/// the CPU kernels under a custom autograd function, the ATen reference elsewhere. Gradient
/// w.r.t. the table only (straight-through when binarize). `spec` must outlive the backward.
torch::Tensor grid_lookup(const GridSpec& spec, const torch::Tensor& positions01,
                          const torch::Tensor& table, bool binarize);

/// HAC's B_h = n₊(−log2 p) + n₋(−log2(1−p)) + 32, p = n₊/n clamped to [1e-6, 1−1e-6], over the
/// whole table, differentiable through the straight-through estimator (a scalar). A float
/// table (binarize false) counts 32 bits per value, with no gradient.
/// On CPU, a fused autograd function of two passes over the table.
torch::Tensor table_bits(const torch::Tensor& table, bool binarize);
/// The binarised B_h as an ATen expression, differentiated by autograd: the definition the fused
/// CPU function is tested against, and the path for tables on other devices.
torch::Tensor table_bits_reference(const torch::Tensor& table);

/// Binary: `varint L | L bytes encode_bernoulli(bit = value >= 0)` in row-major order; float:
/// numel float32. Throws (TORCH_CHECK) only if the bit coder fails, which it cannot for 0/1.
void write_table(coding::ByteWriter& w, const torch::Tensor& table, bool binarize);
/// Inverse of write_table for a table of the given size: a CPU float tensor holding ±1 (binary)
/// or the stored values. Refuses truncation and malformed bit streams.
Status read_table(coding::ByteReader& r, int64_t n_entries, int64_t n_features, bool binarize,
                  torch::Tensor* out);

/// Tensors as float32, row-major, one after the other (the MLPs of the grid plugins' states).
void write_f32_tensors(coding::ByteWriter& w, const std::vector<torch::Tensor>& tensors);
/// Reads tensors shaped like `like` into CPU float tensors; "truncated <what>" when short.
Status read_f32_tensors(coding::ByteReader& r, const std::vector<torch::Tensor>& like,
                        const std::string& what, std::vector<torch::Tensor>* out);

/// The header of a grid component's state: what it is, how it was configured.
struct StateHeader {
  std::array<uint8_t, 4> magic;
  uint16_t version = 1;
  bool binarize = true;
  std::vector<uint64_t> dims;          ///< the component's dimensions, in order
  std::vector<const char*> dim_names;  ///< named in the error when one differs
  const char* what = "grid";           ///< e.g. "hash_grid", for "bad magic (not a ... state)"
};
/// `magic | u16 version | u8 binarize | varint dims...`.
void write_state_header(coding::ByteWriter& w, const StateHeader& h);
/// Reads and checks a header against the configured one: bad magic, another version
/// (kUnsupportedVersion), binary/float mismatch or a differing dimension is refused by name.
Status read_state_header(coding::ByteReader& r, const StateHeader& expected);

}  // namespace crpgs::hash_grid
