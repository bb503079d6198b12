# Test sources of tests/raster (paths relative to tests/).
