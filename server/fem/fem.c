// SPDX-License-Identifier: GPL-2.0-or-later
// FEM object: per-element data in flat arrays, model evaluation (linear, co-rotated, StVK, with
// the optional average-nodal-pressure volumetric term), and assembly by a precomputed scatter.
//
// DESIGN. hs_fem_create does all allocation: element shape gradients and volumes, the node ->
// element incidence, the node adjacency of the tangent (1-ring, or 2-ring with ANP) and, for
// every 3x3 node block of that pattern, the 9 positions in hs_csc.val; each element keeps a
// flat copy of its 78 upper-triangle positions, the ANP node terms address blocks by id, so
// hs_fem_assemble is a pure scatter with no search (upper triangle, then a mirror pass).
// hs_fem_update evaluates the model and keeps what the tangent needs (F, R, S, ANP gradients);
// element tangents are formed on the fly from those in assemble / apply_tangent, since a
// 12x12 block per element costs more memory traffic than recomputing it from 3x3 pieces.
#include "fem.h"

#include "element.h"
#include "fem_internal.h"
#include "polar4.h"

#include <float.h>
#include <limits.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>

#define HS_FEM_COOKIE 0x46454d31

struct hs_fem {
    const hs_mesh* mesh;
    hs_fem_def def;
    int n, ne, n_free;
    double lambda, mu, kappa; // Lame parameters and bulk modulus, Pa
    double lam_el;            // lambda of the element term: lambda, or -2mu_el/3 with ANP
    double mu_el;             // mu of the element term: mu, or (1 - alpha) mu with SNS
    int* dof;                 // [3n] free index or -1

    // elements
    int* tet;              // [4ne]
    double* g;             // [12ne] rest shape gradients g_a (a = 0..3), 1/m
    double* vol0;          // [ne] rest volume, m^3
    double* kscale;        // [ne] element stiffness scale (1; hs_fem_set_element_stiffness_scale)
    unsigned char* active; // [ne]
    uint64_t k_version;    // grows whenever the rest stiffness or the mass changes
    double* F;             // [9ne] deformation gradient at the last update
    double* R;             // [9ne] rotation (co-rotated); warm start of the next update
    double* S;             // [9ne] second Piola-Kirchhoff stress (StVK), Pa
    double* det;           // [ne] det F
    double* qsum;          // [4n] co-rotated: sum of vol0 q(R) over each node's active tets
    uint64_t qsum_stamp;   // 1 + k_version of the update that made qsum (0: none)

    // nodes
    double* f;     // [3n] elastic forces, N
    double* mass;  // [n] lumped mass, kg
    double* held;  // [n] mass a node had when its last element went (system diagonal only)
    int n_held;    // nodes with held mass
    int* nt_start; // [n+1] node -> element incidence (CSR)
    int* nt;       // element of each incidence

    // pattern: per column node k the sorted row nodes adj[adj_start[k] ..] (self included);
    // block id = position in adj
    int* adj_start;
    int* adj;
    int n_blocks;
    // Assembly writes the upper triangle only (row <= col) and then mirrors it: a symmetric
    // matrix, so half the scatter. "Canonical" position of (r, c) = position of (min, max).
    int* blkpos;   // [9 n_blocks] row-major canonical positions in val, -1 for constrained dofs
    int* elem_pos; // [78ne] canonical positions of the element's dof pairs (r <= c), in the
                   // order of build_scatter
    int n_mirror;  // strictly lower entries
    int* mirror;   // [2 n_mirror] (lower position, its upper transpose)
    int* low_of;   // [nnz] lower transpose of a strictly upper position, else -1
    int* diag_pos; // [3n]
    int nnz;

    // average nodal pressure
    int anp;
    int* ring_start;     // [n+1] 1-ring of each node, self included, sorted
    int* ring;           //
    int* nt_slot;        // [4 * incidences]: slot in ring(n) of each local node of the element
    int64_t* pair_start; // [n+1] offsets into pair_blk
    int* pair_blk;       // ring(n) x ring(n) block ids, row-major per node
    double* theta_e;     // [ne] element volumetric strain
    double* w;           // [12ne] d theta_e / d x_a
    double* pbar;        // [ne] element mean of the nodal pressures, Pa
    double* vn;          // [n] nodal volume, m^3
    double* theta_n;     // [n] nodal volumetric strain
    double* cvec;        // [3 * ring total] d theta_n / d x_m

    // selective node smoothing (SNS, locking_free 2): a share alpha of the deviatoric energy
    // from the node-smoothed strain, with the node's own rotation (co-rotated)
    int sns;
    double mu_n;  // alpha mu, Pa
    double* gbar; // [3 * ring total] smoothed rest gradients d F_n / d x_m
    double* rn;   // [9n] node rotations (warm start of the next update)

    hs_fem_stats stats;
};

hs_fem_def hs_fem_default_def(void) {
    hs_fem_def d;
    memset(&d, 0, sizeof d);
    d.model = HS_MODEL_LINEAR;
    d.material.youngs_pa = 3000.0;
    d.material.poisson = 0.45;
    d.material.density_kg_m3 = 1000.0;
    d.rotation = HS_ROTATION_POLAR;
    d.polar_tol = 1e-6;
    d.polar_max_iter = 20;
    d.inversion = HS_INVERSION_LINEAR_FALLBACK;
    d.locking_free = 0;
    d.locking_free_alpha = HS_SNS_ALPHA_DEFAULT;
    d.cookie = HS_FEM_COOKIE;
    return d;
}

void hs_fem_destroy(hs_fem** pfem) {
    if (!pfem || !*pfem) return;
    hs_fem* m = *pfem;
    void* ptrs[] = {m->dof,        m->tet,      m->g,         m->vol0,       m->active, m->F,
                    m->R,          m->S,        m->det,       m->f,          m->mass,   m->held,
                    m->nt_start,   m->nt,       m->adj_start, m->adj,        m->blkpos, m->elem_pos,
                    m->diag_pos,   m->mirror,   m->low_of,    m->ring_start, m->ring,   m->nt_slot,
                    m->pair_start, m->pair_blk, m->theta_e,   m->w,          m->pbar,   m->vn,
                    m->theta_n,    m->cvec,     m->kscale,    m->qsum,       m->gbar,   m->rn};
    for (size_t i = 0; i < sizeof ptrs / sizeof ptrs[0]; i++) hs_free(ptrs[i]);
    hs_free(m);
    *pfem = NULL;
}

static int cmp_int(const void* a, const void* b) {
    int x = *(const int*)a, y = *(const int*)b;
    return (x > y) - (x < y);
}

/// Index of v in the sorted a[0..n), or -1.
static int bsearch_int(const int* a, int n, int v) {
    int lo = 0, hi = n - 1;
    while (lo <= hi) {
        int mid = (lo + hi) / 2;
        if (a[mid] < v)
            lo = mid + 1;
        else if (a[mid] > v)
            hi = mid - 1;
        else
            return mid;
    }
    return -1;
}

static hs_status check_def(const hs_fem_def* d, hs_err* err) {
    if (d->cookie != HS_FEM_COOKIE)
        return hs_err_set(err, HS_ERR_INVALID,
                          "fem: definition not initialised (use hs_fem_default_def())");
    if (d->model < HS_MODEL_LINEAR || d->model > HS_MODEL_STVK)
        return hs_err_set(err, HS_ERR_INVALID, "fem: unknown model %d", (int)d->model);
    if (d->rotation < HS_ROTATION_POLAR || d->rotation > HS_ROTATION_SVD)
        return hs_err_set(err, HS_ERR_INVALID, "fem: unknown rotation method %d", (int)d->rotation);
    if (d->inversion < HS_INVERSION_LINEAR_FALLBACK || d->inversion > HS_INVERSION_KEEP_REFLECTION)
        return hs_err_set(err, HS_ERR_INVALID, "fem: unknown inversion remedy %d",
                          (int)d->inversion);
    const hs_material* m = &d->material;
    if (!(m->youngs_pa > 0) || !isfinite(m->youngs_pa))
        return hs_err_set(err, HS_ERR_INVALID, "fem: Young's modulus must be > 0 (got %g Pa)",
                          m->youngs_pa);
    if (!(m->poisson > -1.0 && m->poisson < 0.5))
        return hs_err_set(err, HS_ERR_INVALID, "fem: Poisson ratio must be in (-1, 0.5) (got %g)",
                          m->poisson);
    // Finite E and nu can still overflow the Lame parameters (E 1e300 Pa near nu 0.5 or -1):
    // the energy at rest was then NaN. Bound them far beyond any tissue (or steel, 1e11 Pa).
    const double mu = m->youngs_pa / (2 * (1 + m->poisson)),
                 lam = m->youngs_pa * m->poisson / ((1 + m->poisson) * (1 - 2 * m->poisson)),
                 kap = m->youngs_pa / (3 * (1 - 2 * m->poisson));
    if (!(mu <= 1e20 && fabs(lam) <= 1e20 && kap <= 1e20))
        return hs_err_set(err, HS_ERR_INVALID,
                          "fem: E %g Pa with nu %g gives moduli beyond 1e20 Pa (mu %g, lambda "
                          "%g, bulk %g)",
                          m->youngs_pa, m->poisson, mu, lam, kap);
    if (!(m->density_kg_m3 >= 0) || !isfinite(m->density_kg_m3))
        return hs_err_set(err, HS_ERR_INVALID, "fem: density must be >= 0 (got %g kg/m^3)",
                          m->density_kg_m3);
    if (!(m->rayleigh_mass >= 0) || !(m->rayleigh_stiffness >= 0) || !isfinite(m->rayleigh_mass) ||
        !isfinite(m->rayleigh_stiffness))
        return hs_err_set(err, HS_ERR_INVALID,
                          "fem: Rayleigh coefficients must be finite and >= 0 (got %g, %g)",
                          m->rayleigh_mass, m->rayleigh_stiffness);
    // SVD reads polar_tol too (how far a kept rotation may be from F's polar factor).
    if (d->model == HS_MODEL_COROTATED &&
        (!(d->polar_tol > 0) || !isfinite(d->polar_tol) ||
         (d->rotation == HS_ROTATION_POLAR && d->polar_max_iter < 1)))
        return hs_err_set(err, HS_ERR_INVALID,
                          "fem: polar_tol must be > 0 and polar_max_iter >= 1 (got %g, %d)",
                          d->polar_tol, d->polar_max_iter);
    if (d->locking_free < HS_LOCKING_FREE_NONE || d->locking_free > HS_LOCKING_FREE_SNS)
        return hs_err_set(err, HS_ERR_INVALID, "fem: locking_free must be 0, 1 or 2 (got %d)",
                          d->locking_free);
    if (d->locking_free == HS_LOCKING_FREE_SNS && d->model == HS_MODEL_STVK)
        return hs_err_set(err, HS_ERR_UNSUPPORTED,
                          "fem: locking_free 2 (sns) is for linear and co-rotated, not StVK");
    if (!(d->locking_free_alpha >= 0 && d->locking_free_alpha < 1))
        return hs_err_set(err, HS_ERR_INVALID, "fem: locking_free_alpha must be in [0, 1) (got %g)",
                          d->locking_free_alpha);
    return HS_OK;
}

static hs_status nomem(hs_err* err) {
    return hs_err_set(err, HS_ERR_NOMEM, "fem: out of memory");
}

/// Recompute the lumped mass of node i from its active elements. A node whose last element
/// goes keeps that mass on the system diagonal only (`held`): with no force and no inertia it
/// stays where it is, and a dynamic system stays definite without a pin spring.
static void node_mass(hs_fem* m, int i) {
    double s = 0;
    for (int p = m->nt_start[i]; p < m->nt_start[i + 1]; p++) {
        int e = m->nt[p];
        if (m->active[e]) s += m->vol0[e];
    }
    double mass = 0.25 * m->def.material.density_kg_m3 * s;
    if (mass == 0 && m->mass[i] > 0 && m->held[i] == 0) {
        m->held[i] = m->mass[i];
        m->n_held++;
    } else if (mass > 0 && m->held[i] > 0) {
        m->held[i] = 0;
        m->n_held--;
    }
    m->mass[i] = mass;
}

static hs_status build_incidence(hs_fem* m) {
    int n = m->n, ne = m->ne;
    m->nt_start = hs_calloc((size_t)n + 1, sizeof(int));
    m->nt = hs_alloc(sizeof(int) * 4 * (size_t)ne + 1);
    if (!m->nt_start || !m->nt) return HS_ERR_NOMEM;
    for (int k = 0; k < 4 * ne; k++) m->nt_start[m->tet[k] + 1]++;
    for (int i = 0; i < n; i++) m->nt_start[i + 1] += m->nt_start[i];
    int* fill = hs_alloc(sizeof(int) * ((size_t)n + 1));
    if (!fill) return HS_ERR_NOMEM;
    memcpy(fill, m->nt_start, sizeof(int) * (size_t)n);
    for (int e = 0; e < ne; e++)
        for (int a = 0; a < 4; a++) {
            int i = m->tet[4 * e + a], p = fill[i]++;
            m->nt[p] = e;
        }
    hs_free(fill);
    return HS_OK;
}

/// 1-ring of every node (self included, sorted): ring_start/ring.
static hs_status build_rings(hs_fem* m) {
    int n = m->n;
    m->ring_start = hs_calloc((size_t)n + 1, sizeof(int));
    // Before de-duplication a node writes itself and 4 entries per incident tet.
    size_t cap = (size_t)n + 4 * (size_t)m->nt_start[n] + 1;
    int* tmp = hs_alloc(sizeof(int) * cap);
    if (!m->ring_start || !tmp) {
        hs_free(tmp);
        return HS_ERR_NOMEM;
    }
    int w = 0;
    for (int i = 0; i < n; i++) {
        int b = w;
        tmp[w++] = i;
        for (int p = m->nt_start[i]; p < m->nt_start[i + 1]; p++)
            for (int a = 0; a < 4; a++) tmp[w++] = m->tet[4 * m->nt[p] + a];
        qsort(tmp + b, (size_t)(w - b), sizeof(int), cmp_int);
        int u = b;
        for (int q = b; q < w; q++)
            if (u == b || tmp[u - 1] != tmp[q]) tmp[u++] = tmp[q];
        w = u;
        m->ring_start[i + 1] = w;
    }
    m->ring = hs_alloc(sizeof(int) * ((size_t)w + 1));
    if (!m->ring) {
        hs_free(tmp);
        return HS_ERR_NOMEM;
    }
    memcpy(m->ring, tmp, sizeof(int) * (size_t)w);
    hs_free(tmp);
    return HS_OK;
}

/// Pattern adjacency (self included, sorted): the 1-ring, or with ANP the 2-ring.
static hs_status build_adjacency(hs_fem* m) {
    int n = m->n;
    if (!m->anp) {
        int tot = m->ring_start[n];
        m->adj_start = hs_alloc(sizeof(int) * ((size_t)n + 1));
        m->adj = hs_alloc(sizeof(int) * ((size_t)tot + 1));
        if (!m->adj_start || !m->adj) return HS_ERR_NOMEM;
        memcpy(m->adj_start, m->ring_start, sizeof(int) * ((size_t)n + 1));
        memcpy(m->adj, m->ring, sizeof(int) * (size_t)tot);
        return HS_OK;
    }
    int* mark = hs_alloc(sizeof(int) * ((size_t)n + 1));
    m->adj_start = hs_calloc((size_t)n + 1, sizeof(int));
    if (!mark || !m->adj_start) {
        hs_free(mark);
        return HS_ERR_NOMEM;
    }
    for (int i = 0; i < n; i++) mark[i] = -1;
    int64_t tot = 0;
    for (int pass = 0; pass < 2; pass++) {
        for (int i = 0; i < n; i++) mark[i] = -1;
        tot = 0;
        for (int i = 0; i < n; i++) {
            int64_t b = tot;
            for (int p = m->ring_start[i]; p < m->ring_start[i + 1]; p++) {
                int j = m->ring[p];
                for (int q = m->ring_start[j]; q < m->ring_start[j + 1]; q++) {
                    int k = m->ring[q];
                    if (mark[k] == i) continue;
                    mark[k] = i;
                    if (pass == 1) m->adj[tot] = k;
                    tot++;
                }
            }
            if (pass == 1)
                qsort(m->adj + b, (size_t)(tot - b), sizeof(int), cmp_int);
            else if (tot > INT_MAX / 9) {
                hs_free(mark);
                return HS_ERR_UNSUPPORTED;
            }
            if (pass == 0) m->adj_start[i + 1] = (int)tot;
        }
        if (pass == 0) {
            m->adj = hs_alloc(sizeof(int) * ((size_t)tot + 1));
            if (!m->adj) {
                hs_free(mark);
                return HS_ERR_NOMEM;
            }
        }
    }
    hs_free(mark);
    return HS_OK;
}

static int block_id(const hs_fem* m, int row, int col) {
    int b = m->adj_start[col];
    int k = bsearch_int(m->adj + b, m->adj_start[col + 1] - b, row);
    return k < 0 ? -1 : b + k;
}

/// Block positions in a matrix with the pattern of hs_fem_create_matrix.
static hs_status build_scatter(hs_fem* m, const hs_csc* a, hs_err* err) {
    int n = m->n;
    m->n_blocks = m->adj_start[n];
    m->nnz = a->nnz;
    m->blkpos = hs_alloc(sizeof(int) * 9 * (size_t)m->n_blocks + 1);
    m->elem_pos = hs_alloc(sizeof(int) * 78 * (size_t)m->ne + 1);
    m->n_mirror = (a->nnz - a->n) / 2;
    m->mirror = hs_alloc(sizeof(int) * 2 * (size_t)m->n_mirror + 1);
    m->diag_pos = hs_alloc(sizeof(int) * 3 * (size_t)n + 1);
    m->low_of = hs_alloc(sizeof(int) * (size_t)a->nnz + 1);
    if (!m->blkpos || !m->elem_pos || !m->diag_pos || !m->mirror || !m->low_of) return nomem(err);
    for (int p = 0; p < a->nnz; p++) m->low_of[p] = -1;
    for (int col = 0; col < n; col++) {
        for (int p = m->adj_start[col]; p < m->adj_start[col + 1]; p++) {
            int row = m->adj[p];
            for (int ri = 0; ri < 3; ri++)
                for (int cj = 0; cj < 3; cj++) {
                    int dr = m->dof[3 * row + ri], dc = m->dof[3 * col + cj];
                    int lo = dr < dc ? dr : dc, hi = dr < dc ? dc : dr;
                    int pos = dr >= 0 && dc >= 0 ? hs_csc_find(a, lo, hi) : -1;
                    if (dr >= 0 && dc >= 0 && pos < 0)
                        return hs_err_set(err, HS_ERR_INVALID,
                                          "fem: matrix pattern lacks entry (%d, %d)", dr, dc);
                    m->blkpos[9 * p + 3 * ri + cj] = pos;
                }
        }
    }
    // Flat per element (streamed in assemble) rather than via the block id: one indirection
    // less on the hot path. Order: blocks a <= b, rows i, columns j (j >= i when a == b).
    for (int e = 0; e < m->ne; e++) {
        int k = 0;
        for (int aa = 0; aa < 4; aa++)
            for (int b = aa; b < 4; b++) {
                int id = block_id(m, m->tet[4 * e + aa], m->tet[4 * e + b]);
                HS_ASSERT(id >= 0);
                for (int i = 0; i < 3; i++)
                    for (int j = aa == b ? i : 0; j < 3; j++)
                        m->elem_pos[78 * e + k++] = m->blkpos[9 * id + 3 * i + j];
            }
        HS_ASSERT(k == 78);
    }
    int w = 0;
    for (int c = 0; c < a->n; c++)
        for (int p = a->colp[c]; p < a->colp[c + 1]; p++) {
            int r = a->rowi[p];
            if (r <= c) continue;
            int t = hs_csc_find(a, c, r);
            if (t < 0 || w >= m->n_mirror)
                return hs_err_set(err, HS_ERR_INVALID, "fem: matrix pattern is not symmetric");
            m->mirror[2 * w] = p;
            m->mirror[2 * w + 1] = t;
            m->low_of[t] = p;
            w++;
        }
    if (w != m->n_mirror)
        return hs_err_set(err, HS_ERR_INVALID, "fem: matrix pattern is not symmetric");
    for (int i = 0; i < n; i++) {
        int id = block_id(m, i, i);
        HS_ASSERT(id >= 0);
        for (int c = 0; c < 3; c++) m->diag_pos[3 * i + c] = m->blkpos[9 * id + 4 * c];
    }
    return HS_OK;
}

static hs_status build_anp(hs_fem* m) {
    int n = m->n, ne = m->ne, ninc = m->nt_start[n];
    m->nt_slot = hs_alloc(sizeof(int) * 4 * (size_t)ninc + 1);
    m->pair_start = hs_alloc(sizeof(int64_t) * ((size_t)n + 1));
    m->theta_e = hs_calloc((size_t)ne + 1, sizeof(double));
    m->w = hs_calloc(12 * (size_t)ne + 1, sizeof(double));
    m->pbar = hs_calloc((size_t)ne + 1, sizeof(double));
    m->vn = hs_calloc((size_t)n + 1, sizeof(double));
    m->theta_n = hs_calloc((size_t)n + 1, sizeof(double));
    m->cvec = hs_calloc(3 * (size_t)m->ring_start[n] + 1, sizeof(double));
    if (!m->nt_slot || !m->pair_start || !m->theta_e || !m->w || !m->pbar || !m->vn ||
        !m->theta_n || !m->cvec)
        return HS_ERR_NOMEM;
    if (m->sns) {
        m->gbar = hs_calloc(3 * (size_t)m->ring_start[n] + 1, sizeof(double));
        m->rn = hs_alloc(sizeof(double) * 9 * (size_t)n + 1);
        if (!m->gbar || !m->rn) return HS_ERR_NOMEM;
        for (int i = 0; i < n; i++) m3_identity(m->rn + 9 * i);
    }
    for (int i = 0; i < n; i++) {
        int b = m->ring_start[i], s = m->ring_start[i + 1] - b;
        for (int p = m->nt_start[i]; p < m->nt_start[i + 1]; p++)
            for (int a = 0; a < 4; a++) {
                int k = bsearch_int(m->ring + b, s, m->tet[4 * m->nt[p] + a]);
                HS_ASSERT(k >= 0);
                m->nt_slot[4 * p + a] = k;
            }
    }
    m->pair_start[0] = 0;
    for (int i = 0; i < n; i++) {
        int64_t s = m->ring_start[i + 1] - m->ring_start[i];
        m->pair_start[i + 1] = m->pair_start[i] + s * s;
    }
    m->pair_blk = hs_alloc(sizeof(int) * (size_t)m->pair_start[n] + 1);
    if (!m->pair_blk) return HS_ERR_NOMEM;
    for (int i = 0; i < n; i++) {
        int b = m->ring_start[i], s = m->ring_start[i + 1] - b;
        int* pb = m->pair_blk + m->pair_start[i];
        for (int r = 0; r < s; r++)
            for (int c = 0; c < s; c++) {
                int id = block_id(m, m->ring[b + r], m->ring[b + c]);
                HS_ASSERT(id >= 0);
                pb[r * s + c] = id;
            }
    }
    return HS_OK;
}

hs_status hs_fem_create(const hs_mesh* mesh, const hs_fem_def* def, const int* dof_map, int n_free,
                        hs_fem** out, hs_err* err) {
    if (!out) return hs_err_set(err, HS_ERR_INVALID, "fem: out is NULL");
    *out = NULL;
    if (!mesh || !def || !dof_map)
        return hs_err_set(err, HS_ERR_INVALID, "fem: mesh, def and dof_map must not be NULL");
    hs_status st = check_def(def, err);
    if (st != HS_OK) return st;
    if (mesh->n_nodes <= 0 || mesh->n_tets <= 0 || !mesh->x0 || !mesh->tets)
        return hs_err_set(err, HS_ERR_INVALID, "fem: empty mesh (%d nodes, %d tets)", mesh->n_nodes,
                          mesh->n_tets);
    int n = mesh->n_nodes, ne = mesh->n_tets;
    if (n > INT_MAX / 3 || ne > INT_MAX / 78) // 78 scatter positions per tet (elem_pos)
        return hs_err_set(err, HS_ERR_UNSUPPORTED, "fem: mesh too large (%d nodes, %d tets)", n,
                          ne);
    if (n_free < 0 || n_free > 3 * n)
        return hs_err_set(err, HS_ERR_INVALID, "fem: n_free %d out of range [0, %d]", n_free,
                          3 * n);
    for (int k = 0; k < 4 * ne; k++)
        if (mesh->tets[k] < 0 || mesh->tets[k] >= n)
            return hs_err_set(err, HS_ERR_INVALID, "fem: tet %d references node %d (of %d)", k / 4,
                              mesh->tets[k], n);

    hs_fem* m = hs_calloc(1, sizeof *m);
    if (!m) return nomem(err);
    m->mesh = mesh;
    m->def = *def;
    m->n = n;
    m->ne = ne;
    m->n_free = n_free;
    m->anp = def->locking_free != HS_LOCKING_FREE_NONE;
    m->sns = def->locking_free == HS_LOCKING_FREE_SNS;
    double E = def->material.youngs_pa, nu = def->material.poisson;
    m->mu = E / (2.0 * (1.0 + nu));
    m->lambda = E * nu / ((1.0 + nu) * (1.0 - 2.0 * nu));
    m->kappa = m->lambda + 2.0 * m->mu / 3.0;
    m->mu_n = m->sns ? def->locking_free_alpha * m->mu : 0.0;
    m->mu_el = m->mu - m->mu_n;
    m->lam_el = m->anp ? -2.0 * m->mu_el / 3.0 : m->lambda;

    m->dof = hs_alloc(sizeof(int) * 3 * (size_t)n);
    unsigned char* seen = hs_calloc((size_t)n_free + 1, 1);
    m->tet = hs_alloc(sizeof(int) * 4 * (size_t)ne);
    m->g = hs_alloc(sizeof(double) * 12 * (size_t)ne);
    m->vol0 = hs_alloc(sizeof(double) * (size_t)ne);
    m->kscale = hs_alloc(sizeof(double) * (size_t)ne);
    m->active = hs_alloc((size_t)ne);
    m->F = hs_alloc(sizeof(double) * 9 * (size_t)ne);
    m->R = hs_alloc(sizeof(double) * 9 * (size_t)ne);
    m->S = hs_calloc(9 * (size_t)ne, sizeof(double));
    m->det = hs_alloc(sizeof(double) * (size_t)ne);
    m->qsum = hs_calloc(4 * (size_t)n + 1, sizeof(double));
    m->f = hs_calloc(3 * (size_t)n, sizeof(double));
    m->mass = hs_calloc((size_t)n, sizeof(double));
    m->held = hs_calloc((size_t)n + 1, sizeof(double));
    if (!m->dof || !seen || !m->tet || !m->g || !m->vol0 || !m->kscale || !m->active || !m->F ||
        !m->R || !m->S || !m->det || !m->qsum || !m->f || !m->mass || !m->held) {
        hs_free(seen);
        st = nomem(err);
        goto fail;
    }
    for (int d = 0; d < 3 * n; d++) {
        int v = dof_map[d];
        if (v < -1 || v >= n_free || (v >= 0 && seen[v])) {
            hs_free(seen);
            st = hs_err_set(err, HS_ERR_INVALID,
                            "fem: dof_map[%d] = %d is out of range or repeated (n_free %d)", d, v,
                            n_free);
            goto fail;
        }
        if (v >= 0) seen[v] = 1;
        m->dof[d] = v;
    }
    for (int v = 0; v < n_free; v++)
        if (!seen[v]) {
            hs_free(seen);
            st = hs_err_set(err, HS_ERR_INVALID, "fem: free index %d is not used by dof_map", v);
            goto fail;
        }
    hs_free(seen);
    memcpy(m->tet, mesh->tets, sizeof(int) * 4 * (size_t)ne);

    // Shape gradients: F = sum_i (x_i - x_0) g_i^T with g_i the rows of Dm^-1 (i = 1..3).
    for (int e = 0; e < ne; e++) {
        const int* t = m->tet + 4 * e;
        const double* p0 = mesh->x0 + 3 * t[0];
        double dm[9];
        for (int i = 0; i < 3; i++)
            for (int c = 0; c < 3; c++) dm[3 * c + i] = mesh->x0[3 * t[i + 1] + c] - p0[c];
        double det = m3_det(dm);
        double scale = 0;
        for (int k = 0; k < 9; k++) scale = fmax(scale, fabs(dm[k]));
        if (!(det > 1e-14 * scale * scale * scale) || !isfinite(det)) {
            st = hs_err_set(err, HS_ERR_INVALID,
                            "fem: tet %d (nodes %d %d %d %d) has rest volume %g m^3 <= 0", e, t[0],
                            t[1], t[2], t[3], det / 6.0);
            goto fail;
        }
        double cof[9];
        m3_cofactor(dm, cof); // Dm^-1 = cof^T / det, so row i of Dm^-1 is column i of cof / det
        double* g = m->g + 12 * e;
        for (int i = 0; i < 3; i++)
            for (int c = 0; c < 3; c++) g[3 * (i + 1) + c] = cof[3 * c + i] / det;
        for (int c = 0; c < 3; c++) g[c] = -(g[3 + c] + g[6 + c] + g[9 + c]);
        m->vol0[e] = det / 6.0;
        m->kscale[e] = 1.0;
        m->active[e] = 1;
        m3_identity(m->F + 9 * e);
        m3_identity(m->R + 9 * e);
        m->det[e] = 1.0;
    }
    if (build_incidence(m) != HS_OK || build_rings(m) != HS_OK) {
        st = nomem(err);
        goto fail;
    }
    st = build_adjacency(m);
    if (st != HS_OK) {
        st = st == HS_ERR_NOMEM ? nomem(err)
                                : hs_err_set(err, st, "fem: locking-free pattern too large");
        goto fail;
    }
    if (m->anp && build_anp(m) != HS_OK) {
        st = nomem(err);
        goto fail;
    }
    for (int i = 0; i < n; i++) node_mass(m, i);
    {
        hs_csc* a = NULL;
        // The pattern wants neighbour lists without self; ours include it (the builder skips it).
        st = hs_csc_create_block_pattern(n, m->adj_start, m->adj, m->dof, n_free, &a, err);
        if (st != HS_OK) goto fail;
        st = build_scatter(m, a, err);
        hs_csc_destroy(&a);
        if (st != HS_OK) goto fail;
    }
    m->stats.volume_ratio_mean = m->stats.volume_ratio_min = m->stats.volume_ratio_max = 1.0;
    *out = m;
    return HS_OK;
fail:
    hs_fem_destroy(&m);
    return st;
}

hs_status hs_fem_create_matrix(const hs_fem* fem, hs_csc** out) {
    if (!out) return HS_ERR_INVALID;
    *out = NULL;
    if (!fem) return HS_ERR_INVALID;
    hs_status st = hs_csc_create_block_pattern(fem->n, fem->adj_start, fem->adj, fem->dof,
                                               fem->n_free, out, NULL);
    if (st != HS_OK) return st;
    HS_ASSERT((*out)->nnz == fem->nnz);
    return HS_OK;
}

const double* hs_fem_lumped_mass(const hs_fem* fem) {
    HS_ASSERT(fem);
    return fem->mass;
}

int hs_fem_held_nodes(const hs_fem* fem) {
    return fem ? fem->n_held : 0;
}

const double* hs_fem_held_mass(const hs_fem* fem) {
    return fem->held;
}

void hs_fem_set_element_active(hs_fem* fem, int tet, int active) {
    HS_ASSERT(fem && tet >= 0 && tet < fem->ne);
    unsigned char v = active ? 1 : 0;
    if (fem->active[tet] == v) return;
    fem->active[tet] = v;
    fem->k_version++;
    for (int a = 0; a < 4; a++) node_mass(fem, fem->tet[4 * tet + a]);
}

const unsigned char* hs_fem_active_elements(const hs_fem* fem) {
    return fem->active;
}

int hs_fem_element_active(const hs_fem* fem, int tet) {
    return fem && tet >= 0 && tet < fem->ne && fem->active[tet];
}

hs_status hs_fem_set_element_stiffness_scale(hs_fem* fem, int tet, double s) {
    if (!fem || tet < 0 || tet >= fem->ne || !(s > 0) || !isfinite(s)) return HS_ERR_INVALID;
    if (fem->anp) return HS_ERR_UNSUPPORTED; // the nodal volumetric term mixes elements
    fem->kscale[tet] = s;
    fem->k_version++;
    return HS_OK;
}

hs_status hs_fem_refresh_elements(hs_fem* fem, const int* tets, int n) {
    if (!fem || n < 0 || (n > 0 && !tets)) return HS_ERR_INVALID;
    const double* x0 = fem->mesh->x0;
    // Validate every element first so a bad one leaves all element data untouched.
    for (int k = 0; k < n; k++) {
        int e = tets[k];
        if (e < 0 || e >= fem->ne) return HS_ERR_INVALID;
        const int* t = fem->tet + 4 * e;
        double dm[9], scale = 0;
        for (int i = 0; i < 3; i++)
            for (int c = 0; c < 3; c++) dm[3 * c + i] = x0[3 * t[i + 1] + c] - x0[3 * t[0] + c];
        for (int q = 0; q < 9; q++) scale = fmax(scale, fabs(dm[q]));
        double det = m3_det(dm);
        if (!(det > 1e-14 * scale * scale * scale) || !isfinite(det)) return HS_ERR_INVALID;
    }
    for (int k = 0; k < n; k++) {
        int e = tets[k];
        const int* t = fem->tet + 4 * e;
        double dm[9], cof[9];
        for (int i = 0; i < 3; i++)
            for (int c = 0; c < 3; c++) dm[3 * c + i] = x0[3 * t[i + 1] + c] - x0[3 * t[0] + c];
        double det = m3_det(dm);
        m3_cofactor(dm, cof);
        double* g = fem->g + 12 * e;
        for (int i = 0; i < 3; i++)
            for (int c = 0; c < 3; c++) g[3 * (i + 1) + c] = cof[3 * c + i] / det;
        for (int c = 0; c < 3; c++) g[c] = -(g[3 + c] + g[6 + c] + g[9 + c]);
        fem->vol0[e] = det / 6.0;
    }
    for (int k = 0; k < n; k++)
        for (int a = 0; a < 4; a++) node_mass(fem, fem->tet[4 * tets[k] + a]);
    fem->k_version++;
    return HS_OK;
}

uint64_t hs_fem_stiffness_version(const hs_fem* fem) {
    HS_ASSERT(fem);
    return fem->k_version;
}

void hs_fem_reset_rotations(hs_fem* fem) {
    HS_ASSERT(fem);
    for (int e = 0; e < fem->ne; e++) m3_identity(fem->R + 9 * (size_t)e);
    for (int i = 0; fem->sns && i < fem->n; i++) m3_identity(fem->rn + 9 * (size_t)i);
    fem->qsum_stamp = 0; // the quaternion sums were made from the rotations just dropped
}

hs_status hs_fem_set_polar_tol(hs_fem* fem, double tol) {
    HS_ASSERT(fem);
    if (!(tol > 0) || !isfinite(tol)) return HS_ERR_INVALID;
    fem->def.polar_tol = tol;
    return HS_OK;
}

// ---------------------------------------------------------------------------------------------
// Evaluation

/// Rotation of element e for the co-rotated model and rtf = R^T F; returns polar iterations.
static int element_rotation(hs_fem* m, int e, const double F[9], double det, double rtf[9]) {
    double* r = m->R + 9 * e;
    int it = 0;
    if (!(det > 0)) {
        if (m->def.inversion == HS_INVERSION_LINEAR_FALLBACK)
            m3_identity(r);
        else
            hs_polar_svd(F, r);
    } else if (m->def.rotation == HS_ROTATION_SVD) {
        // Kept while it is still F's polar factor to polar_tol, as the polar method's warm
        // start is. Recomputed at every update, it followed each Newton correction, which the
        // rotation-frozen tangent leaves out, and the static solve converged only linearly
        // (47-52 iterations against 3-7 on a 3,750-tet cantilever; docs/fem.md).
        m3_mul_tn(r, F, rtf);
        if (hs_polar_accepts(rtf, m3_fro2(F), m->def.polar_tol)) return 0;
        hs_polar_svd(F, r);
    } else {
        return hs_polar_higham_ex(F, r, m->def.polar_tol, m->def.polar_max_iter, 1, rtf);
    }
    m3_mul_tn(r, F, rtf);
    return it;
}

/// F = sum_a x_a g_a^T of element e.
static inline __attribute__((always_inline)) void element_F(const hs_fem* m, const double* x, int e,
                                                            double F[9]) {
    const int* t = m->tet + 4 * e;
    const double* g = m->g + 12 * e;
    const double* x0 = x + 3 * t[0];
    memset(F, 0, 9 * sizeof(double));
    for (int a = 1; a < 4; a++) {
        const double* xa = x + 3 * t[a];
        const double* ga = g + 3 * a;
        for (int i = 0; i < 3; i++) {
            double d = xa[i] - x0[i];
            F[3 * i] += d * ga[0];
            F[3 * i + 1] += d * ga[1];
            F[3 * i + 2] += d * ga[2];
        }
    }
}

// The warped solver's node rotations are the chordal means of the rotations of each node's
// tets: quaternions summed, then normalised. A rotation R with quaternion (w, x, y, z), w >= 0,
// gives 4 w (w, x, y, z) = (1 + tr R, R21 - R12, R02 - R20, R10 - R01) without a square root;
// weighted by the rest volume. t returns 1 + tr R = 4 w^2: a tet turned by more than 90
// degrees (t < 2) has a w too small to tell its quaternion from its opposite, and the caller
// makes q[0] -inf (see QUAT_ROTATION). One text for double and v4d (bit-identical lanes).
#define ELEMENT_QUAT(R, vol, q, t)                                                                 \
    do {                                                                                           \
        (t) = 1.0 + (R)[0] + (R)[4] + (R)[8];                                                      \
        (q)[0] = (vol) * (t);                                                                      \
        (q)[1] = (vol) * ((R)[7] - (R)[5]);                                                        \
        (q)[2] = (vol) * ((R)[2] - (R)[6]);                                                        \
        (q)[3] = (vol) * ((R)[3] - (R)[1]);                                                        \
    } while (0)

// ELEMENT_QUAT of element e, the scalar text.
static inline __attribute__((always_inline)) void element_quat(const hs_fem* m, int e,
                                                               double q[4]) {
    double t;
    ELEMENT_QUAT(m->R + 9 * (size_t)e, m->vol0[e], q, t);
    if (!(t >= 2.0)) q[0] = -INFINITY;
}

/// Adds q (4 doubles) to the quaternion sums of element e's nodes, in element order: the
/// order in which node_quat_sum sums a node's tets (nt lists them by element).
static inline __attribute__((always_inline)) void node_quat_add(hs_fem* m, int e, v4d q) {
    const int* t = m->tet + 4 * e;
    for (int a = 0; a < 4; a++) {
        double* s = m->qsum + 4 * t[a];
        v4d s0;
        memcpy(&s0, s, sizeof s0);
        s0 += q;
        memcpy(s, &s0, sizeof s0);
    }
}

// Linear and co-rotated stress: H = F - I or R^T F - I -> small strain eps, its trace and the
// stress sig. One text for double and v4d, so the four-wide pass performs the one-element
// code's operations in the same order (bit-identical results).
#define SMALL_STRAIN_STRESS(H, eps, tr, sig, mu, lam)                                              \
    do {                                                                                           \
        (H)[0] -= 1.0;                                                                             \
        (H)[4] -= 1.0;                                                                             \
        (H)[8] -= 1.0;                                                                             \
        for (int i_ = 0; i_ < 3; i_++)                                                             \
            for (int j_ = 0; j_ < 3; j_++)                                                         \
                (eps)[3 * i_ + j_] = 0.5 * ((H)[3 * i_ + j_] + (H)[3 * j_ + i_]);                  \
        (tr) = (eps)[0] + (eps)[4] + (eps)[8];                                                     \
        for (int k_ = 0; k_ < 9; k_++) (sig)[k_] = 2.0 * (mu) * (eps)[k_];                         \
        (sig)[0] += (lam) * (tr);                                                                  \
        (sig)[4] += (lam) * (tr);                                                                  \
        (sig)[8] += (lam) * (tr);                                                                  \
    } while (0)

/// Running sums of the element loop.
typedef struct {
    double energy, vsum, vmin, vmax;
    int inverted, n_active, pmax;
} loop_acc;

/// One active element of any model: F, its stress and its nodal forces into m->f.
static inline __attribute__((always_inline)) void element_one(hs_fem* m, const double* x, int e,
                                                              loop_acc* acc) {
    const double mu = m->mu_el, lam = m->lam_el;
    const hs_model model = m->def.model;
    const int* t = m->tet + 4 * e;
    const double* g = m->g + 12 * e;
    double F[9];
    element_F(m, x, e, F);
    memcpy(m->F + 9 * e, F, sizeof F);
    double det = m3_det(F);
    m->det[e] = det;
    acc->n_active++;
    acc->vsum += det;
    if (det < acc->vmin) acc->vmin = det;
    if (det > acc->vmax) acc->vmax = det;
    if (!(det > 0)) acc->inverted++;
    const double V = m->vol0[e] * m->kscale[e];

    double P[9]; // first Piola-Kirchhoff stress, Pa
    if (model == HS_MODEL_STVK) {
        double C[9], Ev[9], S[9];
        m3_mul_tn(F, F, C);
        for (int k = 0; k < 9; k++) Ev[k] = 0.5 * C[k];
        Ev[0] -= 0.5;
        Ev[4] -= 0.5;
        Ev[8] -= 0.5;
        double tr = Ev[0] + Ev[4] + Ev[8];
        for (int k = 0; k < 9; k++) S[k] = 2.0 * mu * Ev[k];
        S[0] += lam * tr;
        S[4] += lam * tr;
        S[8] += lam * tr;
        memcpy(m->S + 9 * e, S, sizeof S);
        m3_mul(F, S, P);
        acc->energy += V * (mu * m3_fro2(Ev) + 0.5 * lam * tr * tr);
        if (m->anp) {
            double cof[9];
            m3_cofactor(F, cof); // d det F / dF
            m->theta_e[e] = det - 1.0;
            double* w = m->w + 12 * e;
            for (int a = 0; a < 4; a++) m3_vec(cof, g + 3 * a, w + 3 * a);
        }
    } else {
        // Linear and co-rotated: small strain of the (unrotated) displacement gradient.
        const double* r = NULL;
        double H[9];
        if (model == HS_MODEL_COROTATED) {
            int it = element_rotation(m, e, F, det, H);
            if (it > acc->pmax) acc->pmax = it;
            r = m->R + 9 * e;
            double q[4];
            element_quat(m, e, q);
            node_quat_add(m, e, (v4d){q[0], q[1], q[2], q[3]});
        } else {
            memcpy(H, F, sizeof H);
        }
        double eps[9], sig[9], tr;
        SMALL_STRAIN_STRESS(H, eps, tr, sig, mu, lam);
        if (r)
            m3_mul(r, sig, P);
        else
            memcpy(P, sig, sizeof P);
        acc->energy += V * (mu * m3_fro2(eps) + 0.5 * lam * tr * tr);
        if (m->anp) {
            m->theta_e[e] = tr;
            double* w = m->w + 12 * e;
            for (int a = 0; a < 4; a++) {
                if (r)
                    m3_vec(r, g + 3 * a, w + 3 * a);
                else
                    memcpy(w + 3 * a, g + 3 * a, 3 * sizeof(double));
            }
        }
    }
    // f_a = -V P g_a; node 0 balances the others.
    double f0[3] = {0, 0, 0};
    for (int a = 1; a < 4; a++) {
        double pg[3];
        m3_vec(P, g + 3 * a, pg);
        double* fa = m->f + 3 * t[a];
        for (int c = 0; c < 3; c++) {
            fa[c] -= V * pg[c];
            f0[c] += V * pg[c];
        }
    }
    double* fz = m->f + 3 * t[0];
    fz[0] += f0[0];
    fz[1] += f0[1];
    fz[2] += f0[2];
}

// Four elements at once, linear or co-rotated with the polar rotation: the operations of
// element_one in each lane, in the same order (so bit-identical results), on GCC vectors; the
// warm polar steps are polar4_core on registers, with no gather of F or scatter of R^T F. Only
// the nodal sums are scalar, lane by lane in element order. A lane that is inactive, inverted
// or leaves the warm polar phase is done by element_one at its place in that order.
static inline __attribute__((always_inline)) void elements4(hs_fem* m, const double* x, int e0,
                                                            const int corot, loop_acc* acc) {
    const int* t[4];
    const double* g[4];
    for (int l = 0; l < 4; l++) {
        t[l] = m->tet + 4 * (e0 + l);
        g[l] = m->g + 12 * (e0 + l);
    }
    // F = sum_a (x_a - x_0) g_a^T, in element_F's order (from 0, a = 1, 2, 3)
    // ga[0] is read only by the locking-free term; {0}: GCC warns maybe-uninitialized otherwise
    v4d F[9], ga[4][3] = {{{0}}};
    for (int a = 1; a < 4; a++)
        for (int j = 0; j < 3; j++)
            ga[a][j] = (v4d){g[0][3 * a + j], g[1][3 * a + j], g[2][3 * a + j], g[3][3 * a + j]};
    for (int k = 0; k < 9; k++) F[k] = (v4d){0, 0, 0, 0};
    for (int a = 1; a < 4; a++) {
        for (int i = 0; i < 3; i++) {
            v4d d = (v4d){
                x[3 * t[0][a] + i] - x[3 * t[0][0] + i], x[3 * t[1][a] + i] - x[3 * t[1][0] + i],
                x[3 * t[2][a] + i] - x[3 * t[2][0] + i], x[3 * t[3][a] + i] - x[3 * t[3][0] + i]};
            F[3 * i] += d * ga[a][0];
            F[3 * i + 1] += d * ga[a][1];
            F[3 * i + 2] += d * ga[a][2];
        }
    }
    v4d det = F[0] * (F[4] * F[8] - F[5] * F[7]) - F[1] * (F[3] * F[8] - F[5] * F[6]) +
              F[2] * (F[3] * F[7] - F[4] * F[6]);
    v4l lanes = det > 0;
    for (int l = 0; l < 4; l++) lanes[l] &= -(long long)(m->active[e0 + l] != 0);
    v4d H[9], R[9];
    v4l itv = {0, 0, 0, 0};
    if (corot) {
        for (int k = 0; k < 9; k++) {
            const double* r = m->R + 9 * e0 + k;
            R[k] = (v4d){r[0], r[9], r[18], r[27]};
        }
        polar4_core(F, R, H, m->def.polar_tol, m->def.polar_max_iter, &lanes, &itv);
    } else {
        for (int k = 0; k < 9; k++) H[k] = F[k];
    }
    const double mu = m->mu_el, lam = m->lam_el;
    v4d eps[9], sig[9], P[9], tr;
    SMALL_STRAIN_STRESS(H, eps, tr, sig, mu, lam);
    if (corot) {
        for (int i = 0; i < 3; i++)
            for (int j = 0; j < 3; j++)
                P[3 * i + j] =
                    R[3 * i] * sig[j] + R[3 * i + 1] * sig[3 + j] + R[3 * i + 2] * sig[6 + j];
    } else {
        for (int k = 0; k < 9; k++) P[k] = sig[k];
    }
    v4d V = {m->vol0[e0] * m->kscale[e0], m->vol0[e0 + 1] * m->kscale[e0 + 1],
             m->vol0[e0 + 2] * m->kscale[e0 + 2], m->vol0[e0 + 3] * m->kscale[e0 + 3]};
    v4d fro = {0, 0, 0, 0};
    for (int k = 0; k < 9; k++) fro += eps[k] * eps[k];
    v4d en = V * (mu * fro + 0.5 * lam * tr * tr);
    // V P g_a, a = 1, 2, 3, and node 0's balance
    v4d vpg[3][3], f0[3] = {{0, 0, 0, 0}, {0, 0, 0, 0}, {0, 0, 0, 0}};
    for (int a = 1; a < 4; a++) {
        for (int c = 0; c < 3; c++) {
            v4d pg = P[3 * c] * ga[a][0] + P[3 * c + 1] * ga[a][1] + P[3 * c + 2] * ga[a][2];
            vpg[a - 1][c] = V * pg;
            f0[c] += vpg[a - 1][c];
        }
    }
    v4d Q[4]; // the lanes' quaternions (ELEMENT_QUAT), one vector per lane
    if (corot) {
        v4d vol = {m->vol0[e0], m->vol0[e0 + 1], m->vol0[e0 + 2], m->vol0[e0 + 3]}, q[4], tq;
        ELEMENT_QUAT(R, vol, q, tq);
        const v4l small = ~(tq >= 2.0); // as element_quat: -inf
        const v4d ninf = {-INFINITY, -INFINITY, -INFINITY, -INFINITY};
        q[0] = (v4d)(((v4l)q[0] & ~small) | ((v4l)ninf & small));
        for (int l = 0; l < 4; l++) Q[l] = (v4d){q[0][l], q[1][l], q[2][l], q[3][l]};
    }
    v4d W[4][3];
    if (m->anp) {
        for (int j = 0; j < 3; j++) ga[0][j] = (v4d){g[0][j], g[1][j], g[2][j], g[3][j]};
        for (int a = 0; a < 4; a++)
            for (int c = 0; c < 3; c++)
                W[a][c] =
                    corot ? R[3 * c] * ga[a][0] + R[3 * c + 1] * ga[a][1] + R[3 * c + 2] * ga[a][2]
                          : ga[a][c];
    }
    for (int l = 0; l < 4; l++) {
        const int e = e0 + l;
        if (!m->active[e]) continue;
        if (!lanes[l]) { // inverted, or the warm polar phase gave up: the scalar code
            element_one(m, x, e, acc);
            continue;
        }
        double* Fe = m->F + 9 * e;
        for (int k = 0; k < 9; k++) Fe[k] = F[k][l];
        if (corot) node_quat_add(m, e, Q[l]);
        m->det[e] = det[l];
        acc->n_active++;
        acc->vsum += det[l];
        if (det[l] < acc->vmin) acc->vmin = det[l];
        if (det[l] > acc->vmax) acc->vmax = det[l];
        if (corot) {
            double* Re = m->R + 9 * e;
            for (int k = 0; k < 9; k++) Re[k] = R[k][l];
            if ((int)itv[l] > acc->pmax) acc->pmax = (int)itv[l];
        }
        acc->energy += en[l];
        if (m->anp) {
            m->theta_e[e] = tr[l];
            double* w = m->w + 12 * e;
            for (int a = 0; a < 4; a++)
                for (int c = 0; c < 3; c++) w[3 * a + c] = W[a][c][l];
        }
        for (int a = 1; a < 4; a++) {
            double* fa = m->f + 3 * t[l][a];
            fa[0] -= vpg[a - 1][0][l];
            fa[1] -= vpg[a - 1][1][l];
            fa[2] -= vpg[a - 1][2][l];
        }
        double* fz = m->f + 3 * t[l][0];
        fz[0] += f0[0][l];
        fz[1] += f0[1][l];
        fz[2] += f0[2][l];
    }
}

enum { LOOP_SCALAR, LOOP_LINEAR4, LOOP_COROT4 };

// SNS node rotations are solved tighter than the elements': kept within polar_tol 1e-6, the
// static solve's residual stalled near 2.6e-8 of the load (1k cantilever); at 1e-12 the warm
// iteration often missed the tolerance and fell back to the SVD, and the Newton solve needed
// 29 iterations and 543 line-search cuts (5k); 1e-9: 5 iterations, 1 cut (the SVD: 6, 2).
#define SNS_POLAR_TOL 1e-9

/// SNS nodal deviatoric term (after the element pass and ANP's nodal volumes): per node,
/// F_n = sum (V_e / 4) F_e / V_n over its active tets, R_n its polar factor (co-rotated; warm
/// from the last update), eps_n = sym(R_n^T F_n) - I, energy V_n alpha mu |dev eps_n|^2 and
/// forces -V_n R_n sigma_n gbar_m over the node's 1-ring (sigma_n = 2 alpha mu dev eps_n).
/// Exact for the co-rotated energy: d tr(R^T F) / dF = R, so R's derivative drops out.
/// Returns the energy, J.
static double sns_update(hs_fem* m) {
    const int corot = m->def.model == HS_MODEL_COROTATED;
    double energy = 0;
    for (int i = 0; i < m->n; i++) {
        int rb = m->ring_start[i], rs = m->ring_start[i + 1] - rb;
        double* gb = m->gbar + 3 * rb;
        memset(gb, 0, sizeof(double) * 3 * (size_t)rs);
        const double vn = m->vn[i];
        if (!(vn > 0)) continue;
        double Fn[9] = {0};
        for (int p = m->nt_start[i]; p < m->nt_start[i + 1]; p++) {
            int e = m->nt[p];
            if (!m->active[e]) continue;
            const double wgt = 0.25 * m->vol0[e] / vn;
            const double* Fe = m->F + 9 * e;
            for (int k = 0; k < 9; k++) Fn[k] += wgt * Fe[k];
            const double* g = m->g + 12 * e;
            for (int a = 0; a < 4; a++) {
                double* gs = gb + 3 * m->nt_slot[4 * p + a];
                gs[0] += wgt * g[3 * a];
                gs[1] += wgt * g[3 * a + 1];
                gs[2] += wgt * g[3 * a + 2];
            }
        }
        double H[9], *R = m->rn + 9 * i;
        if (corot) {
            hs_polar_higham(Fn, R, SNS_POLAR_TOL, 20);
            m3_mul_tn(R, Fn, H);
        } else {
            memcpy(H, Fn, sizeof H);
        }
        double dev[9];
        for (int r = 0; r < 3; r++)
            for (int c = 0; c < 3; c++) dev[3 * r + c] = 0.5 * (H[3 * r + c] + H[3 * c + r]);
        const double tr3 = (dev[0] + dev[4] + dev[8] - 3.0) / 3.0;
        dev[0] -= 1.0 + tr3;
        dev[4] -= 1.0 + tr3;
        dev[8] -= 1.0 + tr3;
        energy += vn * m->mu_n * m3_fro2(dev);
        double P[9];
        for (int k = 0; k < 9; k++) dev[k] *= 2.0 * m->mu_n * vn;
        if (corot)
            m3_mul(R, dev, P);
        else
            memcpy(P, dev, sizeof P);
        for (int r = 0; r < rs; r++) {
            double pg[3];
            m3_vec(P, gb + 3 * r, pg);
            double* fr = m->f + 3 * m->ring[rb + r];
            fr[0] -= pg[0];
            fr[1] -= pg[1];
            fr[2] -= pg[2];
        }
    }
    return energy;
}

// The element loop of hs_fem_update; `kind` (a constant at each call) chooses elements4 for
// linear and co-rotated + polar, element_one for the rest and the last ne mod 4 elements.
static inline __attribute__((always_inline)) void update_all(hs_fem* m, const double* x,
                                                             const int kind) {
    const int ne = m->ne, n = m->n;
    memset(m->f, 0, sizeof(double) * 3 * (size_t)n);
    const int corot = m->def.model == HS_MODEL_COROTATED;
    if (corot) memset(m->qsum, 0, sizeof(double) * 4 * (size_t)n);
    loop_acc acc = {0, 0, INFINITY, -INFINITY, 0, 0, 0};
    int first = 0; // of the elements left to element_one
    if (kind != LOOP_SCALAR)
        for (; first + 4 <= ne; first += 4) elements4(m, x, first, kind == LOOP_COROT4, &acc);
    for (int e = first; e < ne; e++)
        if (m->active[e]) element_one(m, x, e, &acc);
    double energy = acc.energy;

    if (m->anp) {
        // Nodal volumetric strain: volume-weighted mean of the incident element strains.
        for (int i = 0; i < n; i++) {
            double vn = 0, th = 0;
            for (int p = m->nt_start[i]; p < m->nt_start[i + 1]; p++) {
                int e = m->nt[p];
                if (!m->active[e]) continue;
                vn += 0.25 * m->vol0[e];
                th += 0.25 * m->vol0[e] * m->theta_e[e];
            }
            m->vn[i] = vn;
            m->theta_n[i] = vn > 0 ? th / vn : 0.0;
            energy += 0.5 * m->kappa * vn * m->theta_n[i] * m->theta_n[i];
            // c_n[m] = d theta_n / d x_m over the 1-ring of i.
            int rb = m->ring_start[i], rs = m->ring_start[i + 1] - rb;
            double* c = m->cvec + 3 * rb;
            memset(c, 0, sizeof(double) * 3 * (size_t)rs);
            if (!(vn > 0)) continue;
            for (int p = m->nt_start[i]; p < m->nt_start[i + 1]; p++) {
                int e = m->nt[p];
                if (!m->active[e]) continue;
                double wgt = 0.25 * m->vol0[e] / vn;
                const double* w = m->w + 12 * e;
                for (int a = 0; a < 4; a++) {
                    double* cs = c + 3 * m->nt_slot[4 * p + a];
                    cs[0] += wgt * w[3 * a];
                    cs[1] += wgt * w[3 * a + 1];
                    cs[2] += wgt * w[3 * a + 2];
                }
            }
        }
        // Forces: -dW_vol/dx = -sum_e V_e pbar_e w_e with pbar_e the mean nodal pressure.
        for (int e = 0; e < ne; e++) {
            if (!m->active[e]) continue;
            const int* t = m->tet + 4 * e;
            double pb = 0.25 * m->kappa *
                        (m->theta_n[t[0]] + m->theta_n[t[1]] + m->theta_n[t[2]] + m->theta_n[t[3]]);
            m->pbar[e] = pb;
            double s = m->vol0[e] * pb;
            const double* w = m->w + 12 * e;
            for (int a = 0; a < 4; a++) {
                double* fa = m->f + 3 * t[a];
                fa[0] -= s * w[3 * a];
                fa[1] -= s * w[3 * a + 1];
                fa[2] -= s * w[3 * a + 2];
            }
        }
    }

    if (m->sns) energy += sns_update(m);

    m->qsum_stamp = corot ? m->k_version + 1 : 0;
    m->stats.inverted = acc.inverted;
    m->stats.volume_ratio_mean = acc.n_active ? acc.vsum / acc.n_active : 1.0;
    m->stats.volume_ratio_min = acc.n_active ? acc.vmin : 1.0;
    m->stats.volume_ratio_max = acc.n_active ? acc.vmax : 1.0;
    m->stats.polar_iters_max = acc.pmax;
    m->stats.energy_j = energy;
}

// elements4 in AVX2 (one instruction per vector operation) where the processor has it.
__attribute__((target("avx2"))) static void update_linear4_avx2(hs_fem* m, const double* x) {
    update_all(m, x, LOOP_LINEAR4);
}
__attribute__((target("avx2"))) static void update_corot4_avx2(hs_fem* m, const double* x) {
    update_all(m, x, LOOP_COROT4);
}
static void update_linear4_base(hs_fem* m, const double* x) {
    update_all(m, x, LOOP_LINEAR4);
}
static void update_corot4_base(hs_fem* m, const double* x) {
    update_all(m, x, LOOP_COROT4);
}

void hs_fem_update(hs_fem* m, const double* x, hs_fem_stats* stats) {
    HS_ASSERT(m && x);
    const int avx2 = __builtin_cpu_supports("avx2");
    if (m->def.model == HS_MODEL_COROTATED && m->def.rotation == HS_ROTATION_POLAR)
        (avx2 ? update_corot4_avx2 : update_corot4_base)(m, x);
    else if (m->def.model == HS_MODEL_LINEAR)
        (avx2 ? update_linear4_avx2 : update_linear4_base)(m, x);
    else
        update_all(m, x, LOOP_SCALAR);
    if (stats) *stats = m->stats;
}

void hs_fem_update_scalar(hs_fem* m, const double* x, hs_fem_stats* stats) {
    HS_ASSERT(m && x);
    update_all(m, x, LOOP_SCALAR);
    if (stats) *stats = m->stats;
}

void hs_fem_forces(const hs_fem* fem, double* f) {
    HS_ASSERT(fem && f);
    memcpy(f, fem->f, sizeof(double) * 3 * (size_t)fem->n);
}

// ---------------------------------------------------------------------------------------------
// Tangent

/// The 10 upper blocks (a <= b) of element e's tangent, row-major 3x3 each, in the order
/// (0,0),(0,1),(0,2),(0,3),(1,1),(1,2),(1,3),(2,2),(2,3),(3,3). With p_a = Q g_a:
/// K_ab = V [ s_ab I + lambda p_a p_b^T + mu p_b p_a^T + mu (g_a.g_b) M ]
/// linear: Q = I, M = I, s = 0; co-rotated: Q = R, M = R R^T = I, s = 0 (the R K_e R^T of the
/// paper, no dR/dx term); StVK: Q = F, M = F F^T, s_ab = g_a.S g_b (exact). With ANP and StVK
/// the volumetric term adds V pbar d^2 det F / dx_a dx_b = V pbar [F (g_a x g_b)]x^T.
static void element_blocks(const hs_fem* m, int e, double sc, double kb[10][9]) {
    const double* g = m->g + 12 * e;
    const double cV = sc * m->vol0[e] * m->kscale[e], cmu = cV * m->mu_el, clam = cV * m->lam_el;
    double p[4][3], lp[4][3], mp[4][3];
    double M[9];
    int stvk = m->def.model == HS_MODEL_STVK;
    const double* Q = NULL;
    if (m->def.model == HS_MODEL_COROTATED)
        Q = m->R + 9 * e;
    else if (stvk)
        Q = m->F + 9 * e;
    for (int a = 0; a < 4; a++) {
        if (Q)
            m3_vec(Q, g + 3 * a, p[a]);
        else
            memcpy(p[a], g + 3 * a, sizeof p[a]);
        for (int i = 0; i < 3; i++) {
            lp[a][i] = clam * p[a][i];
            mp[a][i] = cmu * p[a][i];
        }
    }
    double Sg[4][3];
    if (stvk) {
        m3_mul_nt(Q, Q, M);
        for (int a = 0; a < 4; a++) m3_vec(m->S + 9 * e, g + 3 * a, Sg[a]);
    }
    double geo = (stvk && m->anp) ? cV * m->pbar[e] : 0.0;
    int k = 0;
    for (int a = 0; a < 4; a++)
        for (int b = a; b < 4; b++, k++) {
            double* B = kb[k];
            const double* pa = p[a];
            const double* pb = p[b];
            double gg = cmu * v3_dot(g + 3 * a, g + 3 * b);
            for (int i = 0; i < 3; i++)
                for (int j = 0; j < 3; j++) B[3 * i + j] = lp[a][i] * pb[j] + mp[b][i] * pa[j];
            if (stvk) {
                double s = cV * v3_dot(Sg[a], g + 3 * b);
                for (int q = 0; q < 9; q++) B[q] += gg * M[q];
                B[0] += s;
                B[4] += s;
                B[8] += s;
                if (geo != 0.0) {
                    double gx[3], v[3];
                    v3_cross(g + 3 * a, g + 3 * b, gx);
                    m3_vec(Q, gx, v);
                    // [v]x^T: (0,1) = v2, (0,2) = -v1, (1,2) = v0, antisymmetric
                    B[1] += geo * v[2];
                    B[3] -= geo * v[2];
                    B[2] -= geo * v[1];
                    B[6] += geo * v[1];
                    B[5] += geo * v[0];
                    B[7] -= geo * v[0];
                }
            } else {
                B[0] += gg;
                B[4] += gg;
                B[8] += gg;
            }
        }
}

// Scatter s * kb (assembly order) into val through element e's upper-triangle positions.
static void scatter_blocks(const hs_fem* m, int e, double kb[10][9], double s, double* val) {
    const int* ep = m->elem_pos + 78 * e;
    int k = 0;
    for (int q = 0; q < 10; q++) {
        const double* B = kb[q];
        if (q == 0 || q == 4 || q == 7 || q == 9) { // diagonal block: upper half
            for (int i = 0; i < 3; i++)
                for (int j = i; j < 3; j++, k++)
                    if (ep[k] >= 0) val[ep[k]] += s * B[3 * i + j];
        } else {
            for (int t = 0; t < 9; t++, k++)
                if (ep[k] >= 0) val[ep[k]] += s * B[t];
        }
    }
}

// The strictly lower entries from their upper transposes.
static void mirror_upper(const hs_fem* m, double* val) {
    for (int w = 0; w < m->n_mirror; w++) val[m->mirror[2 * w]] = val[m->mirror[2 * w + 1]];
}

static void sns_assemble(const hs_fem* m, double kcoef, double* val);

void hs_fem_assemble(const hs_fem* m, double kcoef, double mcoef, hs_csc* a) {
    HS_ASSERT(m && a && a->n == m->n_free && a->nnz == m->nnz);
    memset(a->val, 0, sizeof(double) * (size_t)a->nnz);
    double* val = a->val;
    if (kcoef != 0.0) {
        double kb[10][9];
        for (int e = 0; e < m->ne; e++) {
            if (!m->active[e]) continue;
            element_blocks(m, e, kcoef, kb);
            scatter_blocks(m, e, kb, 1.0, val);
        }
        if (m->anp) {
            // K_vol = sum_n kappa V_n c_n c_n^T over the 1-ring of each node (upper half).
            for (int i = 0; i < m->n; i++) {
                double s = kcoef * m->kappa * m->vn[i];
                if (s == 0.0) continue;
                int rb = m->ring_start[i], rs = m->ring_start[i + 1] - rb;
                const double* c = m->cvec + 3 * rb;
                const int* pb = m->pair_blk + m->pair_start[i];
                for (int r = 0; r < rs; r++) {
                    const double cr[3] = {s * c[3 * r], s * c[3 * r + 1], s * c[3 * r + 2]};
                    for (int q = r; q < rs; q++) {
                        const double* cq = c + 3 * q;
                        const int* pos = m->blkpos + 9 * pb[r * rs + q];
                        for (int ii = 0; ii < 3; ii++)
                            for (int jj = q == r ? ii : 0; jj < 3; jj++) {
                                int p = pos[3 * ii + jj];
                                if (p >= 0) val[p] += cr[ii] * cq[jj];
                            }
                    }
                }
            }
        }
        if (m->sns) sns_assemble(m, kcoef, val);
    }
    if (mcoef != 0.0) {
        for (int i = 0; i < m->n; i++)
            for (int c = 0; c < 3; c++) {
                int p = m->diag_pos[3 * i + c];
                if (p >= 0) val[p] += mcoef * (m->mass[i] + m->held[i]);
            }
    }
    mirror_upper(m, val);
}

/// SNS tangent, upper half: per node, the co-rotated block formula of element_blocks over its
/// 1-ring with g -> gbar, V -> V_n, Q = R_n, mu -> alpha mu, lambda -> -2 alpha mu / 3 (the
/// node's rotation frozen, as the elements' are).
static void sns_assemble(const hs_fem* m, double kcoef, double* val) {
    const int corot = m->def.model == HS_MODEL_COROTATED;
    for (int i = 0; i < m->n; i++) {
        const double cmu = kcoef * m->vn[i] * m->mu_n, clam = -2.0 * cmu / 3.0;
        if (cmu == 0.0) continue;
        int rb = m->ring_start[i], rs = m->ring_start[i + 1] - rb;
        const double* gb = m->gbar + 3 * rb;
        const int* pb = m->pair_blk + m->pair_start[i];
        double pv[64][3];
        double(*p)[3] = rs <= 64 ? pv : hs_alloc(sizeof(double) * 3 * (size_t)rs);
        if (!p) continue; // not reached for meshes with a sane valence
        for (int r = 0; r < rs; r++) {
            if (corot)
                m3_vec(m->rn + 9 * i, gb + 3 * r, p[r]);
            else
                memcpy(p[r], gb + 3 * r, sizeof p[r]);
        }
        for (int r = 0; r < rs; r++)
            for (int q = r; q < rs; q++) {
                const int* pos = m->blkpos + 9 * pb[r * rs + q];
                const double gg = cmu * v3_dot(gb + 3 * r, gb + 3 * q);
                for (int ii = 0; ii < 3; ii++)
                    for (int jj = q == r ? ii : 0; jj < 3; jj++) {
                        int ps = pos[3 * ii + jj];
                        if (ps < 0) continue;
                        val[ps] += clam * p[r][ii] * p[q][jj] + cmu * p[q][ii] * p[r][jj] +
                                   (ii == jj ? gg : 0.0);
                    }
            }
        if (p != pv) hs_free(p);
    }
}

// Element e's rest share in assembly order: kcoef K_e at R = I (S = 0) plus mcoef times its
// lumped mass share on the diagonal blocks.
static void rest_blocks(const hs_fem* m, int e, double kcoef, double mcoef, double kb[10][9]) {
    const double* g = m->g + 12 * e;
    const double cV = kcoef * m->vol0[e] * m->kscale[e], cmu = cV * m->mu_el, clam = cV * m->lam_el;
    const double ms = mcoef * 0.25 * m->def.material.density_kg_m3 * m->vol0[e];
    int k = 0;
    for (int a = 0; a < 4; a++)
        for (int b = a; b < 4; b++, k++) {
            double* B = kb[k];
            const double *ga = g + 3 * a, *gb = g + 3 * b;
            for (int i = 0; i < 3; i++)
                for (int j = 0; j < 3; j++)
                    B[3 * i + j] = clam * ga[i] * gb[j] + cmu * gb[i] * ga[j];
            double d = cmu * v3_dot(ga, gb) + (a == b ? ms : 0.0);
            B[0] += d;
            B[4] += d;
            B[8] += d;
        }
}

hs_status hs_fem_assemble_rest(const hs_fem* m, double kcoef, double mcoef, hs_csc* a) {
    if (!m || !a || a->n != m->n_free || a->nnz != m->nnz) return HS_ERR_INVALID;
    if (m->anp) return HS_ERR_UNSUPPORTED;
    memset(a->val, 0, sizeof(double) * (size_t)a->nnz);
    double kb[10][9];
    for (int e = 0; e < m->ne; e++) {
        if (!m->active[e]) continue;
        rest_blocks(m, e, kcoef, mcoef, kb);
        scatter_blocks(m, e, kb, 1.0, a->val);
    }
    for (int i = 0; mcoef != 0.0 && m->n_held > 0 && i < m->n; i++)
        for (int c = 0; c < 3; c++) {
            int p = m->diag_pos[3 * i + c];
            if (p >= 0) a->val[p] += mcoef * m->held[i];
        }
    mirror_upper(m, a->val);
    return HS_OK;
}

hs_status hs_fem_rest_element_matrix(const hs_fem* m, int e, double kcoef, double mcoef,
                                     double out[144]) {
    if (!m || e < 0 || e >= m->ne || !out) return HS_ERR_INVALID;
    if (m->anp) return HS_ERR_UNSUPPORTED;
    double kb[10][9];
    rest_blocks(m, e, kcoef, mcoef, kb);
    int k = 0;
    for (int a = 0; a < 4; a++)
        for (int b = a; b < 4; b++, k++)
            for (int i = 0; i < 3; i++)
                for (int j = 0; j < 3; j++) {
                    out[(3 * a + i) * 12 + 3 * b + j] = kb[k][3 * i + j];
                    out[(3 * b + j) * 12 + 3 * a + i] = kb[k][3 * i + j];
                }
    return HS_OK;
}

hs_status hs_fem_add_rest_elements(const hs_fem* m, int n, const int* tets, double kcoef,
                                   double mcoef, double s, hs_csc* a) {
    if (!m || !a || a->n != m->n_free || a->nnz != m->nnz || n < 0 || (n > 0 && !tets))
        return HS_ERR_INVALID;
    if (m->anp) return HS_ERR_UNSUPPORTED;
    for (int k = 0; k < n; k++)
        if (tets[k] < 0 || tets[k] >= m->ne) return HS_ERR_INVALID;
    double kb[10][9];
    for (int k = 0; k < n; k++) {
        rest_blocks(m, tets[k], kcoef, mcoef, kb);
        scatter_blocks(m, tets[k], kb, s, a->val);
        // Mirror just these entries: a pass over the whole matrix would cost more than the
        // few elements of a cut.
        const int* ep = m->elem_pos + 78 * tets[k];
        for (int q = 0; q < 78; q++)
            if (ep[q] >= 0 && m->low_of[ep[q]] >= 0) a->val[m->low_of[ep[q]]] = a->val[ep[q]];
    }
    return HS_OK;
}

void hs_fem_apply_tangent(const hs_fem* m, const double* x, double* y) {
    HS_ASSERT(m && x && y && x != y);
    memset(y, 0, sizeof(double) * 3 * (size_t)m->n);
    double kb[10][9];
    for (int e = 0; e < m->ne; e++) {
        if (!m->active[e]) continue;
        element_blocks(m, e, 1.0, kb);
        const int* t = m->tet + 4 * e;
        int k = 0;
        for (int aa = 0; aa < 4; aa++)
            for (int b = aa; b < 4; b++, k++) {
                const double* B = kb[k];
                const double* xb = x + 3 * t[b];
                double* ya = y + 3 * t[aa];
                for (int i = 0; i < 3; i++)
                    ya[i] += B[3 * i] * xb[0] + B[3 * i + 1] * xb[1] + B[3 * i + 2] * xb[2];
                if (b != aa) {
                    const double* xa = x + 3 * t[aa];
                    double* yb = y + 3 * t[b];
                    for (int i = 0; i < 3; i++)
                        yb[i] += B[i] * xa[0] + B[3 + i] * xa[1] + B[6 + i] * xa[2];
                }
            }
    }
    if (m->anp) {
        for (int i = 0; i < m->n; i++) {
            double s = m->kappa * m->vn[i];
            if (s == 0.0) continue;
            int rb = m->ring_start[i], rs = m->ring_start[i + 1] - rb;
            const double* c = m->cvec + 3 * rb;
            double d = 0;
            for (int r = 0; r < rs; r++) d += v3_dot(c + 3 * r, x + 3 * m->ring[rb + r]);
            d *= s;
            for (int r = 0; r < rs; r++) {
                double* yr = y + 3 * m->ring[rb + r];
                yr[0] += d * c[3 * r];
                yr[1] += d * c[3 * r + 1];
                yr[2] += d * c[3 * r + 2];
            }
            if (!m->sns) continue;
            // sum_q K_rq x_q = V_n [lambda' tr(A) p_r + mu' (A + A^T) p_r], A = sum_q x_q p_q^T
            const double cmu = m->vn[i] * m->mu_n, clam = -2.0 * cmu / 3.0;
            const double* gb = m->gbar + 3 * rb;
            const double* R = m->rn + 9 * i;
            const int corot = m->def.model == HS_MODEL_COROTATED;
            double A[9] = {0};
            for (int r = 0; r < rs; r++) {
                double pr[3];
                if (corot)
                    m3_vec(R, gb + 3 * r, pr);
                else
                    memcpy(pr, gb + 3 * r, sizeof pr);
                const double* xr = x + 3 * m->ring[rb + r];
                for (int a = 0; a < 3; a++)
                    for (int b = 0; b < 3; b++) A[3 * a + b] += xr[a] * pr[b];
            }
            const double tra = A[0] + A[4] + A[8];
            double S[9];
            for (int a = 0; a < 3; a++)
                for (int b = 0; b < 3; b++) S[3 * a + b] = cmu * (A[3 * a + b] + A[3 * b + a]);
            for (int k = 0; k < 9; k += 4) S[k] += clam * tra;
            for (int r = 0; r < rs; r++) {
                double pr[3], sp[3];
                if (corot)
                    m3_vec(R, gb + 3 * r, pr);
                else
                    memcpy(pr, gb + 3 * r, sizeof pr);
                m3_vec(S, pr, sp);
                double* yr = y + 3 * m->ring[rb + r];
                yr[0] += sp[0];
                yr[1] += sp[1];
                yr[2] += sp[2];
            }
        }
    }
}

// Volume-weighted sum of the deformation gradients of the node's active tets. Returns 0 for
// the linear model (no rotation).
static inline __attribute__((always_inline)) int node_mean_f(const hs_fem* m, int node,
                                                             double sum[9]) {
    HS_ASSERT(m && node >= 0 && node < m->n);
    if (m->def.model == HS_MODEL_LINEAR) return 0;
    double acc[9] = {0}; // local: the compiler cannot keep sum[] in registers (aliasing)
    for (int p = m->nt_start[node]; p < m->nt_start[node + 1]; p++) {
        int e = m->nt[p];
        if (!m->active[e]) continue;
        const double* F = m->F + 9 * e;
        const double w = m->vol0[e];
        for (int k = 0; k < 9; k++) acc[k] += w * F[k];
    }
    for (int k = 0; k < 9; k++) sum[k] = acc[k];
    return 1;
}

void hs_fem_node_rotation(const hs_fem* m, int node, double r[9]) {
    double sum[9];
    if (node_mean_f(m, node, sum))
        hs_polar_svd(sum, r);
    else
        m3_identity(r);
}

void hs_fem_node_rotation_warm(const hs_fem* m, int node, double r[9]) {
    double sum[9];
    // Node rotations change little per step: a warm polar iteration replaces the SVD. They
    // only shape a preconditioner or an approximate tangent, so the elements' tolerance is
    // enough (1e-10 made this cost more than all the element rotations).
    if (node_mean_f(m, node, sum))
        hs_polar_higham(sum, r, m->def.polar_tol, 20);
    else
        m3_identity(r);
}

// The rotation of an unnormalised quaternion (w, x, y, z) into R (row-major), and in ok
// whether to use it: w > 0 (not -inf: no tet at the node turned by more than 90 degrees; not
// 0: some tet) and a turn of at most 90 degrees (2 w^2 >= |q|^2, implied by the first for a
// sum of such quaternions). One text for double and v4d (bit-identical lanes).
#define QUAT_ROTATION(w, x, y, z, R, ok)                                                           \
    do {                                                                                           \
        const __typeof__(w) n2_ = (w) * (w) + (x) * (x) + (y) * (y) + (z) * (z);                   \
        (ok) = ((w) > 0) & (2.0 * (w) * (w) >= n2_);                                               \
        const __typeof__(w) s_ = 2.0 / n2_;                                                        \
        (R)[0] = 1.0 - s_ * ((y) * (y) + (z) * (z));                                               \
        (R)[1] = s_ * ((x) * (y) - (w) * (z));                                                     \
        (R)[2] = s_ * ((x) * (z) + (w) * (y));                                                     \
        (R)[3] = s_ * ((x) * (y) + (w) * (z));                                                     \
        (R)[4] = 1.0 - s_ * ((x) * (x) + (z) * (z));                                               \
        (R)[5] = s_ * ((y) * (z) - (w) * (x));                                                     \
        (R)[6] = s_ * ((x) * (z) - (w) * (y));                                                     \
        (R)[7] = s_ * ((y) * (z) + (w) * (x));                                                     \
        (R)[8] = 1.0 - s_ * ((x) * (x) + (y) * (y));                                               \
    } while (0)

// Sum of ELEMENT_QUAT over the node's active tets, in element order (as the update adds them).
static void node_quat_sum(const hs_fem* m, int node, double q[4]) {
    double acc[4] = {0, 0, 0, 0};
    for (int p = m->nt_start[node]; p < m->nt_start[node + 1]; p++) {
        int e = m->nt[p];
        if (!m->active[e]) continue;
        double qe[4];
        element_quat(m, e, qe);
        for (int k = 0; k < 4; k++) acc[k] += qe[k];
    }
    memcpy(q, acc, sizeof acc);
}

void hs_fem_tangent_rotation(const hs_fem* m, int node, double r[9]) {
    HS_ASSERT(m && node >= 0 && node < m->n);
    if (m->def.model == HS_MODEL_COROTATED) {
        double q[4], R[9];
        int ok;
        node_quat_sum(m, node, q);
        QUAT_ROTATION(q[0], q[1], q[2], q[3], R, ok);
        if (ok) {
            memcpy(r, R, sizeof R);
            return;
        }
    }
    hs_fem_node_rotation_warm(m, node, r); // StVK, a larger turn, no active tet
}

static inline __attribute__((always_inline)) void tangent_rotations(const hs_fem* m, double* rot) {
    int first = 0; // of the nodes left to the loop below
    // The sums of the last update, unless the elements changed since (a cut): then gather.
    if (m->def.model == HS_MODEL_COROTATED && m->qsum_stamp == m->k_version + 1) {
        for (; first + 4 <= m->n; first += 4) { // four contiguous nodes at once
            const double* q = m->qsum + 4 * (size_t)first;
            double* r = rot + 9 * (size_t)first;
            v4d w = {q[0], q[4], q[8], q[12]}, x = {q[1], q[5], q[9], q[13]},
                y = {q[2], q[6], q[10], q[14]}, z = {q[3], q[7], q[11], q[15]}, R[9];
            v4l ok;
            QUAT_ROTATION(w, x, y, z, R, ok);
            for (int l = 0; l < 4; l++) {
                if (ok[l])
                    for (int k = 0; k < 9; k++) r[9 * l + k] = R[k][l];
                else
                    hs_fem_node_rotation_warm(m, first + l, r + 9 * l);
            }
        }
    }
    for (int i = first; i < m->n; i++) hs_fem_tangent_rotation(m, i, rot + 9 * (size_t)i);
}

__attribute__((target("avx2"))) static void tangent_rotations_avx2(const hs_fem* m, double* rot) {
    tangent_rotations(m, rot);
}

static void tangent_rotations_base(const hs_fem* m, double* rot) {
    tangent_rotations(m, rot);
}

void hs_fem_tangent_rotations(const hs_fem* m, double* rot) {
    if (__builtin_cpu_supports("avx2"))
        tangent_rotations_avx2(m, rot);
    else
        tangent_rotations_base(m, rot);
}

// ---------------------------------------------------------------------------------------------
// Whether a static problem has a unique solution (fem_internal.h).

static int uf_find(int* parent, int i) {
    while (parent[i] != i) i = parent[i] = parent[parent[i]];
    return i;
}

hs_status hs_check_constrained(const hs_mesh* mesh, const unsigned char* active, const int* dof_map,
                               hs_err* err) {
    const int n = mesh->n_nodes, nt = mesh->n_tets;
    int* parent = hs_alloc(sizeof(int) * (size_t)n);
    int* first = hs_alloc(sizeof(int) * (size_t)n);      // per root: a fixed node, or -1
    int* second = hs_alloc(sizeof(int) * (size_t)n);     // per root: farthest fixed node from first
    double* span = hs_calloc((size_t)n, sizeof(double)); // per root: bbox diagonal^2
    char* in = hs_calloc((size_t)n, 1);                  // the node is in an active tet
    hs_status st = HS_OK;
    if (!parent || !first || !second || !span || !in) {
        st = hs_err_set(err, HS_ERR_NOMEM, "%s:%d: out of memory", __FILE__, __LINE__);
        goto done;
    }
    for (int i = 0; i < n; i++) parent[i] = i, first[i] = second[i] = -1;
    for (int e = 0; e < nt; e++) {
        if (active && !active[e]) continue;
        const int* t = mesh->tets + 4 * e;
        for (int a = 0; a < 4; a++) in[t[a]] = 1;
        for (int a = 1; a < 4; a++) {
            int x = uf_find(parent, t[0]), y = uf_find(parent, t[a]);
            if (x != y) parent[x] = y;
        }
    }
    const double* x0 = mesh->x0;
#define D2(i, j)                                                                                   \
    ((x0[3 * (i)] - x0[3 * (j)]) * (x0[3 * (i)] - x0[3 * (j)]) +                                   \
     (x0[3 * (i) + 1] - x0[3 * (j) + 1]) * (x0[3 * (i) + 1] - x0[3 * (j) + 1]) +                   \
     (x0[3 * (i) + 2] - x0[3 * (j) + 2]) * (x0[3 * (i) + 2] - x0[3 * (j) + 2]))
    // pass 1: a fixed node per piece, and the piece's size
    for (int i = 0; i < n; i++) {
        if (in[i]) {
            int r = uf_find(parent, i);
            if (dof_map[3 * i] < 0 && first[r] < 0) first[r] = i;
            if (first[r] >= 0) span[r] = fmax(span[r], D2(i, first[r]));
        }
    }
    // pass 2: the fixed node farthest from the first one
    for (int i = 0; i < n; i++) {
        int r = uf_find(parent, i);
        if (dof_map[3 * i] >= 0 || first[r] < 0 || i == first[r]) continue;
        if (second[r] < 0 || D2(i, first[r]) > D2(second[r], first[r])) second[r] = i;
    }
    // pass 3: a fixed node off the line through the two, by more than 1e-6 of the piece size
    for (int i = 0; i < n; i++) {
        int r = uf_find(parent, i);
        if (first[r] < 0 || second[r] < 0 || dof_map[3 * i] >= 0) continue;
        const double *a = x0 + 3 * first[r], *b = x0 + 3 * second[r], *c = x0 + 3 * i;
        double u[3] = {b[0] - a[0], b[1] - a[1], b[2] - a[2]};
        double v[3] = {c[0] - a[0], c[1] - a[1], c[2] - a[2]};
        double w[3] = {u[1] * v[2] - u[2] * v[1], u[2] * v[0] - u[0] * v[2],
                       u[0] * v[1] - u[1] * v[0]};
        double d2 =
            (w[0] * w[0] + w[1] * w[1] + w[2] * w[2]) / (u[0] * u[0] + u[1] * u[1] + u[2] * u[2]);
        if (d2 > 1e-12 * span[r]) second[r] = -2; // marks the piece as constrained
    }
#undef D2
    for (int e = 0; e < nt && st == HS_OK; e++) {
        if (active && !active[e]) continue;
        int r = uf_find(parent, mesh->tets[4 * e]);
        if (second[r] != -2)
            st = hs_err_set(err, HS_ERR_INVALID,
                            "the piece of the mesh containing tet %d has %s: rigid motion is "
                            "free, so it has no static equilibrium (fix at least 3 non-collinear "
                            "nodes of every piece)",
                            e,
                            first[r] < 0    ? "no fixed node"
                            : second[r] < 0 ? "one fixed node"
                                            : "only collinear fixed nodes");
    }
done:
    hs_free(in);
    hs_free(parent);
    hs_free(first);
    hs_free(second);
    hs_free(span);
    return st;
}

hs_status hs_fem_check_fixed(const hs_mesh* mesh, const unsigned char* fixed, hs_err* err) {
    if (!mesh || !fixed) return hs_err_set(err, HS_ERR_INVALID, "hs_fem_check_fixed: NULL");
    int* map = hs_alloc(3 * (size_t)mesh->n_nodes * sizeof(int) + 1);
    if (!map) return nomem(err);
    for (int i = 0; i < mesh->n_nodes; i++) map[3 * i] = fixed[i] ? -1 : 0;
    hs_status st = hs_check_constrained(mesh, NULL, map, err);
    hs_free(map);
    return st;
}
