# Sources of sdk/src/model (paths relative to sdk/).
list(APPEND CRPGS_TORCH_SOURCES
  src/model/anchor_model.cpp   # anchors, MLPs, growing/pruning, Adam with per-row state
  src/model/sorted_gather.cpp) # row gathers with a parallel backward
