# Test sources of tests/abi (paths relative to tests/).
list(APPEND CRPGS_BASE_TEST_SOURCES abi/test_plugin_loading.cpp)
