// SPDX-License-Identifier: GPL-2.0-or-later
// Condensed compliance: C = K0^-1 restricted to what contact needs (compliance.h).
//
// DESIGN. Owned by the deformation thread. K0 is the rest-state stiffness of a linear model
// over the free dofs (the body's dof map), factored once with CHOLMOD. Diagonal blocks of all
// surface nodes come from the factor's sparse inverse-diagonal solves at set-up
// (hs_cholesky_inverse_diag3). Column blocks
// C(:, k) restricted to the surface rows live in a cache of fixed capacity with least-recently
// used eviction; a per-step epoch pins the columns in use so one snapshot's columns never
// evict each other. Everything is allocated in create.
#include "compliance.h"
#include "sparse.h"

#include "dense.h"

#include <math.h>
#include <string.h>

#define BATCH_NODES 32 // surface nodes per batched solve (3 right-hand sides each)

struct hs_compliance {
    const hs_mesh* mesh; // the fem's mesh (element numbering, rest positions)
    const hs_mesh* surf; // whose boundary nodes are the surface: mesh, or a cut's live mesh
    int n, n_free, n_surf;
    int* dof;    // [3n] free index or -1
    hs_fem* fem; // linear model at rest
    hs_csc* k;   // K0 over the free dofs
    hs_cholesky* chol;
    double* diag;       // [9 n_surf] C_kk per surface index, row-major
    int cap;            // cache capacity, nodes
    int* slot_node;     // [cap] node in the slot or -1
    int64_t* slot_used; // [cap] epoch of last use
    int* node_slot;     // [n] slot or -1
    double* cols;       // [cap][n_surf][9]: C_sk for surface s, row-major
    double* rhs;        // [n_free * 3 * BATCH_NODES]
    double* sol;        // [n_free * 3 * BATCH_NODES]
    int* batch;         // [BATCH_NODES] nodes of the batch being solved
    int64_t epoch;
    int64_t solves;
    double setup_ms;
    // Following cuts (hs_compliance_change_elements).
    unsigned char* diag_ok; // [n_surf] diag block exact for the current factor
    unsigned char* held;    // [n] node given the hold diagonal (no element left)
    unsigned char* emark;   // [n_tets] scratch
    int* elist;             // [n_tets] scratch: elements whose share changes
    int* dlist;             // [12 n_tets] scratch: their free dofs
    double hold_k;          // diagonal that holds a node with no element, N/m
    int partial;            // the factor is set up for partial refactors
    int64_t updates;
    double update_ms;
};

void hs_compliance_destroy(hs_compliance** pc) {
    if (!pc || !*pc) return;
    hs_compliance* c = *pc;
    hs_cholesky_destroy(&c->chol);
    hs_csc_destroy(&c->k);
    hs_fem_destroy(&c->fem);
    hs_free(c->dof);
    hs_free(c->diag);
    hs_free(c->slot_node);
    hs_free(c->slot_used);
    hs_free(c->node_slot);
    hs_free(c->cols);
    hs_free(c->rhs);
    hs_free(c->sol);
    hs_free(c->batch);
    hs_free(c->diag_ok);
    hs_free(c->held);
    hs_free(c->emark);
    hs_free(c->elist);
    hs_free(c->dlist);
    hs_free(c);
    *pc = NULL;
}

// Solve for the unit columns of nb nodes (3 rhs each) into c->sol.
static hs_status solve_batch(hs_compliance* c, int nb, const int* nodes) {
    const size_t nf = (size_t)c->n_free;
    memset(c->rhs, 0, nf * 3 * (size_t)nb * sizeof(double));
    for (int q = 0; q < nb; ++q)
        for (int b = 0; b < 3; ++b) {
            int d = c->dof[3 * nodes[q] + b];
            if (d >= 0) c->rhs[nf * (size_t)(3 * q + b) + (size_t)d] = 1.0;
        }
    c->solves += nb;
    return hs_cholesky_solve_many(c->chol, 3 * nb, c->rhs, c->sol);
}

// Block C_{row node, batch column q} from c->sol.
static void sol_block(const hs_compliance* c, int q, int row_node, double out[9]) {
    const size_t nf = (size_t)c->n_free;
    for (int a = 0; a < 3; ++a) {
        int d = c->dof[3 * row_node + a];
        for (int b = 0; b < 3; ++b)
            out[3 * a + b] = d >= 0 ? c->sol[nf * (size_t)(3 * q + b) + (size_t)d] : 0.0;
    }
}

hs_status hs_compliance_create(const hs_mesh* mesh, const hs_fem_def* def,
                               const unsigned char* fixed, int cache_nodes, hs_compliance** out,
                               hs_err* err) {
    return hs_compliance_create_par(mesh, def, fixed, cache_nodes, NULL, out, err);
}

hs_status hs_compliance_create_par(const hs_mesh* mesh, const hs_fem_def* def,
                                   const unsigned char* fixed, int cache_nodes,
                                   const hs_parallel* par, hs_compliance** out, hs_err* err) {
    if (out) *out = NULL;
    if (!mesh || !def || !out)
        return hs_err_set(err, HS_ERR_INVALID, "hs_compliance_create: NULL argument");
    if (cache_nodes < 1)
        return hs_err_set(err, HS_ERR_INVALID,
                          "hs_compliance_create: cache_nodes must be >= 1, got %d", cache_nodes);
    if (mesh->n_surf_nodes < 1 || !mesh->surf_nodes)
        return hs_err_set(err, HS_ERR_INVALID, "hs_compliance_create: mesh has no surface");
    int64_t t0 = hs_now_ns();
    hs_compliance* c = hs_calloc(1, sizeof *c);
    if (!c) return hs_err_set(err, HS_ERR_NOMEM, "hs_compliance_create: out of memory");
    c->mesh = mesh;
    c->surf = mesh;
    c->n = mesh->n_nodes;
    c->n_surf = mesh->n_surf_nodes;
    c->cap = cache_nodes;
    c->dof = hs_alloc(3 * (size_t)c->n * sizeof(int));
    if (!c->dof) goto nomem;
    int nf = 0;
    for (int i = 0; i < c->n; ++i) {
        // The same elimination as hs_body: fixed and unused nodes have no free dofs.
        int fx = (fixed && fixed[i]) || (mesh->node_used && !mesh->node_used[i]);
        for (int a = 0; a < 3; ++a) c->dof[3 * i + a] = fx ? -1 : nf++;
    }
    if (nf == 0) {
        hs_compliance_destroy(&c);
        return hs_err_set(err, HS_ERR_INVALID, "hs_compliance_create: every node is fixed");
    }
    c->n_free = nf;

    hs_fem_def lin = *def;
    lin.model = HS_MODEL_LINEAR;
    hs_status s = hs_fem_create(mesh, &lin, c->dof, nf, &c->fem, err);
    if (s != HS_OK) {
        hs_compliance_destroy(&c);
        return s;
    }
    s = hs_fem_create_matrix(c->fem, &c->k);
    if (s != HS_OK) {
        hs_compliance_destroy(&c);
        return hs_err_set(err, s, "hs_compliance_create: matrix: %s", hs_status_str(s));
    }
    hs_fem_update(c->fem, mesh->x0, NULL);
    hs_fem_assemble(c->fem, 1.0, 0.0, c->k);
    s = hs_cholesky_create(c->k, &c->chol, err);
    if (s != HS_OK) {
        hs_compliance_destroy(&c);
        if (s == HS_ERR_NOT_POSDEF)
            return hs_err_set(err, s,
                              "hs_compliance_create: stiffness not positive definite (a part of "
                              "the mesh without fixed nodes?)");
        return s;
    }

    const size_t ns = (size_t)c->n_surf, cap = (size_t)c->cap;
    c->diag = hs_calloc(9 * ns, sizeof(double));
    c->slot_node = hs_alloc(cap * sizeof(int));
    c->slot_used = hs_calloc(cap, sizeof(int64_t));
    c->node_slot = hs_alloc((size_t)c->n * sizeof(int));
    c->cols = hs_calloc(cap * ns * 9, sizeof(double));
    c->rhs = hs_alloc((size_t)nf * 3 * BATCH_NODES * sizeof(double));
    c->sol = hs_alloc((size_t)nf * 3 * BATCH_NODES * sizeof(double));
    c->batch = hs_alloc(BATCH_NODES * sizeof(int));
    c->diag_ok = hs_alloc(ns + 1);
    if (!c->diag || !c->slot_node || !c->slot_used || !c->node_slot || !c->cols || !c->rhs ||
        !c->sol || !c->batch || !c->diag_ok)
        goto nomem;
    memset(c->diag_ok, 1, ns);
    {
        double sum = 0;
        for (int j = 0; j < c->k->n; ++j) {
            int p = hs_csc_find(c->k, j, j);
            if (p >= 0) sum += c->k->val[p];
        }
        c->hold_k = sum / c->k->n;
    }
    for (size_t i = 0; i < cap; ++i) c->slot_node[i] = -1;
    for (int i = 0; i < c->n; ++i) c->node_slot[i] = -1;

    // Diagonal blocks of every surface node, each from a sparse forward solve along its
    // elimination-tree path (a full solve per batch of unit loads cost 10-20x more).
    {
        int* dl = hs_alloc(3 * ns * sizeof(int) + sizeof(int));
        if (!dl) goto nomem;
        for (size_t q = 0; q < ns; ++q)
            for (int a = 0; a < 3; ++a) dl[3 * q + a] = c->dof[3 * mesh->surf_nodes[q] + a];
        s = hs_cholesky_inverse_diag3_par(c->chol, c->n_surf, dl, c->diag, par);
        hs_free(dl);
        if (s != HS_OK) {
            hs_compliance_destroy(&c);
            return hs_err_set(err, s, "hs_compliance_create: diagonal blocks: %s",
                              hs_status_str(s));
        }
    }
    c->solves = 0;
    c->setup_ms = (double)(hs_now_ns() - t0) * 1e-6;
    *out = c;
    return HS_OK;
nomem:
    hs_compliance_destroy(&c);
    return hs_err_set(err, HS_ERR_NOMEM, "hs_compliance_create: out of memory");
}

double hs_compliance_setup_ms(const hs_compliance* c) {
    return c->setup_ms;
}
int64_t hs_compliance_column_solves(const hs_compliance* c) {
    return c->solves;
}
int hs_compliance_cache_capacity(const hs_compliance* c) {
    return c->cap;
}

int hs_compliance_contactable(const hs_compliance* c, int node) {
    if (node < 0 || node >= c->n || c->surf->node_surf[node] < 0) return 0;
    return c->dof[3 * node] >= 0;
}

// C_kk of surface node k: the table, or after a change its column (0 when neither is known).
static int diag_block(const hs_compliance* c, int node, double out[9]) {
    const int s = c->surf->node_surf[node];
    if (c->diag_ok[s]) {
        memcpy(out, c->diag + 9 * (size_t)s, 9 * sizeof(double));
        return 1;
    }
    const int slot = c->node_slot[node];
    if (slot >= 0) {
        memcpy(out, c->cols + ((size_t)slot * (size_t)c->n_surf + (size_t)s) * 9,
               9 * sizeof(double));
        return 1;
    }
    memset(out, 0, 9 * sizeof(double));
    return 0;
}

void hs_compliance_diag(const hs_compliance* c, int node, double out[9]) {
    HS_ASSERT(node >= 0 && node < c->n);
    HS_ASSERT(c->surf->node_surf[node] >= 0);
    (void)diag_block(c, node, out);
}

void hs_compliance_begin_step(hs_compliance* c) {
    ++c->epoch;
}

int hs_compliance_has_column(const hs_compliance* c, int node) {
    return node >= 0 && node < c->n && c->node_slot[node] >= 0;
}

// A slot for a new column: empty, else the least recently used one not pinned this epoch.
static int free_slot(const hs_compliance* c) {
    int best = -1;
    for (int i = 0; i < c->cap; ++i) {
        if (c->slot_node[i] < 0) return i;
        if (c->slot_used[i] >= c->epoch) continue;
        if (best < 0 || c->slot_used[i] < c->slot_used[best]) best = i;
    }
    return best;
}

// Solve the pending batch and store its columns.
static hs_status flush_batch(hs_compliance* c, int nb) {
    if (nb == 0) return HS_OK;
    hs_status s = solve_batch(c, nb, c->batch);
    if (s != HS_OK) {
        for (int q = 0; q < nb; ++q) {
            int slot = c->node_slot[c->batch[q]];
            c->slot_node[slot] = -1;
            c->node_slot[c->batch[q]] = -1;
        }
        return s;
    }
    for (int q = 0; q < nb; ++q) {
        int node = c->batch[q], slot = c->node_slot[node];
        double* col = c->cols + (size_t)slot * (size_t)c->n_surf * 9;
        for (int si = 0; si < c->n_surf; ++si)
            sol_block(c, q, c->surf->surf_nodes[si], col + 9 * (size_t)si);
        const int sn = c->surf->node_surf[node];
        if (!c->diag_ok[sn]) { // exactly symmetric, as the table's
            const double* b = col + 9 * (size_t)sn;
            double* d = c->diag + 9 * (size_t)sn;
            for (int a = 0; a < 3; ++a)
                for (int e = 0; e < 3; ++e) d[3 * a + e] = 0.5 * (b[3 * a + e] + b[3 * e + a]);
            c->diag_ok[sn] = 1;
        }
    }
    return HS_OK;
}

// Diagonal blocks of nodes[n] that a change made stale and no column gave back: sparse solves
// along the factor's elimination tree (hs_cholesky_inverse_diag3), BATCH_NODES at a time.
static hs_status refresh_diag(hs_compliance* c, int n, const int* nodes) {
    int dl[3 * BATCH_NODES], which[BATCH_NODES], nb = 0;
    double out[9 * BATCH_NODES];
    for (int i = 0; i <= n; ++i) {
        if (i < n) {
            const int node = nodes[i], sn = c->surf->node_surf[node];
            if (!hs_compliance_contactable(c, node) || c->diag_ok[sn]) continue;
            int dup = 0;
            for (int q = 0; q < nb; ++q) dup |= which[q] == sn;
            if (dup) continue;
            for (int a = 0; a < 3; ++a) dl[3 * nb + a] = c->dof[3 * node + a];
            which[nb++] = sn;
        }
        if (nb == BATCH_NODES || (i == n && nb > 0)) {
            hs_status s = hs_cholesky_inverse_diag3(c->chol, nb, dl, out);
            if (s != HS_OK) return s;
            for (int q = 0; q < nb; ++q) {
                memcpy(c->diag + 9 * (size_t)which[q], out + 9 * q, 9 * sizeof(double));
                c->diag_ok[which[q]] = 1;
            }
            nb = 0;
        }
    }
    return HS_OK;
}

int hs_compliance_ensure(hs_compliance* c, int n, const int* nodes, int max_new) {
    int have = 0, nb = 0, added = 0;
    // Pin every cached column asked for first, so that a new one cannot evict a later node's.
    for (int i = 0; i < n; ++i) {
        HS_ASSERT(nodes[i] >= 0 && nodes[i] < c->n);
        int slot = c->node_slot[nodes[i]];
        if (slot >= 0) c->slot_used[slot] = c->epoch;
    }
    for (int i = 0; i < n; ++i) {
        int node = nodes[i];
        HS_ASSERT(node >= 0 && node < c->n);
        int slot = c->node_slot[node];
        if (slot >= 0) {
            c->slot_used[slot] = c->epoch;
            ++have;
            continue;
        }
        if (added >= max_new || !hs_compliance_contactable(c, node)) continue;
        slot = free_slot(c);
        if (slot < 0) continue; // every slot pinned this step: keep the diagonal approximation
        if (c->slot_node[slot] >= 0) c->node_slot[c->slot_node[slot]] = -1;
        c->slot_node[slot] = node;
        c->slot_used[slot] = c->epoch;
        c->node_slot[node] = slot;
        c->batch[nb++] = node;
        ++added;
        ++have;
        if (nb == BATCH_NODES) {
            hs_status s = flush_batch(c, nb);
            if (s != HS_OK) return s;
            nb = 0;
        }
    }
    hs_status s = flush_batch(c, nb);
    if (s == HS_OK) s = refresh_diag(c, n, nodes);
    if (s != HS_OK) return s;
    return have;
}

int hs_compliance_block(const hs_compliance* c, int i, int j, double out[9]) {
    const int* ns = c->surf->node_surf;
    HS_ASSERT(i >= 0 && i < c->n && j >= 0 && j < c->n && ns[i] >= 0 && ns[j] >= 0);
    if (i == j) return diag_block(c, i, out);
    int sj = c->node_slot[j], si = c->node_slot[i];
    if (sj >= 0) {
        memcpy(out, c->cols + ((size_t)sj * (size_t)c->n_surf + (size_t)ns[i]) * 9,
               9 * sizeof(double));
        return 1;
    }
    if (si >= 0) {
        const double* t = c->cols + ((size_t)si * (size_t)c->n_surf + (size_t)ns[j]) * 9;
        for (int a = 0; a < 3; ++a)
            for (int b = 0; b < 3; ++b) out[3 * a + b] = t[3 * b + a];
        return 1;
    }
    memset(out, 0, 9 * sizeof(double));
    return 0;
}

int hs_compliance_surface_displacement(const hs_compliance* c, int n, const int* nodes,
                                       const double* f, double* u_surf) {
    for (int k = 0; k < n; ++k)
        if (!hs_compliance_has_column(c, nodes[k])) return -1;
    memset(u_surf, 0, 3 * (size_t)c->n_surf * sizeof(double));
    for (int k = 0; k < n; ++k) {
        const double* col = c->cols + (size_t)c->node_slot[nodes[k]] * (size_t)c->n_surf * 9;
        const double* fk = f + 3 * k;
        for (int s = 0; s < c->n_surf; ++s) {
            const double* b = col + 9 * (size_t)s;
            double* u = u_surf + 3 * (size_t)s;
            u[0] += b[0] * fk[0] + b[1] * fk[1] + b[2] * fk[2];
            u[1] += b[3] * fk[0] + b[4] * fk[1] + b[5] * fk[2];
            u[2] += b[6] * fk[0] + b[7] * fk[1] + b[8] * fk[2];
        }
    }
    return 0;
}

hs_status hs_compliance_apply(hs_compliance* c, const double* g, double* v) {
    for (int k = 0; k < 3 * c->n; ++k)
        if (c->dof[k] >= 0 && !isfinite(g[k])) return HS_ERR_INVALID; // v untouched
    for (int k = 0; k < 3 * c->n; ++k)
        if (c->dof[k] >= 0) c->rhs[c->dof[k]] = g[k];
    hs_status s = hs_cholesky_solve(c->chol, c->rhs, c->sol);
    if (s != HS_OK) return s;
    for (int k = 0; k < 3 * c->n; ++k) v[k] = c->dof[k] >= 0 ? c->sol[c->dof[k]] : 0.0;
    return HS_OK;
}

hs_status hs_compliance_solve_set(hs_compliance* c, int m, const int* nodes, const double* rot,
                                  const double* d, double* f) {
    enum { MAXN = 3 * HS_MAX_CONTACT };
    if (m < 1 || m > HS_MAX_CONTACT) return HS_ERR_INVALID;
    for (int i = 0; i < m; ++i)
        if (!hs_compliance_contactable(c, nodes[i])) return HS_ERR_INVALID;
    hs_compliance_begin_step(c);
    int got = hs_compliance_ensure(c, m, nodes, m);
    if (got < 0) return (hs_status)got;
    if (got < m) return HS_ERR_INVALID; // cache smaller than the set
    double a[MAXN * MAXN];
    const int n = 3 * m;
    for (int i = 0; i < m; ++i)
        for (int j = 0; j < m; ++j) {
            double blk[9], rb[9];
            hs_compliance_block(c, nodes[i], nodes[j], blk);
            if (rot)
                hs_mat3_rotate(rot + 9 * i, blk, rot + 9 * j, rb);
            else
                memcpy(rb, blk, sizeof rb);
            for (int p = 0; p < 3; ++p)
                for (int q = 0; q < 3; ++q) a[(3 * i + p) * n + 3 * j + q] = rb[3 * p + q];
        }
    if (hs_dense_cholesky(a, n) != 0) return HS_ERR_NOT_POSDEF;
    memcpy(f, d, (size_t)n * sizeof(double));
    hs_dense_cholesky_solve(a, n, f);
    return HS_OK;
}

const hs_mesh* hs_compliance_mesh(const hs_compliance* c) {
    return c->mesh;
}
int64_t hs_compliance_updates(const hs_compliance* c) {
    return c->updates;
}
double hs_compliance_update_ms(const hs_compliance* c) {
    return c->update_ms;
}

// Scratch and the surface-sized tables for a change onto surface sm.
static hs_status change_scratch(hs_compliance* c, const hs_mesh* sm) {
    const size_t nt = (size_t)c->mesh->n_tets;
    if (!c->emark) {
        c->emark = hs_calloc(nt + 1, 1);
        c->elist = hs_alloc((nt + 1) * sizeof(int));
        c->dlist = hs_alloc((12 * nt + 1) * sizeof(int));
        c->held = hs_calloc((size_t)c->n + 1, 1);
        if (!c->emark || !c->elist || !c->dlist || !c->held) return HS_ERR_NOMEM;
    }
    if (sm->n_surf_nodes != c->n_surf) {
        const size_t ns = (size_t)sm->n_surf_nodes;
        double* d = hs_realloc(c->diag, 9 * ns * sizeof(double));
        if (d) c->diag = d;
        unsigned char* ok = hs_realloc(c->diag_ok, ns + 1);
        if (ok) c->diag_ok = ok;
        double* cols = hs_realloc(c->cols, (size_t)c->cap * ns * 9 * sizeof(double));
        if (cols) c->cols = cols;
        if (!d || !ok || !cols) return HS_ERR_NOMEM;
        c->n_surf = sm->n_surf_nodes;
    }
    return HS_OK;
}

hs_status hs_compliance_prepare_changes(hs_compliance* c) {
    if (!c) return HS_ERR_INVALID;
    hs_status s = change_scratch(c, c->surf);
    if (s != HS_OK || c->partial || !hs_cholesky_is_supernodal(c->chol)) return s;
    s = hs_cholesky_prepare_partial(c->chol, c->k);
    c->partial = s == HS_OK;
    return s;
}

hs_status hs_compliance_change_elements(hs_compliance* c, int n_off, const int* off, int n_moved,
                                        const int* moved, const hs_mesh* surface) {
    if (!c || !surface || n_off < 0 || n_moved < 0 || (n_off > 0 && !off) ||
        (n_moved > 0 && !moved) || surface->n_nodes != c->n || surface->n_surf_nodes < 1)
        return HS_ERR_INVALID;
    const int ne = c->mesh->n_tets;
    for (int k = 0; k < n_off; ++k)
        if (off[k] < 0 || off[k] >= ne) return HS_ERR_INVALID;
    for (int k = 0; k < n_moved; ++k)
        if (moved[k] < 0 || moved[k] >= ne) return HS_ERR_INVALID;
    const int64_t t0 = hs_now_ns();
    hs_status s = change_scratch(c, surface);
    if (s != HS_OK) return s;
    // Every cached column and diagonal block answers for the old stiffness from here on.
    for (int i = 0; i < c->cap; ++i) c->slot_node[i] = -1;
    for (int i = 0; i < c->n; ++i) c->node_slot[i] = -1;
    memset(c->diag_ok, 0, (size_t)c->n_surf);
    c->surf = surface;

    // Elements whose share changes, each once: moved ones still active (list[0, n_new)), then
    // active ones going off; one both moved and going off only goes off.
    unsigned char* mk = c->emark;
    int* list = c->elist;
    int n_all = 0;
    for (int k = 0; k < n_off; ++k) mk[off[k]] = 2;
    for (int k = 0; k < n_moved; ++k) {
        const int e = moved[k];
        if (!mk[e] && hs_fem_element_active(c->fem, e)) list[n_all++] = e;
        mk[e] |= 1;
    }
    const int n_new = n_all;
    for (int k = 0; k < n_off; ++k) {
        const int e = off[k];
        if (mk[e] != 4 && hs_fem_element_active(c->fem, e)) list[n_all++] = e;
        mk[e] = 4;
    }
    for (int k = 0; k < n_off; ++k) mk[off[k]] = 0;
    for (int k = 0; k < n_moved; ++k) mk[moved[k]] = 0;

    // K' = K - old shares + new shares, in place (the pattern never changes).
    s = hs_fem_add_rest_elements(c->fem, n_all, list, 1.0, 0.0, -1.0, c->k);
    if (s == HS_OK) s = hs_fem_refresh_elements(c->fem, list, n_new);
    if (s != HS_OK) return s; // K partly changed: the caller rebuilds
    for (int k = 0; k < n_off; ++k) hs_fem_set_element_active(c->fem, off[k], 0);
    s = hs_fem_add_rest_elements(c->fem, n_new, list, 1.0, 0.0, 1.0, c->k);
    if (s != HS_OK) return s;
    // A node that lost its last element leaves the system: a diagonal holds it (its rows and
    // columns are zero now up to round-off), so the stiffness stays definite and it couples to
    // nothing. The compliance built afresh eliminates it instead: the same C elsewhere.
    const double* held = hs_fem_held_mass(c->fem);
    int nd = 0;
    for (int k = 0; k < n_all; ++k)
        for (int q = 0; q < 12; ++q) {
            const int node = c->mesh->tets[4 * list[k] + q / 3], d = c->dof[3 * node + q % 3];
            if (d < 0) continue;
            c->dlist[nd++] = d;
            if (held[node] > 0 && !c->held[node]) {
                for (int a = 0; a < 3; ++a) {
                    const int dd = c->dof[3 * node + a], p = hs_csc_find(c->k, dd, dd);
                    if (p >= 0) c->k->val[p] += c->hold_k;
                }
                c->held[node] = 1;
            }
        }

    // The factor follows exactly: a supernodal one recomputes only the supernodes on the
    // elimination-tree paths from the changed dofs (the first change sets that up with one full
    // pass); a simplicial one (small meshes) refactors, which costs about the same there.
    if (c->partial) {
        s = hs_cholesky_refactor_partial(c->chol, c->k, nd, c->dlist);
    } else if (hs_cholesky_is_supernodal(c->chol)) {
        s = hs_cholesky_prepare_partial(c->chol, c->k);
        c->partial = s == HS_OK;
    } else {
        s = hs_cholesky_refactor(c->chol, c->k);
    }
    if (s != HS_OK) return s; // e.g. a piece left without a hold: the caller rebuilds
    c->updates++;
    c->update_ms = (double)(hs_now_ns() - t0) * 1e-6;
    return HS_OK;
}
