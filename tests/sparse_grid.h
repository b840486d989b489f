// SPDX-License-Identifier: GPL-2.0-or-later
// Test helper: a structured nx x ny x nz node grid with a 27-point node stencil, cut into six
// tetrahedra per cell, and an elasticity-like SPD "block Laplacian plus shift" assembled from
// per-tet 12x12 blocks. Nodes on the x = 0 face are fixed. Test data uses malloc, not hs_alloc,
// so the library's allocation counters see only the library.
#ifndef HS_SPARSE_GRID_H
#define HS_SPARSE_GRID_H

#include "sparse.h"

#include <math.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

typedef struct grid {
    int nx, ny, nz, n_nodes, n_free, n_tets;
    int* nbr_start; // [n_nodes+1]
    int* nbr;       // 26-neighbour lists
    int* dof_map;   // [3*n_nodes], -1 on the x = 0 face
    int* tets;      // [4*n_tets]
    double* w;      // [n_tets] element weight
} grid;

static inline int grid_node(const grid* g, int i, int j, int k) {
    return i + g->nx * (j + g->ny * k);
}

static inline uint64_t grid_rand_next(uint64_t* s) {
    *s = *s * 6364136223846793005ull + 1442695040888963407ull;
    return *s >> 11;
}
static inline double grid_rand01(uint64_t* s) {
    return (double)grid_rand_next(s) / 9007199254740992.0;
}

static inline void grid_free(grid* g) {
    free(g->nbr_start);
    free(g->nbr);
    free(g->dof_map);
    free(g->tets);
    free(g->w);
    memset(g, 0, sizeof *g);
}

static inline int grid_make(grid* g, int nx, int ny, int nz, uint64_t seed) {
    memset(g, 0, sizeof *g);
    g->nx = nx;
    g->ny = ny;
    g->nz = nz;
    g->n_nodes = nx * ny * nz;
    g->nbr_start = malloc(sizeof(int) * ((size_t)g->n_nodes + 1));
    g->nbr = malloc(sizeof(int) * 26 * (size_t)g->n_nodes);
    g->dof_map = malloc(sizeof(int) * 3 * (size_t)g->n_nodes);
    int ncell = (nx - 1) * (ny - 1) * (nz - 1);
    g->tets = malloc(sizeof(int) * 24 * (size_t)(ncell > 0 ? ncell : 1));
    g->w = malloc(sizeof(double) * 6 * (size_t)(ncell > 0 ? ncell : 1));
    if (!g->nbr_start || !g->nbr || !g->dof_map || !g->tets || !g->w) return -1;
    int q = 0;
    for (int k = 0; k < nz; k++)
        for (int j = 0; j < ny; j++)
            for (int i = 0; i < nx; i++) {
                int v = grid_node(g, i, j, k);
                g->nbr_start[v] = q;
                for (int dk = -1; dk <= 1; dk++)
                    for (int dj = -1; dj <= 1; dj++)
                        for (int di = -1; di <= 1; di++) {
                            int a = i + di, b = j + dj, c = k + dk;
                            if ((di | dj | dk) == 0 || a < 0 || b < 0 || c < 0 || a >= nx ||
                                b >= ny || c >= nz)
                                continue;
                            g->nbr[q++] = grid_node(g, a, b, c);
                        }
                for (int d = 0; d < 3; d++) g->dof_map[3 * v + d] = i == 0 ? -1 : g->n_free++;
            }
    g->nbr_start[g->n_nodes] = q;
    // Kuhn subdivision: tet (0, e_a, e_a + e_b, 1) for each permutation (a, b, c) of the axes.
    static const int perm[6][3] = {{0, 1, 2}, {0, 2, 1}, {1, 0, 2},
                                   {1, 2, 0}, {2, 0, 1}, {2, 1, 0}};
    uint64_t s = seed;
    for (int k = 0; k + 1 < nz; k++)
        for (int j = 0; j + 1 < ny; j++)
            for (int i = 0; i + 1 < nx; i++)
                for (int t = 0; t < 6; t++) {
                    int c[3] = {i, j, k};
                    int* tet = g->tets + 4 * g->n_tets;
                    tet[0] = grid_node(g, c[0], c[1], c[2]);
                    c[perm[t][0]]++;
                    tet[1] = grid_node(g, c[0], c[1], c[2]);
                    c[perm[t][1]]++;
                    tet[2] = grid_node(g, c[0], c[1], c[2]);
                    c[perm[t][2]]++;
                    tet[3] = grid_node(g, c[0], c[1], c[2]);
                    g->w[g->n_tets] = 0.5 + grid_rand01(&s);
                    g->n_tets++;
                }
    return 0;
}

static inline void grid_coords(const grid* g, int v, double x[3]) {
    x[0] = v % g->nx;
    x[1] = (v / g->nx) % g->ny;
    x[2] = v / (g->nx * g->ny);
}

// 12x12 row-major stiffness of tet e: sum over its 6 edges of w (e_a - e_b)(e_a - e_b)^T (x)
// (I + d d^T), d the unit edge direction. PSD, translations in its null space.
static inline void grid_tet_block(const grid* g, int e, double w, double ke[144]) {
    memset(ke, 0, sizeof(double) * 144);
    const int* t = g->tets + 4 * e;
    for (int a = 0; a < 4; a++)
        for (int b = a + 1; b < 4; b++) {
            double xa[3], xb[3], d[3], len = 0;
            grid_coords(g, t[a], xa);
            grid_coords(g, t[b], xb);
            for (int c = 0; c < 3; c++) {
                d[c] = xb[c] - xa[c];
                len += d[c] * d[c];
            }
            len = sqrt(len);
            for (int r = 0; r < 3; r++)
                for (int c = 0; c < 3; c++) {
                    double bij = w * ((r == c) + d[r] * d[c] / (len * len));
                    ke[(3 * a + r) * 12 + 3 * a + c] += bij;
                    ke[(3 * b + r) * 12 + 3 * b + c] += bij;
                    ke[(3 * a + r) * 12 + 3 * b + c] -= bij;
                    ke[(3 * b + r) * 12 + 3 * a + c] -= bij;
                }
        }
}

static inline void grid_tet_dofs(const grid* g, int e, int dofs[12]) {
    for (int a = 0; a < 4; a++)
        for (int c = 0; c < 3; c++) dofs[3 * a + c] = g->dof_map[3 * g->tets[4 * e + a] + c];
}

// Add scale * K_e into a. Returns -1 if an entry is missing from the pattern.
static inline int grid_add_tet(const grid* g, hs_csc* a, int e, double scale) {
    double ke[144];
    int dofs[12];
    grid_tet_block(g, e, g->w[e] * scale, ke);
    grid_tet_dofs(g, e, dofs);
    for (int r = 0; r < 12; r++)
        for (int c = 0; c < 12; c++) {
            if (dofs[r] < 0 || dofs[c] < 0) continue;
            int p = hs_csc_find(a, dofs[r], dofs[c]);
            if (p < 0) return -1;
            a->val[p] += ke[r * 12 + c];
        }
    return 0;
}

// A = sum_e K_e + shift I over the free dofs.
static inline int grid_assemble(const grid* g, hs_csc* a, double shift) {
    hs_csc_zero(a);
    for (int e = 0; e < g->n_tets; e++)
        if (grid_add_tet(g, a, e, 1.0) != 0) return -1;
    for (int i = 0; i < a->n; i++) {
        int p = hs_csc_find(a, i, i);
        if (p < 0) return -1;
        a->val[p] += shift;
    }
    return 0;
}

static inline hs_status grid_pattern(const grid* g, hs_csc** out, hs_err* err) {
    return hs_csc_create_block_pattern(g->n_nodes, g->nbr_start, g->nbr, g->dof_map, g->n_free, out,
                                       err);
}

static inline double vec_norm(int n, const double* x) {
    double s = 0;
    for (int i = 0; i < n; i++) s += x[i] * x[i];
    return sqrt(s);
}

// ||A x - b|| / ||b|| using spmv into scratch r[n].
static inline double rel_residual(const hs_csc* a, const double* x, const double* b, double* r) {
    hs_csc_spmv(a, x, r);
    for (int i = 0; i < a->n; i++) r[i] -= b[i];
    return vec_norm(a->n, r) / vec_norm(a->n, b);
}

#endif
