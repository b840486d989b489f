// SPDX-License-Identifier: GPL-2.0-or-later
// Sparse: CSC pattern and products against a dense reference, CHOLMOD factor/refactor/solve,
// keeping the last good factor, allocation-free solves, PCG, low-rank updates for cutting,
// fault injection.
#define _GNU_SOURCE // RTLD_DEFAULT
#include "platform.h"
#include "sparse.h"
#include "sparse_grid.h"
#include "test_macros.h"
#include "worker.h"

#include <dlfcn.h>
#include <pthread.h>
#include <stdatomic.h>
#include <stdlib.h>

static void fill_random(int n, double* x, uint64_t seed) {
    for (int i = 0; i < n; i++) x[i] = grid_rand01(&seed) - 0.5;
}

static double max_abs_diff(int n, const double* a, const double* b) {
    double m = 0;
    for (int i = 0; i < n; i++) m = fmax(m, fabs(a[i] - b[i]));
    return m;
}

static int CscPatternAndSpmv(void) {
    int64_t bytes0 = hs_byte_count();
    grid g;
    ENSURE(grid_make(&g, 4, 3, 3, 1) == 0);
    hs_csc* a = NULL;
    hs_err err = {0};
    ENSURE(grid_pattern(&g, &a, &err) == HS_OK);
    ENSURE(a->n == g.n_free && a->colp[a->n] == a->nnz);
    // Entry (r, c) is stored iff the two dofs' nodes are equal or grid neighbours.
    int n = a->n;
    int* node = malloc(sizeof(int) * (size_t)n);
    for (int v = 0; v < g.n_nodes; v++)
        for (int d = 0; d < 3; d++)
            if (g.dof_map[3 * v + d] >= 0) node[g.dof_map[3 * v + d]] = v;
    int stored = 0;
    for (int c = 0; c < n; c++)
        for (int r = 0; r < n; r++) {
            double xr[3], xc[3];
            grid_coords(&g, node[r], xr);
            grid_coords(&g, node[c], xc);
            int adj =
                fabs(xr[0] - xc[0]) <= 1 && fabs(xr[1] - xc[1]) <= 1 && fabs(xr[2] - xc[2]) <= 1;
            int p = hs_csc_find(a, r, c);
            ENSURE((p >= 0) == adj);
            if (p >= 0) ENSURE(a->rowi[p] == r && p >= a->colp[c] && p < a->colp[c + 1]);
            stored += p >= 0;
        }
    ENSURE(stored == a->nnz);
    ENSURE(hs_csc_find(a, -1, 0) == -1 && hs_csc_find(a, 0, n) == -1);

    // Values, then spmv against a dense product.
    ENSURE(grid_assemble(&g, a, 0.25) == 0);
    double* dense = calloc((size_t)n * (size_t)n, sizeof(double));
    for (int c = 0; c < n; c++)
        for (int p = a->colp[c]; p < a->colp[c + 1]; p++) dense[a->rowi[p] * n + c] = a->val[p];
    for (int r = 0; r < n; r++)
        for (int c = 0; c < r; c++) ENSURE_SMALL(dense[r * n + c] - dense[c * n + r], 1e-14);
    double *x = malloc(sizeof(double) * (size_t)n), *y = malloc(sizeof(double) * (size_t)n),
           *yref = calloc((size_t)n, sizeof(double));
    fill_random(n, x, 7);
    for (int r = 0; r < n; r++)
        for (int c = 0; c < n; c++) yref[r] += dense[r * n + c] * x[c];
    hs_csc_spmv(a, x, y);
    ENSURE(max_abs_diff(n, y, yref) <= 1e-12 * vec_norm(n, yref));

    hs_csc* b = NULL;
    ENSURE(hs_csc_clone(a, &b) == HS_OK);
    ENSURE(b->nnz == a->nnz && memcmp(b->rowi, a->rowi, sizeof(int) * (size_t)a->nnz) == 0);
    ENSURE(memcmp(b->val, a->val, sizeof(double) * (size_t)a->nnz) == 0);
    hs_csc_zero(b);
    hs_csc_spmv(b, x, y);
    ENSURE(vec_norm(n, y) == 0.0 && a->val[0] != 0.0);

    hs_csc_destroy(&a);
    hs_csc_destroy(&b);
    hs_csc_destroy(&b);
    ENSURE(a == NULL && b == NULL);
    free(node);
    free(dense);
    free(x);
    free(y);
    free(yref);
    grid_free(&g);
    ENSURE(hs_byte_count() == bytes0);
    return 0;
}

static int CscBadInput(void) {
    int64_t bytes0 = hs_byte_count();
    int nbr_start[3] = {0, 1, 2}, nbr[2] = {1, 0}, dof_map[6] = {0, 1, 2, 3, 4, 5};
    hs_csc* a = NULL;
    hs_err err = {0};
    int bad_nbr[2] = {1, 7};
    ENSURE(hs_csc_create_block_pattern(2, nbr_start, bad_nbr, dof_map, 6, &a, &err) ==
           HS_ERR_INVALID);
    ENSURE(a == NULL && strstr(err.msg, "neighbour 7") != NULL && strstr(err.msg, "csc.c"));
    int dup_map[6] = {0, 1, 2, 3, 4, 4};
    ENSURE(hs_csc_create_block_pattern(2, nbr_start, nbr, dup_map, 6, &a, &err) == HS_ERR_INVALID);
    int bad_start[3] = {0, 2, 1};
    ENSURE(hs_csc_create_block_pattern(2, bad_start, nbr, dof_map, 6, &a, &err) == HS_ERR_INVALID);
    ENSURE(hs_csc_create_block_pattern(2, nbr_start, nbr, dof_map, 6, NULL, &err) ==
           HS_ERR_INVALID);
    // One-sided neighbour lists are symmetrised; self entries and duplicates are ignored.
    int one_start[3] = {0, 3, 3}, one[3] = {1, 0, 1};
    ENSURE(hs_csc_create_block_pattern(2, one_start, one, dof_map, 6, &a, &err) == HS_OK);
    ENSURE(a->nnz == 36 && hs_csc_find(a, 0, 5) >= 0 && hs_csc_find(a, 5, 0) >= 0);
    hs_csc_destroy(&a);
    // Fault injection: every allocation in turn fails cleanly.
    for (int k = 1;; k++) {
        hs_alloc_fail_after(k);
        hs_status st = hs_csc_create_block_pattern(2, nbr_start, nbr, dof_map, 6, &a, &err);
        hs_alloc_fail_after(0);
        if (st == HS_OK) break;
        ENSURE(st == HS_ERR_NOMEM && a == NULL && k < 50);
        ENSURE(hs_byte_count() == bytes0);
    }
    hs_csc_destroy(&a);
    ENSURE(hs_byte_count() == bytes0);
    return 0;
}

// Grid matrix and a factor of it; callers free.
typedef struct fixture {
    grid g;
    hs_csc* a;
    hs_cholesky* f;
    double *b, *x, *r;
} fixture;

static int fixture_make(fixture* t, int nx, int ny, int nz, double shift) {
    memset(t, 0, sizeof *t);
    hs_err err = {0};
    if (grid_make(&t->g, nx, ny, nz, 3) != 0) return -1;
    if (grid_pattern(&t->g, &t->a, &err) != HS_OK) return -1;
    if (grid_assemble(&t->g, t->a, shift) != 0) return -1;
    if (hs_cholesky_create(t->a, &t->f, &err) != HS_OK) {
        printf("  create: %s\n", err.msg);
        return -1;
    }
    int n = t->a->n;
    t->b = malloc(sizeof(double) * 4 * (size_t)n);
    t->x = malloc(sizeof(double) * 4 * (size_t)n);
    t->r = malloc(sizeof(double) * 4 * (size_t)n);
    fill_random(4 * n, t->b, 11);
    return 0;
}

static void fixture_free(fixture* t) {
    hs_cholesky_destroy(&t->f);
    hs_csc_destroy(&t->a);
    free(t->b);
    free(t->x);
    free(t->r);
    grid_free(&t->g);
}

static int CholeskySolve(void) {
    int64_t bytes0 = hs_byte_count();
    fixture t;
    ENSURE(fixture_make(&t, 9, 8, 8, 1e-3) == 0);
    int n = t.a->n;
    // CHOLMOD's own memory goes through hs_alloc: the factor's bytes are counted.
    ENSURE(hs_byte_count() - bytes0 >= 8 * hs_cholesky_factor_nnz(t.f));
    ENSURE(hs_cholesky_size(t.f) == n && hs_cholesky_factor_nnz(t.f) >= (t.a->nnz + n) / 2);
    ENSURE(hs_cholesky_solve(t.f, t.b, t.x) == HS_OK);
    ENSURE_SMALL(rel_residual(t.a, t.x, t.b, t.r), 1e-12);
    // x may alias b.
    double* y = malloc(sizeof(double) * (size_t)n);
    memcpy(y, t.b, sizeof(double) * (size_t)n);
    ENSURE(hs_cholesky_solve(t.f, y, y) == HS_OK);
    ENSURE(max_abs_diff(n, y, t.x) == 0.0);
    // Several right-hand sides agree with one-at-a-time solves.
    ENSURE(hs_cholesky_solve_many(t.f, 3, t.b, t.x) == HS_OK);
    for (int k = 0; k < 3; k++) {
        ENSURE(hs_cholesky_solve(t.f, t.b + k * n, y) == HS_OK);
        ENSURE(max_abs_diff(n, y, t.x + k * n) <= 1e-12 * vec_norm(n, y));
    }
    free(y);
    fixture_free(&t);
    ENSURE(hs_byte_count() == bytes0);
    return 0;
}

static int CholeskyRefactor(void) {
    int64_t bytes0 = hs_byte_count();
    fixture t;
    ENSURE(fixture_make(&t, 8, 7, 9, 1e-3) == 0);
    int n = t.a->n;
    ENSURE(hs_cholesky_solve(t.f, t.b, t.x) == HS_OK);
    double* x_old = malloc(sizeof(double) * (size_t)n);
    memcpy(x_old, t.x, sizeof(double) * (size_t)n);
    // New values on the same pattern, given as a different hs_csc object.
    hs_csc* a2 = NULL;
    ENSURE(hs_csc_clone(t.a, &a2) == HS_OK);
    for (int e = 0; e < t.g.n_tets; e++) t.g.w[e] = 2.0 + sin(e);
    ENSURE(grid_assemble(&t.g, a2, 0.5) == 0);
    ENSURE(hs_cholesky_refactor(t.f, a2) == HS_OK);
    ENSURE(hs_cholesky_solve(t.f, t.b, t.x) == HS_OK);
    ENSURE_SMALL(rel_residual(a2, t.x, t.b, t.r), 1e-12);
    ENSURE(max_abs_diff(n, t.x, x_old) > 1e-3 * vec_norm(n, x_old) / sqrt(n));
    // A different pattern is refused, also with the same column counts.
    hs_csc_destroy(&a2);
    ENSURE(hs_csc_clone(t.a, &a2) == HS_OK);
    int c = n / 2, p0 = a2->colp[c];
    ENSURE(a2->rowi[p0] > 0 && hs_csc_find(a2, a2->rowi[p0] - 1, c) < 0);
    a2->rowi[p0]--; // still sorted, now another row
    ENSURE(hs_cholesky_refactor(t.f, a2) == HS_ERR_INVALID);
    hs_csc_destroy(&a2);
    grid g2;
    ENSURE(grid_make(&g2, 8, 7, 8, 3) == 0);
    hs_err err;
    ENSURE(grid_pattern(&g2, &a2, &err) == HS_OK);
    ENSURE(hs_cholesky_refactor(t.f, a2) == HS_ERR_INVALID);
    hs_csc_destroy(&a2);
    grid_free(&g2);
    free(x_old);
    fixture_free(&t);
    ENSURE(hs_byte_count() == bytes0);
    return 0;
}

static int CholeskyNotPosdefKeepsFactor(void) {
    int64_t bytes0 = hs_byte_count();
    fixture t;
    ENSURE(fixture_make(&t, 7, 7, 7, 1e-3) == 0);
    int n = t.a->n;
    hs_csc* bad = NULL;
    ENSURE(hs_csc_clone(t.a, &bad) == HS_OK);
    // One strongly negative diagonal entry in the middle of the ordering.
    bad->val[hs_csc_find(bad, n / 2, n / 2)] = -100.0;
    for (int rep = 0; rep < 2; rep++) {
        ENSURE(hs_cholesky_refactor(t.f, bad) == HS_ERR_NOT_POSDEF);
        ENSURE(hs_cholesky_solve(t.f, t.b, t.x) == HS_OK);
        ENSURE_SMALL(rel_residual(t.a, t.x, t.b, t.r), 1e-12);
    }
    // NaN in the matrix is refused too, and the good factor survives.
    hs_csc* nan_a = NULL;
    ENSURE(hs_csc_clone(t.a, &nan_a) == HS_OK);
    nan_a->val[nan_a->colp[n / 3] + 1] = NAN;
    hs_status st = hs_cholesky_refactor(t.f, nan_a);
    ENSURE(st == HS_ERR_NUMERIC || st == HS_ERR_NOT_POSDEF);
    ENSURE(hs_cholesky_solve(t.f, t.b, t.x) == HS_OK);
    ENSURE_SMALL(rel_residual(t.a, t.x, t.b, t.r), 1e-12);
    // After failures the spare factor still refactors correctly.
    ENSURE(hs_cholesky_refactor(t.f, t.a) == HS_OK);
    ENSURE(hs_cholesky_solve(t.f, t.b, t.x) == HS_OK);
    ENSURE_SMALL(rel_residual(t.a, t.x, t.b, t.r), 1e-12);
    // Creating from a non-SPD matrix fails cleanly with a message.
    hs_cholesky* f2 = (hs_cholesky*)&t; // must be overwritten with NULL
    hs_err err = {0};
    ENSURE(hs_cholesky_create(bad, &f2, &err) == HS_ERR_NOT_POSDEF);
    ENSURE(f2 == NULL && strstr(err.msg, "not positive definite") != NULL);
    hs_csc_destroy(&bad);
    hs_csc_destroy(&nan_a);
    fixture_free(&t);
    ENSURE(hs_byte_count() == bytes0);
    return 0;
}

static int SolveAllocatesNothing(void) {
    int64_t bytes0 = hs_byte_count();
    fixture t;
    ENSURE(fixture_make(&t, 8, 8, 8, 1e-3) == 0);
    // Supernodal first (cholmod_solve2 with kept workspaces), then simplicial LDL^T.
    ENSURE(hs_cholesky_is_supernodal(t.f));
    for (int mode = 0; mode < 2; mode++) {
        if (mode == 1) ENSURE(hs_cholesky_prepare_updates(t.f, 1) == HS_OK);
        ENSURE(hs_cholesky_solve(t.f, t.b, t.x) == HS_OK); // warm-up
        ENSURE(hs_cholesky_solve_many(t.f, 4, t.b, t.x) == HS_OK);
        int64_t calls = hs_alloc_calls(), bytes = hs_byte_count();
        for (int i = 0; i < 20; i++) {
            ENSURE(hs_cholesky_solve(t.f, t.b + (i % 4) * t.a->n, t.x) == HS_OK);
            ENSURE(hs_cholesky_solve_many(t.f, 4, t.b, t.x) == HS_OK);
        }
        ENSURE(hs_alloc_calls() == calls && hs_byte_count() == bytes);
        for (int k = 0; k < 4; k++)
            ENSURE_SMALL(rel_residual(t.a, t.x + k * t.a->n, t.b + k * t.a->n, t.r), 1e-12);
        // In place, and 3 columns (a remainder after blocks of four) against single solves.
        size_t n4 = 4 * (size_t)t.a->n;
        double* y = malloc(sizeof(double) * n4);
        memcpy(y, t.b, sizeof(double) * n4);
        ENSURE(hs_cholesky_solve_many(t.f, 4, y, y) == HS_OK);
        ENSURE(max_abs_diff((int)n4, y, t.x) == 0.0);
        ENSURE(hs_cholesky_solve_many(t.f, 3, t.b + t.a->n, y) == HS_OK);
        for (int k = 0; k < 3; k++)
            ENSURE(max_abs_diff(t.a->n, y + k * t.a->n, t.x + (k + 1) * t.a->n) <=
                   1e-13 * vec_norm(t.a->n, t.x));
        free(y);
    }
    fixture_free(&t);
    ENSURE(hs_byte_count() == bytes0);
    return 0;
}

static int ThreadControl(void) {
    ENSURE(hs_platform_set_threads(0) == HS_ERR_INVALID);
    // libgomp comes with Debian's CHOLMOD, so at least the OpenMP control exists.
    ENSURE(hs_platform_set_threads(1) == HS_OK);
    return 0;
}

// The sparse layer leaves the program's BLAS thread count alone (it once set 1 on first use).
static int LeavesBlasThreads(void) {
    int (*get)(void);
    *(void**)&get = dlsym(RTLD_DEFAULT, "openblas_get_num_threads");
    if (!get) {
        printf("  SKIP: the BLAS is not OpenBLAS\n");
        return 0;
    }
    ENSURE(hs_platform_set_threads(2) == HS_OK);
    ENSURE(get() == 2);
    fixture t;
    ENSURE(fixture_make(&t, 6, 5, 4, 0.0) == 0);
    ENSURE(hs_cholesky_solve(t.f, t.b, t.x) == HS_OK);
    int after = get();
    fixture_free(&t);
    ENSURE(hs_platform_set_threads(1) == HS_OK);
    ENSURE(after == 2);
    return 0;
}

static int CholeskyFaultInjection(void) {
    int64_t bytes0 = hs_byte_count();
    grid g;
    ENSURE(grid_make(&g, 6, 5, 5, 5) == 0);
    hs_csc* a = NULL;
    hs_err err;
    ENSURE(grid_pattern(&g, &a, &err) == HS_OK);
    ENSURE(grid_assemble(&g, a, 1e-3) == 0);
    int64_t with_matrix = hs_byte_count();
    int failures = 0;
    for (int k = 1;; k++) {
        hs_cholesky* f = NULL;
        hs_alloc_fail_after(k);
        hs_status st = hs_cholesky_create(a, &f, &err);
        hs_alloc_fail_after(0);
        if (st == HS_OK) {
            hs_cholesky_destroy(&f);
            break;
        }
        ENSURE(st == HS_ERR_NOMEM && f == NULL);
        ENSURE(hs_byte_count() == with_matrix);
        failures++;
        ENSURE(k < 1000);
    }
    // More than our own few allocations failed: CHOLMOD's are reached as well.
    ENSURE(failures > 5);
    hs_pcg* p = NULL;
    hs_alloc_fail_after(1);
    ENSURE(hs_pcg_create(10, &p) == HS_ERR_NOMEM && p == NULL);
    hs_alloc_fail_after(0);
    hs_csc_destroy(&a);
    grid_free(&g);
    ENSURE(hs_byte_count() == bytes0);
    return 0;
}

typedef struct counted_precond {
    hs_cholesky* f;
    int calls;
} counted_precond;

static hs_status counted_solve(void* ctx, const double* r, double* z) {
    counted_precond* c = ctx;
    c->calls++;
    return hs_cholesky_solve(c->f, r, z);
}

static int PcgConverges(void) {
    int64_t bytes0 = hs_byte_count();
    fixture t;
    ENSURE(fixture_make(&t, 8, 7, 7, 1e-2) == 0);
    int n = t.a->n;
    hs_pcg* pcg = NULL;
    ENSURE(hs_pcg_create(n, &pcg) == HS_OK);
    int iters[3];
    for (int pc = 0; pc < 3; pc++) {
        memset(t.x, 0, sizeof(double) * (size_t)n);
        double rel = 0;
        ENSURE(hs_pcg_solve(pcg, t.a, t.b, t.x, (hs_precond)pc, t.f, 1e-10, 2000, &iters[pc],
                            &rel) == HS_OK);
        ENSURE(rel <= 1e-10);
        ENSURE_SMALL(rel_residual(t.a, t.x, t.b, t.r) - rel, 1e-14);
    }
    // Exact factor: one iteration; Jacobi helps over none on this varied-weight matrix.
    ENSURE(iters[HS_PRECOND_FACTOR] == 1);
    ENSURE(iters[HS_PRECOND_JACOBI] <= iters[HS_PRECOND_NONE] && iters[HS_PRECOND_NONE] > 10);
    // Warm start from the solution: no iteration.
    int it = -1;
    double rel = 1;
    ENSURE(hs_pcg_solve(pcg, t.a, t.b, t.x, HS_PRECOND_JACOBI, NULL, 1e-8, 100, &it, &rel) ==
           HS_OK);
    ENSURE(it == 0 && rel <= 1e-8);
    // Perturbed matrix (+-10 % element weights), preconditioned with the old factor: few
    // iterations and no allocation.
    hs_csc* a2 = NULL;
    ENSURE(hs_csc_clone(t.a, &a2) == HS_OK);
    for (int e = 0; e < t.g.n_tets; e++) t.g.w[e] *= 1.0 + 0.1 * sin(3.0 * e);
    ENSURE(grid_assemble(&t.g, a2, 1e-2) == 0);
    int64_t calls = hs_alloc_calls();
    memset(t.x, 0, sizeof(double) * (size_t)n);
    ENSURE(hs_pcg_solve(pcg, a2, t.b, t.x, HS_PRECOND_FACTOR, t.f, 1e-10, 100, &it, &rel) == HS_OK);
    ENSURE(hs_alloc_calls() == calls);
    ENSURE(it >= 2 && it <= 15 && rel <= 1e-10);
    ENSURE_SMALL(rel_residual(a2, t.x, t.b, t.r), 1e-10);
    // Too few iterations: a warning with the best x and an honest residual.
    memset(t.x, 0, sizeof(double) * (size_t)n);
    ENSURE(hs_pcg_solve(pcg, a2, t.b, t.x, HS_PRECOND_NONE, NULL, 1e-12, 3, &it, &rel) ==
           HS_WARN_NOT_CONVERGED);
    ENSURE(it == 3 && rel > 1e-12 && rel < 1.0);
    ENSURE_NEAR(rel_residual(a2, t.x, t.b, t.r), rel, 1e-14);
    // A budget of k iterations costs exactly k preconditioner solves: none is wasted on a
    // direction that is never taken.
    for (int k = 1; k <= 4; k++) {
        counted_precond cp = {t.f, 0};
        hs_pcg_set_preconditioner(pcg, counted_solve, &cp);
        memset(t.x, 0, sizeof(double) * (size_t)n);
        ENSURE(hs_pcg_solve(pcg, a2, t.b, t.x, HS_PRECOND_CUSTOM, NULL, 1e-14, k, &it, &rel) ==
               HS_WARN_NOT_CONVERGED);
        ENSURE(it == k && cp.calls == k);
        ENSURE(fabs(rel_residual(a2, t.x, t.b, t.r) - rel) <= 1e-12 * rel + 1e-15);
    }
    // Wrong sizes are refused.
    ENSURE(hs_pcg_solve(pcg, a2, t.b, t.x, HS_PRECOND_FACTOR, NULL, 1e-8, 10, &it, &rel) ==
           HS_ERR_INVALID);
    hs_csc_destroy(&a2);
    hs_pcg_destroy(&pcg);
    hs_pcg_destroy(&pcg);
    fixture_free(&t);
    ENSURE(hs_byte_count() == bytes0);
    return 0;
}

// Solve with f and with a fresh factor of a; relative difference of the two solutions.
static double compare_with_fresh(hs_cholesky* f, const hs_csc* a, const double* b, double* x1,
                                 double* x2) {
    hs_cholesky* g = NULL;
    hs_err err;
    if (hs_cholesky_create(a, &g, &err) != HS_OK) return INFINITY;
    if (hs_cholesky_solve(f, b, x1) != HS_OK || hs_cholesky_solve(g, b, x2) != HS_OK) {
        hs_cholesky_destroy(&g);
        return INFINITY;
    }
    hs_cholesky_destroy(&g);
    for (int i = 0; i < a->n; i++) x2[i] -= x1[i];
    return vec_norm(a->n, x2) / vec_norm(a->n, x1);
}

static int UpdownMatchesFreshFactor(void) {
    int64_t bytes0 = hs_byte_count();
    fixture t;
    ENSURE(fixture_make(&t, 9, 8, 8, 1e-3) == 0);
    int n = t.a->n;
    double* x2 = malloc(sizeof(double) * (size_t)n);
    ENSURE(hs_cholesky_prepare_updates(t.f, 8) == HS_OK);
    ENSURE(!hs_cholesky_is_supernodal(t.f));
    // The converted factor still solves the original matrix.
    ENSURE(hs_cholesky_solve(t.f, t.b, t.x) == HS_OK);
    ENSURE_SMALL(rel_residual(t.a, t.x, t.b, t.r), 1e-12);
    // In update mode too, a failed refactor keeps the factor, and a good one replaces it.
    hs_csc* bad = NULL;
    ENSURE(hs_csc_clone(t.a, &bad) == HS_OK);
    bad->val[hs_csc_find(bad, n / 3, n / 3)] = -50.0;
    ENSURE(hs_cholesky_refactor(t.f, bad) == HS_ERR_NOT_POSDEF);
    ENSURE(hs_cholesky_solve(t.f, t.b, t.x) == HS_OK);
    ENSURE_SMALL(rel_residual(t.a, t.x, t.b, t.r), 1e-12);
    grid_assemble(&t.g, bad, 0.3);
    ENSURE(hs_cholesky_refactor(t.f, bad) == HS_OK);
    ENSURE(hs_cholesky_solve(t.f, t.b, t.x) == HS_OK);
    ENSURE_SMALL(rel_residual(bad, t.x, t.b, t.r), 1e-12);
    ENSURE(hs_cholesky_refactor(t.f, t.a) == HS_OK);
    hs_csc_destroy(&bad);

    // Remove (downdate) 8 elements around the middle, as a cut would: no allocation.
    int removed[8];
    double dk[8 * 144];
    int dofs[8 * 12];
    for (int i = 0; i < 8; i++) {
        removed[i] = t.g.n_tets / 2 + 37 * i;
        grid_tet_block(&t.g, removed[i], -t.g.w[removed[i]], dk + 144 * i);
        grid_tet_dofs(&t.g, removed[i], dofs + 12 * i);
        ENSURE(grid_add_tet(&t.g, t.a, removed[i], -1.0) == 0);
    }
    int64_t calls = hs_alloc_calls();
    ENSURE(hs_cholesky_update_elements(t.f, 8, dk, dofs) == HS_OK);
    ENSURE(hs_cholesky_solve(t.f, t.b, t.x) == HS_OK);
    ENSURE(hs_alloc_calls() == calls);
    ENSURE_SMALL(compare_with_fresh(t.f, t.a, t.b, t.x, x2), 1e-8);
    ENSURE_SMALL(rel_residual(t.a, t.x, t.b, t.r), 1e-10);

    // An indefinite change (element stiffened in one direction, softened in another), one
    // element at a time, including an element touching the fixed face.
    int moved[3] = {0, t.g.n_tets / 3, t.g.n_tets - 1};
    for (int i = 0; i < 3; i++) {
        int e = moved[i];
        double k_old[144], k_new[144];
        grid_tet_block(&t.g, e, t.g.w[e], k_old);
        grid_tet_block(&t.g, e, t.g.w[e], k_new);
        for (int r = 0; r < 12; r++) // K_new = S K_old S with S = diag(1.5, 0.6, 1, ...)
            for (int c = 0; c < 12; c++) {
                double sr = r % 3 == 0 ? 1.5 : r % 3 == 1 ? 0.6 : 1.0;
                double sc = c % 3 == 0 ? 1.5 : c % 3 == 1 ? 0.6 : 1.0;
                k_new[r * 12 + c] *= sr * sc;
            }
        int d[12];
        grid_tet_dofs(&t.g, e, d);
        double delta[144];
        for (int q = 0; q < 144; q++) delta[q] = k_new[q] - k_old[q];
        for (int r = 0; r < 12; r++)
            for (int c = 0; c < 12; c++)
                if (d[r] >= 0 && d[c] >= 0)
                    t.a->val[hs_csc_find(t.a, d[r], d[c])] += delta[r * 12 + c];
        ENSURE(hs_cholesky_update_elements(t.f, 1, delta, d) == HS_OK);
    }
    ENSURE_SMALL(compare_with_fresh(t.f, t.a, t.b, t.x, x2), 1e-8);

    // General C C^T update and downdate through hs_cholesky_updown: add then remove.
    int colp[3] = {0, 3, 5}, rowi[5] = {n - 1, 4, n / 2, 7, 6};
    double val[5] = {0.7, -0.2, 0.4, 1.1, 0.3};
    ENSURE(hs_cholesky_updown(t.f, 1, 2, colp, rowi, val) == HS_OK);
    // Rows outside one clique make L fill in: CHOLMOD grows those columns.
    ENSURE(hs_cholesky_solve(t.f, t.b, t.x) == HS_OK);
    hs_csc_spmv(t.a, t.x, t.r);
    for (int j = 0; j < 2; j++) { // r += C (C^T x)
        double s = 0;
        for (int p = colp[j]; p < colp[j + 1]; p++) s += val[p] * t.x[rowi[p]];
        for (int p = colp[j]; p < colp[j + 1]; p++) t.r[rowi[p]] += val[p] * s;
    }
    for (int i = 0; i < n; i++) t.r[i] -= t.b[i];
    ENSURE_SMALL(vec_norm(n, t.r) / vec_norm(n, t.b), 1e-10);
    ENSURE(hs_cholesky_updown(t.f, 0, 2, colp, rowi, val) == HS_OK);
    ENSURE_SMALL(compare_with_fresh(t.f, t.a, t.b, t.x, x2), 1e-8);
    int dup_rowi[5] = {3, 3, 1, 2, 0};
    ENSURE(hs_cholesky_updown(t.f, 1, 2, colp, dup_rowi, val) == HS_ERR_INVALID);

    // A downdate that breaks definiteness is reported; a refactor recovers.
    int big_colp[2] = {0, 1}, big_rowi[1] = {n / 2};
    double big_val[1] = {1e3};
    ENSURE(hs_cholesky_updown(t.f, 0, 1, big_colp, big_rowi, big_val) == HS_ERR_NOT_POSDEF);
    ENSURE(hs_cholesky_solve(t.f, t.b, t.x) == HS_ERR_NOT_POSDEF);
    ENSURE(hs_cholesky_refactor(t.f, t.a) == HS_OK);
    ENSURE(!hs_cholesky_is_supernodal(t.f));
    ENSURE(hs_cholesky_solve(t.f, t.b, t.x) == HS_OK);
    ENSURE_SMALL(rel_residual(t.a, t.x, t.b, t.r), 1e-12);
    // ... and updates keep working on the refactored (simplicial) factor.
    ENSURE(grid_add_tet(&t.g, t.a, removed[0], 1.0) == 0);
    for (int q = 0; q < 144; q++) dk[q] = -dk[q];
    ENSURE(hs_cholesky_update_elements(t.f, 1, dk, dofs) == HS_OK);
    ENSURE_SMALL(compare_with_fresh(t.f, t.a, t.b, t.x, x2), 1e-8);
    // Non-finite C is refused before the factor changes; an update that overflows is reported
    // and the factor refuses to solve until a refactor (both returned OK, factor poisoned).
    double nan_val[1] = {NAN}, huge_val[1] = {1e200};
    ENSURE(hs_cholesky_updown(t.f, 1, 1, big_colp, big_rowi, nan_val) == HS_ERR_NUMERIC);
    ENSURE(hs_cholesky_solve(t.f, t.b, t.x) == HS_OK);
    ENSURE_SMALL(rel_residual(t.a, t.x, t.b, t.r), 1e-10);
    ENSURE(hs_cholesky_updown(t.f, 1, 1, big_colp, big_rowi, huge_val) == HS_ERR_NUMERIC);
    ENSURE(hs_cholesky_solve(t.f, t.b, t.x) != HS_OK);
    ENSURE(hs_cholesky_refactor(t.f, t.a) == HS_OK);
    ENSURE(hs_cholesky_solve(t.f, t.b, t.x) == HS_OK);

    free(x2);
    fixture_free(&t);
    ENSURE(hs_byte_count() == bytes0);
    return 0;
}

// Add sign * blocks [e0, e1) of k (row-major 12x12, dofs[12 e], -1 fixed) into a.
static void add_blocks(hs_csc* a, const double* k, const int* dofs, int e0, int e1, double sign) {
    for (int e = e0; e < e1; e++)
        for (int r = 0; r < 12; r++)
            for (int c = 0; c < 12; c++) {
                int dr = dofs[12 * e + r], dc = dofs[12 * e + c];
                if (dr >= 0 && dc >= 0)
                    a->val[hs_csc_find(a, dr, dc)] += sign * k[144 * e + 12 * r + c];
            }
}

// The aggregated update (one factorisation of the summed change over the union of its dofs)
// against a fresh factor and against the element-by-element update, for removals, indefinite
// relocations, a pin block, and a change whose unpivoted factorisation breaks down (zero
// diagonal: the semidefinite parts are then factored apart). Rank <= union every time.
static int AggregatedUpdates(void) {
    int64_t bytes0 = hs_byte_count();
    fixture t;
    ENSURE(fixture_make(&t, 8, 8, 6, 1e-3) == 0);
    int n = t.a->n;
    hs_cholesky* g = NULL; // element by element, the reference path
    hs_err err;
    ENSURE(hs_cholesky_create(t.a, &g, &err) == HS_OK);
    hs_cholesky_set_aggregate(g, 0);
    ENSURE(hs_cholesky_prepare_updates(t.f, 25) == HS_OK);
    ENSURE(hs_cholesky_prepare_updates(g, 25) == HS_OK);
    double* x2 = malloc(sizeof(double) * (size_t)n);
    double k[25 * 144];
    int dofs[25 * 12];
    hs_cholesky_update_info ia, ie;
    const int mid = t.g.n_tets / 2;
    for (int step = 0; step < 4; step++) {
        int np = 0, nm = 0;
        if (step == 0) { // remove 12 neighbouring tets (the 6 of two adjacent cells)
            for (int i = 0; i < 12; i++) {
                grid_tet_block(&t.g, mid + i, t.g.w[mid + i], k + 144 * i);
                grid_tet_dofs(&t.g, mid + i, dofs + 12 * i);
            }
            nm = 12;
        } else if (step == 1 || step == 3) {
            // Relocation: 12 tets (one of them touching the fixed face at step 3) change
            // their stiffness to S K S, S = diag(1.4, 0.7, 1) per node: indefinite change.
            int e0 = step == 1 ? mid - 40 : 0;
            for (int i = 0; i < 12; i++) {
                int e = e0 + i;
                double* kn = k + 144 * i;
                grid_tet_block(&t.g, e, t.g.w[e], kn);
                grid_tet_block(&t.g, e, t.g.w[e], k + 144 * (12 + i));
                for (int r = 0; r < 12; r++)
                    for (int c = 0; c < 12; c++)
                        kn[12 * r + c] *= (r % 3 == 0   ? 1.4
                                           : r % 3 == 1 ? 0.7
                                                        : 1.0) *
                                          (c % 3 == 0   ? 1.4
                                           : c % 3 == 1 ? 0.7
                                                        : 1.0);
                grid_tet_dofs(&t.g, e, dofs + 12 * i);
                grid_tet_dofs(&t.g, e, dofs + 12 * (12 + i));
            }
            np = nm = 12;
            if (step == 3) { // plus a pin spring on the three dofs of one node
                memmove(k + 144 * 13, k + 144 * 12, sizeof(double) * 144 * 12);
                memmove(dofs + 12 * 13, dofs + 12 * 12, sizeof(int) * 12 * 12);
                memset(k + 144 * 12, 0, sizeof(double) * 144);
                for (int q = 0; q < 12; q++) dofs[12 * 12 + q] = q < 3 ? 3 * (n / 6) + q : -1;
                for (int q = 0; q < 3; q++) k[144 * 12 + 13 * q] = 5.0;
                np = 13;
            }
        } else {
            // D K D - K with D = +-1 per node has a zero diagonal: the summed change has no
            // usable pivot, its semidefinite parts K and D K D do.
            int e = mid + 100;
            grid_tet_block(&t.g, e, 0.3 * t.g.w[e], k);
            grid_tet_block(&t.g, e, 0.3 * t.g.w[e], k + 144);
            for (int r = 0; r < 12; r++)
                for (int c = 0; c < 12; c++)
                    k[144 + 12 * r + c] *= ((r / 3) % 2 ? -1.0 : 1.0) * ((c / 3) % 2 ? -1.0 : 1.0);
            grid_tet_dofs(&t.g, e, dofs);
            grid_tet_dofs(&t.g, e, dofs + 12);
            np = nm = 1;
        }
        add_blocks(t.a, k, dofs, 0, np, 1.0);
        add_blocks(t.a, k, dofs, np, np + nm, -1.0);
        ENSURE(hs_cholesky_update_parts(t.f, np, nm, k, dofs) == HS_OK);
        ENSURE(hs_cholesky_update_parts(g, np, nm, k, dofs) == HS_OK);
        hs_cholesky_last_update(t.f, &ia);
        hs_cholesky_last_update(g, &ie);
        printf("  step %d: aggregated rank %d (union %d, method %d), per element %d\n", step,
               ia.rank, ia.union_dofs, ia.method, ie.rank);
        ENSURE(ie.method == HS_UPDATE_PER_ELEMENT);
        ENSURE(ia.union_dofs > 0 && ia.rank > 0);
        if (step == 2) {
            ENSURE(ia.method == HS_UPDATE_PARTS);
            ENSURE(ia.rank <= 2 * ia.union_dofs);
        } else {
            ENSURE(ia.method == HS_UPDATE_AGGREGATED);
            ENSURE(ia.rank <= ia.union_dofs);
            ENSURE(ia.rank < ie.rank);
        }
        ENSURE_SMALL(compare_with_fresh(t.f, t.a, t.b, t.x, x2), 1e-8);
        ENSURE_SMALL(compare_with_fresh(g, t.a, t.b, t.x, x2), 1e-8);
    }
    // update_elements (summed differences) aggregates too: undo step 0's removal.
    for (int i = 0; i < 12; i++) {
        grid_tet_block(&t.g, mid + i, t.g.w[mid + i], k + 144 * i);
        grid_tet_dofs(&t.g, mid + i, dofs + 12 * i);
    }
    add_blocks(t.a, k, dofs, 0, 12, 1.0);
    int64_t calls = hs_alloc_calls();
    ENSURE(hs_cholesky_update_elements(t.f, 12, k, dofs) == HS_OK);
    ENSURE(hs_alloc_calls() == calls);
    hs_cholesky_last_update(t.f, &ia);
    ENSURE(ia.method == HS_UPDATE_AGGREGATED && ia.rank <= ia.union_dofs);
    ENSURE_SMALL(compare_with_fresh(t.f, t.a, t.b, t.x, x2), 1e-8);
    // Bad input changes nothing.
    ENSURE(hs_cholesky_update_parts(t.f, -1, 2, k, dofs) == HS_ERR_INVALID);
    dofs[5] = dofs[4];
    ENSURE(hs_cholesky_update_parts(t.f, 1, 0, k, dofs) == HS_ERR_INVALID);
    ENSURE_SMALL(compare_with_fresh(t.f, t.a, t.b, t.x, x2), 1e-8);
    free(x2);
    hs_cholesky_destroy(&g);
    fixture_free(&t);
    ENSURE(hs_byte_count() == bytes0);
    return 0;
}

// Soften (scale -0.5) or stiffen (2.0) the tets of grid cell (cx, cy, cz) in t's matrix; their
// free dofs into dofs. Returns how many, -1 on failure.
static int change_cell(fixture* t, int cx, int cy, int cz, double scale, int* dofs) {
    int nd = 0;
    for (int e = 0; e < t->g.n_tets; e++) {
        double x0[3];
        grid_coords(&t->g, t->g.tets[4 * e], x0);
        if (x0[0] != cx || x0[1] != cy || x0[2] != cz) continue;
        if (grid_add_tet(&t->g, t->a, e, scale) != 0) return -1;
        grid_tet_dofs(&t->g, e, dofs + nd);
        nd += 12;
    }
    for (int q = 0; q < nd; q++) // fixed dofs are -1: leave them out
        if (dofs[q] < 0) dofs[q--] = dofs[--nd];
    return nd;
}

// Partial refactorisation: changes confined to small regions of the grid recompute part of the
// factor and agree with a fresh factor; a whole pass, a non-SPD change (factor refused until a
// refactor), the pattern check, update mode and allocation faults.
// hs_parallel runners for the tests: every task in turn on this thread, or each on a thread.
typedef struct par_log {
    int calls, parts;
    _Atomic int tasks;
} par_log;
static void par_in_turn(int n, hs_task_fn* task, void* ctx, void* user);

static int PartialRefactor(void) {
    int64_t bytes0 = hs_byte_count();
    fixture t;
    ENSURE(fixture_make(&t, 12, 10, 8, 1e-3) == 0);
    ENSURE(hs_cholesky_is_supernodal(t.f));
    int n = t.a->n;
    double* x2 = malloc(sizeof(double) * (size_t)n);
    int* dofs = malloc(sizeof(int) * 12 * (size_t)t.g.n_tets);
    // Before prepare: unsupported.
    ENSURE(hs_cholesky_refactor_partial(t.f, t.a, -1, NULL) == HS_ERR_UNSUPPORTED);
    // Every allocation of prepare fails in turn cleanly; the factor stays usable. What it
    // keeps is what hs_cholesky_partial_bytes says beforehand.
    int64_t est = hs_cholesky_partial_bytes(t.f), before = hs_byte_count();
    ENSURE(est > 8 * hs_cholesky_factor_nnz(t.f) / 2);
    for (int k = 1;; k++) {
        hs_alloc_fail_after(k);
        hs_status st = hs_cholesky_prepare_partial(t.f, t.a);
        hs_alloc_fail_after(0);
        if (st == HS_OK) break;
        ENSURE(st == HS_ERR_NOMEM && k < 60);
        ENSURE(hs_cholesky_solve(t.f, t.b, t.x) == HS_OK);
        ENSURE_SMALL(rel_residual(t.a, t.x, t.b, t.r), 1e-12);
    }
    int64_t kept = hs_byte_count() - before;
    printf("  partial data: %lld bytes kept, %lld estimated, factor %lld entries\n",
           (long long)kept, (long long)est, (long long)hs_cholesky_factor_nnz(t.f));
    ENSURE(llabs(kept - est) <= est / 50);
    ENSURE(hs_cholesky_partial_share(t.f) == 1.0);
    ENSURE_SMALL(compare_with_fresh(t.f, t.a, t.b, t.x, x2), 1e-10);
    // Soften or stiffen the tets of one cell at a time, in cells across the grid.
    double least = 1;
    for (int k = 0; k < 8; k++) {
        int nd =
            change_cell(&t, 1 + (k * 5) % 10, 1 + (k * 3) % 8, 1 + k % 6, k % 2 ? -0.5 : 2.0, dofs);
        ENSURE(nd > 0);
        ENSURE(hs_cholesky_refactor_partial(t.f, t.a, nd, dofs) == HS_OK);
        double share = hs_cholesky_partial_share(t.f);
        ENSURE(share > 0 && share < 1);
        least = share < least ? share : least;
        ENSURE_SMALL(compare_with_fresh(t.f, t.a, t.b, t.x, x2), 1e-10);
    }
    printf("  8 local changes: least share of a factorisation %.2f\n", least);
    ENSURE(least < 0.6);
    // The same on two threads: a clone of the factor state cannot be had, so compare each
    // step with a fresh factor and with the one-thread result of the same matrix.
    hs_parallel no_runner = {.width = 2};
    ENSURE(hs_cholesky_set_partial_parallel(t.f, &no_runner) == HS_ERR_INVALID);
    hs_worker* w = NULL;
    ENSURE(hs_worker_create(hs_sparse_thread_init, NULL, &w) == HS_OK);
    hs_parallel two = {.run = hs_worker_run,
                       .user = w,
                       .width = 2,
                       .begin = hs_worker_begin,
                       .end = hs_worker_end};
    ENSURE(hs_cholesky_set_partial_parallel(t.f, &two) == HS_OK);
    double* x1 = malloc(sizeof(double) * (size_t)n);
    long long helped = 0;
    double t_two = 1e30, t_one = 1e30; // fastest whole pass, ms
    for (int k = 0; k < 60 && (k < 4 || helped == 0); k++) {
        // Stiffen only: a cell comes round again every 40 rounds.
        int nd = change_cell(&t, 1 + (k * 7) % 10, 1 + (k * 5) % 8, 1 + (k * 3) % 6,
                             k % 2 ? 0.5 : 1.0, dofs);
        ENSURE(nd > 0);
        ENSURE(hs_cholesky_refactor_partial(t.f, t.a, nd, dofs) == HS_OK);
        ENSURE(hs_cholesky_solve(t.f, t.b, x1) == HS_OK);
        ENSURE_SMALL(compare_with_fresh(t.f, t.a, t.b, t.x, x2), 1e-10);
        // A whole pass on two threads, then one on one thread: the same to round-off.
        int64_t t0 = hs_now_ns();
        ENSURE(hs_cholesky_refactor_partial(t.f, t.a, -1, NULL) == HS_OK);
        t_two = fmin(t_two, (double)(hs_now_ns() - t0) * 1e-6);
        ENSURE(hs_cholesky_solve(t.f, t.b, x1) == HS_OK);
        ENSURE(hs_cholesky_set_partial_parallel(t.f, NULL) == HS_OK);
        t0 = hs_now_ns();
        ENSURE(hs_cholesky_refactor_partial(t.f, t.a, -1, NULL) == HS_OK);
        t_one = fmin(t_one, (double)(hs_now_ns() - t0) * 1e-6);
        ENSURE(hs_cholesky_solve(t.f, t.b, x2) == HS_OK);
        double dn = 0, xn = 0;
        for (int i = 0; i < n; i++) {
            dn = fmax(dn, fabs(x1[i] - x2[i]));
            xn = fmax(xn, fabs(x2[i]));
        }
        ENSURE_SMALL(dn / xn, 1e-12);
        ENSURE(hs_cholesky_set_partial_parallel(t.f, &two) == HS_OK);
        helped = hs_worker_tasks(w);
    }
    // The helper took chunks of the large supernodes (a busy machine may delay it for a
    // while, hence up to 60 rounds).
    printf("  two threads: %lld chunks run by the helper; fastest whole pass %.3f ms, one thread "
           "%.3f ms\n",
           helped, t_two, t_one);
    ENSURE(helped > 0);
    // The chunks are the runner's to run, not to choose: the helper, and one thread running
    // them backwards, give the same bits.
    ENSURE(hs_cholesky_refactor_partial(t.f, t.a, -1, NULL) == HS_OK);
    ENSURE(hs_cholesky_solve(t.f, t.b, x1) == HS_OK);
    par_log log = {0};
    hs_parallel backwards = {.run = par_in_turn, .user = &log, .width = 2};
    ENSURE(hs_cholesky_set_partial_parallel(t.f, &backwards) == HS_OK);
    ENSURE(hs_cholesky_refactor_partial(t.f, t.a, -1, NULL) == HS_OK);
    ENSURE(hs_cholesky_solve(t.f, t.b, x2) == HS_OK);
    ENSURE(log.calls > 0);
    ENSURE(memcmp(x1, x2, sizeof(double) * (size_t)n) == 0);
    ENSURE(hs_cholesky_set_partial_parallel(t.f, NULL) == HS_OK);
    hs_worker_destroy(&w);
    ENSURE(w == NULL);
    free(x1);
    // No change at all recomputes nothing and changes nothing.
    ENSURE(hs_cholesky_refactor_partial(t.f, t.a, 0, dofs) == HS_OK);
    ENSURE(hs_cholesky_partial_share(t.f) == 0.0);
    ENSURE_SMALL(compare_with_fresh(t.f, t.a, t.b, t.x, x2), 1e-10);
    // Bad dofs are refused before anything changes.
    int bad_dof = n;
    ENSURE(hs_cholesky_refactor_partial(t.f, t.a, 1, &bad_dof) == HS_ERR_INVALID);
    ENSURE(hs_cholesky_solve(t.f, t.b, t.x) == HS_OK);
    // Another matrix object with the same pattern is accepted (checked in full), a different
    // pattern refused.
    hs_csc* a2 = NULL;
    ENSURE(hs_csc_clone(t.a, &a2) == HS_OK);
    ENSURE(hs_cholesky_refactor_partial(t.f, a2, -1, NULL) == HS_OK);
    ENSURE(hs_cholesky_partial_share(t.f) == 1.0);
    hs_csc* a3 = NULL;
    ENSURE(hs_csc_clone(t.a, &a3) == HS_OK);
    int c = n / 2, p0 = a3->colp[c];
    a3->rowi[p0]--;
    ENSURE(hs_cholesky_refactor_partial(t.f, a3, -1, NULL) == HS_ERR_INVALID);
    hs_csc_destroy(&a3);
    hs_csc_destroy(&a2);
    // A change that makes A indefinite: refused, and solves refuse until a refactor.
    int d = dofs[0], pd = hs_csc_find(t.a, d, d);
    double keep = t.a->val[pd];
    t.a->val[pd] = -100.0;
    ENSURE(hs_cholesky_refactor_partial(t.f, t.a, 1, &d) == HS_ERR_NOT_POSDEF);
    ENSURE(hs_cholesky_solve(t.f, t.b, t.x) == HS_ERR_NOT_POSDEF);
    t.a->val[pd] = keep;
    ENSURE(hs_cholesky_refactor(t.f, t.a) == HS_OK);
    ENSURE_SMALL(compare_with_fresh(t.f, t.a, t.b, t.x, x2), 1e-10);
    // After a full refactor the kept update matrices are stale: the next call redoes all.
    ENSURE(hs_cholesky_refactor_partial(t.f, t.a, 1, &d) == HS_OK);
    ENSURE(hs_cholesky_partial_share(t.f) == 1.0);
    ENSURE_SMALL(compare_with_fresh(t.f, t.a, t.b, t.x, x2), 1e-10);
    // Update mode (simplicial LDL^T) excludes it.
    ENSURE(hs_cholesky_prepare_updates(t.f, 1) == HS_OK);
    ENSURE(hs_cholesky_refactor_partial(t.f, t.a, 1, &d) == HS_ERR_UNSUPPORTED);
    ENSURE(hs_cholesky_prepare_partial(t.f, t.a) == HS_ERR_UNSUPPORTED);
    ENSURE(hs_cholesky_partial_bytes(t.f) == -1);
    free(x2);
    free(dofs);
    fixture_free(&t);
    ENSURE(hs_byte_count() == bytes0);
    return 0;
}

// Removing a slab of elements leaves the far part of the grid without support: the downdate
// must report the singular result rather than produce a factor with round-off pivots.
static int FreeFragmentDetected(void) {
    int64_t bytes0 = hs_byte_count();
    fixture t;
    ENSURE(fixture_make(&t, 8, 6, 6, 0.0) == 0);
    ENSURE(hs_cholesky_prepare_updates(t.f, 1) == HS_OK);
    int cap = t.g.n_tets;
    double* dk = malloc(sizeof(double) * 144 * (size_t)cap);
    int* dofs = malloc(sizeof(int) * 12 * (size_t)cap);
    int* eid = malloc(sizeof(int) * (size_t)cap);
    int m = 0;
    for (int e = 0; e < t.g.n_tets; e++) {
        double x0[3];
        grid_coords(&t.g, t.g.tets[4 * e], x0);
        if (x0[0] != 3) continue; // the tet's first node is its cell's lowest corner
        grid_tet_block(&t.g, e, -t.g.w[e], dk + 144 * m);
        grid_tet_dofs(&t.g, e, dofs + 12 * m);
        eid[m++] = e;
    }
    ENSURE(m == 6 * 5 * 5);
    ENSURE(hs_cholesky_update_elements(t.f, m, dk, dofs) == HS_ERR_NOT_POSDEF);
    ENSURE(hs_cholesky_solve(t.f, t.b, t.x) == HS_ERR_NOT_POSDEF);
    // Removing only half of the slab keeps the structure connected: accepted.
    ENSURE(hs_cholesky_refactor(t.f, t.a) == HS_OK);
    ENSURE(hs_cholesky_update_elements(t.f, m / 2, dk, dofs) == HS_OK);
    for (int k = 0; k < m / 2; k++) ENSURE(grid_add_tet(&t.g, t.a, eid[k], -1.0) == 0);
    double* x2 = malloc(sizeof(double) * (size_t)t.a->n);
    ENSURE_SMALL(compare_with_fresh(t.f, t.a, t.b, t.x, x2), 1e-8);
    free(x2);
    free(eid);
    free(dk);
    free(dofs);
    fixture_free(&t);
    ENSURE(hs_byte_count() == bytes0);
    return 0;
}

// Allocation failures while entering update mode and updating leave a factor that a refactor
// restores, and nothing leaks.
static int UpdateFaultInjection(void) {
    int64_t bytes0 = hs_byte_count();
    fixture t;
    ENSURE(fixture_make(&t, 8, 7, 7, 1e-3) == 0);
    ENSURE(hs_cholesky_is_supernodal(t.f));
    double dk[144];
    int dofs[12];
    int e = t.g.n_tets / 2;
    grid_tet_block(&t.g, e, -t.g.w[e], dk);
    grid_tet_dofs(&t.g, e, dofs);
    int failures = 0;
    for (int k = 1;; k++) {
        hs_alloc_fail_after(k);
        hs_status st = hs_cholesky_prepare_updates(t.f, 1);
        if (st == HS_OK) st = hs_cholesky_update_elements(t.f, 1, dk, dofs);
        hs_alloc_fail_after(0);
        if (st == HS_OK) break;
        ENSURE(st == HS_ERR_NOMEM && k < 100);
        failures++;
        ENSURE(hs_cholesky_refactor(t.f, t.a) == HS_OK);
        ENSURE(hs_cholesky_solve(t.f, t.b, t.x) == HS_OK);
        ENSURE_SMALL(rel_residual(t.a, t.x, t.b, t.r), 1e-12);
    }
    ENSURE(failures >= 3);
    ENSURE(grid_add_tet(&t.g, t.a, e, -1.0) == 0);
    double* x2 = malloc(sizeof(double) * (size_t)t.a->n);
    ENSURE_SMALL(compare_with_fresh(t.f, t.a, t.b, t.x, x2), 1e-8);
    free(x2);
    fixture_free(&t);
    ENSURE(hs_byte_count() == bytes0);
    return 0;
}

// Small matrices get a simplicial factor from CHOLMOD; update mode and refactor work there too,
// and an empty matrix is valid.
// A simplicial factor (LDL^T) takes negative pivots where LL^T stops: still NOT_POSDEF, as
// the body's step relies on to go on with its last good factor (it said NUMERIC, found in
// review: a StVK bar under compression then failed every later step).
static int SimplicialNotPosdef(void) {
    int64_t bytes0 = hs_byte_count();
    fixture t;
    ENSURE(fixture_make(&t, 4, 3, 3, 1e-3) == 0);
    ENSURE(!hs_cholesky_is_supernodal(t.f));
    int n = t.a->n;
    hs_csc *bad = NULL, *nan_a = NULL;
    ENSURE(hs_csc_clone(t.a, &bad) == HS_OK && hs_csc_clone(t.a, &nan_a) == HS_OK);
    bad->val[hs_csc_find(bad, n / 2, n / 2)] = -100.0;
    nan_a->val[hs_csc_find(nan_a, n / 3, n / 3)] = NAN;
    ENSURE(hs_cholesky_refactor(t.f, bad) == HS_ERR_NOT_POSDEF);
    ENSURE(hs_cholesky_solve(t.f, t.b, t.x) == HS_OK); // the good factor is kept
    ENSURE_SMALL(rel_residual(t.a, t.x, t.b, t.r), 1e-12);
    ENSURE(hs_cholesky_refactor(t.f, nan_a) == HS_ERR_NUMERIC);
    ENSURE(hs_cholesky_solve(t.f, t.b, t.x) == HS_OK);
    ENSURE_SMALL(rel_residual(t.a, t.x, t.b, t.r), 1e-12);
    hs_cholesky* f2 = NULL;
    hs_err err = {0};
    ENSURE(hs_cholesky_create(bad, &f2, &err) == HS_ERR_NOT_POSDEF);
    ENSURE(f2 == NULL && strstr(err.msg, "not positive definite") != NULL);
    ENSURE(hs_cholesky_create(nan_a, &f2, &err) == HS_ERR_NUMERIC && f2 == NULL);
    hs_csc_destroy(&bad);
    hs_csc_destroy(&nan_a);
    fixture_free(&t);
    ENSURE(hs_byte_count() == bytes0);
    return 0;
}

static int SmallAndEmpty(void) {
    int64_t bytes0 = hs_byte_count();
    fixture t;
    ENSURE(fixture_make(&t, 4, 3, 3, 1e-3) == 0);
    int n = t.a->n;
    ENSURE(!hs_cholesky_is_supernodal(t.f));
    ENSURE(hs_cholesky_prepare_updates(t.f, 2) == HS_OK);
    double dk[144];
    int dofs[12];
    int e = t.g.n_tets / 2;
    grid_tet_block(&t.g, e, -t.g.w[e], dk);
    grid_tet_dofs(&t.g, e, dofs);
    ENSURE(grid_add_tet(&t.g, t.a, e, -1.0) == 0);
    ENSURE(hs_cholesky_update_elements(t.f, 1, dk, dofs) == HS_OK);
    double* x2 = malloc(sizeof(double) * (size_t)n);
    ENSURE_SMALL(compare_with_fresh(t.f, t.a, t.b, t.x, x2), 1e-8);
    ENSURE(hs_cholesky_refactor(t.f, t.a) == HS_OK);
    ENSURE(hs_cholesky_solve(t.f, t.b, t.x) == HS_OK);
    ENSURE_SMALL(rel_residual(t.a, t.x, t.b, t.r), 1e-12);
    // Bad element input changes nothing.
    dofs[3] = dofs[4];
    ENSURE(hs_cholesky_update_elements(t.f, 1, dk, dofs) == HS_ERR_INVALID);
    dofs[3] = n;
    ENSURE(hs_cholesky_update_elements(t.f, 1, dk, dofs) == HS_ERR_INVALID);
    ENSURE(hs_cholesky_solve(t.f, t.b, t.x) == HS_OK);
    ENSURE_SMALL(rel_residual(t.a, t.x, t.b, t.r), 1e-12);
    free(x2);
    fixture_free(&t);

    int start[2] = {0, 0}, map[3] = {-1, -1, -1};
    hs_csc* a = NULL;
    hs_cholesky* f = NULL;
    hs_pcg* p = NULL;
    hs_err err;
    ENSURE(hs_csc_create_block_pattern(1, start, NULL, map, 0, &a, &err) == HS_OK);
    ENSURE(a->n == 0 && a->nnz == 0);
    ENSURE(hs_cholesky_create(a, &f, &err) == HS_OK);
    ENSURE(hs_cholesky_solve(f, NULL, NULL) == HS_OK);
    ENSURE(hs_pcg_create(0, &p) == HS_OK);
    int it = -1;
    double rel = -1;
    ENSURE(hs_pcg_solve(p, a, NULL, NULL, HS_PRECOND_FACTOR, f, 1e-8, 10, &it, &rel) == HS_OK);
    hs_pcg_destroy(&p);
    hs_cholesky_destroy(&f);
    hs_csc_destroy(&a);
    ENSURE(hs_byte_count() == bytes0);
    return 0;
}

// P A P^T for perm[k] = row of A at position k (test helper; triplets sorted per column).
static hs_csc* permute_csc(const hs_csc* a, const int* perm) {
    int n = a->n;
    int* pos = malloc(sizeof(int) * (size_t)n);
    for (int k = 0; k < n; k++) pos[perm[k]] = k;
    hs_csc* p = hs_calloc(1, sizeof *p);
    p->n = n;
    p->nnz = a->nnz;
    p->colp = hs_calloc((size_t)n + 1, sizeof(int));
    p->rowi = hs_alloc(sizeof(int) * (size_t)a->nnz);
    p->val = hs_alloc(sizeof(double) * (size_t)a->nnz);
    for (int j = 0; j < n; j++) p->colp[pos[j] + 1] += a->colp[j + 1] - a->colp[j];
    for (int j = 0; j < n; j++) p->colp[j + 1] += p->colp[j];
    for (int j = 0; j < n; j++) {
        int c = pos[j], q = p->colp[c];
        for (int t = a->colp[j]; t < a->colp[j + 1]; t++, q++) {
            p->rowi[q] = pos[a->rowi[t]];
            p->val[q] = a->val[t];
        }
        for (int u = p->colp[c] + 1; u < q; u++) // insertion sort of the column by row
            for (int v = u; v > p->colp[c] && p->rowi[v - 1] > p->rowi[v]; v--) {
                int ti = p->rowi[v];
                p->rowi[v] = p->rowi[v - 1];
                p->rowi[v - 1] = ti;
                double tv = p->val[v];
                p->val[v] = p->val[v - 1];
                p->val[v - 1] = tv;
            }
    }
    free(pos);
    return p;
}

// A matrix renumbered by hs_cholesky_fill_order and factorised with the natural ordering
// solves the same system, with the same fill, and refactorises without any allocation:
// for a supernodal (large) and a simplicial (small) factor.
static int NaturalOrderInPlace(void) {
    int64_t bytes0 = hs_byte_count();
    const int dims[2][3] = {{9, 8, 8}, {3, 2, 2}};
    for (int c = 0; c < 2; c++) {
        fixture t;
        ENSURE(fixture_make(&t, dims[c][0], dims[c][1], dims[c][2], 1e-3) == 0);
        int n = t.a->n;
        int* perm = malloc(sizeof(int) * (size_t)n);
        ENSURE(hs_cholesky_fill_order(t.a, perm, NULL) == HS_OK);
        hs_csc* pa = permute_csc(t.a, perm);
        hs_cholesky* f = NULL;
        ENSURE(hs_cholesky_create_natural(pa, &f, NULL) == HS_OK);
        ENSURE(hs_cholesky_is_supernodal(f) == hs_cholesky_is_supernodal(t.f));
        ENSURE(hs_cholesky_is_supernodal(f) == (c == 0));
        ENSURE(hs_cholesky_factor_nnz(f) <= hs_cholesky_factor_nnz(t.f) * 11 / 10);
        double *pb = malloc(sizeof(double) * (size_t)n), *y = malloc(sizeof(double) * (size_t)n);
        for (int k = 0; k < n; k++) pb[k] = t.b[perm[k]];
        ENSURE(hs_cholesky_solve(t.f, t.b, t.x) == HS_OK);
        ENSURE(hs_cholesky_solve(f, pb, y) == HS_OK);
        for (int k = 0; k < n; k++) ENSURE_SMALL(y[k] - t.x[perm[k]], 1e-10 * vec_norm(n, t.x));
        ENSURE(hs_cholesky_refactor(f, pa) == HS_OK); // warm-up (first-call workspaces)
        for (int q = 0; q < pa->nnz; q++) pa->val[q] *= 2.0;
        int64_t calls = hs_alloc_calls();
        ENSURE(hs_cholesky_refactor(f, pa) == HS_OK);
        ENSURE(hs_cholesky_solve(f, pb, y) == HS_OK);
        ENSURE(hs_alloc_calls() == calls);
        for (int k = 0; k < n; k++) ENSURE_SMALL(2 * y[k] - t.x[perm[k]], 1e-10 * vec_norm(n, t.x));
        free(pb);
        free(y);
        free(perm);
        hs_cholesky_destroy(&f);
        hs_csc_destroy(&pa);
        fixture_free(&t);
    }
    ENSURE(hs_byte_count() == bytes0);
    return 0;
}

// hs_parallel runners for the tests: every task in turn on this thread, or each on a thread.

typedef struct par_task {
    hs_task_fn* task;
    void* ctx;
    int i;
    par_log* log;
} par_task;

static void* par_task_main(void* a) {
    par_task* p = a;
    p->task(p->i, p->ctx);
    atomic_fetch_add(&p->log->tasks, 1);
    return NULL;
}

static void par_in_turn(int n, hs_task_fn* task, void* ctx, void* user) {
    par_log* log = user;
    log->calls++;
    log->parts = n;
    for (int i = n - 1; i >= 0; --i) { // backwards: no part may rely on another's having run
        task(i, ctx);
        atomic_fetch_add(&log->tasks, 1);
    }
}

static void par_threads(int n, hs_task_fn* task, void* ctx, void* user) {
    par_log* log = user;
    log->calls++;
    log->parts = n;
    pthread_t t[HS_PARALLEL_MAX];
    par_task a[HS_PARALLEL_MAX];
    for (int i = 0; i < n; ++i) {
        a[i] = (par_task){task, ctx, i, log};
        if (pthread_create(&t[i], NULL, par_task_main, &a[i]) != 0) {
            t[i] = 0;
            par_task_main(&a[i]);
        }
    }
    for (int i = 0; i < n; ++i)
        if (t[i]) pthread_join(t[i], NULL);
}

// Diagonal 3x3 blocks of A^-1 from sparse forward solves agree with full solves: on the
// supernodal factor, on the natural-order one and on an updatable (simplicial LDL') one;
// a missing dof gives a zero row and column; bad input is refused.
static int InverseDiagBlocks(void) {
    int64_t bytes0 = hs_byte_count();
    fixture t;
    ENSURE(fixture_make(&t, 7, 6, 5, 1e-3) == 0);
    const int n = t.a->n, nb = n / 3;
    int* dofs = malloc(sizeof(int) * 3 * (size_t)nb);
    double* blk = malloc(sizeof(double) * 9 * (size_t)nb);
    double* blk2 = malloc(sizeof(double) * 9 * (size_t)nb);
    double* e = calloc((size_t)n, sizeof(double));
    double* col = malloc(sizeof(double) * (size_t)n);
    ENSURE(dofs && blk && blk2 && e && col);
    for (int k = 0; k < 3 * nb; ++k) dofs[k] = k;
    dofs[3 * 5 + 1] = -1; // block 5 without its y dof
    hs_err err = {0};
    hs_cholesky* nat = NULL;
    ENSURE(hs_cholesky_create_natural(t.a, &nat, &err) == HS_OK);
    hs_cholesky* upd = NULL;
    ENSURE(hs_cholesky_create(t.a, &upd, &err) == HS_OK);
    ENSURE(hs_cholesky_prepare_updates(upd, 12) == HS_OK);
    hs_cholesky* fs[3] = {t.f, nat, upd};
    double worst = 0;
    for (int v = 0; v < 3; ++v) {
        ENSURE(hs_cholesky_inverse_diag3(fs[v], nb, dofs, blk) == HS_OK);
        for (int b = 0; b < nb; b += 7) { // every 7th block against three full solves
            for (int a = 0; a < 3; ++a) {
                int d = dofs[3 * b + a];
                for (int c = 0; c < 3; ++c) {
                    double ref = 0;
                    if (d >= 0 && dofs[3 * b + c] >= 0) {
                        e[d] = 1;
                        ENSURE(hs_cholesky_solve(t.f, e, col) == HS_OK);
                        e[d] = 0;
                        ref = col[dofs[3 * b + c]];
                    }
                    double got = blk[9 * b + 3 * a + c];
                    ENSURE(got == blk[9 * b + 3 * c + a]); // exactly symmetric
                    if (ref == 0) ENSURE(got == 0);
                    worst = fmax(worst, fabs(got - ref) / fabs(blk[9 * b]));
                }
            }
        }
        // Block 5 lacks its y dof: row and column 1 are zero, the rest is not.
        const double* b5 = blk + 9 * 5;
        ENSURE(b5[1] == 0 && b5[3] == 0 && b5[4] == 0 && b5[5] == 0 && b5[7] == 0);
        ENSURE(b5[0] > 0 && b5[8] > 0);
        // Split into parts (run in turn, then on threads): the same blocks bit for bit, and
        // every part ran.
        for (int width = 2; width <= 5; width += 3)
            for (int threaded = 0; threaded < 2; ++threaded) {
                par_log log = {0};
                hs_parallel par = {
                    .run = threaded ? par_threads : par_in_turn, .user = &log, .width = width};
                ENSURE(hs_cholesky_inverse_diag3_par(fs[v], nb, dofs, blk2, &par) == HS_OK);
                ENSURE(memcmp(blk, blk2, sizeof(double) * 9 * (size_t)nb) == 0);
                ENSURE(log.calls == 1 && log.parts == width && log.tasks == width);
            }
        // And on an hs_worker, woken by begin and put back to sleep by end.
        hs_worker* w = NULL;
        ENSURE(hs_worker_create(NULL, NULL, &w) == HS_OK);
        hs_parallel on_worker = {.run = hs_worker_run,
                                 .user = w,
                                 .width = 4,
                                 .begin = hs_worker_begin,
                                 .end = hs_worker_end};
        ENSURE(hs_cholesky_inverse_diag3_par(fs[v], nb, dofs, blk2, &on_worker) == HS_OK);
        ENSURE(memcmp(blk, blk2, sizeof(double) * 9 * (size_t)nb) == 0);
        hs_worker_destroy(&w);
    }
    printf("  %d blocks, worst difference from full solves %.2e (of the block's first entry)\n", nb,
           worst);
    ENSURE(worst < 1e-12);
    dofs[0] = n; // out of range
    ENSURE(hs_cholesky_inverse_diag3(t.f, nb, dofs, blk) == HS_ERR_INVALID);
    ENSURE(hs_cholesky_inverse_diag3(NULL, nb, dofs, blk) == HS_ERR_INVALID);
    ENSURE(hs_cholesky_inverse_diag3(t.f, 0, NULL, NULL) == HS_OK);
    dofs[0] = 0;
    hs_parallel bad = {.width = 2};
    ENSURE(hs_cholesky_inverse_diag3_par(t.f, nb, dofs, blk2, &bad) == HS_ERR_INVALID);
    hs_cholesky_destroy(&nat);
    hs_cholesky_destroy(&upd);
    free(dofs);
    free(blk);
    free(blk2);
    free(e);
    free(col);
    fixture_free(&t);
    ENSURE(hs_byte_count() == bytes0);
    return 0;
}

HS_TEST_MAIN(HS_CASE(CscPatternAndSpmv), HS_CASE(CscBadInput), HS_CASE(CholeskySolve),
             HS_CASE(SimplicialNotPosdef), HS_CASE(CholeskyRefactor),
             HS_CASE(CholeskyNotPosdefKeepsFactor), HS_CASE(SolveAllocatesNothing),
             HS_CASE(ThreadControl), HS_CASE(LeavesBlasThreads), HS_CASE(CholeskyFaultInjection),
             HS_CASE(PcgConverges), HS_CASE(UpdownMatchesFreshFactor), HS_CASE(AggregatedUpdates),
             HS_CASE(PartialRefactor), HS_CASE(FreeFragmentDetected), HS_CASE(UpdateFaultInjection),
             HS_CASE(SmallAndEmpty), HS_CASE(NaturalOrderInPlace), HS_CASE(InverseDiagBlocks))
