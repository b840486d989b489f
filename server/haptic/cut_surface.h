// SPDX-License-Identifier: GPL-2.0-or-later
// The boundary of a mesh's live tets, followed removal by removal (cutting): the surface the
// probe touches and the compliance's contactable nodes, without rebuilding a live mesh.
#ifndef HS_HAPTIC_CUT_SURFACE_H
#define HS_HAPTIC_CUT_SURFACE_H

#include "mesh.h"

typedef struct hs_cut_surface hs_cut_surface;

/// The boundary of every tet of mesh (kept by the caller; its x0 may change, its tets not).
/// Allocates: yes. @param out OUT
hs_status hs_cut_surface_create(const hs_mesh* mesh, hs_cut_surface** out);
/// Release; accepts NULL, sets *s = NULL.
void hs_cut_surface_destroy(hs_cut_surface** s);
/// Tets gone[n] leave (indices into mesh->tets; one already gone is skipped): their boundary
/// faces go, their faces shared with a live tet join, oriented outward of it (at the rest
/// positions now). Allocates: no.
void hs_cut_surface_remove(hs_cut_surface* s, int n, const int* gone);
/// The surface as a mesh view: n_nodes, x0 (the mesh's), tris, n_tris, surf_nodes (ascending),
/// n_surf_nodes, node_surf; no tets or other derived data. Valid until the next remove.
const hs_mesh* hs_cut_surface_mesh(const hs_cut_surface* s);

#endif
