// SPDX-License-Identifier: GPL-2.0-or-later
// Library-internal entry points of hs_fem used by the body solver (dynamics.c).
#ifndef HS_FEM_INTERNAL_H
#define HS_FEM_INTERNAL_H

#include "fem.h"

/// The warped solver's rotation of a node at the last update (row-major; r: in the previous
/// one, out the new one). Co-rotated: the chordal mean of its active tets' rotations (their
/// quaternions, weighted by rest volume times 4 cos(angle / 2), summed, normalised); where that
/// mean turns by more than 90 degrees, or for StVK, hs_fem_node_rotation_warm from r (the polar
/// part of the mean deformation gradient). Linear: identity.
void hs_fem_tangent_rotation(const hs_fem* fem, int node, double r[9]);
/// hs_fem_tangent_rotation for every node, bit-identical, from the quaternion sums the update
/// made (four nodes at a time) unless elements changed since. rot: [9n], in/out.
void hs_fem_tangent_rotations(const hs_fem* fem, double* rot);

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
