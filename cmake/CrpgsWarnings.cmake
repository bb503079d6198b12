# Warnings are errors in our own code; third-party headers come in as system headers.
function(crpgs_set_warnings target)
  target_compile_options(${target} PRIVATE
    $<$<COMPILE_LANGUAGE:CXX>:-Wall -Wextra -Wpedantic -Werror -Wno-unused-parameter>)
endfunction()
