# Sources of sdk/src/model (paths relative to sdk/).
list(APPEND CRPGS_TORCH_SOURCES
  src/model/adam_kernel.cpp    # Adam's element loop (no libtorch header)
  src/model/anchor_model.cpp   # anchors, MLPs, growing/pruning, Adam with per-row state
  src/model/chunked_mlp.cpp    # the MLPs over row chunks in parallel
  src/model/sorted_gather.cpp) # row gathers with a parallel backward
# errno-free sqrt lets Adam's loop vectorise; no libtorch header, so no precompiled one.
set_source_files_properties(src/model/adam_kernel.cpp PROPERTIES
  COMPILE_OPTIONS "-fno-math-errno" SKIP_PRECOMPILE_HEADERS ON)
