// SPDX-License-Identifier: GPL-2.0-or-later
// Internal to hs_mesh: shared between the readers and the mesh core.
#ifndef HAPSIM_MESH_INTERNAL_H
#define HAPSIM_MESH_INTERNAL_H

#include "mesh.h"

/// Largest node or tet count accepted: keeps every derived count (12 per tet) inside an int.
#define HS_MESH_MAX_COUNT (0x7fffffff / 16)

/// What a failed finalize found wrong, in the input's terms, so a reader can name file lines.
typedef struct hs_mesh_fault {
    int tet[2];    ///< input tets (0-based, before any was removed) sharing the face; -1: none
    int node[3];   ///< that face's nodes; -1: none
    int n_sharing; ///< tets on the face: 2 = they overlap, > 2 = not a volume mesh; 0: none
} hs_mesh_fault;

/// Wrap arrays into a new mesh, taking ownership of x0 and tets (released on failure too),
/// then finalize. `skipped` goes to report.skipped_elements. Rejects a mesh without tets.
/// fault (may be NULL) is filled on a face error.
hs_status hs_mesh_adopt(int n_nodes, double* x0, int n_tets, int* tets, int skipped, hs_mesh** out,
                        hs_mesh_fault* fault, hs_err* err);

#endif
