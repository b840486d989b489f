// SPDX-License-Identifier: GPL-2.0-or-later
// hapsim sparse: symmetric CSC matrices with a fixed pattern, CHOLMOD Cholesky with analysis
// done once, and preconditioned conjugate gradients. Only server/sparse/cholesky.c includes
// cholmod.h. An object here is used by one thread at a time (one cholmod_common each).
#ifndef HAPSIM_SPARSE_H
#define HAPSIM_SPARSE_H

#include "base.h"

#ifdef __cplusplus
extern "C" {
#endif

/// Symmetric matrix stored with its FULL pattern (both triangles) in compressed columns,
/// row indices sorted within each column. The pattern never changes after creation.
typedef struct hs_csc {
    int n;       ///< rows = columns
    int nnz;     ///< stored entries
    int* colp;   ///< [n+1] column starts
    int* rowi;   ///< [nnz] row indices, ascending per column
    double* val; ///< [nnz] values
} hs_csc;

/// Build the pattern of a 3x3-block matrix over free dofs. Node i couples to itself and to the
/// nodes in nbr[nbr_start[i] .. nbr_start[i+1]); dof_map[3*i+c] is the free dof index or -1.
/// Values are zero. @param out OUT
hs_status hs_csc_create_block_pattern(int n_nodes, const int* nbr_start, const int* nbr,
                                      const int* dof_map, int n_free, hs_csc** out, hs_err* err);
/// Position of (row, col) in val, or -1 if not in the pattern. O(log column length).
int hs_csc_find(const hs_csc* a, int row, int col);
/// y = A x. Allocates: no.
void hs_csc_spmv(const hs_csc* a, const double* x, double* y);
/// Set all values to zero. Allocates: no.
void hs_csc_zero(hs_csc* a);
/// Deep copy. @param out OUT
hs_status hs_csc_clone(const hs_csc* a, hs_csc** out);
/// Release; accepts NULL, sets *a = NULL.
void hs_csc_destroy(hs_csc** a);

// ---------------------------------------------------------------------------------------------
/// Sparse Cholesky L L^T of an SPD hs_csc (CHOLMOD, supernodal where it pays).
typedef struct hs_cholesky hs_cholesky;

/// Symbolic analysis of the pattern of a (CHOLMOD's default ordering: AMD, or METIS when AMD
/// fills badly) + first numeric factor. Keeps a spare factor of the same structure for
/// refactors, so memory is about twice nnz(L) doubles. CHOLMOD allocates through hs_alloc.
/// Returns HS_ERR_NOT_POSDEF if a is not SPD, HS_ERR_NUMERIC on NaN/Inf. @param out OUT
hs_status hs_cholesky_create(const hs_csc* a, hs_cholesky** out, hs_err* err);
/// Fill-reducing order of a's pattern (CHOLMOD's choice of AMD/METIS, postordered):
/// perm[k] is the row of a that goes to position k. Renumber the unknowns by it, then use
/// hs_cholesky_create_natural. @param perm OUT [n]
hs_status hs_cholesky_fill_order(const hs_csc* a, int* perm, hs_err* err);
/// As hs_cholesky_create for a matrix already in fill-reducing order (hs_cholesky_fill_order):
/// no further permutation, and every refactorisation reads A in place, allocating nothing.
/// @param out OUT
hs_status hs_cholesky_create_natural(const hs_csc* a, hs_cholesky** out, hs_err* err);
/// Numeric refactorisation of a matrix with the same pattern (checked: HS_ERR_INVALID);
/// reuses the analysis. Factors into the spare and swaps on success, so on HS_ERR_NOT_POSDEF
/// or HS_ERR_NUMERIC the previous good factor is kept and still usable. Allocates: CHOLMOD's
/// temporary workspace (a few blocks per call; its numeric factorisation always does).
hs_status hs_cholesky_refactor(hs_cholesky* f, const hs_csc* a);
/// Solve A x = b (x and b may alias). No allocation after the first call.
/// HS_ERR_NOT_POSDEF after a failed downdate (until a refactor succeeds).
hs_status hs_cholesky_solve(hs_cholesky* f, const double* b, double* x);
/// Solve for several right-hand sides stored column-major: b[n*k], x[n*k] (may alias).
/// Allocates: only when k differs from the previous call, and never in update mode.
hs_status hs_cholesky_solve_many(hs_cholesky* f, int k, const double* b, double* x);
/// Diagonal 3x3 blocks of A^-1: for block b the dofs dofs[3b..3b+2] (-1: none, its row and
/// column are zero); out[9b..9b+8] row-major, exactly symmetric. Each block costs one sparse
/// forward solve along the elimination-tree paths of its dofs, not a full solve (A^-1 = L^-T
/// L^-1, so an entry is a dot product of two columns of L^-1), done for 16 blocks at once in
/// the order of their dofs in L (their paths mostly coincide), the dense root separator by one
/// dense triangular solve per 16. Allocates: yes (work arrays, 48 doubles per row of L, and a
/// simplicial copy of a supernodal L; freed before return).
hs_status hs_cholesky_inverse_diag3(hs_cholesky* f, int nb, const int* dofs, double* out);

#define HS_PARALLEL_MAX 8 ///< parts one call splits its work into, at most

/// Task i of a parallel job.
typedef void hs_task_fn(int i, void* ctx);
/// Parallelism from the caller (the sparse layer starts no thread): run(n, task, ctx, user)
/// calls task(i, ctx) for every i in [0, n), at once on other threads or in turn, and returns
/// when all have returned. width: how many parts to split a job into (1 .. HS_PARALLEL_MAX).
/// begin(user) and end(user), optional, bracket every burst of run calls (a runner that polls
/// for work in between, as hs_worker in server/base/worker.h does, sleeps outside them).
typedef struct hs_parallel {
    void (*run)(int n, hs_task_fn* task, void* ctx, void* user);
    void* user;
    int width;
    void (*begin)(void* user);
    void (*end)(void* user);
} hs_parallel;
/// For a thread that will run hs_parallel tasks (an hs_worker's init; arg unused): one small
/// BLAS call, so that the BLAS maps the thread's work buffer now (faulted in at once under
/// mlockall) rather than in the first job.
void hs_sparse_thread_init(void* arg);

/// As hs_cholesky_inverse_diag3, the blocks split into par->width parts that par->run may
/// solve at once (each part its own scratch; BLAS calls from several threads). par NULL: one
/// part on this thread. Same results bit for bit whatever the split.
hs_status hs_cholesky_inverse_diag3_par(hs_cholesky* f, int nb, const int* dofs, double* out,
                                        const hs_parallel* par);
/// Entries stored in the current factor (supernodal: including the unused upper parts of its
/// dense blocks), a memory and cost indicator.
int64_t hs_cholesky_factor_nnz(const hs_cholesky* f);
/// Release; accepts NULL, sets *f = NULL.
void hs_cholesky_destroy(hs_cholesky** f);
/// Order n of the factored matrix.
int hs_cholesky_size(const hs_cholesky* f);
/// 1 if the factor is supernodal (BLAS-3 blocks), 0 if simplicial.
int hs_cholesky_is_supernodal(const hs_cholesky* f);

// Partial refactorisation (cutting). A change of A confined to a few dofs alters only the
// columns of L in the elimination-tree paths from those dofs to the root. Multifrontal over
// CHOLMOD's supernodes, keeping every supernode's update matrix (memory: the sum of their
// squares, 2-3.5x the factor on the benchmark's meshes: hs_cholesky_partial_bytes), the factor
// then recomputes only the supernodes holding a changed dof and their ancestors, with the same
// arithmetic as a full factorisation; the rest of L and the other update matrices are reused.
// A localised change still reaches the top separators, where most of the flops are: a quarter
// to two thirds of a factorisation in hapsim-bench cut (hs_cholesky_partial_share), run at
// dense-BLAS speed (a full pass is faster than CHOLMOD's own refactor there). Not for a factor
// in update mode (they exclude each other: updates need simplicial LDL^T, this supernodal LL^T).

/// Set up partial refactorisation of a supernodal factor (a has the factor's pattern, both
/// halves stored) and factor a once in full through it. HS_ERR_UNSUPPORTED for a simplicial
/// factor or one in update mode. Allocates: yes (the maps and update matrices).
hs_status hs_cholesky_prepare_partial(hs_cholesky* f, const hs_csc* a);
/// Refactor after a changed only in the rows and columns dofs[n_dofs] (original numbering;
/// repeats allowed; n_dofs < 0: everything). The pattern is checked in full only when a's
/// arrays are not the ones checked last: change values, not the pattern, in place. The first call
/// after hs_cholesky_refactor redoes everything. On HS_ERR_NOT_POSDEF (a pivot not positive, or
/// below 1e-12 of its diagonal entry: a singular A) L is partly recomputed: solves refuse until
/// hs_cholesky_refactor succeeds. HS_ERR_UNSUPPORTED before hs_cholesky_prepare_partial or in
/// update mode. Allocates: no.
hs_status hs_cholesky_refactor_partial(hs_cholesky* f, const hs_csc* a, int n_dofs,
                                       const int* dofs);
/// Memory hs_cholesky_prepare_partial would allocate (the update matrices dominate), bytes;
/// -1 for a factor that is not supernodal. O(supernodes), allocates nothing.
int64_t hs_cholesky_partial_bytes(const hs_cholesky* f);
/// Share of a full factorisation's flops the last partial refactor did (0..1).
double hs_cholesky_partial_share(const hs_cholesky* f);
/// Parallelism for the partial refactor's large supernodes (over ~3 Mflop); NULL or width < 2:
/// one thread (the default). With width >= 2 each large dense kernel is cut into 8 chunks
/// writing disjoint parts, run through par->run: the off-diagonal solve by rows, the update
/// matrix and the extend-adds by columns, the diagonal block's Cholesky by recursive halves;
/// par->begin and par->end bracket each refactor's large supernodes. The cut does not depend on
/// the runner, so results are the same bit for bit whichever threads run the chunks, and agree
/// with one thread to round-off (BLAS blocking differs). *par is copied; par->user must outlive
/// the factor's partial refactors. HS_ERR_INVALID for width >= 2 without run. Allocates: no.
hs_status hs_cholesky_set_partial_parallel(hs_cholesky* f, const hs_parallel* par);

// Low-rank modification (cutting). CHOLMOD updates only a simplicial LDL^T factor, so update
// mode converts the current factor once (O(nnz(L)), allocates; done by prepare or the first
// update) and keeps it simplicial, in the supernodal column layout. The spare stays supernodal:
// a refactor is a supernodal factorisation plus an O(nnz(L)) copy into the LDL^T factor, and
// solves run per supernode (about 1.5-2x a supernodal solve). Memory: about 2.5x nnz(L), plus
// for element updates a dense d x d workspace and column buffers, d = min(12 max_elems, 768, n)
// (up to ~8 MB). A rank-r change costs about ceil(r/8) passes along the elimination-tree paths
// of its rows, which in 3D cross the large separators (one removed element, measured with
// tests/sparse_timing on 27-point grids: ~3.5 ms at 7.6k dofs, ~25 ms at 30k dofs).

/// Convert to an updatable factor and size workspaces for changes of up to max_elems elements
/// (or max_elems*12 columns) per call, so later updates allocate nothing. Idempotent.
hs_status hs_cholesky_prepare_updates(hs_cholesky* f, int max_elems);
/// Factor of A + C C^T (update = 1) or A - C C^T (update = 0). C is n x n_cols in compressed
/// columns over the original (unpermuted) dof numbering: colp[n_cols+1], rowi/val[colp[n_cols]],
/// rows unique within a column, any order. Returns HS_ERR_NOT_POSDEF if a downdate leaves the
/// matrix indefinite or singular (a pivot below 1e-10 of its value at the last full factor,
/// e.g. a fragment cut free of every fixed node): the factor is then unusable (solves return
/// HS_ERR_NOT_POSDEF) until the next successful refactor. A non-finite value in C is refused
/// with HS_ERR_NUMERIC before the factor is touched; an update whose pivots overflow gives
/// HS_ERR_NUMERIC and leaves the factor unusable likewise.
/// Allocates: only when C is larger than any earlier call (see prepare).
hs_status hs_cholesky_updown(hs_cholesky* f, int update, int n_cols, const int* colp,
                             const int* rowi, const double* val);
/// Factor of A + sum_e dK_e for n_elem element changes: dk[144*e] is a symmetric 12x12 (any
/// sign; row-major), dofs[12*e] its free dof indices or -1 for fixed dofs. Aggregated (the
/// default): the changes are summed over the union of their free dofs (d of them, at most 768)
/// and factored S = G Q G^T in L's elimination order, so at most d columns (one per nonzero
/// pivot) go to update/downdate, each within L's pattern (no fill). An S whose unpivoted
/// factorisation breaks down, or a larger union, goes element by element: each dK_e split by
/// its eigen-decomposition (up to 12 columns each). All updates run before all downdates, so
/// the intermediate matrices stay SPD whenever the result is. Errors as hs_cholesky_updown; on
/// HS_ERR_INVALID (dof out of range or repeated) nothing changed.
/// Allocates: only when n_elem exceeds every earlier call and prepare.
hs_status hs_cholesky_update_elements(hs_cholesky* f, int n_elem, const double* dk,
                                      const int* dofs);
/// As hs_cholesky_update_elements for a change given as semidefinite parts: factor of
/// A + sum_{e < n_plus} K_e - sum_{e >= n_plus} K_e, blocks k[144*e], dofs[12*e] for
/// e < n_plus + n_minus (e.g. new element matrices and pin springs, then the old ones). When the
/// summed change's factorisation breaks down, each part is aggregated alone (semidefinite: no
/// breakdown; rank <= twice the union) instead of going element by element.
hs_status hs_cholesky_update_parts(hs_cholesky* f, int n_plus, int n_minus, const double* k,
                                   const int* dofs);
/// 1 (default): hs_cholesky_update_elements aggregates the step; 0: element by element.
void hs_cholesky_set_aggregate(hs_cholesky* f, int on);
/// How hs_cholesky_update_elements / _parts applied a change.
typedef enum hs_cholesky_update_method {
    HS_UPDATE_PER_ELEMENT = 0, ///< each block split by its own eigen-decomposition
    HS_UPDATE_AGGREGATED = 1,  ///< the summed change factored once (rank <= union_dofs)
    HS_UPDATE_PARTS = 2,       ///< the summed + and - parts factored apart (rank <= 2 union_dofs)
} hs_cholesky_update_method;

/// What the last hs_cholesky_update_elements / _parts did.
typedef struct hs_cholesky_update_info {
    int rank;       ///< rank-1 columns sent to update/downdate
    int union_dofs; ///< free dofs the change touched (-1: more than the aggregation limit)
    hs_cholesky_update_method method;
} hs_cholesky_update_info;

/// The last update's rank, union and method. @param info OUT
void hs_cholesky_last_update(const hs_cholesky* f, hs_cholesky_update_info* info);

// ---------------------------------------------------------------------------------------------
/// Preconditioned conjugate gradients with warm start.
typedef enum hs_precond {
    HS_PRECOND_NONE = 0,
    HS_PRECOND_JACOBI = 1, ///< inverse diagonal of A
    HS_PRECOND_FACTOR = 2, ///< solve with a given Cholesky factor (e.g. of the rest-state matrix)
    HS_PRECOND_CUSTOM = 3, ///< the function given to hs_pcg_set_preconditioner
    /// hs_body only: the rest-state factor warped by the node rotations, R K0^-1 R^T
    HS_PRECOND_WARPED = 4,
} hs_precond;

/// A preconditioner z = M^-1 r (M SPD). Must not allocate; returns HS_OK or an error.
typedef hs_status hs_precond_fn(void* ctx, const double* r, double* z);

typedef struct hs_pcg hs_pcg;

/// Workspace for systems of size n. @param out OUT
hs_status hs_pcg_create(int n, hs_pcg** out);
/// Solve A x = b. x holds the initial guess on entry (warm start) and the result on exit.
/// Stops when ||r|| <= tol ||b|| or after max_iter. factor is used only with HS_PRECOND_FACTOR.
/// Returns HS_OK, or HS_WARN_NOT_CONVERGED with the best x. rel_residual is the true residual
/// when converged, the recurrence's when stopped by max_iter (no extra product). Allocates: no.
hs_status hs_pcg_solve(hs_pcg* pcg, const hs_csc* a, const double* b, double* x, hs_precond precond,
                       hs_cholesky* factor, double tol, int max_iter, int* iters /* OUT */,
                       double* rel_residual /* OUT */);
/// Preconditioner used with HS_PRECOND_CUSTOM (ctx is passed back to fn).
void hs_pcg_set_preconditioner(hs_pcg* pcg, hs_precond_fn* fn, void* ctx);
/// Release; accepts NULL, sets *pcg = NULL.
void hs_pcg_destroy(hs_pcg** pcg);

#ifdef __cplusplus
}
#endif
#endif
