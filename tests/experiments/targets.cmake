# `crpgs sweep --slurm` against a single-node Slurm started by the script (skips, exit 77, when
# slurm-wlm / munge are not installed or cannot start). Needs the crpgs executable.
if(TARGET crpgs_cli)
  add_test(NAME experiments.slurm_sweep
    COMMAND ${CMAKE_CURRENT_SOURCE_DIR}/experiments/slurm_test.sh ${PROJECT_BINARY_DIR}
            $<TARGET_FILE:crpgs_cli>)
  set_tests_properties(experiments.slurm_sweep PROPERTIES SKIP_RETURN_CODE 77 TIMEOUT 300)
endif()
