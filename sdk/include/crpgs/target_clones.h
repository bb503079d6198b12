/// @file target_clones.h
/// @brief CRPGS_TARGET_CLONES: a hot loop compiled for x86-64-v4, x86-64-v3 and baseline
/// x86-64, picked at load time for the machine (GCC ifunc). Use it only in translation units
/// without the precompiled header (its saved options would apply to every clone), built with
/// -ffp-contract=off where clones must round alike.
#pragma once

#if defined(__GNUC__) && !defined(__clang__) && defined(__x86_64__) && defined(__ELF__)
#define CRPGS_TARGET_CLONES \
  __attribute__((target_clones("arch=x86-64-v4", "arch=x86-64-v3", "default")))
#else
#define CRPGS_TARGET_CLONES
#endif
