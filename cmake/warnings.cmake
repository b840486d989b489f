# SPDX-License-Identifier: GPL-2.0-or-later
# Per-target warnings (no global CMAKE_C_FLAGS).
function(hs_set_warnings target)
  target_compile_options(${target} PRIVATE -Wall -Wextra -Wpedantic -Wmissing-prototypes
    -Wstrict-prototypes -Wshadow -Wpointer-arith -Wcast-qual -Wformat=2 -Wvla
    -ffp-contract=off)
  if(HS_WARNINGS_AS_ERRORS)
    target_compile_options(${target} PRIVATE -Werror)
  endif()
endfunction()
