/// @file sorted_gather.h
/// @brief Row gathers by a non-decreasing index (what nonzero() gives), with a cheaper backward,
/// and the row max-pool of anchor growing.
#pragma once

#include <torch/types.h>

namespace crpgs {

/// src.index_select(0, index) for a 1-D non-decreasing `index` into src's rows. The backward
/// writes each source row once, summing its contiguous run of gradient rows in index order, in
/// parallel over source rows; index_select's backward zero-fills the source and then adds row
/// by row on one thread. Same values bit for bit. Where it records a gradient it throws on a
/// negative, decreasing or out-of-range index.
torch::Tensor gather_sorted_rows(const torch::Tensor& src, const torch::Tensor& index);

/// out [rows, D]: out[c] = the element-wise max of src's rows r with cell[r] = c (src [S, D]
/// float, cell [S] long in [0, rows)); -inf in a row no r maps to. No gradient.
torch::Tensor max_rows_into(const torch::Tensor& src, const torch::Tensor& cell, int64_t rows);
/// The same as one scatter_reduce (the path off the CPU).
torch::Tensor max_rows_into_reference(const torch::Tensor& src, const torch::Tensor& cell,
                                      int64_t rows);

}  // namespace crpgs
