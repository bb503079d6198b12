/// @file shared_prefix.h
/// @brief Which runs may share the start of their training (no torch: the sweep uses it too).
#pragma once

#include <string>

#include "crpgs/config.h"

namespace crpgs {

/// Up to and including iteration schedule.rate_start nothing reads the rate weights
/// (rate.lambda, rate.mask_lambda: the rate and mask terms start after it, docs/method.md §2.3), so
/// runs whose resolved configs differ only there train identically until then (bit for bit on
/// one build, thread count and BLAS kernel set) and can share that prefix: for an RD sweep a third
/// of HAC's 30k iterations. Thread counts (train.threads, rasterizer.threads) are blanked too:
/// like the BLAS kernels they change only the last bits, and a run that starts from a prefix
/// trained on others says so (Trainer::state_origin_differences). train.device is part of the
/// key (a GPU's sums run in other orders), but its default, cpu, is left out, so that CPU runs
/// keep the keys they had before the key existed. Returns the FNV-1a 64 of the
/// config with those keys blanked, as 16 hex digits; "" for a config without the rate path (no
/// `context` section).
std::string shared_prefix_key(const Config& resolved);

/// Where the prefix of `key` is published in the prefix directory `dir`.
std::string shared_prefix_path(const std::string& dir, const std::string& key);

}  // namespace crpgs
