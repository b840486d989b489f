// Library-internal entry points of hs_fem used by the body solver (dynamics.c).
#ifndef HS_FEM_INTERNAL_H
#define HS_FEM_INTERNAL_H

#include "hapsim/fem.h"

/// hs_fem_node_rotation_warm for every node (rot: [9n], previous rotations in, new out), with
/// bit-identical results; the warm polar steps run four nodes at a time.
void hs_fem_node_rotations_warm(const hs_fem* fem, double* rot);

#endif
