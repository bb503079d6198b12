# Sources of sdk/src/codec (paths relative to sdk/): entropy parameters, model encode/decode.
list(APPEND CRPGS_TORCH_SOURCES
  src/codec/entropy_params.cpp
  src/codec/codec.cpp
  src/codec/link_report.cpp)
