list(APPEND CRPGS_TORCH_TEST_SOURCES codec/test_codec.cpp)
