# Sources of sdk/src/io (paths relative to sdk/).
