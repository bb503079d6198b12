# Compile options of hash_grid_kernels.cpp, wherever it is compiled (both grid plugins, the tests,
# the bench). No contraction: kernel, reference and every ISA clone round identically. No FP
# traps: the per-lane selects of the corner blocks if-convert, so they vectorise.
set(CRPGS_HASH_GRID_KERNEL_OPTIONS "-ffp-contract=off;-fno-trapping-math")
