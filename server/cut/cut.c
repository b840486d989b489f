// SPDX-License-Identifier: GPL-2.0-or-later
// Vertex-preserving cutting: sweep crossing test, vertex moves with a quality guard, tet
// removal with the orphan and free-piece rules, the live mesh, and the low-rank factor update.
// See include/hapsim/cut.h for the design and docs/cutting.md for the choices.
#include "hapsim/cut.h"

#include <math.h>
#include <pthread.h>
#include <stdatomic.h>
#include <stdlib.h>
#include <string.h>

#define HS_CUT_COOKIE 0x43555431

struct hs_cut {
    hs_mesh* mesh; // x0 moves with cuts; tets never change
    hs_cut_def def;
    int n, ne;
    double lambda, mu; // Lame parameters of the linear K, Pa

    unsigned char* fixed;  // [n] eliminated from K (user fixed or unused at create)
    unsigned char* pinned; // [n] held by a pin spring after a cut
    unsigned char* active; // [ne]
    int* count;            // [n] active tets per node
    int* nt_start;         // [n+1] node -> tet incidence over all mesh tets
    int* nt;               //
    double* vol_orig;      // [ne] rest volume at create, m^3
    double* q_orig;        // [ne] rest quality at create

    int* dof; // [3n] free index or -1
    int n_free;
    hs_fem* fem;
    hs_csc* a;
    hs_cholesky* factor;
    double k_pin; // pin spring, N/m (mean diagonal of K)
    int updates_since_refactor;
    double refactor_ms; // measured numeric refactor of this factor, ms (running mean)
    int auto_partial;   // AUTO chose the partial refactor at create
    int a_stale;        // `a` no longer holds K (a sweep failed half way): reassemble
    int factor_stale;   // a sweep failed after the mesh changed: the next one refactors first
    double update_ms_per_rank; // measured update cost per rank-1 column, ms (running mean)

    hs_mesh* live;  // active tets only
    int* live_tet;  // [ne] live index -> mesh tet
    int components; // of the live mesh
    int live_dirty; // 1: tets or x0 changed since the live mesh was built
    int64_t version;

    // per-sweep scratch, allocated at create
    double* x;            // [3n] current positions
    double* x0_old;       // [3n] rest positions before this sweep
    double* nrm;          // [3n] vertex normals
    unsigned char* tmark; // [ne] 1 cut, 2 to remove
    unsigned char* nmark; // [n] 1 candidate vertex
    int* cut_list;        // [ne]
    int* removed;         // [ne] removed by the last sweep
    int n_removed;
    int* moved; // [n] moved by the last sweep
    int n_moved;
    int* onb;     // [n] this sweep: vertices near the blade's plane, to check for hinges
    int* changed; // [ne] active tets whose rest data changed in the last sweep
    int n_changed;
    int* pins; // [n] nodes pinned by the last sweep
    int n_pins;
    int* edges;          // [2 * 6ne] crossed edges (a < b)
    int* parent;         // [n] scratch
    int* fnbr;           // [4ne] tet across face f of tet e (face f omits local node f), -1
    int* tparent;        // [ne] union-find over tets
    int* fa;             // [ne] first fixed node of a piece (at its root)
    int* fb;             // [ne] second
    unsigned char* anch; // [ne] piece is held
    unsigned* tstamp;    // [ne] fast piece check: visited in search number stamp
    int* gopen;          // [ne] fast piece check: tets of a group still to expand
    unsigned stamp;
    int pieces_checked; // every piece was found held by a full check, and nothing freed since
    double* rhs;        // [n_free]
    double* sol;        // [n_free]

    // element changes for the factor, grown when a sweep needs more
    int cap_elem;
    double* dk;         // [144 cap_elem] new element matrices and pins, then the old matrices
    int* edof;          // [12 cap_elem]
    int first_minus;    // blocks from here on are subtracted
    unsigned char* win; // [n_free] 1: eliminated last in the factor (the update window)
    double win_org[3];  // blade midpoint when the window was chosen
    double win_dir[3];  // unit blade travel then (0 if it did not move)
    int win_stale;      // the last sweep changed dofs outside the window
    int have_win;       // a window has been swapped in (hs_cut_window_finish)
    double blade[12];   // last sweep: p0, q0, p1, q1
    int have_blade;
    // Background window rebuild (hs_cut_window_begin / _build / _finish).
    int bg_state;          // 0 idle, 1 begun (snapshot taken); deformation thread only
    int bg_built;          // build ran (written by the build thread, read by finish)
    hs_status bg_caught;   // the build thread's catch-up
    hs_csc* bg_a;          // snapshot of K
    unsigned char* bg_win; // [n_free] its window
    double bg_org[3], bg_dir[3];
    hs_cholesky* bg_f;
    hs_status bg_status;
    int acc_valid;      // every sweep since begin recorded its blocks
    int n_accp, n_accm; // blocks added / subtracted since begin
    int cap_acc;
    double *accp_k, *accm_k; // [144 cap_acc]
    int *accp_d, *accm_d;    // [12 cap_acc]
    int n_accs, cap_accs;    // sweeps recorded
    int* accs;               // [2 cap_accs] where each sweep's + and - blocks start
    // The record (acc*, n_acc*) is shared with the build thread, which applies it to bg_f as
    // it grows: guarded by bg_lock. The rest of bg_* is the build thread's until finish.
    pthread_mutex_t bg_lock;
    int has_lock;
    int bg_applied;       // recorded sweeps already applied to bg_f
    int *bg_pos, *bg_set; // [n_free] union marks of the catch-up (-1 outside)
    int n_bgu;            // PARTIAL: free dofs K changed in since begin (in bg_set)
    int bg_all;           // PARTIAL: K was reassembled since begin (redo everything)
    // The cut's own build thread (def.window_thread); the rest is the deformation thread's.
    pthread_t wt;
    int wt_running;     // a build thread is started and not yet joined
    atomic_int wt_done; // set by the build thread when hs_cut_window_build returned
    double wt_ms;       // its wall time (written before wt_done)
    int wt_waited;      // changing sweeps since the build ended (PARTIAL swap rule)
    hs_cut_window_stats wstats;
    int win_off; // window_accept_ratio: windows do not pay on this mesh (probe at create)
    double wt_ms_sum;
    int bg_cap;   // blocks bg_k / bg_d hold
    double* bg_k; // [144 bg_cap] one catch-up group: + blocks, then - blocks
    int* bg_d;    // [12 bg_cap]

    // tracked compliance
    hs_cut_compliance_mode cmode;
    int n_track;
    int* track;   // [n_track] nodes
    double* cblk; // [9 n_track]
    double cms;   // last update, ms
    int* dset;    // [n_free] changed dofs of a sweep
    int* dpos;    // [n_free] position in dset or -1
    double* zbuf; // [n_free * HS_CUT_BATCH]
    double* zd;   // [d * d] C_DD (grown)
    double* zt;   // [n_track*3 * d] tracked rows of Z (grown)
    double* kdd;  // [d * d] dK_DD (grown)
    double* wrk;  // [d * d] (grown)
    int* piv;     // [d]
    int cap_d;
};

#define HS_CUT_BATCH 48

hs_cut_def hs_cut_default_def(void) {
    hs_cut_def d;
    memset(&d, 0, sizeof d);
    d.material = hs_fem_default_def().material;
    d.orphan = HS_CUT_ORPHAN_PIN;
    d.fragment = HS_CUT_FRAGMENT_DROP;
    d.pins_hold = 1;
    d.min_volume_ratio = 0.1;
    d.min_quality = 0.02;
    d.max_bisections = 8;
    d.tangent_surface = 1;
    d.factor_policy = HS_CUT_FACTOR_AUTO;
    d.validate = 1;
    d.window_due_fraction = 0.5;
    d.cookie = HS_CUT_COOKIE;
    return d;
}

void hs_cut_def_auto_window(hs_cut_def* def, const hs_mesh* m) {
    if (!def || !m || m->n_tets <= 0) return;
    double h = 0; // mean length of each tet's first edge: the mesh's edge length
    for (int t = 0; t < m->n_tets; t++) {
        const double *a = m->x0 + 3 * m->tets[4 * t], *b = m->x0 + 3 * m->tets[4 * t + 1];
        h += sqrt((a[0] - b[0]) * (a[0] - b[0]) + (a[1] - b[1]) * (a[1] - b[1]) +
                  (a[2] - b[2]) * (a[2] - b[2]));
    }
    h /= m->n_tets;
    def->window_radius_m = 3.0 * h;
    def->window_ahead_m = 14.0 * h;
    def->window_due_fraction = 1.0 / 3.0; // a build takes ~40 % of a window's steps (plate5043)
    def->window_background = 1;
    def->window_thread = 1;
    def->window_accept_ratio = 0.5;
}

void hs_cut_destroy(hs_cut** pc) {
    if (!pc || !*pc) return;
    hs_cut* c = *pc;
    if (c->wt_running) pthread_join(c->wt, NULL); // its build reads the snapshot and bg_f
    hs_fem_destroy(&c->fem);
    hs_csc_destroy(&c->a);
    hs_cholesky_destroy(&c->factor);
    hs_cholesky_destroy(&c->bg_f);
    hs_csc_destroy(&c->bg_a);
    hs_mesh_destroy(&c->live);
    void* p[] = {c->fixed,  c->pinned,   c->active,   c->count,  c->nt_start, c->nt,   c->vol_orig,
                 c->q_orig, c->dof,      c->live_tet, c->x,      c->x0_old,   c->nrm,  c->tmark,
                 c->nmark,  c->cut_list, c->removed,  c->moved,  c->changed,  c->pins, c->edges,
                 c->parent, c->fnbr,     c->tparent,  c->fa,     c->fb,       c->anch, c->rhs,
                 c->sol,    c->dk,       c->edof,     c->track,  c->cblk,     c->dset, c->dpos,
                 c->zbuf,   c->zd,       c->zt,       c->kdd,    c->wrk,      c->piv,  c->win,
                 c->bg_win, c->accp_k,   c->accm_k,   c->accp_d, c->accm_d,   c->accs, c->bg_pos,
                 c->bg_set, c->bg_k,     c->bg_d,     c->tstamp, c->gopen,    c->onb};
    if (c->has_lock) pthread_mutex_destroy(&c->bg_lock);
    for (size_t i = 0; i < sizeof p / sizeof p[0]; i++) hs_free(p[i]);
    hs_free(c);
    *pc = NULL;
}

// ---------------------------------------------------------------------------------------------
// Small geometry

static inline void v3_sub(const double* a, const double* b, double* o) {
    o[0] = a[0] - b[0];
    o[1] = a[1] - b[1];
    o[2] = a[2] - b[2];
}
static inline double v3_dot(const double* a, const double* b) {
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
}
static inline void v3_cross(const double* a, const double* b, double* o) {
    o[0] = a[1] * b[2] - a[2] * b[1];
    o[1] = a[2] * b[0] - a[0] * b[2];
    o[2] = a[0] * b[1] - a[1] * b[0];
}

static double tet_vol4(const double* p0, const double* p1, const double* p2, const double* p3) {
    double a[3], b[3], c[3], x[3];
    v3_sub(p1, p0, a);
    v3_sub(p2, p0, b);
    v3_sub(p3, p0, c);
    v3_cross(b, c, x);
    return v3_dot(a, x) / 6.0;
}

/// Shape quality 6 sqrt(2) V / l_rms^3: 1 for a regular tet, -> 0 for slivers and needles.
static double tet_quality4(const double* p[4], double vol) {
    double s = 0;
    for (int i = 0; i < 4; i++)
        for (int j = i + 1; j < 4; j++) {
            double d[3];
            v3_sub(p[i], p[j], d);
            s += v3_dot(d, d);
        }
    double l = sqrt(s / 6.0);
    return l > 0 ? 6.0 * sqrt(2.0) * vol / (l * l * l) : 0.0;
}

/// Closest point of triangle (a, b, c) to p (Ericson, Real-Time Collision Detection 5.1.5).
static void closest_on_tri(const double* p, const double* a, const double* b, const double* c,
                           double* out) {
    double ab[3], ac[3], ap[3];
    v3_sub(b, a, ab);
    v3_sub(c, a, ac);
    v3_sub(p, a, ap);
    double d1 = v3_dot(ab, ap), d2 = v3_dot(ac, ap);
    if (d1 <= 0 && d2 <= 0) {
        memcpy(out, a, 3 * sizeof(double));
        return;
    }
    double bp[3];
    v3_sub(p, b, bp);
    double d3 = v3_dot(ab, bp), d4 = v3_dot(ac, bp);
    if (d3 >= 0 && d4 <= d3) {
        memcpy(out, b, 3 * sizeof(double));
        return;
    }
    double vc = d1 * d4 - d3 * d2;
    if (vc <= 0 && d1 >= 0 && d3 <= 0) {
        double v = d1 / (d1 - d3);
        for (int k = 0; k < 3; k++) out[k] = a[k] + v * ab[k];
        return;
    }
    double cp[3];
    v3_sub(p, c, cp);
    double d5 = v3_dot(ab, cp), d6 = v3_dot(ac, cp);
    if (d6 >= 0 && d5 <= d6) {
        memcpy(out, c, 3 * sizeof(double));
        return;
    }
    double vb = d5 * d2 - d1 * d6;
    if (vb <= 0 && d2 >= 0 && d6 <= 0) {
        double w = d2 / (d2 - d6);
        for (int k = 0; k < 3; k++) out[k] = a[k] + w * ac[k];
        return;
    }
    double va = d3 * d6 - d5 * d4;
    if (va <= 0 && (d4 - d3) >= 0 && (d5 - d6) >= 0) {
        double w = (d4 - d3) / ((d4 - d3) + (d5 - d6));
        for (int k = 0; k < 3; k++) out[k] = b[k] + w * (c[k] - b[k]);
        return;
    }
    double den = 1.0 / (va + vb + vc);
    double v = vb * den, w = vc * den;
    for (int k = 0; k < 3; k++) out[k] = a[k] + ab[k] * v + ac[k] * w;
}

/// Distance from x to segment ab.
static double seg_dist(const double* x, const double* a, const double* b) {
    double d[3], w[3];
    v3_sub(b, a, d);
    v3_sub(x, a, w);
    double dd = v3_dot(d, d), t = dd > 0 ? v3_dot(w, d) / dd : 0;
    t = t < 0 ? 0 : t > 1 ? 1 : t;
    for (int k = 0; k < 3; k++) w[k] -= t * d[k];
    return sqrt(v3_dot(w, w));
}

/// 1 when segment (a, b) crosses triangle (t0, t1, t2): endpoints strictly on opposite sides
/// (beyond tol, m) and the crossing point (x, may be NULL) inside or on the triangle.
static int seg_tri(const double* a, const double* b, const double* t0, const double* t1,
                   const double* t2, double tol, double* xo) {
    double e1[3], e2[3], n[3];
    v3_sub(t1, t0, e1);
    v3_sub(t2, t0, e2);
    v3_cross(e1, e2, n);
    double nn = sqrt(v3_dot(n, n));
    if (!(nn > 0)) return 0;
    double da[3], db[3];
    v3_sub(a, t0, da);
    v3_sub(b, t0, db);
    double sa = v3_dot(n, da) / nn, sb = v3_dot(n, db) / nn;
    if (!((sa > tol && sb < -tol) || (sa < -tol && sb > tol))) return 0;
    double s = sa / (sa - sb), x[3];
    for (int k = 0; k < 3; k++) x[k] = a[k] + s * (b[k] - a[k]);
    // Barycentric signs of x in the triangle (edges inclusive, so the shared diagonal counts).
    const double* t[3] = {t0, t1, t2};
    for (int i = 0; i < 3; i++) {
        double ei[3], xi[3], c[3];
        v3_sub(t[(i + 1) % 3], t[i], ei);
        v3_sub(x, t[i], xi);
        v3_cross(ei, xi, c);
        if (v3_dot(c, n) < -1e-12 * nn * sqrt(v3_dot(ei, ei))) return 0;
    }
    if (xo) memcpy(xo, x, sizeof x);
    return 1;
}

// ---------------------------------------------------------------------------------------------
// Element stiffness of the linear model (same formula as fem.c's linear element):
// K_ab = V (lambda g_a g_b^T + mu g_b g_a^T + mu (g_a . g_b) I), row-major 12x12.

static int element_k(const hs_cut* c, const double* x0, int e, double k[144]) {
    const int* t = c->mesh->tets + 4 * e;
    double dm[9];
    for (int i = 0; i < 3; i++)
        for (int r = 0; r < 3; r++) dm[3 * r + i] = x0[3 * t[i + 1] + r] - x0[3 * t[0] + r];
    double det = dm[0] * (dm[4] * dm[8] - dm[5] * dm[7]) - dm[1] * (dm[3] * dm[8] - dm[5] * dm[6]) +
                 dm[2] * (dm[3] * dm[7] - dm[4] * dm[6]);
    if (!(det > 0)) return 0;
    // rows of Dm^-1 = columns of the cofactor matrix / det
    double cof[9];
    cof[0] = dm[4] * dm[8] - dm[5] * dm[7];
    cof[1] = -(dm[3] * dm[8] - dm[5] * dm[6]);
    cof[2] = dm[3] * dm[7] - dm[4] * dm[6];
    cof[3] = -(dm[1] * dm[8] - dm[2] * dm[7]);
    cof[4] = dm[0] * dm[8] - dm[2] * dm[6];
    cof[5] = -(dm[0] * dm[7] - dm[1] * dm[6]);
    cof[6] = dm[1] * dm[5] - dm[2] * dm[4];
    cof[7] = -(dm[0] * dm[5] - dm[2] * dm[3]);
    cof[8] = dm[0] * dm[4] - dm[1] * dm[3];
    double g[4][3];
    for (int i = 0; i < 3; i++)
        for (int r = 0; r < 3; r++) g[i + 1][r] = cof[3 * r + i] / det;
    for (int r = 0; r < 3; r++) g[0][r] = -(g[1][r] + g[2][r] + g[3][r]);
    double V = det / 6.0, lam = c->lambda, mu = c->mu;
    for (int a = 0; a < 4; a++)
        for (int b = 0; b < 4; b++) {
            double gg = mu * v3_dot(g[a], g[b]);
            for (int i = 0; i < 3; i++)
                for (int j = 0; j < 3; j++)
                    k[12 * (3 * a + i) + 3 * b + j] =
                        V * (lam * g[a][i] * g[b][j] + mu * g[b][i] * g[a][j] + (i == j ? gg : 0));
        }
    return 1;
}

// ---------------------------------------------------------------------------------------------
// Set-up

static hs_status nomem(hs_err* err) {
    return hs_err_set(err, HS_ERR_NOMEM, "cut: out of memory");
}

static hs_status grow_elems(hs_cut* c, int need) {
    if (need <= c->cap_elem) return HS_OK;
    int cap = c->cap_elem * 2 > need ? c->cap_elem * 2 : need;
    double* dk = hs_realloc(c->dk, sizeof(double) * 144 * (size_t)cap);
    if (!dk) return HS_ERR_NOMEM;
    c->dk = dk;
    int* ed = hs_realloc(c->edof, sizeof(int) * 12 * (size_t)cap);
    if (!ed) return HS_ERR_NOMEM;
    c->edof = ed;
    c->cap_elem = cap;
    return HS_OK;
}

void hs_cut_assemble(const hs_cut* c, hs_csc* a) {
    hs_fem_assemble(c->fem, 1.0, 0.0, a);
    for (int i = 0; i < c->n; i++) {
        if (!c->pinned[i]) continue;
        for (int q = 0; q < 3; q++) {
            int d = c->dof[3 * i + q];
            if (d < 0) continue;
            int p = hs_csc_find(a, d, d);
            HS_ASSERT(p >= 0);
            a->val[p] += c->k_pin;
        }
    }
}

// K's pin springs on the nodes pinned by the last sweep.
static void add_pins(hs_cut* c, hs_csc* a) {
    for (int k = 0; k < c->n_pins; k++)
        for (int q = 0; q < 3; q++) {
            int d = c->dof[3 * c->pins[k] + q];
            int p = d >= 0 ? hs_csc_find(a, d, d) : -1;
            if (p >= 0) a->val[p] += c->k_pin;
        }
}

// Free dofs of the last sweep's removed and changed tets and new pins, into c->dset.
static int partial_dofs(hs_cut* c) {
    int d = 0;
    const int* T = c->mesh->tets;
    for (int k = 0; k < c->n_removed + c->n_changed + c->n_pins; k++) {
        int nv = k < c->n_removed + c->n_changed ? 4 : 1;
        for (int a = 0; a < nv; a++) {
            int v = k < c->n_removed                  ? T[4 * c->removed[k] + a]
                    : k < c->n_removed + c->n_changed ? T[4 * c->changed[k - c->n_removed] + a]
                                                      : c->pins[k - c->n_removed - c->n_changed];
            for (int q = 0; q < 3; q++) {
                int f = c->dof[3 * v + q];
                if (f >= 0 && c->dpos[f] < 0) {
                    c->dpos[f] = d;
                    c->dset[d++] = f;
                }
            }
        }
    }
    for (int i = 0; i < d; i++) c->dpos[c->dset[i]] = -1;
    return d;
}

hs_status hs_cut_refactor(hs_cut* c) {
    if (!c->factor) return HS_ERR_INVALID;
    hs_cut_assemble(c, c->a);
    c->a_stale = 0;
    hs_status st = hs_cholesky_refactor(c->factor, c->a);
    if (st == HS_OK) c->updates_since_refactor = 0;
    return st;
}

static hs_status rebuild_live(hs_cut* c, hs_err* err) {
    int k = 0;
    for (int e = 0; e < c->ne; e++) {
        if (!c->active[e]) continue;
        memcpy(c->live->tets + 4 * k, c->mesh->tets + 4 * e, 4 * sizeof(int));
        c->live_tet[k++] = e;
    }
    c->live->n_tets = k;
    hs_status st = hs_mesh_finalize(c->live, err);
    if (st == HS_WARN_MESH_REPAIRED)
        return hs_err_set(err, HS_ERR_NUMERIC,
                          "cut: the live mesh needed repair (%d degenerate, %d reoriented tets): "
                          "the quality guard let a bad element through",
                          c->live->report.degenerate_tets, c->live->report.reoriented_tets);
    if (st == HS_OK) c->components = c->live->report.components;
    return st;
}

static int cmp_face(const void* pa, const void* pb) {
    const int* a = pa;
    const int* b = pb;
    for (int k = 0; k < 3; k++)
        if (a[k] != b[k]) return (a[k] > b[k]) - (a[k] < b[k]);
    return 0;
}

/// fnbr: the tet across each face, by sorting the faces' node triples.
static hs_status build_face_neighbours(hs_cut* c) {
    const int ne = c->ne;
    int* key = hs_alloc(sizeof(int) * 5 * 4 * (size_t)ne);
    if (!key) return HS_ERR_NOMEM;
    for (int e = 0; e < ne; e++)
        for (int f = 0; f < 4; f++) {
            int* k = key + 5 * (4 * e + f);
            int m = 0;
            for (int a = 0; a < 4; a++)
                if (a != f) k[m++] = c->mesh->tets[4 * e + a];
            for (int i = 0; i < 3; i++) // sort 3
                for (int j = i + 1; j < 3; j++)
                    if (k[j] < k[i]) {
                        int t = k[i];
                        k[i] = k[j];
                        k[j] = t;
                    }
            k[3] = e;
            k[4] = f;
            c->fnbr[4 * e + f] = -1;
        }
    qsort(key, 4 * (size_t)ne, 5 * sizeof(int), cmp_face);
    for (int i = 0; i + 1 < 4 * ne; i++) {
        int *a = key + 5 * i, *b = a + 5;
        if (cmp_face(a, b) == 0) {
            c->fnbr[4 * a[3] + a[4]] = b[3];
            c->fnbr[4 * b[3] + b[4]] = a[3];
        }
    }
    hs_free(key);
    return HS_OK;
}

static void choose_window(const hs_cut* c, const double* bl, unsigned char* mask, double* org,
                          double* dir);
static int partial_policy(const hs_cut* c);

/// def.factor_threads, with 0 (by the processors) meaning one thread while the cut's own
/// window thread builds on the second core.
static int factor_threads(const hs_cut* c) {
    if (c->def.factor_threads == 0 && c->def.window_thread && !c->win_off) return 1;
    return c->def.factor_threads;
}

/// window_accept_ratio: does a window pay on this mesh? A probe window in the middle of the
/// free nodes, its blade across the thinnest extent moving along the longest: a partial refactor
/// of all its dofs (every sweep inside it at once) in the order with them last, against the
/// default order, from symbolic analyses. Windows are turned off (win_off) when the ratio is
/// above def.window_accept_ratio; kept when the probe cannot tell (out of memory, simplicial).
static void probe_window(hs_cut* c) {
    double ctr[3] = {0, 0, 0}, lo[3] = {0, 0, 0}, hi[3] = {0, 0, 0};
    int nn = 0;
    for (int i = 0; i < c->n; i++) {
        if (c->dof[3 * i] < 0) continue;
        for (int d = 0; d < 3; d++) {
            double v = c->mesh->x0[3 * i + d];
            ctr[d] += v;
            lo[d] = nn == 0 || v < lo[d] ? v : lo[d];
            hi[d] = nn == 0 || v > hi[d] ? v : hi[d];
        }
        nn++;
    }
    if (nn == 0) return;
    int thin = 0, lng = 0;
    for (int d = 0; d < 3; d++) {
        ctr[d] /= nn;
        if (hi[d] - lo[d] < hi[thin] - lo[thin]) thin = d;
        if (hi[d] - lo[d] > hi[lng] - lo[lng]) lng = d;
    }
    if (thin == lng) lng = (thin + 1) % 3;
    // The window starts at the centre and reaches window_ahead_m along the longest extent.
    double bl[12], step = 0.01 * c->def.window_radius_m;
    for (int d = 0; d < 3; d++) {
        double half = d == thin ? 0.6 * (hi[d] - lo[d]) : 0.0;
        bl[6 + d] = ctr[d] - half; // p1
        bl[9 + d] = ctr[d] + half; // q1
        bl[d] = bl[6 + d] - (d == lng ? step : 0.0);
        bl[3 + d] = bl[9 + d] - (d == lng ? step : 0.0);
    }
    unsigned char* mask = hs_calloc((size_t)c->n_free + 1, 1);
    int* dofs = hs_alloc(sizeof(int) * ((size_t)c->n_free + 1));
    if (mask && dofs) {
        double org[3], dir[3];
        memcpy(c->x, c->mesh->x0, sizeof(double) * 3 * (size_t)c->n); // rest positions
        choose_window(c, bl, mask, org, dir);
        int nd = 0;
        for (int k = 0; k < c->n_free; k++)
            if (mask[k]) dofs[nd++] = k;
        double sd = -1, sw = -1;
        hs_err e;
        if (nd > 0 && hs_cholesky_order_shares(c->a, mask, nd, dofs, &sd, &sw, &e) == HS_OK &&
            sd > 0) {
            c->wstats.probe_share_default = sd;
            c->wstats.probe_share_window = sw;
            c->win_off = sw > c->def.window_accept_ratio * sd;
            c->wstats.off = c->win_off;
        }
    }
    hs_free(mask);
    hs_free(dofs);
}

hs_status hs_cut_create(hs_mesh* mesh, const unsigned char* fixed, const hs_cut_def* def,
                        hs_cut** out, hs_err* err) {
    if (!out) return hs_err_set(err, HS_ERR_INVALID, "cut: out is NULL");
    *out = NULL;
    if (!mesh || !def) return hs_err_set(err, HS_ERR_INVALID, "cut: mesh and def must be given");
    if (def->cookie != HS_CUT_COOKIE)
        return hs_err_set(err, HS_ERR_INVALID,
                          "cut: definition not initialised with hs_cut_default_def()");
    if (!(def->min_volume_ratio >= 0 && def->min_volume_ratio < 1) ||
        !(def->min_quality >= 0 && def->min_quality < 1) || def->max_bisections < 0 ||
        def->max_bisections > 60)
        return hs_err_set(err, HS_ERR_INVALID,
                          "cut: guard out of range (volume ratio %g, quality %g, bisections %d)",
                          def->min_volume_ratio, def->min_quality, def->max_bisections);
    if (!(def->window_radius_m >= 0 && def->window_radius_m < 1e6) ||
        !(def->window_ahead_m >= 0 && def->window_ahead_m < 1e6))
        return hs_err_set(err, HS_ERR_INVALID, "cut: window radius %g m / ahead %g m out of range",
                          def->window_radius_m, def->window_ahead_m);
    if (!(def->window_due_fraction > 0 && def->window_due_fraction <= 1))
        return hs_err_set(err, HS_ERR_INVALID, "cut: window due fraction %g (0 < f <= 1)",
                          def->window_due_fraction);
    if (def->factor_threads < 0 || def->factor_threads > 2)
        return hs_err_set(err, HS_ERR_INVALID, "cut: factor threads %d (0, 1 or 2)",
                          def->factor_threads);
    if (def->factor_policy < HS_CUT_FACTOR_AUTO || def->factor_policy > HS_CUT_FACTOR_PARTIAL)
        return hs_err_set(err, HS_ERR_INVALID, "cut: unknown factor policy %d",
                          (int)def->factor_policy);
    if (def->factor_policy == HS_CUT_FACTOR_NONE && def->window_radius_m > 0)
        return hs_err_set(err, HS_ERR_INVALID,
                          "cut: an update window needs a factor (policy NONE)");
    if (def->factor_policy == HS_CUT_FACTOR_PARTIAL && def->window_radius_m > 0 &&
        !def->window_background)
        return hs_err_set(err, HS_ERR_INVALID,
                          "cut: a PARTIAL window is rebuilt in the background only (set "
                          "window_background)");
    if (!(def->window_accept_ratio >= 0 && def->window_accept_ratio <= 1))
        return hs_err_set(err, HS_ERR_INVALID, "cut: window accept ratio %g (0 <= r <= 1)",
                          def->window_accept_ratio);
    if (def->window_thread && !(def->window_radius_m > 0 && def->window_background))
        return hs_err_set(err, HS_ERR_INVALID,
                          "cut: window_thread needs a window (window_radius_m > 0) rebuilt in "
                          "the background (window_background)");
    if (mesh->n_nodes <= 0 || mesh->n_tets <= 0 || !mesh->node_used)
        return hs_err_set(err, HS_ERR_INVALID, "cut: mesh is empty or not finalized");
    hs_cut* c = hs_calloc(1, sizeof *c);
    if (!c) return nomem(err);
    c->mesh = mesh;
    c->def = *def;
    const int n = c->n = mesh->n_nodes, ne = c->ne = mesh->n_tets;
    size_t n3 = 3 * (size_t)n;
    c->fixed = hs_calloc((size_t)n, 1);
    c->pinned = hs_calloc((size_t)n, 1);
    c->active = hs_alloc((size_t)ne);
    c->count = hs_calloc((size_t)n, sizeof(int));
    c->nt_start = hs_calloc((size_t)n + 1, sizeof(int));
    c->nt = hs_alloc(4 * sizeof(int) * (size_t)ne);
    c->vol_orig = hs_alloc(sizeof(double) * (size_t)ne);
    c->q_orig = hs_alloc(sizeof(double) * (size_t)ne);
    c->dof = hs_alloc(sizeof(int) * n3);
    c->live_tet = hs_alloc(sizeof(int) * (size_t)ne);
    c->x = hs_alloc(sizeof(double) * n3);
    c->x0_old = hs_alloc(sizeof(double) * n3);
    c->nrm = hs_alloc(sizeof(double) * n3);
    c->tmark = hs_calloc((size_t)ne, 1);
    c->nmark = hs_calloc((size_t)n, 1);
    c->cut_list = hs_alloc(sizeof(int) * (size_t)ne);
    c->removed = hs_alloc(sizeof(int) * (size_t)ne);
    c->moved = hs_alloc(sizeof(int) * (size_t)n);
    c->onb = hs_alloc(sizeof(int) * (size_t)n);
    c->changed = hs_alloc(sizeof(int) * (size_t)ne);
    c->pins = hs_alloc(sizeof(int) * (size_t)n);
    c->edges = hs_alloc(sizeof(int) * 12 * (size_t)ne);
    c->parent = hs_alloc(sizeof(int) * (size_t)n);
    c->fnbr = hs_alloc(sizeof(int) * 4 * (size_t)ne);
    c->tparent = hs_alloc(sizeof(int) * (size_t)ne);
    c->fa = hs_alloc(sizeof(int) * (size_t)ne);
    c->fb = hs_alloc(sizeof(int) * (size_t)ne);
    c->anch = hs_alloc((size_t)ne);
    c->tstamp = hs_calloc((size_t)ne, sizeof(unsigned));
    c->gopen = hs_alloc(sizeof(int) * (size_t)ne);
    if (!c->tstamp || !c->gopen || !c->fixed || !c->pinned || !c->active || !c->count ||
        !c->nt_start || !c->nt || !c->vol_orig || !c->q_orig || !c->dof || !c->live_tet || !c->x ||
        !c->x0_old || !c->nrm || !c->tmark || !c->nmark || !c->cut_list || !c->removed ||
        !c->moved || !c->onb || !c->changed || !c->pins || !c->edges || !c->parent || !c->fnbr ||
        !c->tparent || !c->fa || !c->fb || !c->anch || grow_elems(c, 256) != HS_OK) {
        hs_cut_destroy(&c);
        return nomem(err);
    }
    const double* x0 = mesh->x0;
    memcpy(c->x0_old, x0, sizeof(double) * n3);
    for (int e = 0; e < ne; e++) {
        const int* t = mesh->tets + 4 * e;
        const double* p[4] = {x0 + 3 * t[0], x0 + 3 * t[1], x0 + 3 * t[2], x0 + 3 * t[3]};
        double v = tet_vol4(p[0], p[1], p[2], p[3]);
        if (!(v > 0)) {
            hs_err_set(err, HS_ERR_INVALID, "cut: tet %d is not positively oriented (V = %g m^3)",
                       e, v);
            hs_cut_destroy(&c);
            return HS_ERR_INVALID;
        }
        c->vol_orig[e] = v;
        c->q_orig[e] = tet_quality4(p, v);
        c->active[e] = 1;
        for (int a = 0; a < 4; a++) {
            c->count[t[a]]++;
            c->nt_start[t[a] + 1]++;
        }
    }
    for (int i = 0; i < n; i++) c->nt_start[i + 1] += c->nt_start[i];
    {
        int* fill = c->parent; // scratch
        memcpy(fill, c->nt_start, sizeof(int) * (size_t)n);
        for (int e = 0; e < ne; e++)
            for (int a = 0; a < 4; a++) c->nt[fill[mesh->tets[4 * e + a]]++] = e;
    }
    if (build_face_neighbours(c) != HS_OK) {
        hs_cut_destroy(&c);
        return nomem(err);
    }
    int nf = 0, nfixed_used = 0;
    for (int i = 0; i < n; i++) {
        int fx = (fixed && fixed[i]) || c->count[i] == 0;
        if (fixed && fixed[i] && c->count[i] > 0) nfixed_used++;
        c->fixed[i] = (unsigned char)fx;
        for (int q = 0; q < 3; q++) c->dof[3 * i + q] = fx ? -1 : nf++;
    }
    c->n_free = nf;
    if (nf == 0 || nfixed_used == 0) {
        hs_err_set(err, HS_ERR_INVALID,
                   "cut: need at least one fixed node and one free node (%d fixed, %d free dofs)",
                   nfixed_used, nf);
        hs_cut_destroy(&c);
        return HS_ERR_INVALID;
    }
    c->rhs = hs_alloc(sizeof(double) * (size_t)nf);
    c->sol = hs_alloc(sizeof(double) * (size_t)nf);
    c->win = hs_calloc((size_t)nf + 1, 1);
    c->dset = hs_alloc(sizeof(int) * (size_t)nf);
    c->dpos = hs_alloc(sizeof(int) * (size_t)nf);
    if (c->dpos)
        for (int d = 0; d < nf; d++) c->dpos[d] = -1;
    if (!c->rhs || !c->sol || !c->dset || !c->dpos || !c->win) {
        hs_cut_destroy(&c);
        return nomem(err);
    }
    hs_fem_def fd = hs_fem_default_def();
    fd.model = HS_MODEL_LINEAR;
    fd.material = def->material;
    hs_status st = hs_fem_create(mesh, &fd, c->dof, nf, &c->fem, err);
    if (st == HS_OK) st = hs_fem_create_matrix(c->fem, &c->a);
    if (st != HS_OK) {
        hs_cut_destroy(&c);
        return st == HS_ERR_NOMEM ? nomem(err) : st;
    }
    double E = def->material.youngs_pa, nu = def->material.poisson;
    c->mu = E / (2.0 * (1.0 + nu));
    c->lambda = E * nu / ((1.0 + nu) * (1.0 - 2.0 * nu));
    hs_fem_update(c->fem, x0, NULL);
    hs_cut_assemble(c, c->a);
    double dsum = 0;
    for (int d = 0; d < nf; d++) {
        int p = hs_csc_find(c->a, d, d);
        dsum += p >= 0 ? c->a->val[p] : 0.0;
    }
    c->k_pin = dsum / nf;
    if (def->factor_policy != HS_CUT_FACTOR_NONE) st = hs_cholesky_create(c->a, &c->factor, err);
    // AUTO keeps the (supernodal) factor until a sweep small enough for updates comes: the
    // conversion to an updatable factor makes later refactors simplicial, hence slower.
    if (st == HS_OK && def->factor_policy == HS_CUT_FACTOR_UPDATE)
        st = hs_cholesky_prepare_updates(c->factor, 256);
    if (st == HS_OK && c->factor) {
        // Calibrate the refactor cost of this factor (AUTO compares updates against it).
        int64_t t0 = hs_now_ns();
        st = hs_cut_refactor(c);
        c->refactor_ms = (double)(hs_now_ns() - t0) * 1e-6;
        // A simplicial factor (tiny meshes) cannot be refactored in part: PARTIAL's sweeps
        // refactor. AUTO takes the partial refactor where it can (the fastest exact path on
        // every mesh of hapsim-bench cut) and its kept data stays within 4x the factor.
        if (st == HS_OK && def->factor_policy == HS_CUT_FACTOR_PARTIAL) {
            st = hs_cholesky_prepare_partial(c->factor, c->a);
            if (st == HS_ERR_UNSUPPORTED) st = HS_OK;
        } else if (st == HS_OK && def->factor_policy == HS_CUT_FACTOR_AUTO &&
                   (def->window_radius_m == 0 || def->window_background) &&
                   hs_cholesky_is_supernodal(c->factor) &&
                   hs_cholesky_partial_bytes(c->factor) <= 32 * hs_cholesky_factor_nnz(c->factor)) {
            hs_status ps = hs_cholesky_prepare_partial(c->factor, c->a);
            c->auto_partial = ps == HS_OK;
            // Else the low-rank path as before; a full pass that failed (a pivot its 1e-12
            // guard refused) leaves L partly recomputed, so refactor it.
            if (ps != HS_OK && ps != HS_ERR_NOMEM) st = hs_cut_refactor(c);
        }
        if (st == HS_OK && def->window_accept_ratio > 0 && def->window_radius_m > 0 &&
            partial_policy(c) && hs_cholesky_is_supernodal(c->factor))
            probe_window(c);
        // A helper thread that cannot start leaves the refactor on one thread.
        if (st == HS_OK && (def->factor_policy == HS_CUT_FACTOR_PARTIAL || c->auto_partial))
            (void)hs_cholesky_set_partial_threads(c->factor, factor_threads(c));
    }
    if (st != HS_OK) {
        hs_cut_destroy(&c);
        return hs_err_set(err, st, "cut: factorising K failed: %s", hs_status_str(st));
    }
    st = hs_mesh_create(n, x0, ne, mesh->tets, &c->live, err);
    if (st >= HS_OK) st = rebuild_live(c, err);
    if (st != HS_OK) {
        hs_cut_destroy(&c);
        return st;
    }
    *out = c;
    return HS_OK;
}

// ---------------------------------------------------------------------------------------------
// Queries

int hs_cut_last_removed(const hs_cut* c, const int** tets) {
    if (tets) *tets = c->removed;
    return c->n_removed;
}
int hs_cut_last_moved(const hs_cut* c, const int** nodes) {
    if (nodes) *nodes = c->moved;
    return c->n_moved;
}
int hs_cut_last_changed(const hs_cut* c, const int** tets) {
    if (tets) *tets = c->changed;
    return c->n_changed;
}
int64_t hs_cut_topology_version(const hs_cut* c) {
    return c->version;
}
int hs_cut_tet_active(const hs_cut* c, int tet) {
    return tet >= 0 && tet < c->ne && c->active[tet];
}
int hs_cut_node_pinned(const hs_cut* c, int node) {
    return node >= 0 && node < c->n && c->pinned[node];
}
hs_status hs_cut_update_live(hs_cut* c, hs_err* err) {
    if (!c) return hs_err_set(err, HS_ERR_INVALID, "cut: NULL");
    if (!c->live_dirty) return HS_OK;
    hs_status st = rebuild_live(c, err);
    if (st == HS_OK) c->live_dirty = 0;
    return st;
}
const hs_mesh* hs_cut_live_mesh(hs_cut* c) {
    return hs_cut_update_live(c, NULL) == HS_OK ? c->live : NULL;
}
int hs_cut_live_tet(hs_cut* c, int k) {
    if (hs_cut_update_live(c, NULL) != HS_OK) return -1;
    HS_ASSERT(k >= 0 && k < c->live->n_tets);
    return c->live_tet[k];
}
int hs_cut_components(hs_cut* c) {
    return hs_cut_update_live(c, NULL) == HS_OK ? c->components : -1;
}
hs_cholesky* hs_cut_factor(hs_cut* c) {
    return c->factor;
}
int hs_cut_free_dofs(const hs_cut* c) {
    return c->n_free;
}
int hs_cut_dof(const hs_cut* c, int node, int comp) {
    HS_ASSERT(node >= 0 && node < c->n && comp >= 0 && comp < 3);
    return c->dof[3 * node + comp];
}
hs_status hs_cut_create_matrix(const hs_cut* c, hs_csc** out) {
    return hs_fem_create_matrix(c->fem, out);
}
const hs_fem* hs_cut_fem(const hs_cut* c) {
    return c->fem;
}

hs_status hs_cut_sync_fem(const hs_cut* c, hs_fem* other) {
    if (!c || !other) return HS_ERR_INVALID;
    for (int e = 0; e < c->ne; e++)
        if (!c->active[e]) hs_fem_set_element_active(other, e, 0);
    return hs_fem_refresh_elements(other, c->changed, c->n_changed);
}

hs_status hs_cut_solve(hs_cut* c, const double* f, double* u) {
    if (!c || !c->factor || !f || !u) return HS_ERR_INVALID;
    for (int k = 0; k < 3 * c->n; k++) {
        int d = c->dof[k];
        if (d >= 0) c->rhs[d] = c->pinned[k / 3] ? 0.0 : f[k];
    }
    hs_status st = hs_cholesky_solve(c->factor, c->rhs, c->sol);
    if (st != HS_OK) return st;
    for (int k = 0; k < 3 * c->n; k++) {
        int d = c->dof[k];
        u[k] = d >= 0 && !c->pinned[k / 3] ? c->sol[d] : 0.0;
        if (!isfinite(u[k])) return HS_ERR_NUMERIC;
    }
    return HS_OK;
}

static int find_pieces(hs_cut* c);
static int find_root(int* parent, int i);

hs_status hs_cut_validate(hs_cut* c, hs_err* err) {
    hs_status st = hs_cut_update_live(c, err);
    if (st != HS_OK) return st;
    st = hs_mesh_check(c->live, err);
    if (st != HS_OK) return st;
    int na = 0;
    for (int e = 0; e < c->ne; e++) {
        if (!c->active[e]) continue;
        na++;
        double v = hs_tet_volume(c->mesh->x0, c->mesh->tets + 4 * e);
        if (!(v > 0))
            return hs_err_set(err, HS_ERR_INVALID, "cut: active tet %d has rest volume %g m^3", e,
                              v);
    }
    if (na != c->live->n_tets)
        return hs_err_set(err, HS_ERR_INVALID, "cut: %d active tets but the live mesh has %d", na,
                          c->live->n_tets);
    for (int i = 0; i < c->n; i++) {
        int cnt = 0;
        for (int p = c->nt_start[i]; p < c->nt_start[i + 1]; p++) cnt += c->active[c->nt[p]];
        if (cnt != c->count[i])
            return hs_err_set(err, HS_ERR_INVALID, "cut: node %d counts %d tets, has %d", i,
                              c->count[i], cnt);
        if (cnt == 0 && c->dof[3 * i] >= 0 && !c->pinned[i])
            return hs_err_set(err, HS_ERR_INVALID,
                              "cut: free node %d has no element and is not pinned (orphan)", i);
        if (cnt > 0 && c->pinned[i] && c->def.fragment == HS_CUT_FRAGMENT_DROP)
            return hs_err_set(err, HS_ERR_INVALID, "cut: pinned node %d still has %d tets", i, cnt);
        if (memcmp(c->live->x0 + 3 * i, c->mesh->x0 + 3 * i, 3 * sizeof(double)))
            return hs_err_set(err, HS_ERR_INVALID, "cut: live x0 of node %d out of sync", i);
    }
    // Every piece held since the first sweep that removed tets (the fast check's claim),
    // recounted over all tets; where pins do not hold, a piece FIX left has every node pinned.
    int loose = c->pieces_checked ? find_pieces(c) : 0;
    if (loose && !c->def.pins_hold && c->def.fragment == HS_CUT_FRAGMENT_FIX) {
        const int* T = c->mesh->tets;
        for (int e = 0; e < c->ne; e++) {
            if (!c->active[e] || c->anch[find_root(c->tparent, e)]) continue;
            for (int a = 0; a < 4; a++)
                if (!c->pinned[T[4 * e + a]])
                    return hs_err_set(err, HS_ERR_INVALID,
                                      "cut: node %d of a free piece is not pinned", T[4 * e + a]);
        }
        loose = 0;
    }
    if (loose)
        return hs_err_set(err, HS_ERR_INVALID,
                          "cut: %d piece(s) without three non-collinear fixed or pinned nodes",
                          loose);
    return HS_OK;
}

// ---------------------------------------------------------------------------------------------
// The sweep

static int find_root(int* parent, int i) {
    while (parent[i] != i) {
        parent[i] = parent[parent[i]];
        i = parent[i];
    }
    return i;
}

static int cmp_edge(const void* pa, const void* pb) {
    const int* a = pa;
    const int* b = pb;
    if (a[0] != b[0]) return (a[0] > b[0]) - (a[0] < b[0]);
    return (a[1] > b[1]) - (a[1] < b[1]);
}

/// 1 when the remaining tets around node v stay acceptable with v at rest position X and
/// current position xv (tmark 2 = being removed, ignored).
static int move_ok(const hs_cut* c, int v, const double* X, const double* xv) {
    const double* x0 = c->mesh->x0;
    const double rmin = c->def.min_volume_ratio, qmin = c->def.min_quality;
    for (int p = c->nt_start[v]; p < c->nt_start[v + 1]; p++) {
        int e = c->nt[p];
        if (!c->active[e] || c->tmark[e] == 2) continue;
        const int* t = c->mesh->tets + 4 * e;
        const double *pr[4], *pc[4];
        for (int a = 0; a < 4; a++) {
            pr[a] = t[a] == v ? X : x0 + 3 * t[a];
            pc[a] = t[a] == v ? xv : c->x + 3 * t[a];
        }
        double vr = tet_vol4(pr[0], pr[1], pr[2], pr[3]);
        if (!(vr >= rmin * c->vol_orig[e]) || !(vr > 0)) return 0;
        if (tet_quality4(pr, vr) < fmin(qmin, c->q_orig[e])) return 0;
        double vc = tet_vol4(pc[0], pc[1], pc[2], pc[3]);
        const double* po[4];
        for (int a = 0; a < 4; a++) po[a] = c->x + 3 * t[a];
        double vo = tet_vol4(po[0], po[1], po[2], po[3]);
        if (!(vc > 0) || vc < rmin * vo) return 0;
        if (tet_quality4(pc, vc) < fmin(qmin, tet_quality4(po, vo))) return 0;
    }
    return 1;
}

/// Unit normal of triangle (a, b, c); zero when it is degenerate.
static void unit_normal(const double* a, const double* b, const double* c, double* nv) {
    double e1[3], e2[3];
    v3_sub(b, a, e1);
    v3_sub(c, a, e2);
    v3_cross(e1, e2, nv);
    double l = sqrt(v3_dot(nv, nv));
    for (int d = 0; d < 3; d++) nv[d] = l > 0 ? nv[d] / l : 0.0;
}

/// Squared shortest edge at v of its active tets, current positions, m^2.
static double shortest_edge2(const hs_cut* c, int v) {
    double h = INFINITY;
    for (int p = c->nt_start[v]; p < c->nt_start[v + 1]; p++) {
        int e = c->nt[p];
        if (!c->active[e]) continue;
        const int* t = c->mesh->tets + 4 * e;
        for (int a = 0; a < 4; a++) {
            if (t[a] == v) continue;
            double d[3];
            v3_sub(c->x + 3 * t[a], c->x + 3 * v, d);
            h = fmin(h, v3_dot(d, d));
        }
    }
    return h;
}

/// Rest-space image of a current-space move: dX = Fbar^-1 dx, Fbar the volume-weighted mean
/// deformation gradient of v's remaining tets; dX = dx when there is no usable Fbar.
static void to_rest(const hs_cut* c, int v, const double* dx, double* dX) {
    const double* x0 = c->mesh->x0;
    double F[9] = {0}, wsum = 0;
    for (int p = c->nt_start[v]; p < c->nt_start[v + 1]; p++) {
        int e = c->nt[p];
        if (!c->active[e] || c->tmark[e] == 2) continue;
        const int* t = c->mesh->tets + 4 * e;
        double dm[9], ds[9];
        for (int i = 0; i < 3; i++)
            for (int r = 0; r < 3; r++) {
                dm[3 * r + i] = x0[3 * t[i + 1] + r] - x0[3 * t[0] + r];
                ds[3 * r + i] = c->x[3 * t[i + 1] + r] - c->x[3 * t[0] + r];
            }
        double det = dm[0] * (dm[4] * dm[8] - dm[5] * dm[7]) -
                     dm[1] * (dm[3] * dm[8] - dm[5] * dm[6]) +
                     dm[2] * (dm[3] * dm[7] - dm[4] * dm[6]);
        if (!(det > 0)) continue;
        double inv[9]; // Dm^-1
        inv[0] = (dm[4] * dm[8] - dm[5] * dm[7]) / det;
        inv[1] = -(dm[1] * dm[8] - dm[2] * dm[7]) / det;
        inv[2] = (dm[1] * dm[5] - dm[2] * dm[4]) / det;
        inv[3] = -(dm[3] * dm[8] - dm[5] * dm[6]) / det;
        inv[4] = (dm[0] * dm[8] - dm[2] * dm[6]) / det;
        inv[5] = -(dm[0] * dm[5] - dm[2] * dm[3]) / det;
        inv[6] = (dm[3] * dm[7] - dm[4] * dm[6]) / det;
        inv[7] = -(dm[0] * dm[7] - dm[1] * dm[6]) / det;
        inv[8] = (dm[0] * dm[4] - dm[1] * dm[3]) / det;
        double w = det / 6.0;
        for (int i = 0; i < 3; i++)
            for (int j = 0; j < 3; j++) {
                double s = 0;
                for (int k = 0; k < 3; k++) s += ds[3 * i + k] * inv[3 * k + j];
                F[3 * i + j] += w * s;
            }
        wsum += w;
    }
    memcpy(dX, dx, 3 * sizeof(double));
    if (!(wsum > 0)) return;
    for (int k = 0; k < 9; k++) F[k] /= wsum;
    double det = F[0] * (F[4] * F[8] - F[5] * F[7]) - F[1] * (F[3] * F[8] - F[5] * F[6]) +
                 F[2] * (F[3] * F[7] - F[4] * F[6]);
    if (!(det > 0.05) || !isfinite(det)) return;
    double inv[9];
    inv[0] = (F[4] * F[8] - F[5] * F[7]) / det;
    inv[1] = -(F[1] * F[8] - F[2] * F[7]) / det;
    inv[2] = (F[1] * F[5] - F[2] * F[4]) / det;
    inv[3] = -(F[3] * F[8] - F[5] * F[6]) / det;
    inv[4] = (F[0] * F[8] - F[2] * F[6]) / det;
    inv[5] = -(F[0] * F[5] - F[2] * F[3]) / det;
    inv[6] = (F[3] * F[7] - F[4] * F[6]) / det;
    inv[7] = -(F[0] * F[7] - F[1] * F[6]) / det;
    inv[8] = (F[0] * F[4] - F[1] * F[3]) / det;
    for (int i = 0; i < 3; i++)
        dX[i] = inv[3 * i] * dx[0] + inv[3 * i + 1] * dx[1] + inv[3 * i + 2] * dx[2];
}

/// Area-weighted outward normal (current positions) of the boundary faces around v: a face of
/// an active tet whose neighbour across it is missing or removed. Zero for interior vertices.
static void surface_normal(const hs_cut* c, int v, double* nv) {
    nv[0] = nv[1] = nv[2] = 0.0;
    for (int p = c->nt_start[v]; p < c->nt_start[v + 1]; p++) {
        int e = c->nt[p];
        if (!c->active[e]) continue;
        const int* t = c->mesh->tets + 4 * e;
        for (int f = 0; f < 4; f++) {
            if (t[f] == v) continue; // face f omits local node f
            int o = c->fnbr[4 * e + f];
            if (o >= 0 && c->active[o]) continue;
            const double* q[3];
            int m = 0;
            for (int a = 0; a < 4; a++)
                if (a != f) q[m++] = c->x + 3 * t[a];
            double e1[3], e2[3], nn[3], away[3];
            v3_sub(q[1], q[0], e1);
            v3_sub(q[2], q[0], e2);
            v3_cross(e1, e2, nn);
            v3_sub(c->x + 3 * t[f], q[0], away);
            double s = v3_dot(nn, away) > 0 ? -1.0 : 1.0; // point away from the opposite node
            for (int d = 0; d < 3; d++) nv[d] += s * nn[d];
        }
    }
}

static void pin_node(hs_cut* c, int v) {
    if (c->pinned[v] || c->fixed[v]) return;
    c->pinned[v] = 1;
    c->pins[c->n_pins++] = v;
}

/// Deactivate tet e; counted = 1 when its nodes' counts were already decremented.
static void remove_tet(hs_cut* c, int e, int counted) {
    c->active[e] = 0;
    c->tmark[e] = 2;
    c->removed[c->n_removed++] = e;
    if (!counted)
        for (int a = 0; a < 4; a++) c->count[c->mesh->tets[4 * e + a]]--;
}

/// Free pieces. Tets sharing a face move as one rigid body in the kernel of K, so the pieces
/// are the face-connected sets of active tets (a piece hanging on by an edge or a vertex can
/// still rotate: K would be singular). A piece is held when its fixed (or pinned, with
/// pins_hold) nodes include three non-collinear ones. Labels them (union-find roots in tparent;
/// anch at a root: held) and returns the number not held.
static int find_pieces(hs_cut* c) {
    const int* T = c->mesh->tets;
    const double* x0 = c->mesh->x0;
    int* par = c->tparent;
    for (int e = 0; e < c->ne; e++) {
        par[e] = e;
        c->fa[e] = c->fb[e] = -1;
        c->anch[e] = 0;
    }
    for (int e = 0; e < c->ne; e++) {
        if (!c->active[e]) continue;
        for (int f = 0; f < 4; f++) {
            int o = c->fnbr[4 * e + f];
            if (o < 0 || !c->active[o]) continue;
            int r0 = find_root(par, e), r1 = find_root(par, o);
            if (r0 != r1) par[r1] = r0;
        }
    }
    for (int e = 0; e < c->ne; e++) {
        if (!c->active[e]) continue;
        int r = find_root(par, e);
        for (int a = 0; a < 4 && !c->anch[r]; a++) {
            int v = T[4 * e + a];
            if (!c->fixed[v] && !(c->pinned[v] && c->def.pins_hold)) continue;
            if (c->fa[r] < 0 || c->fa[r] == v) {
                c->fa[r] = v;
            } else if (c->fb[r] < 0 || c->fb[r] == v) {
                c->fb[r] = v;
            } else {
                double d1[3], d2[3], x[3];
                v3_sub(x0 + 3 * c->fb[r], x0 + 3 * c->fa[r], d1);
                v3_sub(x0 + 3 * v, x0 + 3 * c->fa[r], d2);
                v3_cross(d1, d2, x);
                if (v3_dot(x, x) > 1e-12 * v3_dot(d1, d1) * v3_dot(d2, d2)) c->anch[r] = 1;
            }
        }
    }
    int pieces = 0;
    for (int e = 0; e < c->ne; e++)
        if (c->active[e] && par[e] == e && !c->anch[e]) pieces++;
    return pieces;
}

/// 1 when the last removals cannot have freed a piece, found without visiting every tet. If
/// the active tets next to the removed ones are still face-connected among themselves, so is
/// their piece: a path that ran through removed tets goes round through those neighbours. And if
/// no removed tet held a fixed or pinned node, every piece keeps its hold (one that did may now
/// hold another piece, or, with no tets left, none).
/// Multi-source search from the neighbours, fronts merged by union-find; it stops when one
/// group is left, or gives up (0: run the full check) when a group runs out of tets to expand
/// (it is a piece of its own) or it has visited a quarter of the tets. Needs every piece held
/// before the sweep (a full check ran).
static int pieces_still_held(hs_cut* c, int* visited) {
    *visited = 0;
    if (!c->pieces_checked) return 0;
    const int* T = c->mesh->tets;
    for (int k = 0; k < c->n_removed; k++)
        for (int a = 0; a < 4; a++) {
            int v = T[4 * c->removed[k] + a];
            if (c->fixed[v] || c->pinned[v]) return 0;
        }
    if (++c->stamp == 0) { // wrapped: clear the marks once
        memset(c->tstamp, 0, sizeof(unsigned) * (size_t)c->ne);
        c->stamp = 1;
    }
    const unsigned st = c->stamp;
    int *grp = c->tparent, *queue = c->fa, *gpar = c->fb; // free between full checks
    int* open = c->gopen;
    int ng = 0;
    for (int k = 0; k < c->n_removed; k++)
        for (int f = 0; f < 4; f++) {
            int o = c->fnbr[4 * c->removed[k] + f];
            if (o < 0 || !c->active[o] || c->tstamp[o] == st) continue;
            c->tstamp[o] = st;
            grp[o] = ng;
            gpar[ng] = ng;
            open[ng] = 1;
            queue[ng++] = o;
        }
    int groups = ng, head = 0, tail = ng, budget = c->ne / 4;
    while (groups > 1 && head < tail) {
        int t = queue[head++], g = find_root(gpar, grp[t]);
        open[g]--;
        for (int f = 0; f < 4 && groups > 1; f++) {
            int o = c->fnbr[4 * t + f];
            if (o < 0 || !c->active[o]) continue;
            if (c->tstamp[o] != st) {
                if (tail >= budget) {
                    *visited = tail;
                    return 0;
                }
                c->tstamp[o] = st;
                grp[o] = g;
                open[g]++;
                queue[tail++] = o;
            } else {
                int h = find_root(gpar, grp[o]);
                if (h != g) {
                    gpar[h] = g;
                    open[g] += open[h];
                    groups--;
                }
            }
        }
        if (groups > 1 && open[g] == 0) { // g is closed: a piece apart from the others
            *visited = tail;
            return 0;
        }
    }
    *visited = tail;
    return groups <= 1;
}

/// Drop or pin (per def) the pieces the removals freed; returns their number. visited: see
/// hs_cut_result.piece_check_tets.
static int handle_fragments(hs_cut* c, int* visited) {
    if (pieces_still_held(c, visited)) return 0;
    const int* T = c->mesh->tets;
    int* par = c->tparent;
    int pieces = find_pieces(c);
    *visited += c->ne;
    c->pieces_checked = 1;
    if (!pieces) return 0;
    for (int e = 0; e < c->ne; e++) {
        if (!c->active[e] || c->anch[find_root(par, e)]) continue;
        if (c->def.fragment == HS_CUT_FRAGMENT_DROP)
            remove_tet(c, e, 0);
        else
            for (int a = 0; a < 4; a++) pin_node(c, T[4 * e + a]);
    }
    if (c->def.fragment == HS_CUT_FRAGMENT_DROP)
        for (int k = 0; k < c->n_removed; k++)
            for (int a = 0; a < 4; a++) {
                int v = T[4 * c->removed[k] + a];
                if (c->count[v] == 0) pin_node(c, v);
            }
    return pieces;
}

/// Append a block of the sweep's change: tet e's stiffness at rest positions x0 (zero if the
/// tet is degenerate there), or node v's pin spring when e < 0.
static void add_block(hs_cut* c, int* m, int e, int v, const double* x0) {
    double* dk = c->dk + 144 * (size_t)*m;
    int* ed = c->edof + 12 * (size_t)*m;
    memset(dk, 0, 144 * sizeof(double));
    if (e < 0) {
        for (int q = 0; q < 3; q++) dk[13 * q] = c->k_pin;
        for (int q = 0; q < 12; q++) ed[q] = q < 3 ? c->dof[3 * v + q] : -1;
        ++*m;
        return;
    }
    if (!element_k(c, x0, e, dk)) memset(dk, 0, 144 * sizeof(double));
    for (int a = 0; a < 4; a++)
        for (int q = 0; q < 3; q++) ed[3 * a + q] = c->dof[3 * c->mesh->tets[4 * e + a] + q];
    ++*m;
}

/// Free dofs touched by the sweep's blocks (a bound on the rank of its aggregated update).
static int union_dofs(hs_cut* c, int m) {
    int d = 0;
    for (int k = 0; k < 12 * m; k++) {
        int f = c->edof[k];
        if (f >= 0 && c->dpos[f] < 0) {
            c->dpos[f] = d;
            c->dset[d++] = f;
        }
    }
    for (int i = 0; i < d; i++) c->dpos[c->dset[i]] = -1;
    return d;
}

static hs_status update_compliance(hs_cut* c, int m, int before);

/// The factor follows K by partial refactors (PARTIAL, or AUTO where it chose them).
static int partial_policy(const hs_cut* c) {
    return c->def.factor_policy == HS_CUT_FACTOR_PARTIAL || c->auto_partial;
}

/// 1 if every free dof of the sweep's m blocks lies in the factor's window.
static int in_window(const hs_cut* c, int m) {
    for (int k = 0; k < 12 * m; k++)
        if (c->edof[k] >= 0 && !c->win[c->edof[k]]) return 0;
    return 1;
}

/// The window around the blade's sweep (p0, q0) -> (p1, q1): the free dofs of the nodes (current
/// positions c->x) within window_radius_m of the quad the blade (p1, q1) sweeps moving
/// window_ahead_m along its travel (the mean of p1 - p0 and q1 - q0). Writes mask[n_free], the
/// blade midpoint org and the unit travel dir.
static void choose_window(const hs_cut* c, const double* bl, unsigned char* mask, double* org,
                          double* dir) {
    const double *p0 = bl, *q0 = bl + 3, *p1 = bl + 6, *q1 = bl + 9;
    double v[3], p2[3], q2[3];
    for (int d = 0; d < 3; d++) v[d] = 0.5 * ((p1[d] - p0[d]) + (q1[d] - q0[d]));
    double len = sqrt(v3_dot(v, v));
    for (int d = 0; d < 3; d++) {
        dir[d] = len > 0 ? v[d] / len : 0.0;
        org[d] = 0.5 * (p1[d] + q1[d]);
        p2[d] = p1[d] + c->def.window_ahead_m * dir[d];
        q2[d] = q1[d] + c->def.window_ahead_m * dir[d];
    }
    const double r2 = c->def.window_radius_m * c->def.window_radius_m;
    memset(mask, 0, (size_t)c->n_free);
    for (int i = 0; i < c->n; i++) {
        if (c->dof[3 * i] < 0) continue;
        const double* xi = c->x + 3 * i;
        double a[3], b[3], da[3], db[3];
        closest_on_tri(xi, p1, q1, q2, a);
        closest_on_tri(xi, p1, q2, p2, b);
        v3_sub(xi, a, da);
        v3_sub(xi, b, db);
        if (fmin(v3_dot(da, da), v3_dot(db, db)) > r2) continue;
        for (int q = 0; q < 3; q++) mask[c->dof[3 * i + q]] = 1;
    }
}

/// Rebuild the factor of K as it is now, ordered with a new window around the blade last.
/// Keeps the old factor on failure.
static hs_status rewindow(hs_cut* c, const double* p0, const double* q0, const double* p1,
                          const double* q1, hs_err* err) {
    double bl[12];
    memcpy(bl, p0, 3 * sizeof(double));
    memcpy(bl + 3, q0, 3 * sizeof(double));
    memcpy(bl + 6, p1, 3 * sizeof(double));
    memcpy(bl + 9, q1, 3 * sizeof(double));
    choose_window(c, bl, c->win, c->win_org, c->win_dir);
    hs_cut_assemble(c, c->a);
    hs_cholesky* f = NULL;
    hs_status st = hs_cholesky_create_last(c->a, c->win, &f, err);
    if (st == HS_OK && c->def.factor_policy == HS_CUT_FACTOR_UPDATE)
        st = hs_cholesky_prepare_updates(f, c->cap_elem);
    if (st != HS_OK) {
        hs_cholesky_destroy(&f);
        return st;
    }
    hs_cholesky_destroy(&c->factor);
    c->factor = f;
    c->have_win = 1;
    c->updates_since_refactor = 0;
    return HS_OK;
}

/// Apply the sweep's m blocks to the factor (aggregated: one rank <= union update).
static hs_status apply_changes(hs_cut* c, int m) {
    return hs_cholesky_update_parts(c->factor, c->first_minus, m - c->first_minus, c->dk, c->edof);
}

// Largest union of a catch-up group (the sparse module aggregates up to 768).
#define HS_CUT_CATCHUP_D 360

/// Put free dof f into the union being counted (set/pos from position *d on); returns 1 if it
/// was new. The caller clears pos.
static int mark_dof(int* pos, int* set, int f, const int* d) {
    if (f < 0 || pos[f] >= 0) return 0;
    pos[f] = *d;
    set[*d] = f;
    return 1;
}

/// PARTIAL with a window: whether the sweep's dofs (c->dset[nd]; nd < 0: all of K) left the
/// window, and, while a window is being built, their union since its snapshot.
static void note_partial_window(hs_cut* c, int nd) {
    int out = nd < 0;
    for (int i = 0; i < nd && !out; i++) out = !c->win[c->dset[i]];
    c->win_stale = out;
    if (!c->bg_state) return;
    if (nd < 0) c->bg_all = 1;
    for (int i = 0; i < nd; i++) c->n_bgu += mark_dof(c->bg_pos, c->bg_set, c->dset[i], &c->n_bgu);
}

/// Append the sweep's m blocks to the record kept since hs_cut_window_begin.
static hs_status record_blocks(hs_cut* c, int m) {
    int np = c->first_minus, nm = m - c->first_minus;
    int need = (c->n_accp + np > c->n_accm + nm ? c->n_accp + np : c->n_accm + nm);
    if (need > c->cap_acc) {
        int cap = need > 2 * c->cap_acc ? need : 2 * c->cap_acc;
        double* k = hs_realloc(c->accp_k, sizeof(double) * 144 * (size_t)cap);
        if (!k) return HS_ERR_NOMEM;
        c->accp_k = k;
        k = hs_realloc(c->accm_k, sizeof(double) * 144 * (size_t)cap);
        if (!k) return HS_ERR_NOMEM;
        c->accm_k = k;
        int* d = hs_realloc(c->accp_d, sizeof(int) * 12 * (size_t)cap);
        if (!d) return HS_ERR_NOMEM;
        c->accp_d = d;
        d = hs_realloc(c->accm_d, sizeof(int) * 12 * (size_t)cap);
        if (!d) return HS_ERR_NOMEM;
        c->accm_d = d;
        c->cap_acc = cap;
    }
    if (c->n_accs == c->cap_accs) {
        int cap = c->cap_accs ? 2 * c->cap_accs : 64;
        int* a = hs_realloc(c->accs, sizeof(int) * 2 * (size_t)cap);
        if (!a) return HS_ERR_NOMEM;
        c->accs = a;
        c->cap_accs = cap;
    }
    c->accs[2 * c->n_accs] = c->n_accp;
    c->accs[2 * c->n_accs + 1] = c->n_accm;
    c->n_accs++;
    memcpy(c->accp_k + 144 * (size_t)c->n_accp, c->dk, sizeof(double) * 144 * (size_t)np);
    memcpy(c->accp_d + 12 * (size_t)c->n_accp, c->edof, sizeof(int) * 12 * (size_t)np);
    memcpy(c->accm_k + 144 * (size_t)c->n_accm, c->dk + 144 * (size_t)np,
           sizeof(double) * 144 * (size_t)nm);
    memcpy(c->accm_d + 12 * (size_t)c->n_accm, c->edof + 12 * (size_t)np,
           sizeof(int) * 12 * (size_t)nm);
    c->n_accp += np;
    c->n_accm += nm;
    return HS_OK;
}

int hs_cut_window_due(const hs_cut* c) {
    if (!c || !(c->def.window_radius_m > 0) || c->bg_state || !c->have_blade || c->win_off)
        return 0;
    // PARTIAL on a factor too small to be supernodal: no partial refactor (its sweeps
    // refactor, which is cheap there), so a window's build would fail. Never due.
    if (partial_policy(c) && !hs_cholesky_is_supernodal(c->factor)) return 0;
    if (c->win_stale) return 1;
    // Ahead of time: the blade has used up window_due_fraction of the window's reach along its
    // travel, or (PARTIAL) its midpoint has left the window's strip (or there is none yet),
    // e.g. moving to where the next cut starts: a window around it is then ready when it cuts
    // again. Not for the low-rank policies, whose builds are slower (measured: fewer windows
    // in time on plate5043).
    double mid[3], d[3];
    for (int k = 0; k < 3; k++) mid[k] = 0.5 * (c->blade[6 + k] + c->blade[9 + k]);
    v3_sub(mid, c->win_org, d);
    double along = v3_dot(d, c->win_dir);
    if (along > c->def.window_due_fraction * c->def.window_ahead_m) return 1;
    if (!partial_policy(c)) return 0;
    double side2 = v3_dot(d, d) - along * along, r = c->def.window_radius_m;
    return !c->have_win || along < -r || side2 > r * r;
}

static hs_status window_begin(hs_cut* c, hs_err* err) {
    if (!c || !(c->def.window_radius_m > 0) || !c->have_blade)
        return hs_err_set(err, HS_ERR_INVALID, "cut: no window radius set or no sweep yet");
    if (c->bg_state)
        return hs_err_set(err, HS_ERR_INVALID, "cut: a window rebuild is already under way");
    if (!c->bg_a) {
        hs_status st = hs_csc_clone(c->a, &c->bg_a);
        size_t nf = (size_t)c->n_free + 1;
        if (st == HS_OK && !c->bg_win && !(c->bg_win = hs_calloc(nf, 1))) st = HS_ERR_NOMEM;
        if (st == HS_OK && !c->bg_pos && !(c->bg_pos = hs_alloc(sizeof(int) * nf)))
            st = HS_ERR_NOMEM;
        if (st == HS_OK && !c->bg_set && !(c->bg_set = hs_alloc(sizeof(int) * nf)))
            st = HS_ERR_NOMEM;
        if (st == HS_OK && !c->has_lock) {
            if (pthread_mutex_init(&c->bg_lock, NULL) != 0) st = HS_ERR_NOMEM;
            c->has_lock = st == HS_OK;
        }
        if (st != HS_OK) {
            hs_csc_destroy(&c->bg_a); // retried in full next time
            return hs_err_set(err, st, "cut: window rebuild: out of memory");
        }
        for (int i = 0; i < c->n_free; i++) c->bg_pos[i] = -1;
    }
    // PARTIAL keeps K current in `a` (same pattern): copying it is ~5x cheaper than assembling.
    if (partial_policy(c) && !c->a_stale)
        memcpy(c->bg_a->val, c->a->val, sizeof(double) * (size_t)c->a->nnz);
    else
        hs_cut_assemble(c, c->bg_a);
    choose_window(c, c->blade, c->bg_win, c->bg_org, c->bg_dir);
    c->n_accp = c->n_accm = c->n_accs = 0;
    c->n_bgu = c->bg_all = 0;
    c->bg_applied = 0;
    c->bg_caught = HS_OK;
    c->acc_valid = 1;
    c->bg_status = HS_OK;
    c->bg_built = 0;
    c->bg_state = 1;
    return HS_OK;
}

/// Apply the recorded sweeps not yet in bg_f: consecutive sweeps merged while their union stays
/// within the aggregation limit, one aggregated update per group (inside the new window, so
/// short paths). Returns HS_ERR_UNSUPPORTED if the record is incomplete. The record is read
/// under the lock; the update runs outside it, so sweeps go on meanwhile.
static hs_status catch_up(hs_cut* c) {
    for (;;) {
        pthread_mutex_lock(&c->bg_lock);
        int s0 = c->bg_applied, ns = c->n_accs, valid = c->acc_valid;
        if (!valid || s0 == ns) {
            pthread_mutex_unlock(&c->bg_lock);
            return valid ? HS_OK : HS_ERR_UNSUPPORTED;
        }
        int d = 0, s1 = s0, marked = 0;
        for (; s1 < ns; s1++) {
            int p1 = s1 + 1 < ns ? c->accs[2 * s1 + 2] : c->n_accp;
            int m1 = s1 + 1 < ns ? c->accs[2 * s1 + 3] : c->n_accm;
            int d1 = d;
            for (int k = 12 * c->accs[2 * s1]; k < 12 * p1; k++)
                d1 += mark_dof(c->bg_pos, c->bg_set, c->accp_d[k], &d1);
            for (int k = 12 * c->accs[2 * s1 + 1]; k < 12 * m1; k++)
                d1 += mark_dof(c->bg_pos, c->bg_set, c->accm_d[k], &d1);
            marked = d1;
            if (d1 > HS_CUT_CATCHUP_D && s1 > s0) break;
            d = d1;
        }
        for (int i = 0; i < marked; i++) c->bg_pos[c->bg_set[i]] = -1;
        int pa = c->accs[2 * s0], ma = c->accs[2 * s0 + 1];
        int np = (s1 < ns ? c->accs[2 * s1] : c->n_accp) - pa;
        int nm = (s1 < ns ? c->accs[2 * s1 + 1] : c->n_accm) - ma;
        hs_status st = HS_OK;
        if (np + nm > c->bg_cap) {
            double* k = hs_realloc(c->bg_k, sizeof(double) * 144 * (size_t)(np + nm));
            if (k) c->bg_k = k;
            int* dd = k ? hs_realloc(c->bg_d, sizeof(int) * 12 * (size_t)(np + nm)) : NULL;
            if (dd) c->bg_d = dd;
            if (k && dd)
                c->bg_cap = np + nm;
            else
                st = HS_ERR_NOMEM;
        }
        if (st == HS_OK) {
            memcpy(c->bg_k, c->accp_k + 144 * (size_t)pa, sizeof(double) * 144 * (size_t)np);
            memcpy(c->bg_d, c->accp_d + 12 * (size_t)pa, sizeof(int) * 12 * (size_t)np);
            memcpy(c->bg_k + 144 * (size_t)np, c->accm_k + 144 * (size_t)ma,
                   sizeof(double) * 144 * (size_t)nm);
            memcpy(c->bg_d + 12 * (size_t)np, c->accm_d + 12 * (size_t)ma,
                   sizeof(int) * 12 * (size_t)nm);
        }
        pthread_mutex_unlock(&c->bg_lock);
        if (st == HS_OK) st = hs_cholesky_update_parts(c->bg_f, np, nm, c->bg_k, c->bg_d);
        if (st != HS_OK) return st;
        c->bg_applied = s1;
    }
}

static hs_status window_build(hs_cut* c, hs_err* err) {
    // bg_state is the deformation thread's: not read here (the caller orders the calls).
    if (!c || !c->bg_a)
        return hs_err_set(err, HS_ERR_INVALID, "cut: window build without hs_cut_window_begin");
    // Also frees the factor the last finish replaced, here rather than in the sweeps' thread.
    hs_cholesky_destroy(&c->bg_f);
    hs_status st;
    if (partial_policy(c)) {
        // Factored with its kept update matrices; the sweeps made meanwhile changed K in the
        // dofs finish refactors (a short path when they lie in the new window).
        st = hs_cholesky_create_last_partial(c->bg_a, c->bg_win, &c->bg_f, err);
        if (st == HS_OK && !hs_cholesky_is_supernodal(c->bg_f)) st = HS_ERR_UNSUPPORTED;
    } else {
        st = hs_cholesky_create_last(c->bg_a, c->bg_win, &c->bg_f, err);
        if (st == HS_OK) st = hs_cholesky_prepare_updates(c->bg_f, 0);
        // Catch up with the sweeps made meanwhile (a failure is finish's to handle).
        if (st == HS_OK) c->bg_caught = catch_up(c);
    }
    c->bg_status = st;
    c->bg_built = 1;
    return st;
}

static hs_status window_finish(hs_cut* c, int* swapped, hs_err* err) {
    if (swapped) *swapped = 0;
    if (!c || c->bg_state != 1 || !c->bg_built)
        return hs_err_set(err, HS_ERR_INVALID, "cut: window finish without begin and build");
    c->bg_state = 0;
    c->bg_built = 0;
    hs_status st = c->bg_status;
    if (st != HS_OK) {
        for (int i = 0; i < c->n_bgu; i++) c->bg_pos[c->bg_set[i]] = -1;
        c->n_bgu = c->bg_all = 0;
        hs_cholesky_destroy(&c->bg_f);
        return hs_err_set(err, st, "cut: window build failed: %s", hs_status_str(st));
    }
    if (partial_policy(c)) {
        // K itself is current (or reassembled here): refactor the dofs it changed in since
        // the snapshot.
        int all = c->bg_all || c->a_stale;
        if (c->a_stale) {
            hs_cut_assemble(c, c->a);
            c->a_stale = 0;
        }
        st = hs_cholesky_refactor_partial(c->bg_f, c->a, all ? -1 : c->n_bgu, c->bg_set);
        for (int i = 0; i < c->n_bgu; i++) c->bg_pos[c->bg_set[i]] = -1;
        c->n_bgu = c->bg_all = 0;
    } else {
        // The sweeps since the build caught up; a failed update there breaks bg_f's factor.
        st = c->bg_caught == HS_OK ? catch_up(c) : c->bg_caught;
    }
    if (st != HS_OK) { // unrecorded sweeps or a failed update: refactor the new factor
        hs_cut_assemble(c, c->a);
        st = hs_cholesky_refactor(c->bg_f, c->a);
    }
    if (st != HS_OK) {
        hs_cholesky_destroy(&c->bg_f);
        return hs_err_set(err, st, "cut: bringing the new window up to date failed: %s",
                          hs_status_str(st));
    }
    // The old factor goes to bg_f: the next build frees it (freeing ~100 MB of a large
    // factor's pages took milliseconds here).
    hs_cholesky* old = c->factor;
    c->factor = c->bg_f;
    c->bg_f = old;
    if (partial_policy(c)) (void)hs_cholesky_set_partial_threads(c->factor, factor_threads(c));
    memcpy(c->win, c->bg_win, (size_t)c->n_free);
    memcpy(c->win_org, c->bg_org, sizeof c->win_org);
    memcpy(c->win_dir, c->bg_dir, sizeof c->win_dir);
    c->win_stale = 0;
    c->have_win = 1;
    c->updates_since_refactor = 0;
    if (swapped) *swapped = 1;
    return HS_OK;
}

static hs_status refuse_own_thread(hs_err* err) {
    return hs_err_set(err, HS_ERR_INVALID,
                      "cut: the window is rebuilt by the cut's own thread "
                      "(window_thread)");
}

hs_status hs_cut_window_begin(hs_cut* c, hs_err* err) {
    if (c && c->def.window_thread) return refuse_own_thread(err);
    return window_begin(c, err);
}

hs_status hs_cut_window_build(hs_cut* c, hs_err* err) {
    if (c && c->def.window_thread) return refuse_own_thread(err);
    return window_build(c, err);
}

hs_status hs_cut_window_finish(hs_cut* c, hs_err* err) {
    if (c && c->def.window_thread) return refuse_own_thread(err);
    return window_finish(c, NULL, err);
}

static void* window_thread_main(void* arg) {
    hs_cut* c = arg;
    hs_err e;
    int64_t t0 = hs_now_ns();
    (void)window_build(c, &e); // its status reaches finish through bg_status
    c->wt_ms = (double)(hs_now_ns() - t0) * 1e-6;
    atomic_store_explicit(&c->wt_done, 1, memory_order_release);
    return NULL;
}

/// def.window_thread, after a sweep: swap in a finished build, then start one if due.
static void window_thread_step(hs_cut* c, int changed, hs_cut_result* r) {
    if (c->wt_running && atomic_load_explicit(&c->wt_done, memory_order_acquire)) {
        // PARTIAL: the swap refactors what K changed in since the snapshot, a few ms on top
        // of a changing sweep; in one that changed nothing it is the sweep's only cost.
        int wait = partial_policy(c) && changed && ++c->wt_waited < 5;
        if (!wait) {
            pthread_join(c->wt, NULL);
            c->wt_running = 0;
            c->wt_waited = 0;
            c->wt_ms_sum += c->wt_ms;
            hs_err e;
            int swapped = 0;
            if (window_finish(c, &swapped, &e) == HS_OK) {
                c->wstats.swapped += swapped;
                r->rewindowed = swapped;
            } else {
                c->wstats.failed++; // the sweeps go on with the factor they have
            }
        }
    }
    if (!c->wt_running && hs_cut_window_due(c)) {
        hs_err e;
        if (window_begin(c, &e) != HS_OK) return; // out of memory: tried again next sweep
        atomic_store_explicit(&c->wt_done, 0, memory_order_relaxed);
        if (pthread_create(&c->wt, NULL, window_thread_main, c) == 0) {
            c->wt_running = 1;
            c->wstats.builds++;
            r->window_started = 1;
        } else { // no thread: drop the snapshot (begin again next sweep)
            for (int i = 0; i < c->n_bgu; i++) c->bg_pos[c->bg_set[i]] = -1;
            c->n_bgu = c->bg_all = 0;
            c->bg_state = 0;
        }
    }
}

void hs_cut_window_stats_get(const hs_cut* c, hs_cut_window_stats* out) {
    if (!out) return;
    memset(out, 0, sizeof *out);
    if (!c) return;
    *out = c->wstats;
    out->running = c->wt_running;
    int ended = c->wstats.swapped + c->wstats.failed;
    out->build_ms = ended > 0 ? c->wt_ms_sum / ended : 0;
}

/// 1 when edge ab crosses the swept quad S = {p0, q0, q1, p1} (its two triangles), with a
/// tolerance relative to the edge's length. A crossing on the path of either blade end
/// (within 1e-9 of the edge's length) does not count: the blade ends there and only touches
/// the edge (a tip running exactly along a layer of vertices cut the tets below it).
static int edge_crosses(const double* xa, const double* xb, const double* const S[4]) {
    double d[3], x[3];
    v3_sub(xa, xb, d);
    double len = sqrt(v3_dot(d, d)), tol = 1e-6 * len;
    if (!seg_tri(xa, xb, S[0], S[1], S[2], tol, x) && !seg_tri(xa, xb, S[0], S[2], S[3], tol, x))
        return 0;
    return seg_dist(x, S[0], S[3]) > 1e-9 * len && seg_dist(x, S[1], S[2]) > 1e-9 * len;
}

/// The quad triangle (0 or 1) whose plane vertex v lies on, within tol, with its projection
/// inside the quad where the blade passed; -1 if none. On the quad's leading edge or on the
/// path of either blade end, the cut ends at v, so its tets on both sides do not make it a
/// hinge there, unless no tet of v reaches past that edge (the tissue ends there too).
static int blade_site(const hs_cut* c, int v, const double* const S[4], double tn[2][3],
                      double tol) {
    const double* xv = c->x + 3 * v;
    int tri = -1;
    double xp[3];
    for (int k = 0; k < 2 && tri < 0; k++) {
        const double* nk = tn[k];
        if (!(v3_dot(nk, nk) > 0)) continue; // a flat triangle (the blade turning about an end)
        const double* P[3] = {S[0], S[k + 1], S[k + 2]};
        double d[3];
        v3_sub(xv, P[0], d);
        double along = v3_dot(d, nk);
        if (fabs(along) > tol) continue;
        for (int q = 0; q < 3; q++) xp[q] = xv[q] - along * nk[q];
        int in = 1;
        for (int a = 0; a < 3 && in; a++) { // distance inside the edge opposite P[a]
            const double *b = P[(a + 1) % 3], *e = P[(a + 2) % 3];
            double be[3], bx[3], x[3];
            v3_sub(e, b, be);
            v3_sub(xp, b, bx);
            v3_cross(be, bx, x);
            double l = sqrt(v3_dot(be, be));
            in = !(l > 0) || v3_dot(x, nk) / l >= -tol;
        }
        if (in) tri = k;
    }
    if (tri < 0) return -1;
    // The leading edge p1q1 and the end paths p0p1, q0q1 (S = p0, q0, q1, p1).
    static const int k_end[3][2] = {{3, 2}, {0, 3}, {1, 2}};
    const double* nk = tn[tri];
    for (int s = 0; s < 3; s++) {
        const double *a = S[k_end[s][0]], *b = S[k_end[s][1]];
        if (seg_dist(xp, a, b) > tol) continue;
        // Inward, within the plane: from the edge towards the quad's centre.
        double d[3], u[3];
        v3_sub(b, a, d);
        for (int q = 0; q < 3; q++) u[q] = 0.25 * (S[0][q] + S[1][q] + S[2][q] + S[3][q]) - a[q];
        double un = v3_dot(u, nk), dd = v3_dot(d, d);
        for (int q = 0; q < 3; q++) u[q] -= un * nk[q];
        double ud = dd > 0 ? v3_dot(u, d) / dd : 0;
        for (int q = 0; q < 3; q++) u[q] -= ud * d[q];
        double ul = sqrt(v3_dot(u, u));
        if (!(ul > 0)) return -1;
        // The tissue in the blade's plane: where v's tets meet it (their vertices on it, their
        // edges' crossings). Their corners off the plane would project past a tilted blade's
        // end lying on a face, where the plane's section does not reach.
        for (int p = c->nt_start[v]; p < c->nt_start[v + 1]; p++) {
            int e = c->nt[p];
            if (!c->active[e] || c->tmark[e] != 0) continue;
            const int* t = c->mesh->tets + 4 * e;
            double sd[4], tl[4];
            for (int q = 0; q < 4; q++) {
                double w[3];
                v3_sub(c->x + 3 * t[q], S[0], w);
                sd[q] = v3_dot(w, nk);
                v3_sub(c->x + 3 * t[q], xv, w);
                tl[q] = 1e-6 * sqrt(v3_dot(w, w));
            }
            for (int q = 0; q < 4; q++)
                for (int r = q; r < 4; r++) {
                    double x[3], aw[3], vw[3];
                    if (r == q) { // a vertex on the plane
                        if (fabs(sd[q]) > tl[q] + tol) continue;
                        memcpy(x, c->x + 3 * t[q], sizeof x);
                    } else { // an edge crossing it
                        if (!(sd[q] * sd[r] < 0)) continue;
                        const double *xa = c->x + 3 * t[q], *xb = c->x + 3 * t[r];
                        double f = sd[q] / (sd[q] - sd[r]);
                        for (int k = 0; k < 3; k++) x[k] = xa[k] + f * (xb[k] - xa[k]);
                    }
                    v3_sub(x, a, aw);
                    v3_sub(x, xv, vw);
                    if (v3_dot(aw, u) / ul < -1e-6 * sqrt(v3_dot(vw, vw)) - tol) return -1;
                }
        }
    }
    return tri;
}

/// Which side of the plane (point o, unit normal nk) tet e lies on at its vertex v, which is on
/// the plane: 0 (+), 1 (-), -1 for both or neither. A vertex counts on a side beyond 1e-6 of its
/// edge to v, the tolerance of the crossing test.
static int tet_side(const hs_cut* c, int e, int v, const double* o, const double* nk) {
    const int* t = c->mesh->tets + 4 * e;
    int pos = 0, neg = 0;
    for (int a = 0; a < 4; a++) {
        if (t[a] == v) continue;
        const double* xw = c->x + 3 * t[a];
        double d[3], l[3];
        v3_sub(xw, o, d);
        v3_sub(xw, c->x + 3 * v, l);
        double s = v3_dot(d, nk), tol = 1e-6 * sqrt(v3_dot(l, l));
        pos |= s > tol;
        neg |= s < -tol;
    }
    return pos && !neg ? 0 : neg && !pos ? 1 : -1;
}

/// Marks tet e to go this sweep (2), its nodes' counts taken now so later tets of the sweep see
/// the orphan risk; 0 (nothing changed) when ORPHAN_KEEP_TET keeps it because a node would be
/// left without a tet.
static int take_tet(hs_cut* c, int e) {
    const int* t = c->mesh->tets + 4 * e;
    int orphan = 0;
    for (int a = 0; a < 4; a++) orphan |= c->count[t[a]] == 1;
    if (orphan && c->def.orphan == HS_CUT_ORPHAN_KEEP_TET) return 0;
    for (int a = 0; a < 4; a++) c->count[t[a]]--;
    c->tmark[e] = 2;
    return 1;
}

hs_status hs_cut_sweep(hs_cut* c, const double p0[3], const double q0[3], const double p1[3],
                       const double q1[3], double* u, hs_cut_result* res, hs_err* err) {
    hs_cut_result r;
    memset(&r, 0, sizeof r);
    int64_t t0 = hs_now_ns();
    if (!c || !p0 || !q0 || !p1 || !q1)
        return hs_err_set(err, HS_ERR_INVALID, "cut: NULL argument to hs_cut_sweep");
    const double* S[4] = {p0, q0, q1, p1};
    for (int k = 0; k < 4; k++)
        for (int d = 0; d < 3; d++)
            if (!isfinite(S[k][d]) || fabs(S[k][d]) > 1e6)
                return hs_err_set(err, HS_ERR_INVALID, "cut: blade point %d coordinate %d is %g", k,
                                  d, S[k][d]);
    if (c->factor && c->factor_stale) {
        r.refactored = 1;
        hs_status fs = hs_cut_refactor(c);
        if (fs == HS_OK && c->n_track > 0) fs = update_compliance(c, 0, 0);
        if (fs != HS_OK)
            return hs_err_set(err, fs, "cut: rebuilding the factor a failed sweep left: %s",
                              hs_status_str(fs));
        c->factor_stale = 0;
    }
    const int n = c->n, ne = c->ne;
    double* x0 = c->mesh->x0;
    const int* T = c->mesh->tets;
    for (int k = 0; k < 3 * n; k++) {
        c->x[k] = x0[k] + (u ? u[k] : 0.0);
        if (!isfinite(c->x[k]))
            return hs_err_set(err, HS_ERR_INVALID, "cut: displacement of node %d is not finite",
                              k / 3);
    }
    c->n_removed = c->n_moved = c->n_changed = c->n_pins = 0;

    // 1. Crossing test against the two triangles of the swept quad.
    double lo[3], hi[3];
    for (int d = 0; d < 3; d++) {
        lo[d] = fmin(fmin(p0[d], q0[d]), fmin(p1[d], q1[d]));
        hi[d] = fmax(fmax(p0[d], q0[d]), fmax(p1[d], q1[d]));
    }
    static const int k_edge[6][2] = {{0, 1}, {0, 2}, {0, 3}, {1, 2}, {1, 3}, {2, 3}};
    double tn[2][3]; // unit normals of the quad's triangles (zero when degenerate)
    unit_normal(p0, q0, q1, tn[0]);
    unit_normal(p0, q1, p1, tn[1]);
    int n_cut = 0, n_edges = 0, n_onb = 0;
    for (int e = 0; e < ne; e++) {
        if (!c->active[e]) continue;
        const int* t = T + 4 * e;
        // Plain comparisons, not fmin/fmax (library calls here; x is finite): this loop
        // visits every tet of the mesh each sweep.
        double tl[3], th[3];
        for (int d = 0; d < 3; d++) {
            tl[d] = th[d] = c->x[3 * t[0] + d];
            for (int a = 1; a < 4; a++) {
                double v = c->x[3 * t[a] + d];
                tl[d] = v < tl[d] ? v : tl[d];
                th[d] = v > th[d] ? v : th[d];
            }
        }
        if (tl[0] > hi[0] || th[0] < lo[0] || tl[1] > hi[1] || th[1] < lo[1] || tl[2] > hi[2] ||
            th[2] < lo[2])
            continue;
        // Vertices near the blade's plane (within 1e-6 of this tet's size, a bound on their
        // own tolerance below): checked for hinges in 3c.
        double ext = (th[0] - tl[0]) + (th[1] - tl[1]) + (th[2] - tl[2]);
        for (int a = 0; a < 4; a++) {
            int v = t[a];
            if (c->nmark[v]) continue;
            double d[3];
            v3_sub(c->x + 3 * v, p0, d);
            int near = 0; // a flat triangle's zero normal would let every vertex in
            for (int tri = 0; tri < 2; tri++)
                near |= v3_dot(tn[tri], tn[tri]) > 0 && fabs(v3_dot(d, tn[tri])) <= 1e-6 * ext;
            if (near) {
                c->nmark[v] = 1;
                c->onb[n_onb++] = v;
            }
        }
        int hit = 0;
        for (int k = 0; k < 6; k++) {
            int a = t[k_edge[k][0]], b = t[k_edge[k][1]];
            if (edge_crosses(c->x + 3 * a, c->x + 3 * b, S)) {
                hit = 1;
                c->edges[2 * n_edges] = a < b ? a : b;
                c->edges[2 * n_edges + 1] = a < b ? b : a;
                n_edges++;
            }
        }
        if (hit) {
            c->tmark[e] = 1;
            c->cut_list[n_cut++] = e;
        }
    }
    for (int k = 0; k < n_onb; k++) c->nmark[c->onb[k]] = 0;
    r.cut_tets = n_cut;
    if (n_edges > 0) {
        qsort(c->edges, (size_t)n_edges, 2 * sizeof(int), cmp_edge);
        for (int k = 0; k < n_edges; k++) {
            if (k > 0 && c->edges[2 * k] == c->edges[2 * k - 2] &&
                c->edges[2 * k + 1] == c->edges[2 * k - 1])
                continue;
            double d[3];
            v3_sub(c->x + 3 * c->edges[2 * k], c->x + 3 * c->edges[2 * k + 1], d);
            r.cut_length_m += sqrt(v3_dot(d, d));
        }
    }

    // 2. Removal set with the orphan rule (counts are decremented as tets go).
    for (int k = 0; k < n_cut; k++) {
        int e = c->cut_list[k];
        // The move step below ignores tets marked 2 (going); step 4 deactivates them.
        if (!take_tet(c, e)) {
            c->tmark[e] = 0;
            r.kept++;
        }
    }

    // 3. Vertex moves onto the swept surface (vertices of tets being removed).
    int n_cand = 0;
    for (int k = 0; k < n_cut; k++) {
        int e = c->cut_list[k];
        if (c->tmark[e] != 2) continue;
        for (int a = 0; a < 4; a++) {
            int v = T[4 * e + a];
            if (c->nmark[v] || c->fixed[v] || c->pinned[v]) continue;
            c->nmark[v] = 1;
            c->moved[n_cand++] = v;
        }
    }
    // Surface normals before this sweep's removals (tets marked 2 are still active here).
    if (c->def.tangent_surface)
        for (int k = 0; k < n_cand; k++) surface_normal(c, c->moved[k], c->nrm + 3 * c->moved[k]);
    int n_moved = 0;
    for (int k = 0; k < n_cand; k++) {
        int v = c->moved[k];
        c->nmark[v] = 0;
        double* xv = c->x + 3 * v;
        // Onto the quad's plane where the vertex's projection falls inside one of its
        // triangles (the nearer if both). A projection outside the quad (a vertex ahead of
        // the blade, or beyond its ends) has its closest point on the quad's edge, and going
        // there dragged the vertex along the cut, stretching tets that later sweeps cut and
        // moved again. Such a vertex stays (its tet still goes); the blade moves it when it
        // gets there. Not onto the plane either: its uncut tets would then have no edge
        // across the blade and would stay, joining the two sides.
        const double h2 = shortest_edge2(c, v);
        double dx[3], best = INFINITY;
        for (int tri = 0; tri < 2; tri++) {
            const double* nk = tn[tri];
            if (!(v3_dot(nk, nk) > 0)) continue;
            double cp[3], d[3];
            closest_on_tri(xv, p0, tri ? q1 : q0, tri ? p1 : q1, cp);
            v3_sub(cp, xv, d);
            double along = v3_dot(d, nk), side[3];
            for (int q = 0; q < 3; q++) side[q] = d[q] - along * nk[q];
            if (v3_dot(side, side) > 1e-12 * h2 || !(v3_dot(d, d) < best)) continue;
            best = v3_dot(d, d);
            memcpy(dx, d, sizeof dx);
        }
        if (best == INFINITY) continue;
        if (c->def.tangent_surface) {
            double* nv = c->nrm + 3 * v;
            double nn = v3_dot(nv, nv);
            if (nn > 0) {
                double s = v3_dot(dx, nv) / nn;
                for (int d = 0; d < 3; d++) dx[d] -= s * nv[d];
            }
        }
        if (!(v3_dot(dx, dx) > 0)) continue;
        double dX[3];
        if (u)
            to_rest(c, v, dx, dX);
        else
            memcpy(dX, dx, sizeof dX);
        double s = 1.0, Xt[3], xt[3];
        int ok = 0;
        for (int b = 0; b <= c->def.max_bisections; b++, s *= 0.5) {
            for (int d = 0; d < 3; d++) {
                Xt[d] = x0[3 * v + d] + s * dX[d];
                xt[d] = xv[d] + s * dx[d];
            }
            if (move_ok(c, v, Xt, xt)) {
                ok = 1;
                break;
            }
        }
        if (!ok || s < 1.0) r.clamped++;
        if (!ok) continue;
        for (int d = 0; d < 3; d++) {
            if (u) u[3 * v + d] += s * (dx[d] - dX[d]);
            x0[3 * v + d] = Xt[d];
            c->live->x0[3 * v + d] = Xt[d];
            xv[d] = xt[d];
        }
        c->moved[n_moved++] = v;
    }
    c->n_moved = r.moved = n_moved;

    // 3b. A move can leave a vertex a hair across the blade's plane (the tangent-plane rule, a
    // clamped move): its other tets then cross the swept quad, and no later sweep comes back
    // here. They go now, as they are (no further moves: nothing cascades). Without this, fine
    // sweeps left hundreds of such tets bridging a cut across the skin patch.
    for (int k = 0; k < n_moved; k++) {
        int v = c->moved[k];
        for (int p = c->nt_start[v]; p < c->nt_start[v + 1]; p++) {
            int e = c->nt[p];
            if (!c->active[e] || c->tmark[e] != 0) continue;
            const int* t = T + 4 * e;
            int hit = 0;
            for (int q = 0; q < 6 && !hit; q++)
                hit = edge_crosses(c->x + 3 * t[k_edge[q][0]], c->x + 3 * t[k_edge[q][1]], S);
            if (!hit) continue;
            if (!take_tet(c, e)) {
                int seen = 0; // counted already from an earlier moved vertex of e
                for (int j = 0; j < k && !seen; j++)
                    for (int a = 0; a < 4; a++) seen |= t[a] == c->moved[j];
                if (!seen) r.kept++;
                continue;
            }
            c->cut_list[n_cut++] = e;
            r.cut_tets++;
        }
    }

    // 3c. Hinges. A vertex on the blade's plane (moved there, or lying there) where the blade
    // passed, with tets left on both sides, would keep the sides joined: no edge from it counts
    // as crossing, and its tets on the far side touch the blade only at it (with 0.2 mm sweeps
    // the skin patch's cut stayed in one piece). The smaller side's tets there go, as they are.
    for (int k = 0; k < n_onb; k++) c->nmark[c->onb[k]] = 1; // once each: n_onb <= n
    for (int k = 0; k < n_moved; k++) {
        int v = c->moved[k];
        if (!c->nmark[v]) c->onb[n_onb++] = v;
        c->nmark[v] = 1;
    }
    for (int k = 0; k < n_onb; k++) {
        int v = c->onb[k];
        c->nmark[v] = 0;
        if (c->fixed[v] || c->pinned[v]) continue;
        double h2 = shortest_edge2(c, v);
        int tri = isfinite(h2) ? blade_site(c, v, S, tn, 1e-6 * sqrt(h2)) : -1;
        if (tri < 0) continue;
        double vol[2] = {0, 0};
        for (int p = c->nt_start[v]; p < c->nt_start[v + 1]; p++) {
            int e = c->nt[p], side;
            if (c->active[e] && c->tmark[e] == 0 && (side = tet_side(c, e, v, p0, tn[tri])) >= 0)
                vol[side] += c->vol_orig[e];
        }
        if (!(vol[0] > 0 && vol[1] > 0)) continue;
        const int drop = vol[0] < vol[1] ? 0 : 1;
        int went = 0; // ORPHAN_KEEP_TET may keep them all (not counted in `kept`: not cut tets)
        for (int p = c->nt_start[v]; p < c->nt_start[v + 1]; p++) {
            int e = c->nt[p];
            if (!c->active[e] || c->tmark[e] != 0 || tet_side(c, e, v, p0, tn[tri]) != drop)
                continue;
            if (!take_tet(c, e)) continue;
            c->cut_list[n_cut++] = e;
            r.cut_tets++;
            went = 1;
        }
        r.hinges += went;
    }

    // 4. Remove, then orphans (PIN rule) and free pieces.
    for (int k = 0; k < n_cut; k++) {
        int e = c->cut_list[k];
        if (c->tmark[e] == 2) remove_tet(c, e, 1);
    }
    for (int k = 0; k < c->n_removed; k++)
        for (int a = 0; a < 4; a++) {
            int v = T[4 * c->removed[k] + a];
            if (c->count[v] == 0) pin_node(c, v);
        }
    if (c->n_removed > 0) // moves never disconnect
        r.fragments = handle_fragments(c, &r.piece_check_tets);
    r.removed = c->n_removed;
    r.pinned = c->n_pins;
    r.geometry_ms = (double)(hs_now_ns() - t0) * 1e-6;
    const int mesh_changed = c->n_removed > 0 || n_moved > 0;
    if (mesh_changed) { // whatever fails below, the mesh did change
        c->version++;
        c->live_dirty = 1;
    }
    int factor_done = 0;

    // 5. Element changes: removed tets, remaining tets around moved vertices, pins.
    int64_t t1 = hs_now_ns();
    for (int k = 0; k < n_moved; k++) {
        int v = c->moved[k];
        for (int p = c->nt_start[v]; p < c->nt_start[v + 1]; p++) {
            int e = c->nt[p];
            if (!c->active[e] || c->tmark[e] == 3) continue;
            c->tmark[e] = 3;
            c->changed[c->n_changed++] = e;
        }
    }
    // PARTIAL keeps K itself current: the old shares out before the elements change.
    int partial = c->factor && (c->def.factor_policy == HS_CUT_FACTOR_PARTIAL || c->auto_partial);
    int a_current =
        partial && !c->a_stale &&
        hs_fem_add_rest_elements(c->fem, c->n_removed, c->removed, 1, 0, -1, c->a) == HS_OK &&
        hs_fem_add_rest_elements(c->fem, c->n_changed, c->changed, 1, 0, -1, c->a) == HS_OK;
    for (int k = 0; k < c->n_removed; k++) hs_fem_set_element_active(c->fem, c->removed[k], 0);
    hs_status st = hs_fem_refresh_elements(c->fem, c->changed, c->n_changed);
    if (st != HS_OK) {
        c->a_stale |= a_current; // the old shares are out of `a` already
        hs_err_set(err, st, "cut: refreshing %d elements failed", c->n_changed);
        goto done;
    }
    if (a_current)
        a_current =
            hs_fem_add_rest_elements(c->fem, c->n_changed, c->changed, 1, 0, 1, c->a) == HS_OK;
    if (a_current) add_pins(c, c->a);
    int need = c->n_removed + c->n_changed + c->n_pins, m = 0;
    int blocks = c->n_removed + 2 * c->n_changed + c->n_pins;
    // AUTO: the aggregated update costs about one sparse pass along the elimination tree per
    // unit of rank, and its rank is about the number of free dofs the change touches; a
    // numeric refactor costs a fixed amount. Both are measured as the cut runs: take the
    // cheaper. Until an update has been timed, one rank costs 1/96 of a refactor (measured:
    // 1/77 at 432 vertices, 1/108 at 5,043; docs/cutting.md).
    int can_update = c->factor && c->def.factor_policy != HS_CUT_FACTOR_REFACTOR && !partial &&
                     need > 0 && grow_elems(c, blocks) == HS_OK;
    if (can_update) {
        for (int k = 0; k < c->n_changed; k++) add_block(c, &m, c->changed[k], -1, x0);
        for (int k = 0; k < c->n_pins; k++) add_block(c, &m, -1, c->pins[k], NULL);
        c->first_minus = m;
        for (int k = 0; k < c->n_removed; k++) add_block(c, &m, c->removed[k], -1, c->x0_old);
        for (int k = 0; k < c->n_changed; k++) add_block(c, &m, c->changed[k], -1, c->x0_old);
    }
    // A change reaching outside the update window gets a factor with a new window instead.
    int outside = can_update && c->def.window_radius_m > 0 && !in_window(c, m);
    c->win_stale = outside;
    // In background mode the change still updates the current factor (longer paths) and the
    // caller rebuilds the window off the critical path (hs_cut_window_begin).
    int new_window = outside && !c->def.window_background;
    if (new_window) can_update = 0;
    if (c->bg_state && !partial) { // record the change for the window being built
        pthread_mutex_lock(&c->bg_lock);
        if (m == 0 && need > 0)
            c->acc_valid = 0;
        else if (m > 0 && record_blocks(c, m) != HS_OK)
            c->acc_valid = 0;
        pthread_mutex_unlock(&c->bg_lock);
    }
    if (can_update && c->def.factor_policy == HS_CUT_FACTOR_AUTO) {
        double per = c->update_ms_per_rank > 0 ? c->update_ms_per_rank : c->refactor_ms / 96.0;
        can_update = union_dofs(c, m) * per < c->refactor_ms;
    }
    r.changed_elements = need;
    if (can_update && c->n_track > 0 && m > 0 && c->cmode == HS_CUT_COMPLIANCE_WOODBURY) {
        st = update_compliance(c, m, 1);
        if (st != HS_OK) {
            hs_err_set(err, st, "cut: compliance update failed");
            goto done;
        }
    }
    if (need > 0 && partial) {
        int nd = a_current ? partial_dofs(c) : -1;
        if (c->def.window_radius_m > 0) note_partial_window(c, nd);
        if (a_current) {
            st = hs_cholesky_refactor_partial(c->factor, c->a, nd, c->dset);
        } else {
            hs_cut_assemble(c, c->a);
            c->a_stale = 0;
            st = hs_cholesky_refactor_partial(c->factor, c->a, -1, NULL);
        }
        if (st != HS_OK) { // no partial data (simplicial), or a singular K: refactor in full
            r.refactored = 1;
            st = hs_cut_refactor(c);
            if (st != HS_OK) {
                hs_err_set(err, st, "cut: refactorising K after the cut failed: %s",
                           hs_status_str(st));
                goto done;
            }
        }
        if (c->n_track > 0) {
            st = update_compliance(c, 0, 0);
            if (st != HS_OK) {
                hs_err_set(err, st, "cut: compliance update failed");
                goto done;
            }
        }
    } else if (need > 0 && c->factor) {
        // Entering update mode converts the factor once (allocates): not part of the timing.
        st = can_update ? hs_cholesky_prepare_updates(c->factor, blocks) : HS_ERR_UNSUPPORTED;
        int64_t tu = hs_now_ns();
        if (st == HS_OK) st = apply_changes(c, m);
        if (st == HS_OK) {
            c->updates_since_refactor++;
            hs_cholesky_update_info ui;
            hs_cholesky_last_update(c->factor, &ui);
            double took = (double)(hs_now_ns() - tu) * 1e-6 / (ui.rank > 0 ? ui.rank : 1);
            c->update_ms_per_rank =
                c->update_ms_per_rank > 0 ? 0.8 * c->update_ms_per_rank + 0.2 * took : took;
        } else {
            // Updates off, no memory for them, or a downdate lost definiteness: rebuild.
            r.refactored = 1;
            r.rewindowed = new_window;
            int64_t tr = hs_now_ns();
            st = new_window ? rewindow(c, p0, q0, p1, q1, err) : hs_cut_refactor(c);
            if (!new_window)
                c->refactor_ms = 0.8 * c->refactor_ms + 0.2 * (double)(hs_now_ns() - tr) * 1e-6;
            if (st != HS_OK) {
                hs_err_set(err, st, "cut: refactorising K after the cut failed: %s",
                           hs_status_str(st));
                goto done;
            }
            if (c->n_track > 0 && c->cmode == HS_CUT_COMPLIANCE_WOODBURY) {
                st = update_compliance(c, 0, 0);
                if (st != HS_OK) goto done;
            }
        }
    }
    if (c->n_track > 0 && need > 0 && c->cmode == HS_CUT_COMPLIANCE_RESOLVE && !partial) {
        st = update_compliance(c, m, 0);
        if (st != HS_OK) {
            hs_err_set(err, st, "cut: compliance update failed");
            goto done;
        }
    }
    r.factor_ms = (double)(hs_now_ns() - t1) * 1e-6;
    factor_done = 1;

    // 6. Checks (the live mesh is rebuilt here only when validating, else on first use).
    int64_t t2 = hs_now_ns();
    if (mesh_changed && c->def.validate) st = hs_cut_validate(c, err);
    r.mesh_ms = (double)(hs_now_ns() - t2) * 1e-6;
done:
    // A failure in step 5 can leave the factor (and tracked blocks) without this change.
    if (st != HS_OK && !factor_done && mesh_changed && c->factor) c->factor_stale = 1;
    memcpy(c->blade, p0, 3 * sizeof(double));
    memcpy(c->blade + 3, q0, 3 * sizeof(double));
    memcpy(c->blade + 6, p1, 3 * sizeof(double));
    memcpy(c->blade + 9, q1, 3 * sizeof(double));
    c->have_blade = 1;
    for (int k = 0; k < n_cut; k++) c->tmark[c->cut_list[k]] = 0;
    for (int k = 0; k < c->n_removed; k++) c->tmark[c->removed[k]] = 0;
    for (int k = 0; k < c->n_changed; k++) c->tmark[c->changed[k]] = 0;
    for (int k = 0; k < n_moved; k++)
        memcpy(c->x0_old + 3 * c->moved[k], x0 + 3 * c->moved[k], 3 * sizeof(double));
    if (st == HS_OK && c->def.window_thread) window_thread_step(c, r.changed_elements > 0, &r);
    r.topology_version = c->version;
    r.total_ms = (double)(hs_now_ns() - t0) * 1e-6;
    if (res) *res = r;
    return st;
}

// ---------------------------------------------------------------------------------------------
// Compliance blocks

static hs_status grow_d(hs_cut* c, int d) {
    if (d <= c->cap_d) return HS_OK;
    int cap = d > 2 * c->cap_d ? d : 2 * c->cap_d;
    size_t dd = (size_t)cap * (size_t)cap, td = 3 * (size_t)c->n_track * (size_t)cap;
    double* a = hs_realloc(c->zd, sizeof(double) * dd);
    if (!a) return HS_ERR_NOMEM;
    c->zd = a;
    a = hs_realloc(c->kdd, sizeof(double) * dd);
    if (!a) return HS_ERR_NOMEM;
    c->kdd = a;
    a = hs_realloc(c->wrk, sizeof(double) * dd);
    if (!a) return HS_ERR_NOMEM;
    c->wrk = a;
    a = hs_realloc(c->zt, sizeof(double) * (td + 1));
    if (!a) return HS_ERR_NOMEM;
    c->zt = a;
    int* p = hs_realloc(c->piv, sizeof(int) * (size_t)cap);
    if (!p) return HS_ERR_NOMEM;
    c->piv = p;
    c->cap_d = cap;
    return HS_OK;
}

/// Re-solve the blocks of tracked nodes [k0, k0 + cnt) with the current factor.
// Tracked blocks k0 .. k0+cnt-1 from the current factor: one sparse forward solve per node
// along its elimination-tree paths (hs_cholesky_inverse_diag3), not three full solves.
static hs_status resolve_blocks(hs_cut* c, int k0, int cnt) {
    int* dl = hs_alloc(3 * (size_t)cnt * sizeof(int) + sizeof(int));
    if (!dl) return HS_ERR_NOMEM;
    for (int j = 0; j < cnt; j++) {
        int v = c->track[k0 + j];
        for (int q = 0; q < 3; q++) dl[3 * j + q] = c->pinned[v] ? -1 : c->dof[3 * v + q];
    }
    hs_status st = hs_cholesky_inverse_diag3(c->factor, cnt, dl, c->cblk + 9 * (size_t)k0);
    hs_free(dl);
    return st;
}

hs_status hs_cut_track_compliance(hs_cut* c, int n, const int* nodes, hs_cut_compliance_mode mode) {
    if (!c || !c->factor || n < 0 || (n > 0 && !nodes)) return HS_ERR_INVALID;
    // An unknown mode would match neither update and leave the blocks stale without a word.
    if (mode != HS_CUT_COMPLIANCE_WOODBURY && mode != HS_CUT_COMPLIANCE_RESOLVE)
        return HS_ERR_INVALID;
    for (int k = 0; k < n; k++)
        if (nodes[k] < 0 || nodes[k] >= c->n) return HS_ERR_INVALID;
    hs_free(c->track);
    hs_free(c->cblk);
    c->track = NULL;
    c->cblk = NULL;
    c->n_track = 0;
    c->cmode = mode;
    if (n == 0) return HS_OK;
    c->track = hs_alloc(sizeof(int) * (size_t)n);
    c->cblk = hs_alloc(sizeof(double) * 9 * (size_t)n);
    if (!c->zbuf) c->zbuf = hs_alloc(sizeof(double) * (size_t)c->n_free * HS_CUT_BATCH);
    if (!c->track || !c->cblk || !c->dset || !c->dpos || !c->zbuf) return HS_ERR_NOMEM;
    memcpy(c->track, nodes, sizeof(int) * (size_t)n);
    c->n_track = n; // resolve_blocks reads it
    c->cap_d = 0;   // zt depends on n_track: regrow
    hs_free(c->zd);
    hs_free(c->zt);
    hs_free(c->kdd);
    hs_free(c->wrk);
    hs_free(c->piv);
    c->zd = c->zt = c->kdd = c->wrk = NULL;
    c->piv = NULL;
    int64_t t0 = hs_now_ns();
    hs_status st = resolve_blocks(c, 0, n);
    c->cms = (double)(hs_now_ns() - t0) * 1e-6;
    if (st != HS_OK) c->n_track = 0; // the blocks were not computed: track nothing
    return st;
}

void hs_cut_compliance_block(const hs_cut* c, int k, double out[9]) {
    HS_ASSERT(k >= 0 && k < c->n_track);
    memcpy(out, c->cblk + 9 * (size_t)k, 9 * sizeof(double));
}

double hs_cut_compliance_ms(const hs_cut* c) {
    return c->cms;
}

/// Dense LU with partial pivoting of a (d x d, row-major, in place); 0 if singular.
static int lu_factor(int d, double* a, int* piv) {
    for (int k = 0; k < d; k++) {
        int p = k;
        for (int i = k + 1; i < d; i++)
            if (fabs(a[(size_t)i * d + k]) > fabs(a[(size_t)p * d + k])) p = i;
        piv[k] = p;
        if (a[(size_t)p * d + k] == 0.0) return 0;
        if (p != k)
            for (int j = 0; j < d; j++) {
                double t = a[(size_t)k * d + j];
                a[(size_t)k * d + j] = a[(size_t)p * d + j];
                a[(size_t)p * d + j] = t;
            }
        double inv = 1.0 / a[(size_t)k * d + k];
        for (int i = k + 1; i < d; i++) {
            double l = a[(size_t)i * d + k] *= inv;
            if (l == 0.0) continue;
            for (int j = k + 1; j < d; j++) a[(size_t)i * d + j] -= l * a[(size_t)k * d + j];
        }
    }
    return 1;
}

/// Solve with lu_factor's output for one right-hand side b (in place).
static void lu_solve(int d, const double* a, const int* piv, double* b) {
    for (int k = 0; k < d; k++) {
        double t = b[piv[k]];
        b[piv[k]] = b[k];
        b[k] = t;
    }
    for (int i = 1; i < d; i++) {
        double s = b[i];
        for (int j = 0; j < i; j++) s -= a[(size_t)i * d + j] * b[j];
        b[i] = s;
    }
    for (int i = d - 1; i >= 0; i--) {
        double s = b[i];
        for (int j = i + 1; j < d; j++) s -= a[(size_t)i * d + j] * b[j];
        b[i] = s / a[(size_t)i * d + i];
    }
}

// Woodbury (before = 1, the factor still holds the old K): with D the free dofs the m element
// changes touch, dK = E_D dK_DD E_D^T and Z = K^-1 E_D,
//   C' = C - Z (I + dK_DD Z_D)^-1 dK_DD Z^T,
// so each tracked block needs only its 3 rows of Z. Re-solve (before = 0): every block again.
static hs_status update_compliance(hs_cut* c, int m, int before) {
    int64_t t0 = hs_now_ns();
    if (!before) {
        hs_status st = resolve_blocks(c, 0, c->n_track);
        c->cms = (double)(hs_now_ns() - t0) * 1e-6;
        return st;
    }
    int d = 0;
    for (int e = 0; e < m; e++)
        for (int q = 0; q < 12; q++) {
            int f = c->edof[12 * e + q];
            if (f >= 0 && c->dpos[f] < 0) {
                c->dpos[f] = d;
                c->dset[d++] = f;
            }
        }
    hs_status st = grow_d(c, d);
    if (st != HS_OK) goto out;
    memset(c->kdd, 0, sizeof(double) * (size_t)d * d);
    for (int e = 0; e < m; e++)
        for (int i = 0; i < 12; i++) {
            int fi = c->edof[12 * e + i];
            if (fi < 0) continue;
            for (int j = 0; j < 12; j++) {
                int fj = c->edof[12 * e + j];
                if (fj < 0) continue;
                double x = c->dk[144 * (size_t)e + 12 * i + j];
                c->kdd[(size_t)c->dpos[fi] * d + c->dpos[fj]] += e < c->first_minus ? x : -x;
            }
        }
    const int nf = c->n_free;
    for (int s = 0; s < d; s += HS_CUT_BATCH) {
        int w = d - s < HS_CUT_BATCH ? d - s : HS_CUT_BATCH;
        memset(c->zbuf, 0, sizeof(double) * (size_t)nf * (size_t)w);
        for (int j = 0; j < w; j++) c->zbuf[(size_t)nf * j + (size_t)c->dset[s + j]] = 1.0;
        st = hs_cholesky_solve_many(c->factor, w, c->zbuf, c->zbuf);
        if (st != HS_OK) goto out;
        for (int j = 0; j < w; j++) {
            const double* z = c->zbuf + (size_t)nf * j;
            for (int i = 0; i < d; i++) c->zd[(size_t)i * d + s + j] = z[c->dset[i]];
            for (int k = 0; k < c->n_track; k++) {
                int v = c->track[k];
                for (int q = 0; q < 3; q++) {
                    int f = c->dof[3 * v + q];
                    c->zt[(size_t)(3 * k + q) * d + s + j] = f >= 0 ? z[f] : 0.0;
                }
            }
        }
    }
    // wrk = I + dK_DD Z_D
    for (int i = 0; i < d; i++)
        for (int j = 0; j < d; j++) {
            double sum = i == j ? 1.0 : 0.0;
            for (int k = 0; k < d; k++) sum += c->kdd[(size_t)i * d + k] * c->zd[(size_t)k * d + j];
            c->wrk[(size_t)i * d + j] = sum;
        }
    if (!lu_factor(d, c->wrk, c->piv)) {
        st = HS_ERR_NUMERIC;
        goto out;
    }
    // Per tracked row r of Z: y = (I + dK Z_D)^-1 dK z_r^T; block(i,j) -= z_i . y_j.
    double* y = c->zd; // Z_D no longer needed: reuse its first 3 rows as scratch
    for (int k = 0; k < c->n_track; k++) {
        int v = c->track[k];
        if (c->dof[3 * v] < 0 || c->pinned[v]) {
            memset(c->cblk + 9 * (size_t)k, 0, 9 * sizeof(double));
            continue;
        }
        for (int q = 0; q < 3; q++) {
            const double* z = c->zt + (size_t)(3 * k + q) * d;
            double* yq = y + (size_t)q * d;
            for (int i = 0; i < d; i++) {
                double sum = 0;
                for (int j = 0; j < d; j++) sum += c->kdd[(size_t)i * d + j] * z[j];
                yq[i] = sum;
            }
            lu_solve(d, c->wrk, c->piv, yq);
        }
        double* b = c->cblk + 9 * (size_t)k;
        for (int i = 0; i < 3; i++)
            for (int q = 0; q < 3; q++) {
                const double* zi = c->zt + (size_t)(3 * k + i) * d;
                const double* yq = y + (size_t)q * d;
                double sum = 0;
                for (int j = 0; j < d; j++) sum += zi[j] * yq[j];
                b[3 * i + q] -= sum;
            }
    }
out:
    for (int i = 0; i < d; i++) c->dpos[c->dset[i]] = -1;
    c->cms = (double)(hs_now_ns() - t0) * 1e-6;
    return st;
}

// ---------------------------------------------------------------------------------------------

void hs_cut_force(double toughness_n_m, double cut_length_m, const double travel_m[3], double max_n,
                  double force_n[3]) {
    force_n[0] = force_n[1] = force_n[2] = 0.0;
    if (!travel_m || !(toughness_n_m > 0) || !(cut_length_m > 0)) return;
    double len = sqrt(v3_dot(travel_m, travel_m));
    if (!(len > 0) || !isfinite(len)) return;
    double f = toughness_n_m * cut_length_m;
    if (max_n >= 0 && f > max_n) f = max_n;
    for (int d = 0; d < 3; d++) force_n[d] = -f * travel_m[d] / len;
}
