# Sources of sdk/src/raster (paths relative to sdk/).
