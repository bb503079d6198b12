# Sources of sdk/src/train (paths relative to sdk/).
