list(APPEND CRPGS_TORCH_TEST_SOURCES codec/test_codec.cpp codec/test_portable_math.cpp codec/test_decode_cli.cpp)
# test_decode_cli runs `crpgs decode` / `crpgs render` in fresh processes (it skips, saying why,
# when the executable is absent).
if(TARGET crpgs_cli)
  set_property(SOURCE codec/test_decode_cli.cpp APPEND PROPERTY COMPILE_DEFINITIONS
    CRPGS_CLI_PATH="$<TARGET_FILE:crpgs_cli>")
endif()
