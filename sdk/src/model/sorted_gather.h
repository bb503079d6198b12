/// @file sorted_gather.h
/// @brief Row gathers by a non-decreasing index (what nonzero() gives), with a cheaper backward.
#pragma once

#include <torch/types.h>

namespace crpgs {

/// src.index_select(0, index) for a 1-D non-decreasing `index` into src's rows. The backward
/// writes each source row once, summing its contiguous run of gradient rows in index order, in
/// parallel over source rows; index_select's backward zero-fills the source and then adds row
/// by row on one thread. Same values bit for bit. Where it records a gradient it throws on a
/// negative, decreasing or out-of-range index.
torch::Tensor gather_sorted_rows(const torch::Tensor& src, const torch::Tensor& index);

}  // namespace crpgs
