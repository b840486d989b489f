// Library-internal entry points of hs_fem used by the body solver (dynamics.c).
#ifndef HS_FEM_INTERNAL_H
#define HS_FEM_INTERNAL_H

#include "hapsim/fem.h"

/// hs_fem_node_rotation_warm for every node (rot: [9n], previous rotations in, new out), with
/// bit-identical results; the warm polar steps run four nodes at a time.
void hs_fem_node_rotations_warm(const hs_fem* fem, double* rot);

/// hs_fem_update one element at a time: the reference that the four-wide element pass of
/// hs_fem_update (linear, co-rotated with the polar rotation) must match bit for bit.
void hs_fem_update_scalar(hs_fem* fem, const double* x, hs_fem_stats* stats);

#endif
