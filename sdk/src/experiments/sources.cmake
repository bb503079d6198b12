# Sources of sdk/src/experiments (paths relative to sdk/).
# The run record (metrics.json) is the SDK's: the pipeline writes it, so it is in crpgs_base.
list(APPEND CRPGS_BASE_SOURCES
  src/experiments/run_metrics.cpp)
# The experiment tooling over those records (BD-rate, sweeps with Slurm, reports with plots) is
# its own library, crpgs_experiments, above crpgs_base: the core does not use it.
list(APPEND CRPGS_EXPERIMENTS_SOURCES
  src/experiments/bd_rate.cpp
  src/experiments/sweep.cpp
  src/experiments/report.cpp)
