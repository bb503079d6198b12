# Sources of sdk/src/core (paths relative to sdk/).
