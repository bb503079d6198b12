# Sources of sdk/src/codec (paths relative to sdk/): entropy parameters, model encode/decode.
list(APPEND CRPGS_TORCH_SOURCES
  src/codec/entropy_params.cpp
  src/codec/codec.cpp
  src/codec/link_report.cpp
  src/codec/portable_kernels.cpp)
# Portable arithmetic: no contraction in any target_clones clone, so no precompiled header.
set_source_files_properties(src/codec/portable_kernels.cpp PROPERTIES
  COMPILE_OPTIONS "-ffp-contract=off;-Wno-psabi" SKIP_PRECOMPILE_HEADERS ON)
