// SPDX-License-Identifier: GPL-2.0-or-later
// hapsim fem: element models on a tetrahedral mesh. Computes elastic forces and assembles the
// tangent stiffness and lumped mass into a fixed sparse pattern over the free dofs.
// Pure computation: no threads, no I/O, no allocation after hs_fem_create.
#ifndef HAPSIM_FEM_H
#define HAPSIM_FEM_H

#include "base.h"
#include "mesh.h"
#include "sparse.h"

#ifdef __cplusplus
extern "C" {
#endif

typedef enum hs_model {
    HS_MODEL_LINEAR = 0,    ///< small-strain linear elasticity
    HS_MODEL_COROTATED = 1, ///< f_e = R_e K_e (R_e^T x - x0), R_e from the deformation gradient
    HS_MODEL_STVK = 2,      ///< geometrically nonlinear St.Venant-Kirchhoff
} hs_model;

typedef enum hs_rotation {
    HS_ROTATION_POLAR = 0, ///< Higham's iteration X <- X (I + (I - X^T X)/2), warm-started
    /// rotation from the SVD of F, kept while the element's last one is still F's polar factor
    /// to polar_tol (the polar method's acceptance test)
    HS_ROTATION_SVD = 1,
} hs_rotation;

typedef enum hs_inversion {
    HS_INVERSION_LINEAR_FALLBACK = 0, ///< an inverted element (det F < 0) uses linear FEM (R = I)
    HS_INVERSION_KEEP_REFLECTION =
        1, ///< R stays a proper rotation, the reflection stays in the stretch
} hs_inversion;

typedef struct hs_material {
    double youngs_pa;          ///< Young's modulus, Pa
    double poisson;            ///< Poisson ratio, in (-1, 0.5)
    double density_kg_m3;      ///< kg/m^3
    double rayleigh_mass;      ///< alpha in C = alpha M + beta K, 1/s
    double rayleigh_stiffness; ///< beta in C = alpha M + beta K, s
} hs_material;

/// Locking-free options for near-incompressible tissue (hs_fem_def.locking_free).
typedef enum hs_locking_free {
    HS_LOCKING_FREE_NONE = 0, ///< plain linear tets (lock at nu -> 0.5)
    HS_LOCKING_FREE_ANP = 1,  ///< average nodal pressure (Bonet & Burton)
    HS_LOCKING_FREE_SNS = 2,  ///< selective node smoothing: ANP + node-smoothed deviatoric share
} hs_locking_free;

/// The mode `locking_free = true` means (scenes, hapsim-solve's bare --locking-free): SNS for
/// linear and co-rotated, ANP for StVK (SNS is not defined for it).
static inline int hs_fem_locking_free_default(hs_model model) {
    return model == HS_MODEL_STVK ? HS_LOCKING_FREE_ANP : HS_LOCKING_FREE_SNS;
}

/// Default SNS deviatoric share (measured on the cantilever against CalculiX, docs/fem.md).
#define HS_SNS_ALPHA_DEFAULT 0.6

/// Element model options. Initialise with hs_fem_default_def().
typedef struct hs_fem_def {
    hs_model model;
    hs_material material;
    hs_rotation rotation; ///< co-rotated only
    /// co-rotated, a relative rotation error (default 1e-6): the warm iteration stops (and SVD
    /// keeps an element's rotation) when |axial(skew(X^T F))| <= tol ||F||_F / sqrt(3) and X^T F
    /// is positive definite; the cold iteration when ||I - X^T X||_F <= tol (docs/fem.md,
    /// Rotations)
    double polar_tol;
    int polar_max_iter;     ///< co-rotated + POLAR: iteration cap per element per update
    hs_inversion inversion; ///< what an inverted element does
    /// hs_locking_free: 0 off, 1 ANP (nodal volumetric strain), 2 SNS (ANP plus a share
    /// locking_free_alpha of the deviatoric energy from node-smoothed strain; linear and
    /// co-rotated only); docs/fem.md, "Locking-free options"
    int locking_free;
    double locking_free_alpha; ///< SNS: node-smoothed deviatoric share, in [0, 1)
    int cookie;                ///< set by hs_fem_default_def; catches uninitialised defs
} hs_fem_def;

/// Defaults: linear, E 3 kPa, nu 0.45, 1000 kg/m^3, no damping, POLAR tol 1e-6 x 20 iterations,
/// linear fallback for inverted elements, locking_free off (alpha HS_SNS_ALPHA_DEFAULT).
hs_fem_def hs_fem_default_def(void);

/// Statistics from the last hs_fem_update.
typedef struct hs_fem_stats {
    int inverted;             ///< elements with det F <= 0
    double volume_ratio_mean; ///< mean over elements of V/V0
    double volume_ratio_min;
    double volume_ratio_max;
    int polar_iters_max; ///< worst polar iteration count (POLAR only)
    double energy_j;     ///< elastic strain energy, J
} hs_fem_stats;

typedef struct hs_fem hs_fem;

/// Precompute element data (shape gradients, rest volumes, element stiffness, lumped mass) and
/// the assembly map into the free-dof pattern. dof_map[3*i+c] is the free index of dof (i,c)
/// or -1 for a constrained dof; n_free free dofs in all. The mesh must outlive the fem.
/// @param out OUT
hs_status hs_fem_create(const hs_mesh* mesh, const hs_fem_def* def, const int* dof_map, int n_free,
                        hs_fem** out, hs_err* err);
/// A new matrix with the tangent's sparsity pattern over the free dofs (values zero).
/// It includes the wider stencil that the locking-free option needs. @param out OUT
hs_status hs_fem_create_matrix(const hs_fem* fem, hs_csc** out);
/// Evaluate the model at positions x ([3n], m): rotations / deformation gradients, forces and
/// element tangents. Allocates: no.
void hs_fem_update(hs_fem* fem, const double* x, hs_fem_stats* stats /* OUT, may be NULL */);
/// Elastic (restoring) nodal forces -dW/dx at the last update, N, for all 3n dofs.
void hs_fem_forces(const hs_fem* fem, double* f /* OUT [3n] */);
/// A = kcoef * K_t + mcoef * M over the free dofs, K_t the tangent at the last update, M the
/// lumped mass. A must come from hs_fem_create_matrix. Allocates: no.
void hs_fem_assemble(const hs_fem* fem, double kcoef, double mcoef, hs_csc* a);
/// a = kcoef K(rest) + mcoef M from the element rest data alone (no update needed: rotations are
/// the identity, stresses zero), the matrix a rest-state factor holds. HS_ERR_UNSUPPORTED with
/// locking_free (its nodal term). Allocates: no.
hs_status hs_fem_assemble_rest(const hs_fem* fem, double kcoef, double mcoef, hs_csc* a);
/// Element tet's share of that matrix: kcoef K_e(rest) + mcoef M_e (its lumped mass, rho V / 4
/// per node), row-major 12x12 over its 4 nodes x 3 components. HS_ERR_UNSUPPORTED with
/// locking_free. Allocates: no.
hs_status hs_fem_rest_element_matrix(const hs_fem* fem, int tet, double kcoef, double mcoef,
                                     double out[144] /* OUT */);
/// a += s * (the rest shares of elements tets[n]) in a matrix with the fem's pattern (both
/// halves kept). HS_ERR_UNSUPPORTED with locking_free. Allocates: no.
hs_status hs_fem_add_rest_elements(const hs_fem* fem, int n, const int* tets, double kcoef,
                                   double mcoef, double s, hs_csc* a);
/// y = K_t x for all 3n dofs (constrained included) at the last update. Allocates: no.
void hs_fem_apply_tangent(const hs_fem* fem, const double* x, double* y);
/// Lumped mass per node, kg ([n]); 0 for a node with no active element.
const double* hs_fem_lumped_mass(const hs_fem* fem);
/// Nodes that have lost their last active element. Each keeps the mass it had on the diagonal
/// of the system matrices (hs_fem_assemble, hs_fem_assemble_rest with mcoef != 0) but has no
/// inertia and no gravity load: in a dynamic step it stays where it is, with no pin spring.
/// A static solve (mcoef 0) with such nodes is singular.
int hs_fem_held_nodes(const hs_fem* fem);
/// The mass each held node keeps on the diagonal, kg ([n]; 0 for every other node).
const double* hs_fem_held_mass(const hs_fem* fem);
/// Rotation of node i (polar part of the volume-weighted mean deformation gradient of its
/// tets) at the last update; identity for linear. Row-major 3x3.
void hs_fem_node_rotation(const hs_fem* fem, int node, double r[9] /* OUT */);
/// The same rotation by a polar iteration warm-started from r (input: the previous rotation,
/// or zeros for a cold start; output: the new one). Cheaper when called every step.
void hs_fem_node_rotation_warm(const hs_fem* fem, int node, double r[9] /* in/out */);
/// Set or clear an element's participation (cutting removes elements). Allocates: no.
void hs_fem_set_element_active(hs_fem* fem, int tet, int active);
/// 1 when element tet takes part (not removed by a cut).
int hs_fem_element_active(const hs_fem* fem, int tet);
/// Multiply element tet's stiffness (forces, energy, tangent; not its mass) by s > 0, e.g. two
/// materials in one body. HS_ERR_INVALID for a bad index or s; HS_ERR_UNSUPPORTED with
/// locking_free (its nodal volumetric term is shared between elements). Allocates: no.
hs_status hs_fem_set_element_stiffness_scale(hs_fem* fem, int tet, double s);
/// Recompute the rest data (shape gradients, volume, lumped mass) of elements tets[n] from the
/// mesh's current x0 (cutting moves vertices). HS_ERR_INVALID (nothing changed) for an index out
/// of range or an element with rest volume <= 0. Allocates: no.
hs_status hs_fem_refresh_elements(hs_fem* fem, const int* tets, int n);
/// Grows whenever an element is activated, deactivated, rescaled or refreshed: a caller may
/// keep an assembled matrix of the (state-independent) linear model while it is unchanged.
uint64_t hs_fem_stiffness_version(const hs_fem* fem);
/// Element rotations back to the identity, as after hs_fem_create: the warm start of the next
/// update. A rotation is accepted within polar_tol of the polar factor, so the start shows at
/// that level; hs_body_reset calls this so that a reset body steps exactly as a new one.
void hs_fem_reset_rotations(hs_fem* fem);
/// Set hs_fem_def.polar_tol for the next updates (the body uses a looser one in dynamic
/// steps, hs_body_def.step_polar_tol). HS_ERR_INVALID (nothing changed) unless tol > 0.
hs_status hs_fem_set_polar_tol(hs_fem* fem, double tol);
/// Release; accepts NULL, sets *fem = NULL.
void hs_fem_destroy(hs_fem** fem);

// Element kernels, exposed for tests and the haptic path.
/// Polar rotation of F (row-major 3x3) by Higham's iteration from the warm start r (in/out).
/// Returns iterations used; r is a proper rotation if det F > 0. An r that is not a rotation
/// (e.g. zeros) means a cold start; at most max_iter per phase (warm, cold), then the SVD;
/// det F <= 0 gives hs_polar_svd's rotation and 0. See docs/fem.md.
int hs_polar_higham(const double f[9], double r[9], double tol, int max_iter);
/// Rotation from the SVD of F with det R = +1 (reflection kept in the stretch).
void hs_polar_svd(const double f[9], double r[9] /* OUT */);

/// HS_OK when every connected piece of the mesh holds three non-collinear nodes with
/// fixed[i] != 0: else rigid motion is free, the stiffness is singular and there is no static
/// equilibrium (nor a compliance); HS_ERR_INVALID naming a tet of the free piece.
/// Thread: any | Allocates: temporarily
hs_status hs_fem_check_fixed(const hs_mesh* mesh, const unsigned char* fixed, hs_err* err);

#ifdef __cplusplus
}
#endif
#endif
