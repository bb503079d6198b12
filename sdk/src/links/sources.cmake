# Link strategies' shared algorithms (candidate retrieval, greedy matching).
list(APPEND CRPGS_TORCH_SOURCES src/links/links.cpp)
