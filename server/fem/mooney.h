// SPDX-License-Identifier: GPL-2.0-or-later
// hapsim mooney: nearly incompressible Mooney-Rivlin reference solver (Ogata, Nagasaka, Yamada).
// P1 displacement / P0 pressure tetrahedra, perturbed Lagrange multiplier, pressure
// stabilisation between face neighbours, total Lagrangian Newton-Raphson with load stepping.
// Used as the accuracy reference for the real-time models; not for the 1 kHz path.
// Pure computation: no threads, no I/O, no allocation after hs_mooney_create.
#ifndef HAPSIM_MOONEY_H
#define HAPSIM_MOONEY_H

#include "base.h"
#include "mesh.h"

#ifdef __cplusplus
extern "C" {
#endif

/// Solver definition. Initialise with hs_mooney_default_def().
typedef struct hs_mooney_def {
    double youngs_pa;     ///< small-strain Young's modulus, Pa (> 0)
    double poisson;       ///< small-strain Poisson ratio, in (-1, 0.5)
    double density_kg_m3; ///< for gravity, kg/m^3
    double beta;          ///< pressure stabilisation, dimensionless (>= 0; 0 = plain P1/P0)
    double tolerance;     ///< Newton stop: ||F - Q|| / ||F - Q||_first <= tolerance
    int max_newton_iter;  ///< Newton iterations per load increment before it is bisected
    int load_steps;       ///< equal load increments (>= 1)
    int max_bisections;   ///< step control: times a failed increment may be halved
    int cookie;           ///< set by hs_mooney_default_def; catches uninitialised defs
} hs_mooney_def;

/// Defaults: E 3 kPa, nu 0.45, 1000 kg/m^3, beta 0, tolerance 1e-8, 30 Newton iterations,
/// 1 load step, 10 bisections.
hs_mooney_def hs_mooney_default_def(void);

/// Material constants by the small-strain match: c1 = c2 = E / (8 (1 + nu)),
/// kappa = E / (3 (1 - 2 nu)); all in Pa.
void hs_mooney_constants(const hs_mooney_def* def, double* c1, double* c2, double* kappa);

#define HS_MOONEY_HISTORY 64 ///< entries kept in the per-solve histories below

/// What the last hs_mooney_solve_static did.
typedef struct hs_mooney_stats {
    int increments;                    ///< load increments solved (bisected halves counted)
    int bisections;                    ///< increments that failed and were halved
    int newton_total;                  ///< Newton iterations over all increments
    int newton_max;                    ///< most Newton iterations in one increment
    int n_step_iters;                  ///< entries in step_iters
    int step_iters[HS_MOONEY_HISTORY]; ///< Newton iterations of each increment (first 64)
    int n_ratio;                       ///< entries in ratio
    double ratio[HS_MOONEY_HISTORY];   ///< ||F-Q||/||F-Q||_first of the last increment, [0] = 1
    double final_ratio;                ///< the last increment's final ratio
    int system_size;         ///< unknowns of the factorised system (free dofs, + faces if beta > 0)
    int64_t factor_nnz;      ///< entries of its Cholesky factor
    int line_search_cuts;    ///< Newton steps shortened by the line search
    double volume_ratio_min; ///< smallest element J at the solution
    double volume_ratio_max; ///< largest element J at the solution
    double volume_ratio_total; ///< deformed / rest volume of the whole mesh
    double solve_ms;           ///< wall time, ms
} hs_mooney_stats;

typedef struct hs_mooney hs_mooney;

/// Precompute shape gradients, interior faces, the pressure matrix, the sparse pattern and
/// the factor at rest. HS_ERR_INVALID if a connected piece lacks 3 non-collinear fixed nodes.
/// fixed[i] != 0 makes node i fully prescribed (NULL: none fixed). The mesh must outlive m.
/// @param out OUT: new solver, free with hs_mooney_destroy
hs_status hs_mooney_create(const hs_mesh* mesh, const hs_mooney_def* def,
                           const unsigned char* fixed, hs_mooney** out, hs_err* err);
/// Total external nodal forces, N ([3n]; NULL clears). Scaled by the load factor.
/// HS_ERR_INVALID (nothing changed) if a component is not finite or above 1e9 N.
hs_status hs_mooney_set_forces(hs_mooney* m, const double* f);
/// Gravity acceleration, m/s^2 (rho g, lumped V/4 per node). HS_ERR_INVALID (nothing changed)
/// if a component is not finite or above 1e3 m/s^2.
hs_status hs_mooney_set_gravity(hs_mooney* m, const double g[3]);
/// Total prescribed displacements of fixed nodes, m ([3n]; entries of free nodes ignored;
/// NULL = zero). Reached by the same load factor as the forces. HS_ERR_INVALID (nothing
/// changed) if an entry is not finite or above 1e3 m.
hs_status hs_mooney_set_prescribed(hs_mooney* m, const double* u);
/// Set the current state (initial guess), m ([3n]); pressures follow from their equation.
/// Resets the load factor to 0 (the next solve applies the full load in load_steps).
/// A u that is not finite, above 1e3 m, or inverts an element is refused; the state stays.
hs_status hs_mooney_set_displacement(hs_mooney* m, const double* u, hs_err* err);
/// Solve the static problem for the full load from the current state in def.load_steps
/// increments. Returns HS_OK, HS_ERR_NOT_CONVERGED (state = last converged increment),
/// HS_ERR_NUMERIC or HS_ERR_NOT_POSDEF with err->msg saying where it stopped.
hs_status hs_mooney_solve_static(hs_mooney* m, hs_mooney_stats* stats /* OUT, may be NULL */,
                                 hs_err* err);
/// Displacement, m ([3n]); valid until the next call that changes the state.
const double* hs_mooney_displacement(const hs_mooney* m);
/// Per-element mixed pressure p = mean Cauchy stress, Pa ([n_tets]; positive in tension).
const double* hs_mooney_pressure(const hs_mooney* m);
/// Internal (elastic) nodal forces Q at the current state, N ([3n], fixed nodes included).
void hs_mooney_internal_forces(const hs_mooney* m, double* q /* OUT [3n] */);
/// Cauchy stress of element t at the current state, Pa (row-major 3x3).
void hs_mooney_element_stress(const hs_mooney* m, int t, double sigma[9] /* OUT */);
/// Pressure oscillation: RMS pressure jump over interior faces (area weighted) divided by the
/// RMS element pressure (volume weighted); 0 when all pressures are 0. About 2 for a checkerboard.
double hs_mooney_pressure_oscillation(const hs_mooney* m);
/// Release; accepts NULL, sets *m = NULL.
void hs_mooney_destroy(hs_mooney** m);

/// Element kernel (exposed for tests): first Piola-Kirchhoff stress of the isochoric
/// Mooney-Rivlin part plus p J F^-T, Pa, and optionally its derivative dP/dF at fixed p
/// (a[((i*3+J)*3+k)*3+L] = dP_iJ / dF_kL). F row-major. Returns the isochoric energy density.
double hs_mooney_pk1(double c1, double c2, double p, const double f[9], double pk1[9] /* OUT */,
                     double* a /* OUT [81], may be NULL */);

#ifdef __cplusplus
}
#endif
#endif
