# Test sources of tests/cli (paths relative to tests/): CLI pieces that need no torch, compiled in.
list(APPEND CRPGS_BASE_TEST_SOURCES cli/test_progress_bar.cpp ../apps/progress_bar.cpp)
