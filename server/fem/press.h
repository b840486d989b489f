// SPDX-License-Identifier: GPL-2.0-or-later
// hapsim press: static equilibrium of a body pressed by a frictionless rigid sphere, the
// reference the haptic contact is judged against (hapsim-solve --probe, hapsim-bench organs).
//
// Contact is node-to-sphere: every free boundary-surface node stays on or outside the sphere;
// the surface between nodes may dip into it (a mesh whose surface edges are larger than the
// radius is resolved only as finely as its nodes). Frictionless: a node in contact is pushed
// along the sphere normal (away from the centre) and slides freely along the sphere.
//
// Method: active set around Newton (SQP). With the active nodes held on the sphere, each step
// solves the tangent system with the constraints linearised along the current normals (a stiff
// spring k n n^T per node, k = penalty_scale x the mean rest-stiffness diagonal of the free
// surface nodes) on the tangential residual; a node's push is what balances it along its
// normal. Then the node that pulls hardest is released, or every node inside is added, until
// the set is unchanged with every push >= 0 and every node within pen_tol R. The sphere reaches
// its centre in straight increments of at most max_step R from the first contact along the
// approach direction (or from its previous centre), so the surface always wraps the sphere
// from the side it came from (a sphere dropped 3 radii deep at once has no such side).
// Surface contact (def.surface): one contact point per boundary triangle, its point nearest
// the centre, pushed with max(0, lam + k g) (augmented Lagrangian, lam updated per pass) inside
// the same Newton; passes until the surface is outside the sphere to 0.1 pen_tol R.
// Pure computation: no threads, no I/O; allocates at create and at the first factorisation.
#ifndef HAPSIM_PRESS_H
#define HAPSIM_PRESS_H

#include "base.h"
#include "fem.h"
#include "mesh.h"

#ifdef __cplusplus
extern "C" {
#endif

/// Options. Initialise with hs_press_default_def().
typedef struct hs_press_def {
    hs_fem_def fem;       ///< element model and material
    double gravity[3];    ///< m/s^2
    double radius_m;      ///< sphere radius R, m (> 0)
    double tol;           ///< equilibrium: ||r|| <= tol (||f_contact|| + ||f_gravity||), free dofs
    double pen_tol;       ///< deepest node penetration allowed, relative to R
    double max_step;      ///< sphere travel per increment, in radii (0, 1]
    double penalty_scale; ///< k = penalty_scale x the mean rest-stiffness diagonal (surface)
    int max_newton;       ///< Newton iterations per active-set pass
    int max_passes;       ///< active-set passes per increment
    int surface;          ///< 1: contact on the boundary triangles (default 0: on the nodes)
    int cookie;           ///< set by hs_press_default_def
} hs_press_def;

/// Defaults: hs_fem_default_def(), no gravity, R 5 mm, tol 1e-8, pen_tol 1e-3, max_step 0.125,
/// penalty_scale 1e3, 300 Newton iterations per pass, 40 passes.
hs_press_def hs_press_default_def(void);

/// Statistics of the last hs_press_solve.
typedef struct hs_press_stats {
    double wall_ms;       ///< wall time, ms
    int increments;       ///< sphere increments
    int passes;           ///< active-set passes, all increments
    int newton;           ///< Newton iterations, all increments
    int refactors;        ///< tangent factorisations (a step that converged fast keeps it)
    int fallbacks;        ///< tangents refactored without the contact curvature (not SPD)
    int active;           ///< nodes in contact at the end
    int set_changes;      ///< nodes that entered or left between the last two passes (0)
    double residual;      ///< final ||r|| / (||f_contact|| + ||f_gravity||)
    double penetration_m; ///< deepest node penetration at the end, m (<= pen_tol R)
    double max_edge_m; ///< longest surface edge at a contact node, m (node contact: > R is coarse)
    double travel_m;   ///< sphere travel solved, m
    double force_n[3]; ///< force ON THE TOOL (minus the sum of contact forces), N
} hs_press_stats;

typedef struct hs_press hs_press;

/// A body at rest, fixed[i] != 0 fixes node i (needs three non-collinear fixed nodes per
/// connected piece). No sphere yet. The mesh must outlive it. Allocates: yes. @param out OUT
hs_status hs_press_create(const hs_mesh* mesh, const hs_press_def* def, const unsigned char* fixed,
                          hs_press** out, hs_err* err);
/// Release; accepts NULL, sets *p = NULL.
void hs_press_destroy(hs_press** p);
/// Back to rest with no sphere (the next solve approaches afresh).
void hs_press_reset(hs_press* p);
/// Move the sphere to centre_m and solve the equilibrium there. The first call after create or
/// reset brings it in along dir (unit-normalised; the direction of travel, into the tissue)
/// from where it first touches a surface node; NULL: minus the rest normal of the surface node
/// nearest the centre. Later calls move it straight from its previous centre (dir ignored).
/// HS_ERR_INVALID naming the problem when the sphere meets no surface node on its way or in
/// the end, or reaches a fixed node; HS_ERR_NOT_CONVERGED when an increment does not reach the
/// tolerances (the state is the last iterate); HS_ERR_NOT_POSDEF / HS_ERR_NUMERIC from the
/// solver. On any error the sphere counts as withdrawn (the next call approaches afresh).
hs_status hs_press_solve(hs_press* p, const double centre_m[3], const double* dir,
                         hs_press_stats* stats /* OUT, may be NULL */, hs_err* err);
/// Displacement u [3n], m, valid until the next solve or reset.
const double* hs_press_displacement(const hs_press* p);
/// Contact force ON THE TISSUE at node i, N (zero off contact).
void hs_press_contact_force(const hs_press* p, int node, double f[3] /* OUT */);
/// Reaction at fixed node i (what the support exerts on the body), N; zero at a free node.
void hs_press_reaction(const hs_press* p, int node, double f[3] /* OUT */);
/// Penalty in use, N/m.
double hs_press_penalty(const hs_press* p);

/// One-call reference for tools and tests: the force ON THE TOOL, N, of a sphere of radius
/// def->radius_m pressed from rest along dir (NULL: as hs_press_solve) to centre_m.
/// Allocates: yes (a whole hs_press).
hs_status hs_press_reference_force(const hs_mesh* mesh, const hs_press_def* def,
                                   const unsigned char* fixed, const double centre_m[3],
                                   const double* dir, double force_n[3] /* OUT */, hs_err* err);

#ifdef __cplusplus
}
#endif
#endif
