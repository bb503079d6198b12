# `crpgs export` checked by PlayCanvas splat-transform (npm): reads the .ply, converts it to .spz
# and .sog and back with the same Gaussian count. Installs the package once into the build dir;
# skips (exit 77, a visible SKIP line) without node/npm or a reachable registry. Needs the CLI.
if(TARGET crpgs_cli)
  add_test(NAME io.splat_transform
    COMMAND ${CMAKE_CURRENT_SOURCE_DIR}/io/splat_transform_test.sh ${PROJECT_BINARY_DIR}
            $<TARGET_FILE:crpgs_cli>)
  set_tests_properties(io.splat_transform PROPERTIES SKIP_RETURN_CODE 77 TIMEOUT 600)
endif()
