# Sources of sdk/src/train (paths relative to sdk/).
list(APPEND CRPGS_BASE_SOURCES src/train/sections.cpp)
