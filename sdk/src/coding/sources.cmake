# Sources of sdk/src/coding (paths relative to sdk/).
