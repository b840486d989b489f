// SPDX-License-Identifier: GPL-2.0-or-later
// Internal to the surface module: shared between its readers and the cleaner.
#ifndef HAPSIM_SURFACE_INTERNAL_H
#define HAPSIM_SURFACE_INTERNAL_H

#include "surface.h"

/// Merge vertices with exactly equal coordinates; how many were merged, -1 on no memory.
int hs_surface_weld(hs_surface* s);

/// The triangles of a Gmsh MSH or VTU file ("msh", "vtu"); a file with tets and no triangles
/// gives its boundary.
hs_status hs_surface_parse_mesh(const char* name, const char* format, const char* data, size_t len,
                                hs_surface** out, hs_err* err);

#endif
