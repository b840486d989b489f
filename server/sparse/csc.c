// SPDX-License-Identifier: GPL-2.0-or-later
// Symmetric compressed-column matrices with a fixed, full (both triangles) pattern.
#include "sparse.h"

#include <limits.h>
#include <stdlib.h>
#include <string.h>

static int cmp_int(const void* a, const void* b) {
    int x = *(const int*)a, y = *(const int*)b;
    return (x > y) - (x < y);
}

static hs_csc* csc_alloc(int n, int nnz) {
    hs_csc* a = hs_calloc(1, sizeof *a);
    if (!a) return NULL;
    a->n = n;
    a->nnz = nnz;
    a->colp = hs_alloc(sizeof(int) * ((size_t)n + 1));
    a->rowi = hs_alloc(sizeof(int) * ((size_t)nnz > 0 ? (size_t)nnz : 1));
    a->val = hs_calloc((size_t)nnz > 0 ? (size_t)nnz : 1, sizeof(double));
    if (!a->colp || !a->rowi || !a->val) hs_csc_destroy(&a);
    return a;
}

void hs_csc_destroy(hs_csc** a) {
    if (!a || !*a) return;
    hs_free((*a)->colp);
    hs_free((*a)->rowi);
    hs_free((*a)->val);
    hs_free(*a);
    *a = NULL;
}

static hs_status check_pattern_input(int n_nodes, const int* nbr_start, const int* nbr,
                                     const int* dof_map, int n_free, hs_err* err) {
    if (n_nodes < 0 || n_free < 0)
        return hs_err_set(err, HS_ERR_INVALID, "%s:%d: n_nodes (%d) and n_free (%d) must be >= 0",
                          __FILE__, __LINE__, n_nodes, n_free);
    if (n_nodes > INT_MAX / 3)
        return hs_err_set(err, HS_ERR_INVALID, "%s:%d: n_nodes %d too large", __FILE__, __LINE__,
                          n_nodes);
    if (n_nodes > 0 && (!nbr_start || !dof_map))
        return hs_err_set(err, HS_ERR_INVALID, "%s:%d: nbr_start and dof_map must not be NULL",
                          __FILE__, __LINE__);
    if (n_nodes > 0 && nbr_start[0] != 0)
        return hs_err_set(err, HS_ERR_INVALID, "%s:%d: nbr_start[0] = %d, expected 0", __FILE__,
                          __LINE__, nbr_start[0]);
    for (int i = 0; i < n_nodes; i++) {
        if (nbr_start[i + 1] < nbr_start[i])
            return hs_err_set(err, HS_ERR_INVALID, "%s:%d: nbr_start decreases at node %d",
                              __FILE__, __LINE__, i);
    }
    if (n_nodes > 0 && nbr_start[n_nodes] > 0 && !nbr)
        return hs_err_set(err, HS_ERR_INVALID, "%s:%d: nbr must not be NULL", __FILE__, __LINE__);
    for (int i = 0; i < n_nodes; i++) {
        for (int p = nbr_start[i]; p < nbr_start[i + 1]; p++) {
            if (nbr[p] < 0 || nbr[p] >= n_nodes)
                return hs_err_set(err, HS_ERR_INVALID,
                                  "%s:%d: node %d has neighbour %d outside [0, %d)", __FILE__,
                                  __LINE__, i, nbr[p], n_nodes);
        }
    }
    int n_seen = 0;
    for (int d = 0; d < 3 * n_nodes; d++) {
        if (dof_map[d] < -1 || dof_map[d] >= n_free)
            return hs_err_set(err, HS_ERR_INVALID, "%s:%d: dof_map[%d] = %d outside [-1, %d)",
                              __FILE__, __LINE__, d, dof_map[d], n_free);
        if (dof_map[d] >= 0) n_seen++;
    }
    if (n_seen != n_free)
        return hs_err_set(err, HS_ERR_INVALID,
                          "%s:%d: dof_map has %d free entries but n_free = %d (each free dof "
                          "must appear exactly once)",
                          __FILE__, __LINE__, n_seen, n_free);
    return HS_OK;
}

hs_status hs_csc_create_block_pattern(int n_nodes, const int* nbr_start, const int* nbr,
                                      const int* dof_map, int n_free, hs_csc** out, hs_err* err) {
    if (!out) return hs_err_set(err, HS_ERR_INVALID, "%s:%d: out is NULL", __FILE__, __LINE__);
    *out = NULL;
    hs_status st = check_pattern_input(n_nodes, nbr_start, nbr, dof_map, n_free, err);
    if (st != HS_OK) return st;

    int n_edges = n_nodes > 0 ? nbr_start[n_nodes] : 0;
    int* adj_start = hs_calloc((size_t)n_nodes + 1, sizeof(int));
    int* adj = hs_alloc(sizeof(int) * (2 * (size_t)n_edges + 1));
    int* fill = hs_alloc(sizeof(int) * ((size_t)n_nodes + 1));
    int* node_of_dof = hs_alloc(sizeof(int) * ((size_t)n_free + 1));
    hs_csc* a = NULL;
    if (!adj_start || !adj || !fill || !node_of_dof) {
        st = hs_err_set(err, HS_ERR_NOMEM, "%s:%d: out of memory building pattern", __FILE__,
                        __LINE__);
        goto done;
    }

    // Symmetrised node adjacency without self loops: the caller's lists need not be symmetric.
    for (int i = 0; i < n_nodes; i++) {
        for (int p = nbr_start[i]; p < nbr_start[i + 1]; p++) {
            if (nbr[p] == i) continue;
            adj_start[i + 1]++;
            adj_start[nbr[p] + 1]++;
        }
    }
    for (int i = 0; i < n_nodes; i++) adj_start[i + 1] += adj_start[i];
    memcpy(fill, adj_start, sizeof(int) * (size_t)n_nodes);
    for (int i = 0; i < n_nodes; i++) {
        for (int p = nbr_start[i]; p < nbr_start[i + 1]; p++) {
            int j = nbr[p];
            if (j == i) continue;
            adj[fill[i]++] = j;
            adj[fill[j]++] = i;
        }
    }
    // Sort and deduplicate in place; fill[i] becomes the end of node i's unique list.
    for (int i = 0; i < n_nodes; i++) {
        int b = adj_start[i], e = adj_start[i + 1];
        qsort(adj + b, (size_t)(e - b), sizeof(int), cmp_int);
        int w = b;
        for (int p = b; p < e; p++)
            if (w == b || adj[w - 1] != adj[p]) adj[w++] = adj[p];
        fill[i] = w;
    }

    for (int c = 0; c < n_free; c++) node_of_dof[c] = -1;
    for (int d = 0; d < 3 * n_nodes; d++) {
        if (dof_map[d] < 0) continue;
        if (node_of_dof[dof_map[d]] >= 0) {
            st = hs_err_set(err, HS_ERR_INVALID, "%s:%d: free dof %d is mapped twice (dof_map[%d])",
                            __FILE__, __LINE__, dof_map[d], d);
            goto done;
        }
        node_of_dof[dof_map[d]] = d / 3;
    }

    // Column counts: free dofs of the column's node and of all its neighbours.
    int64_t nnz = 0;
    for (int c = 0; c < n_free; c++) {
        int j = node_of_dof[c];
        for (int k = 0; k < 3; k++) nnz += dof_map[3 * j + k] >= 0;
        for (int p = adj_start[j]; p < fill[j]; p++)
            for (int k = 0; k < 3; k++) nnz += dof_map[3 * adj[p] + k] >= 0;
    }
    if (nnz > INT_MAX) {
        st =
            hs_err_set(err, HS_ERR_UNSUPPORTED, "%s:%d: pattern has %lld entries (int index limit)",
                       __FILE__, __LINE__, (long long)nnz);
        goto done;
    }
    a = csc_alloc(n_free, (int)nnz);
    if (!a) {
        st = hs_err_set(err, HS_ERR_NOMEM, "%s:%d: out of memory for %lld entries", __FILE__,
                        __LINE__, (long long)nnz);
        goto done;
    }
    int q = 0;
    for (int c = 0; c < n_free; c++) {
        a->colp[c] = q;
        int j = node_of_dof[c];
        for (int k = 0; k < 3; k++)
            if (dof_map[3 * j + k] >= 0) a->rowi[q++] = dof_map[3 * j + k];
        for (int p = adj_start[j]; p < fill[j]; p++)
            for (int k = 0; k < 3; k++)
                if (dof_map[3 * adj[p] + k] >= 0) a->rowi[q++] = dof_map[3 * adj[p] + k];
        // Dof numbering need not follow node numbering, so sort each column.
        qsort(a->rowi + a->colp[c], (size_t)(q - a->colp[c]), sizeof(int), cmp_int);
    }
    a->colp[n_free] = q;
    HS_ASSERT(q == a->nnz);
    *out = a;
    a = NULL;

done:
    hs_csc_destroy(&a);
    hs_free(adj_start);
    hs_free(adj);
    hs_free(fill);
    hs_free(node_of_dof);
    return st;
}

int hs_csc_find(const hs_csc* a, int row, int col) {
    if (!a || row < 0 || col < 0 || row >= a->n || col >= a->n) return -1;
    int lo = a->colp[col], hi = a->colp[col + 1] - 1;
    while (lo <= hi) {
        int mid = lo + (hi - lo) / 2;
        int r = a->rowi[mid];
        if (r == row) return mid;
        if (r < row)
            lo = mid + 1;
        else
            hi = mid - 1;
    }
    return -1;
}

void hs_csc_spmv(const hs_csc* a, const double* x, double* y) {
    // Gather form: y[j] = column j . x, which is (A^T x)[j] = (A x)[j] for the symmetric values
    // this type holds. Sequential writes, no scatter. x and y must not alias.
    HS_ASSERT(x != y || a->n == 0);
    const int* colp = a->colp;
    const int* rowi = a->rowi;
    const double* val = a->val;
    for (int j = 0; j < a->n; j++) {
        double s = 0.0;
        for (int p = colp[j]; p < colp[j + 1]; p++) s += val[p] * x[rowi[p]];
        y[j] = s;
    }
}

void hs_csc_zero(hs_csc* a) {
    if (a && a->nnz > 0) memset(a->val, 0, sizeof(double) * (size_t)a->nnz);
}

hs_status hs_csc_clone(const hs_csc* a, hs_csc** out) {
    if (!out) return HS_ERR_INVALID;
    *out = NULL;
    if (!a) return HS_ERR_INVALID;
    hs_csc* b = csc_alloc(a->n, a->nnz);
    if (!b) return HS_ERR_NOMEM;
    memcpy(b->colp, a->colp, sizeof(int) * ((size_t)a->n + 1));
    if (a->nnz > 0) {
        memcpy(b->rowi, a->rowi, sizeof(int) * (size_t)a->nnz);
        memcpy(b->val, a->val, sizeof(double) * (size_t)a->nnz);
    }
    *out = b;
    return HS_OK;
}
