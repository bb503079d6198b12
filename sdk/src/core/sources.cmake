# Sources of sdk/src/core (paths relative to sdk/).
list(APPEND CRPGS_BASE_SOURCES
  src/core/status.cpp
  src/core/schema.cpp
  src/core/config.cpp
  src/core/registry.cpp
  src/core/atomic_file.cpp
  src/core/dir_lock.cpp)
list(APPEND CRPGS_TORCH_SOURCES
  src/core/components.cpp
  src/core/runtime.cpp)        # thread pools (torch + OpenBLAS), allocator
