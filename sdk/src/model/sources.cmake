# Sources of sdk/src/model (paths relative to sdk/).
list(APPEND CRPGS_TORCH_SOURCES
  src/model/adam_kernel.cpp    # Adam's element loop (no libtorch header)
  src/model/anchor_model.cpp   # anchors, MLPs, growing/pruning, Adam with per-row state
  src/model/chunked_mlp.cpp    # the MLPs over row chunks in parallel
  src/model/sparse_head_kernels.cpp  # per-Gaussian output layer (no libtorch header)
  src/model/sorted_gather.cpp) # row gathers with a parallel backward
# errno-free sqrt lets Adam's loop vectorise; no libtorch header, so no precompiled one.
set_source_files_properties(src/model/adam_kernel.cpp PROPERTIES
  COMPILE_OPTIONS "-fno-math-errno" SKIP_PRECOMPILE_HEADERS ON)
# Runtime ISA dispatch (target_clones) in a TU without the precompiled header, whose saved
# options would apply to every clone.
set_source_files_properties(src/model/sparse_head_kernels.cpp PROPERTIES
  SKIP_PRECOMPILE_HEADERS ON COMPILE_OPTIONS "-Wno-psabi")
