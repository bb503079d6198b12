# Test sources of tests/train (paths relative to tests/).
list(APPEND CRPGS_TORCH_TEST_SOURCES train/test_trainer.cpp train/test_rate_training.cpp
  train/test_links_training.cpp train/test_kill_resume.cpp)
# test_kill_resume runs `crpgs train` in processes it kills (it skips, saying why, when the
# executable is absent).
if(TARGET crpgs_cli)
  set_property(SOURCE train/test_kill_resume.cpp APPEND PROPERTY COMPILE_DEFINITIONS
    CRPGS_CLI_PATH="$<TARGET_FILE:crpgs_cli>")
endif()
