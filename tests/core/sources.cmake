# Test sources of tests/core (paths relative to tests/).
list(APPEND CRPGS_BASE_TEST_SOURCES core/test_config.cpp core/test_dir_lock.cpp
     core/test_size_text.cpp)
list(APPEND CRPGS_TORCH_TEST_SOURCES core/test_conformance.cpp core/test_runtime.cpp
     core/seed_every_test.cpp)
