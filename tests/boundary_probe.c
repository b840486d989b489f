// SPDX-License-Identifier: GPL-2.0-or-later
// Compiled with hs_fem's flags it builds; with hs_rt's it must not (ctest deps_rt_no_fem):
// a module sees another's header only by linking it, and rt links base alone.
#include "fem.h"

/// Anything from fem.h, so the include is used.
int hs_boundary_probe(void);
int hs_boundary_probe(void) {
    return (int)sizeof(hs_material);
}
