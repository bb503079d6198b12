# Warnings are errors in our own code; third-party headers come in as system headers.
# CRPGS_WARNINGS_AS_ERRORS=OFF keeps them warnings, for building with another compiler or
# libtorch than CI's (e.g. PyTorch's on a GPU machine: scripts/cuda-check FULL=1).
option(CRPGS_WARNINGS_AS_ERRORS "Treat warnings in crpgs' own code as errors" ON)
function(crpgs_set_warnings target)
  target_compile_options(${target} PRIVATE
    $<$<COMPILE_LANGUAGE:CXX>:-Wall -Wextra -Wpedantic -Wno-unused-parameter>
    $<$<AND:$<COMPILE_LANGUAGE:CXX>,$<BOOL:${CRPGS_WARNINGS_AS_ERRORS}>>:-Werror>)
endfunction()

# libtorch's headers as system headers where they are not under a system include directory
# (PyTorch's libtorch): their warnings are not ours.
function(crpgs_torch_headers_as_system)
  get_target_property(_inc torch INTERFACE_INCLUDE_DIRECTORIES)
  if(_inc)
    set_property(TARGET torch APPEND PROPERTY INTERFACE_SYSTEM_INCLUDE_DIRECTORIES ${_inc})
  endif()
endfunction()
