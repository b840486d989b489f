// SPDX-License-Identifier: GPL-2.0-or-later
// Timing of the sparse module on 3D grid matrices (27-point node stencil, six tets per cell,
// x = 0 face fixed): analysis, numeric refactor, solve, factor size, and the update mode used
// by cutting. A measurement tool, not a test.
//   sparse_timing [--threads N] [--cpu] [NX NY NZ]...   (default: 15 14 13 and 22 22 22)
#define _POSIX_C_SOURCE 200809L // clock_gettime
#include "platform.h"
#include "sparse.h"
#include "sparse_grid.h"

#include <stdio.h>
#include <stdlib.h>
#include <time.h>

static int cmp_double(const void* a, const void* b) {
    double x = *(const double*)a, y = *(const double*)b;
    return (x > y) - (x < y);
}

static double median(double* v, int n) {
    qsort(v, (size_t)n, sizeof(double), cmp_double);
    return v[n / 2];
}

// Wall clock by default; --cpu uses this thread's CPU time, steadier on a shared machine (valid
// with --threads 1, when all the work runs on this thread).
static int g_cpu_clock;
static int64_t now_ns(void) {
    if (!g_cpu_clock) return hs_now_ns();
    struct timespec ts;
    clock_gettime(CLOCK_THREAD_CPUTIME_ID, &ts);
    return (int64_t)ts.tv_sec * 1000000000 + ts.tv_nsec;
}
static double ms_since(int64_t t0) {
    return (double)(now_ns() - t0) * 1e-6;
}

static int run(int nx, int ny, int nz) {
    enum { REPS = 7 };
    grid g;
    hs_csc* a = NULL;
    hs_err err;
    if (grid_make(&g, nx, ny, nz, 1) != 0 || grid_pattern(&g, &a, &err) != HS_OK ||
        grid_assemble(&g, a, 1e-3) != 0) {
        fprintf(stderr, "set-up failed\n");
        return 1;
    }
    int n = a->n;
    double* b = malloc(sizeof(double) * (size_t)n);
    double* x = malloc(sizeof(double) * (size_t)n);
    double* r = malloc(sizeof(double) * (size_t)n);
    for (int i = 0; i < n; i++) b[i] = sin(0.37 * i);
    double t[REPS];

    hs_cholesky* f = NULL;
    int64_t t0 = now_ns();
    if (hs_cholesky_create(a, &f, &err) != HS_OK) {
        fprintf(stderr, "create: %s\n", err.msg);
        return 1;
    }
    double create_ms = ms_since(t0);
    for (int rep = 0; rep < REPS; rep++) {
        t0 = now_ns();
        if (hs_cholesky_refactor(f, a) != HS_OK) return 1;
        t[rep] = ms_since(t0);
    }
    double refactor_ms = median(t, REPS);
    hs_cholesky_solve(f, b, x);
    for (int rep = 0; rep < REPS; rep++) {
        t0 = now_ns();
        hs_cholesky_solve(f, b, x);
        t[rep] = ms_since(t0);
    }
    double solve_ms = median(t, REPS);
    printf("%d,%d,%s,%.1f,%.2f,%.3f,%lld", n, a->nnz,
           hs_cholesky_is_supernodal(f) ? "super" : "simpl", create_ms - refactor_ms, refactor_ms,
           solve_ms, (long long)hs_cholesky_factor_nnz(f));

    // PCG on a perturbed matrix (element weights +-10 %), preconditioned with the factor of
    // the original: the refactor-free path for a changing stiffness.
    {
        hs_csc* a2 = NULL;
        hs_pcg* pcg = NULL;
        if (hs_csc_clone(a, &a2) != HS_OK || hs_pcg_create(n, &pcg) != HS_OK) return 1;
        double* w0 = malloc(sizeof(double) * (size_t)g.n_tets);
        memcpy(w0, g.w, sizeof(double) * (size_t)g.n_tets);
        for (int e = 0; e < g.n_tets; e++) g.w[e] *= 1.0 + 0.1 * sin(3.0 * e);
        grid_assemble(&g, a2, 1e-3);
        memcpy(g.w, w0, sizeof(double) * (size_t)g.n_tets);
        free(w0);
        int it = 0;
        double rel = 0;
        for (int rep = 0; rep < REPS; rep++) {
            memset(x, 0, sizeof(double) * (size_t)n);
            t0 = now_ns();
            hs_pcg_solve(pcg, a2, b, x, HS_PRECOND_FACTOR, f, 1e-8, 100, &it, &rel);
            t[rep] = ms_since(t0);
        }
        printf(",%d,%.2f", it, median(t, REPS));
        hs_pcg_destroy(&pcg);
        hs_csc_destroy(&a2);
    }

    // Update mode: conversion, simplicial refactor and solve, element downdate+update.
    t0 = now_ns();
    if (hs_cholesky_prepare_updates(f, 16) != HS_OK) return 1;
    double convert_ms = ms_since(t0);
    for (int rep = 0; rep < REPS; rep++) {
        t0 = now_ns();
        if (hs_cholesky_refactor(f, a) != HS_OK) return 1;
        t[rep] = ms_since(t0);
    }
    double srefactor_ms = median(t, REPS);
    for (int rep = 0; rep < REPS; rep++) {
        t0 = now_ns();
        hs_cholesky_solve(f, b, x);
        t[rep] = ms_since(t0);
    }
    double ssolve_ms = median(t, REPS);
    // Twelve right-hand sides at once (e.g. condensation onto four contact nodes), per column.
    double* b12 = malloc(sizeof(double) * 12 * (size_t)n);
    for (size_t i = 0; i < 12 * (size_t)n; i++) b12[i] = cos(0.11 * (double)i);
    for (int rep = 0; rep < REPS; rep++) {
        t0 = now_ns();
        hs_cholesky_solve_many(f, 12, b12, b12);
        t[rep] = ms_since(t0) / 12.0;
    }
    double ssolve12_ms = median(t, REPS);
    free(b12);
    // Remove one element (rank <= 9 downdate), then put it back; and the same for 10 at once.
    double dk[16 * 144];
    int dofs[16 * 12];
    double t1[REPS], t10[REPS];
    for (int rep = 0; rep < REPS; rep++) {
        for (int k = 0; k < 10; k++) {
            int e = (g.n_tets / 2 + 101 * rep + 13 * k) % g.n_tets;
            grid_tet_block(&g, e, -g.w[e], dk + 144 * k);
            grid_tet_dofs(&g, e, dofs + 12 * k);
        }
        t0 = now_ns();
        if (hs_cholesky_update_elements(f, 1, dk, dofs) != HS_OK) return 1;
        t1[rep] = ms_since(t0);
        for (int q = 0; q < 144; q++) dk[q] = -dk[q];
        if (hs_cholesky_update_elements(f, 1, dk, dofs) != HS_OK) return 1;
        for (int q = 0; q < 144; q++) dk[q] = -dk[q];
        t0 = now_ns();
        if (hs_cholesky_update_elements(f, 10, dk, dofs) != HS_OK) return 1;
        t10[rep] = ms_since(t0);
        for (int q = 0; q < 10 * 144; q++) dk[q] = -dk[q];
        if (hs_cholesky_update_elements(f, 10, dk, dofs) != HS_OK) return 1;
    }
    hs_cholesky_solve(f, b, x);
    printf(",%.2f,%.2f,%.3f,%.3f,%lld,%.3f,%.3f,%.1e\n", convert_ms, srefactor_ms, ssolve_ms,
           ssolve12_ms, (long long)hs_cholesky_factor_nnz(f), median(t1, REPS), median(t10, REPS),
           rel_residual(a, x, b, r));
    hs_cholesky_destroy(&f);
    hs_csc_destroy(&a);
    grid_free(&g);
    free(b);
    free(x);
    free(r);
    return 0;
}

int main(int argc, char** argv) {
    hs_platform_setup(argv); // one BLAS thread unless --threads says otherwise
    int dims[16][3], nd = 0;
    for (int i = 1; i < argc; i++) {
        if (strcmp(argv[i], "--cpu") == 0) {
            g_cpu_clock = 1;
        } else if (strcmp(argv[i], "--threads") == 0 && i + 1 < argc) {
            hs_status st = hs_platform_set_threads(atoi(argv[++i]));
            printf("# threads %s: %s\n", argv[i], hs_status_str(st));
        } else if (i + 2 < argc && nd < 16) {
            dims[nd][0] = atoi(argv[i]);
            dims[nd][1] = atoi(argv[i + 1]);
            dims[nd][2] = atoi(argv[i + 2]);
            nd++;
            i += 2;
        } else {
            fprintf(stderr, "usage: sparse_timing [--threads N] [--cpu] [NX NY NZ]...\n");
            return 2;
        }
    }
    if (nd == 0) {
        int def[2][3] = {{15, 14, 13}, {22, 22, 22}};
        memcpy(dims, def, sizeof def);
        nd = 2;
    }
    printf("dofs,nnz_a,kind,analyze_ms,refactor_ms,solve_ms,nnz_l,pcg_iters,pcg_ms,to_ldl_ms,"
           "ldl_refactor_ms,"
           "ldl_solve_ms,ldl_solve_per_rhs_of12_ms,nnz_ldl,elem1_ms,elem10_ms,rel_residual\n");
    for (int i = 0; i < nd; i++)
        if (run(dims[i][0], dims[i][1], dims[i][2]) != 0) return 1;
    return 0;
}
