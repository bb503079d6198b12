# Test sources of tests/experiments (paths relative to tests/).
list(APPEND CRPGS_BASE_TEST_SOURCES
  experiments/test_bd_rate.cpp
  experiments/test_run_metrics.cpp
  experiments/test_sweep.cpp
  experiments/test_report.cpp)
