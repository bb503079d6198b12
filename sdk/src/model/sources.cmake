# Sources of sdk/src/model (paths relative to sdk/).
