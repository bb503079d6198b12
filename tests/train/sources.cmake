# Test sources of tests/train (paths relative to tests/).
list(APPEND CRPGS_TORCH_TEST_SOURCES train/test_trainer.cpp train/test_rate_training.cpp
  train/test_links_training.cpp)
