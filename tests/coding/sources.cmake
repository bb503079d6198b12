# Test sources of tests/coding (paths relative to tests/).
list(APPEND CRPGS_BASE_TEST_SOURCES
  coding/test_bitstream.cpp
  coding/test_range_coder.cpp
  coding/test_geometry.cpp
  coding/test_bit_packing.cpp
)
