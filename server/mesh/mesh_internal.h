// Internal to hs_mesh: shared between the readers and the mesh core.
#ifndef HAPSIM_MESH_INTERNAL_H
#define HAPSIM_MESH_INTERNAL_H

#include "hapsim/mesh.h"

/// Largest node or tet count accepted: keeps every derived count (12 per tet) inside an int.
#define HS_MESH_MAX_COUNT (0x7fffffff / 16)

/// Wrap arrays into a new mesh, taking ownership of x0 and tets (released on failure too),
/// then finalize. `skipped` goes to report.skipped_elements. Rejects a mesh without tets.
hs_status hs_mesh_adopt(int n_nodes, double* x0, int n_tets, int* tets, int skipped, hs_mesh** out,
                        hs_err* err);

#endif
