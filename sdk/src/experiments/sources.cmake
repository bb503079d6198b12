# Sources of sdk/src/experiments (paths relative to sdk/): metrics.json, BD-rate, sweeps, reports.
list(APPEND CRPGS_BASE_SOURCES
  src/experiments/run_metrics.cpp
  src/experiments/bd_rate.cpp
  src/experiments/sweep.cpp
  src/experiments/report.cpp)
