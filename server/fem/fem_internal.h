// Library-internal entry points of hs_fem used by the body solver (dynamics.c).
#ifndef HS_FEM_INTERNAL_H
#define HS_FEM_INTERNAL_H

#include "hapsim/fem.h"

/// hs_fem_node_rotation_warm for every node, the warm polar steps four nodes at a time. rot:
/// [9n], in: this function's earlier results or zeros (a cold start), taken as rotations
/// without the orthogonality checks; out: the new rotations, bit-identical to the per-node
/// call's from such starts.
void hs_fem_node_rotations_warm(const hs_fem* fem, double* rot);

/// hs_fem_update one element at a time: the reference that the four-wide element pass of
/// hs_fem_update (linear, co-rotated with the polar rotation) must match bit for bit.
void hs_fem_update_scalar(hs_fem* fem, const double* x, hs_fem_stats* stats);

/// The element activity flags, [n_tets] (hs_fem_set_element_active).
const unsigned char* hs_fem_active_elements(const hs_fem* fem);

/// HS_OK when every connected piece of the mesh's active tets (active: [n_tets], NULL: all) has
/// three non-collinear fixed nodes (dof_map[3 i] < 0): else rigid motion is free and a static
/// problem has no unique solution; HS_ERR_INVALID then, naming a tet of the piece.
hs_status hs_check_constrained(const hs_mesh* mesh, const unsigned char* active, const int* dof_map,
                               hs_err* err);

#endif
