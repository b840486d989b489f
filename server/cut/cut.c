// SPDX-License-Identifier: GPL-2.0-or-later
// Vertex-preserving cutting: sweep crossing test, vertex moves with a quality guard, tet
// removal with the orphan and free-piece rules, the live mesh and the element-change lists.
// See server/cut/cut.h for the design and docs/cutting.md for the choices.
#include "cut.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

#define HS_CUT_COOKIE 0x43555431

struct hs_cut {
    hs_mesh* mesh; // x0 moves with cuts; tets never change
    hs_cut_def def;
    int n, ne;

    unsigned char* fixed;  // [n] held in place (user fixed, or unused at create)
    unsigned char* pinned; // [n] left the system after a cut (orphan or free piece)
    unsigned char* active; // [ne]
    int* count;            // [n] active tets per node
    int* nt_start;         // [n+1] node -> tet incidence over all mesh tets
    int* nt;               //
    double* vol_orig;      // [ne] rest volume at create, m^3
    double* q_orig;        // [ne] rest quality at create

    hs_mesh* live;  // active tets only
    int* live_tet;  // [ne] live index -> mesh tet
    int components; // of the live mesh
    int live_dirty; // 1: tets or x0 changed since the live mesh was built
    int64_t version;

    // per-sweep scratch, allocated at create
    double* x;            // [3n] current positions
    double* nrm;          // [3n] vertex normals
    unsigned char* tmark; // [ne] 1 cut, 2 to remove, 3 listed as changed
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
};

hs_cut_def hs_cut_default_def(void) {
    hs_cut_def d;
    memset(&d, 0, sizeof d);
    d.orphan = HS_CUT_ORPHAN_PIN;
    d.fragment = HS_CUT_FRAGMENT_DROP;
    d.pins_hold = 1;
    d.min_volume_ratio = 0.1;
    d.min_quality = 0.02;
    d.max_bisections = 8;
    d.tangent_surface = 1;
    d.validate = 1;
    d.cookie = HS_CUT_COOKIE;
    return d;
}

void hs_cut_destroy(hs_cut** pc) {
    if (!pc || !*pc) return;
    hs_cut* c = *pc;
    hs_mesh_destroy(&c->live);
    void* p[] = {c->fixed,   c->pinned,   c->active,  c->count, c->nt_start, c->nt,     c->vol_orig,
                 c->q_orig,  c->live_tet, c->x,       c->nrm,   c->tmark,    c->nmark,  c->cut_list,
                 c->removed, c->moved,    c->changed, c->pins,  c->edges,    c->parent, c->fnbr,
                 c->tparent, c->fa,       c->fb,      c->anch,  c->tstamp,   c->gopen,  c->onb};
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

// Set-up

static hs_status nomem(hs_err* err) {
    return hs_err_set(err, HS_ERR_NOMEM, "cut: out of memory");
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
    c->live_tet = hs_alloc(sizeof(int) * (size_t)ne);
    c->x = hs_alloc(sizeof(double) * n3);
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
        !c->nt_start || !c->nt || !c->vol_orig || !c->q_orig || !c->live_tet || !c->x || !c->nrm ||
        !c->tmark || !c->nmark || !c->cut_list || !c->removed || !c->moved || !c->onb ||
        !c->changed || !c->pins || !c->edges || !c->parent || !c->fnbr || !c->tparent || !c->fa ||
        !c->fb || !c->anch) {
        hs_cut_destroy(&c);
        return nomem(err);
    }
    const double* x0 = mesh->x0;
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
    int nfree = 0, nfixed_used = 0;
    for (int i = 0; i < n; i++) {
        int fx = (fixed && fixed[i]) || c->count[i] == 0;
        if (fixed && fixed[i] && c->count[i] > 0) nfixed_used++;
        c->fixed[i] = (unsigned char)fx;
        nfree += !fx;
    }
    // Pieces are held by fixed nodes only: without one, the first cut would drop everything.
    if (nfree == 0 || nfixed_used == 0) {
        hs_err_set(err, HS_ERR_INVALID,
                   "cut: need at least one fixed node and one free node (%d fixed, %d free)",
                   nfixed_used, nfree);
        hs_cut_destroy(&c);
        return HS_ERR_INVALID;
    }
    hs_status st = hs_mesh_create(n, x0, ne, mesh->tets, &c->live, err);
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

hs_status hs_cut_sync_fem(const hs_cut* c, hs_fem* other) {
    if (!c || !other) return HS_ERR_INVALID;
    for (int e = 0; e < c->ne; e++)
        if (!c->active[e]) hs_fem_set_element_active(other, e, 0);
    return hs_fem_refresh_elements(other, c->changed, c->n_changed);
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
        if (cnt == 0 && !c->fixed[i] && !c->pinned[i])
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

static const int k_edge[6][2] = {{0, 1}, {0, 2}, {0, 3}, {1, 2}, {1, 3}, {2, 3}};

// One sweep's shared state, step to step.
typedef struct sweep {
    const double* S[4]; // the swept quad p0, q0, q1, p1
    const double* p0;
    double lo[3], hi[3]; // its bounding box
    double tn[2][3];     // unit normals of the quad's triangles (zero when degenerate)
    double* u;           // displacements (may be NULL)
    int n_cut;           // tets in c->cut_list
    int n_onb;           // vertices in c->onb
    int n_moved;         // vertices in c->moved
    hs_cut_result r;
} sweep;

// Current positions x0 + u, and the blade's points checked.
static hs_status sweep_begin(hs_cut* c, sweep* w, hs_err* err) {
    for (int k = 0; k < 4; k++)
        for (int d = 0; d < 3; d++)
            if (!isfinite(w->S[k][d]) || fabs(w->S[k][d]) > 1e6)
                return hs_err_set(err, HS_ERR_INVALID, "cut: blade point %d coordinate %d is %g", k,
                                  d, w->S[k][d]);
    const double* x0 = c->mesh->x0;
    for (int k = 0; k < 3 * c->n; k++) {
        c->x[k] = x0[k] + (w->u ? w->u[k] : 0.0);
        if (!isfinite(c->x[k]))
            return hs_err_set(err, HS_ERR_INVALID, "cut: displacement of node %d is not finite",
                              k / 3);
    }
    c->n_removed = c->n_moved = c->n_changed = c->n_pins = 0;
    for (int d = 0; d < 3; d++) {
        w->lo[d] = fmin(fmin(w->S[0][d], w->S[1][d]), fmin(w->S[3][d], w->S[2][d]));
        w->hi[d] = fmax(fmax(w->S[0][d], w->S[1][d]), fmax(w->S[3][d], w->S[2][d]));
    }
    unit_normal(w->S[0], w->S[1], w->S[2], w->tn[0]);
    unit_normal(w->S[0], w->S[2], w->S[3], w->tn[1]);
    return HS_OK;
}

// Vertices of tet t near the blade's plane (within 1e-6 of the tet's size ext, a bound on their
// own tolerance below) go on c->onb, to be checked for hinges in sweep_hinges.
static void note_near_plane(hs_cut* c, sweep* w, const int* t, double ext) {
    for (int a = 0; a < 4; a++) {
        int v = t[a];
        if (c->nmark[v]) continue;
        double d[3];
        v3_sub(c->x + 3 * v, w->p0, d);
        int near = 0; // a flat triangle's zero normal would let every vertex in
        for (int tri = 0; tri < 2; tri++)
            near |= v3_dot(w->tn[tri], w->tn[tri]) > 0 && fabs(v3_dot(d, w->tn[tri])) <= 1e-6 * ext;
        if (near) {
            c->nmark[v] = 1;
            c->onb[w->n_onb++] = v;
        }
    }
}

// 1. Crossing test against the two triangles of the swept quad: cut tets (marked 1) and the
// length of the cut edges.
static void sweep_find_cut(hs_cut* c, sweep* w) {
    const int* T = c->mesh->tets;
    int n_edges = 0;
    for (int e = 0; e < c->ne; e++) {
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
        if (tl[0] > w->hi[0] || th[0] < w->lo[0] || tl[1] > w->hi[1] || th[1] < w->lo[1] ||
            tl[2] > w->hi[2] || th[2] < w->lo[2])
            continue;
        note_near_plane(c, w, t, (th[0] - tl[0]) + (th[1] - tl[1]) + (th[2] - tl[2]));
        int hit = 0;
        for (int k = 0; k < 6; k++) {
            int a = t[k_edge[k][0]], b = t[k_edge[k][1]];
            if (edge_crosses(c->x + 3 * a, c->x + 3 * b, w->S)) {
                hit = 1;
                c->edges[2 * n_edges] = a < b ? a : b;
                c->edges[2 * n_edges + 1] = a < b ? b : a;
                n_edges++;
            }
        }
        if (hit) {
            c->tmark[e] = 1;
            c->cut_list[w->n_cut++] = e;
        }
    }
    for (int k = 0; k < w->n_onb; k++) c->nmark[c->onb[k]] = 0;
    w->r.cut_tets = w->n_cut;
    if (n_edges > 0) {
        qsort(c->edges, (size_t)n_edges, 2 * sizeof(int), cmp_edge);
        for (int k = 0; k < n_edges; k++) {
            if (k > 0 && c->edges[2 * k] == c->edges[2 * k - 2] &&
                c->edges[2 * k + 1] == c->edges[2 * k - 1])
                continue;
            double d[3];
            v3_sub(c->x + 3 * c->edges[2 * k], c->x + 3 * c->edges[2 * k + 1], d);
            w->r.cut_length_m += sqrt(v3_dot(d, d));
        }
    }
}

// 2. Removal set with the orphan rule (counts are decremented as tets go).
static void sweep_take_cut(hs_cut* c, sweep* w) {
    for (int k = 0; k < w->n_cut; k++) {
        int e = c->cut_list[k];
        // The move step below ignores tets marked 2 (going); step 4 deactivates them.
        if (!take_tet(c, e)) {
            c->tmark[e] = 0;
            w->r.kept++;
        }
    }
}

// The move of vertex v onto the swept surface, in current coordinates; 0 when it stays.
// Onto the quad's plane where the vertex's projection falls inside one of its triangles (the
// nearer if both). A projection outside the quad (a vertex ahead of the blade, or beyond its
// ends) has its closest point on the quad's edge, and going there dragged the vertex along the
// cut, stretching tets that later sweeps cut and moved again. Such a vertex stays (its tet still
// goes); the blade moves it when it gets there. Not onto the plane either: its uncut tets would
// then have no edge across the blade and would stay, joining the two sides.
static int move_target(const hs_cut* c, const sweep* w, int v, double dx[3]) {
    const double* xv = c->x + 3 * v;
    const double h2 = shortest_edge2(c, v);
    double best = INFINITY;
    for (int tri = 0; tri < 2; tri++) {
        const double* nk = w->tn[tri];
        if (!(v3_dot(nk, nk) > 0)) continue;
        double cp[3], d[3];
        closest_on_tri(xv, w->p0, tri ? w->S[2] : w->S[1], tri ? w->S[3] : w->S[2], cp);
        v3_sub(cp, xv, d);
        double along = v3_dot(d, nk), side[3];
        for (int q = 0; q < 3; q++) side[q] = d[q] - along * nk[q];
        if (v3_dot(side, side) > 1e-12 * h2 || !(v3_dot(d, d) < best)) continue;
        best = v3_dot(d, d);
        memcpy(dx, d, 3 * sizeof *dx);
    }
    if (best == INFINITY) return 0;
    if (c->def.tangent_surface) {
        const double* nv = c->nrm + 3 * v;
        double nn = v3_dot(nv, nv);
        if (nn > 0) {
            double s = v3_dot(dx, nv) / nn;
            for (int d = 0; d < 3; d++) dx[d] -= s * nv[d];
        }
    }
    return v3_dot(dx, dx) > 0;
}

// Moves vertex v by dx (current) as far as the quality guard allows, halving the step up to
// max_bisections times; 1 when it moved.
static int move_vertex(hs_cut* c, sweep* w, int v, const double dx[3]) {
    double* x0 = c->mesh->x0;
    double* xv = c->x + 3 * v;
    double dX[3];
    if (w->u)
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
    if (!ok || s < 1.0) w->r.clamped++;
    if (!ok) return 0;
    for (int d = 0; d < 3; d++) {
        if (w->u) w->u[3 * v + d] += s * (dx[d] - dX[d]);
        x0[3 * v + d] = Xt[d];
        c->live->x0[3 * v + d] = Xt[d];
        xv[d] = xt[d];
    }
    return 1;
}

// 3. Vertex moves onto the swept surface (vertices of tets being removed).
static void sweep_move(hs_cut* c, sweep* w) {
    const int* T = c->mesh->tets;
    int n_cand = 0;
    for (int k = 0; k < w->n_cut; k++) {
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
        double dx[3];
        if (move_target(c, w, v, dx) && move_vertex(c, w, v, dx)) c->moved[n_moved++] = v;
    }
    c->n_moved = w->r.moved = w->n_moved = n_moved;
}

// 3b. A move can leave a vertex a hair across the blade's plane (the tangent-plane rule, a
// clamped move): its other tets then cross the swept quad, and no later sweep comes back
// here. They go now, as they are (no further moves: nothing cascades). Without this, fine
// sweeps left hundreds of such tets bridging a cut across the skin patch.
static void sweep_take_crossed(hs_cut* c, sweep* w) {
    const int* T = c->mesh->tets;
    for (int k = 0; k < w->n_moved; k++) {
        int v = c->moved[k];
        for (int p = c->nt_start[v]; p < c->nt_start[v + 1]; p++) {
            int e = c->nt[p];
            if (!c->active[e] || c->tmark[e] != 0) continue;
            const int* t = T + 4 * e;
            int hit = 0;
            for (int q = 0; q < 6 && !hit; q++)
                hit = edge_crosses(c->x + 3 * t[k_edge[q][0]], c->x + 3 * t[k_edge[q][1]], w->S);
            if (!hit) continue;
            if (!take_tet(c, e)) {
                int seen = 0; // counted already from an earlier moved vertex of e
                for (int j = 0; j < k && !seen; j++)
                    for (int a = 0; a < 4; a++) seen |= t[a] == c->moved[j];
                if (!seen) w->r.kept++;
                continue;
            }
            c->cut_list[w->n_cut++] = e;
            w->r.cut_tets++;
        }
    }
}

// 3c. Hinges. A vertex on the blade's plane (moved there, or lying there) where the blade
// passed, with tets left on both sides, would keep the sides joined: no edge from it counts
// as crossing, and its tets on the far side touch the blade only at it (with 0.2 mm sweeps
// the skin patch's cut stayed in one piece). The smaller side's tets there go, as they are.
static void sweep_hinges(hs_cut* c, sweep* w) {
    for (int k = 0; k < w->n_onb; k++) c->nmark[c->onb[k]] = 1; // once each: n_onb <= n
    for (int k = 0; k < w->n_moved; k++) {
        int v = c->moved[k];
        if (!c->nmark[v]) c->onb[w->n_onb++] = v;
        c->nmark[v] = 1;
    }
    for (int k = 0; k < w->n_onb; k++) {
        int v = c->onb[k];
        c->nmark[v] = 0;
        if (c->fixed[v] || c->pinned[v]) continue;
        double h2 = shortest_edge2(c, v);
        int tri = isfinite(h2) ? blade_site(c, v, w->S, w->tn, 1e-6 * sqrt(h2)) : -1;
        if (tri < 0) continue;
        const double* nrm = w->tn[tri];
        double vol[2] = {0, 0};
        for (int p = c->nt_start[v]; p < c->nt_start[v + 1]; p++) {
            int e = c->nt[p], side;
            if (c->active[e] && c->tmark[e] == 0 && (side = tet_side(c, e, v, w->p0, nrm)) >= 0)
                vol[side] += c->vol_orig[e];
        }
        if (!(vol[0] > 0 && vol[1] > 0)) continue;
        const int drop = vol[0] < vol[1] ? 0 : 1;
        int went = 0; // ORPHAN_KEEP_TET may keep them all (not counted in `kept`: not cut tets)
        for (int p = c->nt_start[v]; p < c->nt_start[v + 1]; p++) {
            int e = c->nt[p];
            if (!c->active[e] || c->tmark[e] != 0 || tet_side(c, e, v, w->p0, nrm) != drop)
                continue;
            if (!take_tet(c, e)) continue;
            c->cut_list[w->n_cut++] = e;
            w->r.cut_tets++;
            went = 1;
        }
        w->r.hinges += went;
    }
}

// 4. Remove, then orphans (PIN rule) and free pieces; 1 when the mesh changed.
static int sweep_remove(hs_cut* c, sweep* w) {
    const int* T = c->mesh->tets;
    for (int k = 0; k < w->n_cut; k++) {
        int e = c->cut_list[k];
        if (c->tmark[e] == 2) remove_tet(c, e, 1);
    }
    for (int k = 0; k < c->n_removed; k++)
        for (int a = 0; a < 4; a++) {
            int v = T[4 * c->removed[k] + a];
            if (c->count[v] == 0) pin_node(c, v);
        }
    if (c->n_removed > 0) // moves never disconnect
        w->r.fragments = handle_fragments(c, &w->r.piece_check_tets);
    w->r.removed = c->n_removed;
    w->r.pinned = c->n_pins;
    const int mesh_changed = c->n_removed > 0 || w->n_moved > 0;
    if (mesh_changed) {
        c->version++;
        c->live_dirty = 1;
    }
    return mesh_changed;
}

// 5. Element changes for the owner of the factor and the compliance: the removed tets
// (sweep_remove) and the remaining tets around moved vertices, whose rest data changed.
static void sweep_changes(hs_cut* c, sweep* w) {
    for (int k = 0; k < w->n_moved; k++) {
        int v = c->moved[k];
        for (int p = c->nt_start[v]; p < c->nt_start[v + 1]; p++) {
            int e = c->nt[p];
            if (!c->active[e] || c->tmark[e] == 3) continue;
            c->tmark[e] = 3;
            c->changed[c->n_changed++] = e;
        }
    }
    w->r.changed_elements = c->n_removed + c->n_changed;
}

hs_status hs_cut_sweep(hs_cut* c, const double p0[3], const double q0[3], const double p1[3],
                       const double q1[3], double* u, hs_cut_result* res, hs_err* err) {
    int64_t t0 = hs_now_ns();
    if (!c || !p0 || !q0 || !p1 || !q1)
        return hs_err_set(err, HS_ERR_INVALID, "cut: NULL argument to hs_cut_sweep");
    sweep w = {.S = {p0, q0, q1, p1}, .p0 = p0, .u = u};
    hs_status st = sweep_begin(c, &w, err);
    if (st != HS_OK) return st;
    sweep_find_cut(c, &w);
    sweep_take_cut(c, &w);
    sweep_move(c, &w);
    sweep_take_crossed(c, &w);
    sweep_hinges(c, &w);
    const int mesh_changed = sweep_remove(c, &w);
    sweep_changes(c, &w);
    w.r.geometry_ms = (double)(hs_now_ns() - t0) * 1e-6;

    // 6. Checks (the live mesh is rebuilt here only when validating, else on first use).
    int64_t t2 = hs_now_ns();
    if (mesh_changed && c->def.validate) st = hs_cut_validate(c, err);
    w.r.mesh_ms = (double)(hs_now_ns() - t2) * 1e-6;
    for (int k = 0; k < w.n_cut; k++) c->tmark[c->cut_list[k]] = 0;
    for (int k = 0; k < c->n_removed; k++) c->tmark[c->removed[k]] = 0;
    for (int k = 0; k < c->n_changed; k++) c->tmark[c->changed[k]] = 0;
    w.r.topology_version = c->version;
    w.r.total_ms = (double)(hs_now_ns() - t0) * 1e-6;
    if (res) *res = w.r;
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