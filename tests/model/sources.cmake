# Test sources of tests/model (paths relative to tests/).
list(APPEND CRPGS_TORCH_TEST_SOURCES model/test_anchor_model.cpp model/test_rate_model.cpp)
