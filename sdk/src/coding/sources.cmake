# Sources of sdk/src/coding (paths relative to sdk/).
list(APPEND CRPGS_BASE_SOURCES
  src/coding/bitstream.cpp     # ByteWriter/ByteReader, CRC32, .crpgs container
  src/coding/range_coder.cpp   # rANS over CDF tables, escapes, chunking, Bernoulli
  src/coding/geometry.cpp      # Draco anchor voxels, Morton order, raw16 fallback
  src/coding/bit_packing.cpp   # fixed-width packing, COHS link vector
)
