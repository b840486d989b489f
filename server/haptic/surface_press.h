// SPDX-License-Identifier: GPL-2.0-or-later
// hapsim surface press: the static equilibrium of a body pressed by a frictionless rigid sphere,
// with contact on the boundary SURFACE (triangles, not only nodes), as a reference for the
// running server's force.
//
// DESIGN. An active-set fixed point between exact static solves and the surface contact
// problem (hs_contact_solve): the body is solved to equilibrium under the current contact
// forces (hs_body_solve_static, warm-started), the contact points and push directions are taken
// on that deformed surface, the gaps from where the surface would be without the forces
// (through the rotated rest compliance, which only sets the convergence rate), and the forces
// found again, relaxed, until they repeat. At the fixed point the exactly solved body touches
// the sphere at every pushing point and nowhere penetrates it, which is checked on the final
// surface. The sphere comes in along a path in increments. Not for the rt path: allocates.
#ifndef HAPSIM_SURFACE_PRESS_H
#define HAPSIM_SURFACE_PRESS_H

#include "base.h"
#include "body.h"
#include "mesh.h"

#ifdef __cplusplus
extern "C" {
#endif

/// What a surface press reports.
typedef struct hs_surface_press_stats {
    double force_n[3];    ///< force ON THE TOOL at the final centre, N
    double change;        ///< last relative change of the tool force between iterations
    double penetration_m; ///< deepest point of the final surface inside the sphere, m
    int iterations;       ///< fixed-point iterations over all increments
    int contact_nodes;    ///< nodes carrying contact force at the end
    double wall_ms;       ///< wall time, ms
} hs_surface_press_stats;

/// Press the body (mesh, def, fixed as hs_body_create; gravity and loads of def apply) with a
/// sphere of radius_m moved from `from` (clear of the surface) to `to` in `increments` equal
/// steps. Converged when the tool force changes by less than tol (relative) between iterations
/// and the final surface is outside the sphere within 1e-3 r. HS_ERR_NOT_CONVERGED (stats
/// filled) otherwise; HS_ERR_INVALID when nothing touches at `to`.
/// Thread: any | Allocates: yes
hs_status hs_surface_press(const hs_mesh* mesh, const hs_body_def* def, const unsigned char* fixed,
                           double radius_m, const double from[3], const double to[3],
                           int increments, double tol, hs_surface_press_stats* stats /* OUT */,
                           hs_err* err);

#ifdef __cplusplus
}
#endif

#endif
