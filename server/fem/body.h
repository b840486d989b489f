// SPDX-License-Identifier: GPL-2.0-or-later
// hapsim body: a deformable body on a tet mesh with boundary conditions, time stepping and
// static equilibrium. Owns its FEM model, matrix, factorisation and solver workspaces.
// Used by one thread at a time (the deformation thread). Allocation: at create, plus the factor
// and its workspaces at the first step or solve that needs them (a first refactorisation adds a
// second buffer); after that, steps and solves allocate nothing.
#ifndef HAPSIM_BODY_H
#define HAPSIM_BODY_H

#include "base.h"
#include "fem.h"
#include "mesh.h"
#include "sparse.h"

#ifdef __cplusplus
extern "C" {
#endif

typedef enum hs_solver_kind {
    HS_SOLVER_DIRECT = 0, ///< CHOLMOD: analysis once, numeric refactor when K changes
    HS_SOLVER_PCG = 1,    ///< conjugate gradients, warm-started, preconditioner per hs_precond
    /// One solve per system with the rest-state factor rotated by the node rotations,
    /// R K0^-1 R^T (stiffness warping): the tangent is approximated, the forces are not, so
    /// equilibria are exact and a step costs about one back-solve. For the linear model it is
    /// the direct solver. See docs/fem.md "Warped solver".
    HS_SOLVER_WARPED = 2,
} hs_solver_kind;

/// Body options. Initialise with hs_body_default_def().
typedef struct hs_body_def {
    hs_fem_def fem;        ///< element model and material
    double gravity[3];     ///< m/s^2, each component within +-1e3
    double dt;             ///< time step for hs_body_step, s, in (0, 1e3]
    hs_solver_kind solver; ///< linear solver for steps and Newton iterations
    hs_precond precond;    ///< PCG only: NONE, JACOBI, FACTOR (rest-state factor) or WARPED
                           ///< (rest-state factor rotated by the node rotations)
    int pcg_max_iter;      ///< PCG iterations per solve (a small fixed count is a valid mode)
    double pcg_tol;        ///< PCG relative residual, in (0, 1)
    double static_tol;     ///< static: stop at ||r|| <= tol * ||r_first|| (paper's rule), [0, 1)
    int static_max_iter;   ///< static: Newton iteration cap per load step
    int static_load_steps; ///< static: load increments (1 = full load at once)
    /// co-rotated: the rotation tolerance (fem.polar_tol) in hs_body_step (default 1e-4; 0:
    /// fem.polar_tol); with SVD rotations, how far a kept rotation may be from F's polar factor.
    /// A step's own error (one linearised solve per step) is far larger, so the static solve's
    /// 1e-6 would only cost Newton steps per element (docs/fem.md, "The tolerance in a step").
    double step_polar_tol;
    /// Parallelism of the partial refactor after element changes (hs_body_change_elements),
    /// from the thread owner (hs_cholesky_set_partial_parallel; the body starts no thread):
    /// NULL (the default) one thread. Must outlive the body.
    const hs_parallel* factor_parallel;
    int cookie; ///< set by hs_body_default_def
} hs_body_def;

/// Defaults: hs_fem_default_def(), no gravity, dt 10 ms, direct solver, PCG warped-factor
/// preconditioner with 20 iterations and tol 1e-8 when chosen, static tol 1e-8, 100 iterations,
/// 1 load step, step polar tol 1e-4, factor threads by the processors online.
hs_body_def hs_body_default_def(void);

/// Statistics of one step or static solve.
typedef struct hs_step_stats {
    double wall_ms;        ///< wall time of the call, ms
    int iterations;        ///< Newton iterations (static) or 1 (step)
    int linear_iterations; ///< PCG iterations summed (0 for direct)
    int refactors;         ///< numeric factorisations done
    double residual;       ///< static: final ||r|| / ||r_first||; step: PCG relative
                           ///< residual (0 direct; NaN warped: not computed)
    int line_search_cuts;  ///< halvings: static line search, or the step's energy safeguard
    int exact_fallbacks;   ///< warped steps redone with the exact tangent (safeguard failed)
    hs_fem_stats fem;      ///< model statistics at the end
} hs_step_stats;

typedef struct hs_body hs_body;

/// Create a body at rest. fixed[i] != 0 fixes node i in x, y, z (eliminated from the system,
/// not penalised); its displacement is 0 until hs_body_set_prescribed. The mesh must outlive it.
/// @param out OUT
hs_status hs_body_create(const hs_mesh* mesh, const hs_body_def* def, const unsigned char* fixed,
                         hs_body** out, hs_err* err);
/// Switch the linear solver of a live body (state, forces and the model kept); the next step
/// or solve factors what the new solver needs (one refactorisation, as after a cut). Only for a
/// body created with a solver that keeps a factor (direct, warped, or PCG with the FACTOR or
/// WARPED preconditioner: its dofs are in the factor's fill order), else HS_ERR_INVALID.
/// Allocates: the PCG workspace or the node rotations on the first switch that needs them
/// (switch to each once at set-up to allocate nothing later).
hs_status hs_body_set_solver(hs_body* b, hs_solver_kind solver, hs_err* err);
/// The solver in use.
hs_solver_kind hs_body_solver(const hs_body* b);
/// Constant external force on node i, N (replaces the previous value). HS_ERR_INVALID (and
/// nothing changed) for a bad node, a non-finite component or one above 1e9 N. A node that has
/// lost its last element (hs_fem_held_nodes) takes no force while it has none.
hs_status hs_body_set_force(hs_body* b, int node, const double f[3]);
/// Remove all external nodal forces (gravity stays).
void hs_body_clear_forces(hs_body* b);
/// Scale applied to gravity and nodal forces (load stepping, ramps). Default 1.
/// HS_ERR_INVALID (nothing changed) if s is not finite.
hs_status hs_body_set_load_scale(hs_body* b, double s);
/// Prescribed displacement of a fixed node, m. HS_ERR_INVALID (nothing changed) if the node
/// is not fixed or a component is not finite or above 1e3 m.
hs_status hs_body_set_prescribed(hs_body* b, int node, const double u[3]);
/// One implicit Euler step of size def.dt:
/// (M + dt C + dt^2 K) du = dt^2 (f_ext + f_el(u)) + M du_prev, linearised once per step,
/// then halved if needed until the incremental potential decreases (no energy gain from the
/// linearisation at large dt or large rotations): at most 8 times, the last (1/256 of the step)
/// taken unchecked; the warped solver redoes a step whose first 4 trials fail with the exact
/// tangent. A failed step (error status) leaves u and v as they were.
hs_status hs_body_step(hs_body* b, hs_step_stats* stats /* OUT, may be NULL */);
/// Make the factor the next hs_body_step needs (the rest-state one for the warped solver and
/// PCG's factor preconditioners, the tangent at the current state for direct) and give its
/// wall time in *factor_ms (may be NULL; a second, numeric factorisation of the same matrix is
/// timed: the first also analyses the pattern): moves the first step's factorisation to a time
/// of the caller's choosing, and measures what a direct step's refactorisation costs. State,
/// forces and velocities are not changed.
hs_status hs_body_prepare_step(hs_body* b, double* factor_ms /* OUT, may be NULL */);
/// Static equilibrium f_el(u) + f_ext = 0 by Newton (co-rotated: its fixed-rotation tangent),
/// with backtracking line search and def.static_load_steps increments. Velocities are reset.
/// An error status (a factorisation failed, NaN/Inf) leaves u and v as they were;
/// HS_WARN_NOT_CONVERGED leaves u at the last iterate, the best the solve found.
hs_status hs_body_solve_static(hs_body* b, hs_step_stats* stats /* OUT, may be NULL */);
/// Whether the static problem has a unique solution: every connected piece of the active
/// elements holds three non-collinear fixed nodes. Else HS_ERR_INVALID, naming a tet of the
/// free piece in err (may be NULL); hs_body_solve_static then refuses with that status.
hs_status hs_body_check_static(const hs_body* b, hs_err* err);
/// Back to rest: u = 0, velocity 0, rotations identity: from here it steps as a new body
/// (forces and prescribed values kept).
void hs_body_reset(hs_body* b);
/// Displacement u, m, [3n], valid until the next step/solve/reset.
const double* hs_body_displacement(const hs_body* b);
/// Overwrite the state (u [3n], velocity v [3n] or NULL for zero). Prescribed dofs keep theirs.
/// HS_ERR_INVALID (nothing changed) if a free dof's u is not finite or above 1e3 m, or its v
/// is not finite.
hs_status hs_body_set_state(hs_body* b, const double* u, const double* v);
/// Velocity, m/s, [3n] (du/dt of the last step).
const double* hs_body_velocity(const hs_body* b);
/// Kinetic energy 1/2 v^T M v, J.
double hs_body_kinetic_energy(const hs_body* b);
/// Elastic energy at the current state, J (from the last model update).
double hs_body_elastic_energy(hs_body* b);
/// Reaction force on fixed node i (what the support exerts on the body), N, at the current state.
void hs_body_reaction(hs_body* b, int node, double f[3] /* OUT */);
/// Follow a cut (or any change of the rest mesh): deactivate elements off[n_off] and refresh the
/// rest data of moved[n_moved] from the mesh's current x0 (their vertices moved); inactive ones
/// are skipped. A factor of the rest-state matrix (the warped solver, PCG with the factor or
/// warped preconditioner, the linear model) that is current follows instead of a numeric
/// refactorisation at the next step: where the body keeps that matrix and the factor is
/// supernodal, by a partial refactor of the supernodes the change reaches
/// (hs_cholesky_refactor_partial; the first time also sets it up), else by one low-rank update
/// of the elements' old and new rest shares (hs_cholesky_update_parts); *low_rank (may be NULL)
/// says whether it followed either way. Otherwise
/// (no such factor, locking_free, a downdate that lost definiteness) the next step refactors as
/// before. Call after every sweep, before hs_body_set_state; replaces hs_cut_sync_fem for a
/// body. HS_ERR_INVALID (nothing changed) for an index out of range or a moved element with rest
/// volume <= 0. An element listed twice counts once; one both moved and going off goes off.
/// Allocates: the element blocks, on growth, and an element mark array on the first call.
hs_status hs_body_change_elements(hs_body* b, int n_off, const int* off, int n_moved,
                                  const int* moved, int* low_rank /* OUT */);
/// Factor updates (partial refactors or low-rank updates) hs_body_change_elements has made.
int64_t hs_body_lowrank_updates(const hs_body* b);
/// Largest relative difference of solves (three random right-hand sides) between the kept
/// rest-state factor and a fresh factorisation of the rest-state matrix assembled now; for
/// tests of the low-rank path. HS_ERR_INVALID when no current rest-state factor is kept.
/// Allocates: yes.
hs_status hs_body_rest_factor_difference(hs_body* b, double* rel /* OUT */);
/// The model (for queries like hs_fem_node_rotation). Owned by the body.
hs_fem* hs_body_fem(hs_body* b);
/// Free dof index of (node, component), or -1 if fixed.
int hs_body_dof(const hs_body* b, int node, int comp);
/// Number of free dofs.
int hs_body_free_dofs(const hs_body* b);
/// The factor of the current system matrix (rest-state K for static linear), or NULL if the
/// solver is PCG without a factor. Valid until the next step/solve.
hs_cholesky* hs_body_factor(hs_body* b);
/// Release; accepts NULL, sets *b = NULL.
void hs_body_destroy(hs_body** b);

#ifdef __cplusplus
}
#endif
#endif
