# Test sources of tests/experiments (paths relative to tests/).
list(APPEND CRPGS_BASE_TEST_SOURCES
  experiments/test_bd_rate.cpp
  experiments/test_run_metrics.cpp
  experiments/test_sweep.cpp
  experiments/test_report.cpp)
# test_sweep runs `crpgs sweep --status` (it skips, saying why, when the executable is absent).
if(TARGET crpgs_cli)
  set_property(SOURCE experiments/test_sweep.cpp APPEND PROPERTY COMPILE_DEFINITIONS
    CRPGS_CLI_PATH="$<TARGET_FILE:crpgs_cli>")
endif()
