# Tests of the link algorithms and link plugins.
list(APPEND CRPGS_TORCH_TEST_SOURCES links/test_links.cpp)
