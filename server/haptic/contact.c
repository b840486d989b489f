// SPDX-License-Identifier: GPL-2.0-or-later
// Probe contact from a compliance snapshot: the per-tick work of the rt thread.
//
// DESIGN. Pure function of (snapshot, tool position): fixed-size stack arrays, no allocation.
// The probe is a smooth sphere, so the contact is frictionless. The tissue is its surface, not
// its nodes: every listed triangle contributes one contact point, its closest point x_i to the
// centre p, x_i = sum_a w_ia q_a over its vertices' contact-free positions q_a (barycentric
// weights; the point lies on a vertex, an edge or the face interior, and a point shared by
// several triangles counts once). Each point is pushed along n_i: away from the centre,
// n_i = (x_i - p) / rho_i, rho_i = |x_i - p| (the smallest displacement that resolves the
// penetration), and for a face-interior point the inward face normal with the signed distance
// rho_i = N . (p - q_a) (the same while the centre is in front of the face, and still defined
// when it reaches or passes the contact-free surface). A force lambda_i n_i at point i puts
// w_ia lambda_i n_i on vertex a; vertex a moves by u_a = sum_b C_ab f_b, the point by
// sum_a w_ia u_a, so to first order its distance from the centre along n_i becomes
// rho_i + (W lambda)_i with W_ij = sum_a sum_b w_ia w_jb n_i^T C_ab n_j. Contact is the linear
// complementarity problem
//     w = (W + eps I) lambda - delta >= 0,  lambda >= 0,  w . lambda = 0,  delta_i = r - rho_i,
// every point ends on or outside the sphere, only pushed, and pushed only where it touches.
// eps (HS_CONTACT_SOFTNESS x the nodes' mean diagonal compliance, a constant of the snapshot)
// is a tiny contact compliance: nearby points (a face point next to an edge point of the next
// triangle) make W nearly singular, eps keeps it positive definite, so the solution is unique
// and continuous in the tool position, and principal pivoting (Murty's least-index rule,
// points ordered deepest first; finite for positive definite matrices) stays well conditioned.
// Each closest point moves continuously with p, so the force does not jump when the centre
// crosses from a face over an edge or a vertex to the next face.
#include "compliance.h"

#include "closest.h"
#include "dense.h"

#include <float.h>
#include <math.h>
#include <stdint.h>
#include <string.h>

#define M            HS_MAX_CONTACT
#define MAX_PIVOTS   (4 * M)
#define BLOCK_PIVOTS 6
#define MAX_FEAT                                                                                   \
    (HS_CONTACT_MAX_TRI > HS_CONTACT_MAX_CAND ? HS_CONTACT_MAX_TRI : HS_CONTACT_MAX_CAND)

// A contact point (feature) of the contact-free surface.
typedef struct feat {
    int kind;      // HS_FEAT_VERTEX / EDGE / FACE: how many vertices carry a weight
    int v[3];      // candidate indices of those vertices, ascending (with kind: the identity)
    double w[3];   // their barycentric weights
    int lv[3];     // local vertex index (once selected)
    int tri;       // the triangle it came from (-1: a node)
    double n[3];   // unit direction the tissue is pushed along
    double rho;    // distance of the point from the centre along -n, m (signed on a face)
    double rho_e;  // rho less the push already applied there (n . pre): what the gap is
    double pre[3]; // sum_k w_k pre_m[v_k]: the point's displacement under the applied forces
    int raw;       // 1 while n is still x - p (not yet divided by rho)
    double fade;   // (0, 1]: how fully the point pushes (FADE_COS below)
    double nt[3];  // its triangle's outward normal (edge and vertex points)
} feat;

// An edge or vertex point is pushed away from the centre, n = (x - p) / |x - p|: the sphere's
// normal while the centre is in front of the surface. Once the centre nears or passes the
// contact-free surface (a press about r deep) that n turns along the surface or out of the
// tissue, with a penetration near r: such pushes tore the surface sideways or pulled it out
// (the linear liver 6 mm under the scene's 5 mm sphere: a node 0.36 m out, the probe pulled in
// with 2 N). So such a point pushes through a softened contact, fade = cos(n, -N) / FADE_COS
// times as stiff (N its triangle's outward normal; at most 1): fully within 75 degrees of the
// inward normal, not at all along the surface or beyond. Continuous in p except where the
// centre passes the point itself, and where a faded point is reported by two triangles as two
// points at one place (an edge point just leaving its vertex: each copy softened alone, the
// two push harder than one); on a flat surface no point inside the sphere fades in a press
// shallower than 3/4 r (docs/haptics.md, "Points pushed along the surface").
#define FADE_COS 0.25
#define FADE_MIN 1e-6

static void tri_normal(const double* a, const double* b, const double* c, double n[3]) {
    double e1[3] = {b[0] - a[0], b[1] - a[1], b[2] - a[2]};
    double e2[3] = {c[0] - a[0], c[1] - a[1], c[2] - a[2]};
    n[0] = e1[1] * e2[2] - e1[2] * e2[1];
    n[1] = e1[2] * e2[0] - e1[0] * e2[2];
    n[2] = e1[0] * e2[1] - e1[1] * e2[0];
    double l = sqrt(hs_dot3(n, n));
    for (int k = 0; k < 3; ++k) n[k] = l > 0 ? n[k] / l : 0;
}

// The point's share of the displacement the applied forces cause (zero on a contact-free
// snapshot): the gap is measured from where the point would be without them.
static void feat_pre(const hs_contact_snapshot* s, feat* f) {
    f->pre[0] = f->pre[1] = f->pre[2] = 0;
    for (int k = 0; k < f->kind; ++k)
        for (int a = 0; a < 3; ++a) f->pre[a] += f->w[k] * s->pre_m[f->v[k]][a];
}

// The contact point of triangle t for centre p; 0 when the triangle gives none (degenerate, or
// the centre more than r behind its face: a face on the far side of a thin part).
static int tri_feature(const hs_contact_snapshot* s, int t, const double p[3], double r, feat* f) {
    const int* tv = s->tri[t];
    for (int k = 0; k < 3; ++k)
        if (tv[k] < 0 || tv[k] >= s->n_cand) return 0; // not a candidate: ignore the triangle
    const double *a = s->surf_m[tv[0]], *b = s->surf_m[tv[1]], *c = s->surf_m[tv[2]];
    double w[3], x[3];
    if (!hs_tri_closest(p, a, b, c, w, x)) return 0;
    f->kind = 0;
    f->tri = t;
    f->raw = 0;
    for (int k = 0; k < 3; ++k) {
        if (!(w[k] > 0)) continue;
        // insertion keeps v ascending
        int at = f->kind++;
        while (at > 0 && f->v[at - 1] > tv[k]) {
            f->v[at] = f->v[at - 1];
            f->w[at] = f->w[at - 1];
            --at;
        }
        f->v[at] = tv[k];
        f->w[at] = w[k];
    }
    if (f->kind == 0) return 0; // no finite weight (a non-finite position)
    feat_pre(s, f);
    double nf[3];
    f->fade = 1;
    if (f->kind == HS_FEAT_FACE) {
        tri_normal(a, b, c, nf);
        double ap[3] = {p[0] - a[0], p[1] - a[1], p[2] - a[2]};
        f->rho = hs_dot3(nf, ap);
        if (f->rho <= -r) return 0;
        for (int k = 0; k < 3; ++k) f->n[k] = -nf[k];
        f->rho_e = f->rho - hs_dot3(f->n, f->pre);
        return 1;
    }
    double d[3] = {x[0] - p[0], x[1] - p[1], x[2] - p[2]};
    f->rho = sqrt(hs_dot3(d, d));
    if (f->rho > 1e-9 * r) {
        for (int k = 0; k < 3; ++k) f->n[k] = d[k]; // normalised once selected (few are)
        f->raw = 1;
        f->rho_e = f->rho - hs_dot3(d, f->pre) / f->rho;
    } else {
        f->rho = 0;
        tri_normal(a, b, c, nf);
        for (int k = 0; k < 3; ++k) f->n[k] = -nf[k];
        f->rho_e = -hs_dot3(f->n, f->pre);
    }
    return 1;
}

// d n_i / d p (3x3 row-major): zero on a face (the normal is fixed), -(I - n n^T - t t^T) / rho
// on an edge with unit direction t (the point slides along it), -(I - n n^T) / rho at a vertex.
static void feat_dn(const hs_contact_snapshot* s, const feat* f, double dn[9]) {
    memset(dn, 0, 9 * sizeof(double));
    if (f->kind == HS_FEAT_FACE || !(f->rho > 0)) return;
    double t[3] = {0, 0, 0};
    if (f->kind == HS_FEAT_EDGE) {
        const double *a = s->surf_m[f->v[0]], *b = s->surf_m[f->v[1]];
        for (int k = 0; k < 3; ++k) t[k] = b[k] - a[k];
        double l = sqrt(hs_dot3(t, t));
        for (int k = 0; k < 3; ++k) t[k] /= l;
    }
    for (int p = 0; p < 3; ++p)
        for (int q = 0; q < 3; ++q)
            dn[3 * p + q] = -((p == q) - f->n[p] * f->n[q] - t[p] * t[q]) / f->rho;
}

// d w_k / d p for the point's vertices (rows): zero at a vertex; along an edge the parameter's
// gradient; on a face the projection's barycentric gradient (inverse Gram matrix).
static void feat_dw(const hs_contact_snapshot* s, const feat* f, double dw[3][3]) {
    memset(dw, 0, 9 * sizeof(double));
    if (f->kind == HS_FEAT_EDGE) {
        const double *a = s->surf_m[f->v[0]], *b = s->surf_m[f->v[1]];
        double e[3] = {b[0] - a[0], b[1] - a[1], b[2] - a[2]};
        double l2 = hs_dot3(e, e);
        for (int k = 0; k < 3; ++k) {
            dw[1][k] = e[k] / l2;
            dw[0][k] = -e[k] / l2;
        }
    } else if (f->kind == HS_FEAT_FACE) {
        const double *a = s->surf_m[f->v[0]], *b = s->surf_m[f->v[1]], *c = s->surf_m[f->v[2]];
        double e1[3] = {b[0] - a[0], b[1] - a[1], b[2] - a[2]};
        double e2[3] = {c[0] - a[0], c[1] - a[1], c[2] - a[2]};
        double g11 = hs_dot3(e1, e1), g12 = hs_dot3(e1, e2), g22 = hs_dot3(e2, e2);
        double det = g11 * g22 - g12 * g12;
        for (int k = 0; k < 3; ++k) {
            dw[1][k] = (g22 * e1[k] - g12 * e2[k]) / det;
            dw[2][k] = (g11 * e2[k] - g12 * e1[k]) / det;
            dw[0][k] = -dw[1][k] - dw[2][k];
        }
    }
}

// Bit of a vertex or edge point in the seen-set (candidate indices < HS_CONTACT_MAX_CAND); a
// face point is its triangle's own, never shared.
static int feat_bit(const feat* f) {
    if (f->kind == HS_FEAT_VERTEX) return f->v[0];
    return HS_CONTACT_MAX_CAND + f->v[0] * HS_CONTACT_MAX_CAND + f->v[1];
}

// W's columns as they are needed (see hs_contact_solve). Arrays are strided by cap, the
// points (and vertices) the workspace holds: HS_MAX_CONTACT per tool.
typedef struct cols {
    const hs_contact_snapshot* s;
    const feat* set;
    const int* vtx; // local vertex -> candidate index
    int m, nv, cap;
    double eps;
    int approx;
    unsigned char* have; // [cap]
    double* wjj;         // [cap] W_jj before a faded point's softening (W_jj (1 / fade - 1) added)
    double* cn; // [cap][cap][3]: cn[a][j] = sum_k w_jk C(a, v_jk) n_j, vertex a's move per lambda_j
    double* w;  // [cap][cap]: w[i][j] = n_i . sum_k w_ik cn[v_ik][j] (+ eps on the diagonal)
} cols;

static double* cn_at(const cols* c, int a, int j) {
    return c->cn + 3 * ((size_t)a * c->cap + j);
}

static void build_col(cols* c, int j) {
    if (c->have[j]) return;
    const feat* f = &c->set[j];
    for (int a = 0; a < c->nv; ++a) {
        double* o = cn_at(c, a, j);
        o[0] = o[1] = o[2] = 0;
        for (int k = 0; k < f->kind; ++k) {
            int va = c->vtx[a], b = c->vtx[f->lv[k]];
            const double* blk = c->s->c[va][b];
            if (va != b && !c->s->coupled[va] && !c->s->coupled[b]) c->approx = 1;
            for (int p = 0; p < 3; ++p)
                o[p] += f->w[k] * (blk[3 * p] * f->n[0] + blk[3 * p + 1] * f->n[1] +
                                   blk[3 * p + 2] * f->n[2]);
        }
    }
    for (int i = 0; i < c->m; ++i) {
        const feat* g = &c->set[i];
        double sum = 0;
        for (int k = 0; k < g->kind; ++k) sum += g->w[k] * hs_dot3(g->n, cn_at(c, g->lv[k], j));
        c->w[i * c->cap + j] = sum;
    }
    // A faded point: its compliance grows to W_jj / fade, so it pushes about fade times as hard.
    c->wjj[j] = c->w[j * c->cap + j];
    c->w[j * c->cap + j] += c->wjj[j] * (1.0 / f->fade - 1.0) + c->eps;
    c->have[j] = 1;
}

// Symmetric entry of W for two built columns.
static double w_sym(const cols* c, int i, int j) {
    return 0.5 * (c->w[i * c->cap + j] + c->w[j * c->cap + i]);
}

// The solve's scratch, carved from caller storage (the stack for one tool, a workspace for
// several): nothing is allocated per tick.
typedef struct work {
    int cap, m, nv;
    feat* set;                  // [cap] the selected points of all tools
    int* vtx;                   // [cap] local vertex -> candidate index
    int* owner;                 // [cap] tool of each point
    int* ia;                    // [cap] pushing points
    int* idx;                   // [cap] active points (solve_active; w->a holds their factor)
    int n_idx;                  // how many
    int* used;                  // [cap] scratch per vertex
    unsigned char* act;         // [cap]
    unsigned char* bad;         // [cap]
    double *delta, *lambda, *x; // [cap]
    double *fv, *uv, *g;        // [cap][3] ([3][cap] for g)
    double *dn, *dw, *e;        // [cap][9]
    double* a;                  // [cap][cap] factor of W over the active points
    cols wc;
} work;

#define WORK_DOUBLES(cap) ((cap)*40 + (cap) * (cap)*5)
#define WORK_INTS(cap)    ((cap)*6)
#define WORK_BYTES(cap)   ((cap)*3)

static void work_carve(work* k, int cap, feat* set, double* d, int* in, unsigned char* b) {
    memset(k, 0, sizeof *k);
    k->cap = k->wc.cap = cap;
    k->set = set;
    k->vtx = in, in += cap;
    k->owner = in, in += cap;
    k->ia = in, in += cap;
    k->idx = in, in += cap;
    k->used = in;
    k->act = b, b += cap;
    k->bad = b, b += cap;
    k->wc.have = b;
    k->delta = d, d += cap;
    k->lambda = d, d += cap;
    k->x = d, d += cap;
    k->wc.wjj = d, d += cap;
    k->fv = d, d += 3 * cap;
    k->uv = d, d += 3 * cap;
    k->g = d, d += 3 * cap;
    k->dn = d, d += 9 * cap;
    k->dw = d, d += 9 * cap;
    k->e = d, d += 9 * cap;
    k->a = d, d += (size_t)cap * cap;
    k->wc.w = d, d += (size_t)cap * cap;
    k->wc.cn = d;
}

struct hs_contact_work {
    int n_tools;
    feat* set;
    double* d;
    int* in;
    unsigned char* b;
};

// Solve W_AA lambda_A = delta_A for the active set (columns built); lambda = 0 elsewhere.
// Returns -1 if W_AA is not positive definite.
static int solve_active(work* w) {
    const cols* c = &w->wc;
    int k = 0;
    for (int i = 0; i < w->m; ++i)
        if (w->act[i]) w->idx[k++] = i;
    for (int i = 0; i < k; ++i) {
        for (int j = 0; j < k; ++j) w->a[i * k + j] = w_sym(c, w->idx[i], w->idx[j]);
        w->x[i] = w->delta[w->idx[i]];
    }
    for (int i = 0; i < w->m; ++i) w->lambda[i] = 0;
    w->n_idx = 0;
    if (k == 0) return 0;
    if (hs_dense_cholesky(w->a, k) != 0) return -1;
    w->n_idx = k;
    hs_dense_cholesky_solve(w->a, k, w->x);
    for (int i = 0; i < k; ++i) w->lambda[w->idx[i]] = w->x[i];
    return 0;
}

// A point's mesh nodes, ascending, -1 padded: its identity across snapshots.
static void point_nodes(const hs_contact_snapshot* s, const feat* f, int out[3]) {
    out[0] = out[1] = out[2] = -1;
    for (int k = 0; k < f->kind; ++k) {
        int node = s->node[f->v[k]], at = k;
        while (at > 0 && out[at - 1] > node) {
            out[at] = out[at - 1];
            --at;
        }
        out[at] = node;
    }
}

// One tool's share of the contact problem.
typedef struct tool_part {
    const double* p; // sphere centre, m
    double r, near;  // radius, band (HS_CONTACT_BAND r), m
    double band;     // the band the push can reach (<= near), m
    double rho_out;  // the deepest point in the band the cap left out (INFINITY: none)
    int m0, m;       // its points: set[m0 .. m0 + m)
    int deep;        // 1 when a point penetrates (else it takes no part)
    int warm_n;      // warm start from nodes (one tool, hs_contact_solve)
    const int* warm_nodes;
    const hs_contact* prev; // warm start from the previous tick's contact, or NULL
} tool_part;

static double tool_radius(const hs_contact_snapshot* s, int t) {
    return t < HS_MAX_TOOLS && s->tool_radius_m[t] > 0 ? s->tool_radius_m[t] : s->probe_radius_m;
}

// How far tool t may still move before leaving the region the snapshot's candidates cover.
static double tool_cover(const hs_contact_snapshot* s, int t, const double p[3], double r) {
    const double* c = t == 0 ? s->centre_m : s->tool_centre_m[t];
    double reach = t == 0 ? s->reach_m : s->tool_reach_m[t];
    double off[3] = {p[0] - c[0], p[1] - c[1], p[2] - c[2]};
    return reach - r - sqrt(hs_dot3(off, off));
}

// Node contact: candidate i itself is the contact point.
static void node_feature(const hs_contact_snapshot* s, int i, const double p[3], double r,
                         feat* f) {
    f->kind = HS_FEAT_VERTEX;
    f->v[0] = i;
    f->w[0] = 1;
    f->tri = -1;
    f->raw = 0;
    f->fade = 1;
    double d[3] = {s->surf_m[i][0] - p[0], s->surf_m[i][1] - p[1], s->surf_m[i][2] - p[2]};
    f->rho = sqrt(hs_dot3(d, d));
    if (f->rho > 1e-9 * (r > 0 ? r : 1)) {
        for (int k = 0; k < 3; ++k) f->n[k] = d[k] / f->rho;
    } else { // at the centre the radial direction is undefined: push along -normal
        f->rho = 0;
        for (int k = 0; k < 3; ++k) f->n[k] = -s->normal[i][k];
    }
    feat_pre(s, f);
    f->rho_e = f->rho - hs_dot3(f->n, f->pre);
}

// Contact points of one tool: penetrating ones and those outside the sphere within the band
// (which the push on their neighbours may carry into the sphere: on liver2 a point 1.25 r from
// the centre on the sphere's flank was), deepest first (cand[order[k]]), each geometric point
// once. Sets out->clearance_m and out->penetrating; returns how many.
static int gather(const hs_contact_snapshot* s, const tool_part* tp, double clearance, feat* cand,
                  int* order, hs_contact* out) {
    const double r = tp->r, near = tp->near, *p = tp->p;
    double key[MAX_FEAT];
    int nc = 0;
    uint64_t seen[(HS_CONTACT_MAX_CAND + 1) * HS_CONTACT_MAX_CAND / 64];
    memset(seen, 0, sizeof seen);
    const int n_src = s->n_tri > 0 ? s->n_tri : s->n_cand;
    // A point's gap is at most its largest preload less than its distance: triangles farther
    // than the band by that much cannot reach the sphere.
    double pre_max = 0;
    for (int i = 0; i < s->n_cand; ++i) pre_max = fmax(pre_max, hs_dot3(s->pre_m[i], s->pre_m[i]));
    pre_max = sqrt(pre_max);
    for (int i = 0; i < n_src; ++i) {
        feat* f = &cand[nc]; // kept when nc advances
        if (s->n_tri > 0) {
            // Beyond the band by its bounding sphere: only a bound on the clearance.
            const double* b = s->tri_bound[i];
            double d[3] = {b[0] - p[0], b[1] - p[1], b[2] - p[2]};
            double lim = near + b[3] + pre_max, d2 = hs_dot3(d, d);
            if (d2 >= lim * lim) {
                double far = clearance + r + b[3] + pre_max;
                if (d2 < far * far) clearance = sqrt(d2) - b[3] - r - pre_max;
                continue;
            }
            if (!tri_feature(s, i, p, r, f)) continue;
        } else { // node contact: every candidate node is a contact point
            node_feature(s, i, p, r, f);
        }
        double gap = f->rho_e - r;
        if (fabs(gap) < clearance) clearance = fabs(gap);
        if (f->rho_e >= near) continue;
        if (f->kind != HS_FEAT_FACE) { // each geometric point once
            int bit = feat_bit(f);
            if (seen[bit >> 6] >> (bit & 63) & 1u) continue;
            seen[bit >> 6] |= (uint64_t)1 << (bit & 63);
        }
        if (gap < 0) ++out->penetrating;
        // at most one point per triangle or node: nc < MAX_FEAT here
        int at = nc++;
        while (at > 0 && key[at - 1] > f->rho_e) {
            order[at] = order[at - 1];
            key[at] = key[at - 1];
            --at;
        }
        order[at] = nc - 1;
        key[at] = f->rho_e;
    }
    out->clearance_m = clearance > 0 ? clearance : 0;
    return nc;
}

// Index of candidate v in list[n], appending it when absent and add is set (-1: absent).
static int vertex_index(int* list, int* n, int v, int add) {
    for (int j = 0; j < *n; ++j)
        if (list[j] == v) return j;
    if (!add) return -1;
    list[*n] = v;
    return (*n)++;
}

// Copy a selected point into the set: n made unit, and its fade for an edge or vertex point.
static void take_point(const hs_contact_snapshot* s, const feat* f, feat* o) {
    *o = *f;
    if (!f->raw) return;
    double inv = 1.0 / f->rho;
    for (int k = 0; k < 3; ++k) o->n[k] *= inv;
    o->raw = 0;
    const int* tv = s->tri[f->tri];
    tri_normal(s->surf_m[tv[0]], s->surf_m[tv[1]], s->surf_m[tv[2]], o->nt);
    double in = -hs_dot3(o->n, o->nt); // cosine to the inward normal
    o->fade = fmax(FADE_MIN, fmin(1.0, in / FADE_COS));
}

// The deepest points of one tool whose vertices fit in HS_MAX_CONTACT nodes, appended to the
// set (tool t). A point outside the sphere joins only if the push can carry it in: it moves by
// about the deepest penetration at most, so the band narrows to r + 1.5 x that when it is less
// than HS_CONTACT_BAND r (continuous in p: a point crossing its edge carries no force).
static void select_points(const hs_contact_snapshot* s, feat* cand, const int* order, int nc, int t,
                          tool_part* tp, work* w) {
    const double r = tp->r;
    tp->band = fmin(tp->near, r + 1.5 * (r - cand[order[0]].rho_e));
    tp->rho_out = INFINITY;
    tp->m0 = w->m;
    int mine[M], n_mine = 0; // this tool's vertices (candidate indices)
    int sel = 0;
    for (; sel < nc && w->m - tp->m0 < M && cand[order[sel]].rho_e < tp->band; ++sel) {
        feat* f = &cand[order[sel]];
        int add = 0;
        for (int k = 0; k < f->kind; ++k) add += vertex_index(mine, &n_mine, f->v[k], 0) < 0;
        if (n_mine + add > M) {
            if (tp->rho_out == INFINITY) tp->rho_out = f->rho_e;
            continue;
        }
        for (int k = 0; k < f->kind; ++k) {
            vertex_index(mine, &n_mine, f->v[k], 1);
            f->lv[k] = vertex_index(w->vtx, &w->nv, f->v[k], 1);
        }
        take_point(s, f, &w->set[w->m]);
        w->owner[w->m++] = t;
    }
    tp->m = w->m - tp->m0;
    if (sel < nc && tp->m == M && cand[order[sel]].rho_e < tp->band &&
        cand[order[sel]].rho_e < tp->rho_out)
        tp->rho_out = cand[order[sel]].rho_e;
}

// Penetrations. Past the cap, which points are solved changes with the tool (the deepest swap
// places): a point's penetration is tapered to zero as its depth nears that of the deepest
// point left out, so a swap at equal depth moves no force (it jumped 0.1 N for 1 um). The taper
// is at most band - r wide, so a point entering the band and left out moves none either.
static void set_delta(const tool_part* tp, work* w) {
    const double taper = fmin(HS_CONTACT_TAPER * tp->r, tp->band - tp->r);
    for (int k = tp->m0; k < tp->m0 + tp->m; ++k) {
        w->delta[k] = tp->r - w->set[k].rho_e;
        if (w->delta[k] > 0 && tp->rho_out < INFINITY)
            w->delta[k] *= fmin(1.0, fmax(0.0, (tp->rho_out - w->set[k].rho_e) / taper));
        w->wc.have[k] = 0;
    }
}

// Start from the previous tick's contact when given (it rarely changes between ticks: usually
// one solve): its pushing points (prev), or else, deepest first, each point whose vertices
// were all contact nodes and that reaches a contact node no earlier one did (a few points
// cover the old contact); with neither, from the penetrating set.
static void warm_start(const hs_contact_snapshot* s, const tool_part* tp, work* w) {
    unsigned int covered = 0; // bit j: warm_nodes[j] reached
    for (int i = tp->m0; i < tp->m0 + tp->m; ++i) {
        const feat* f = &w->set[i];
        w->act[i] = w->delta[i] > 0;
        if (tp->prev && tp->prev->features > 0) {
            int pk[3], found = 0;
            point_nodes(s, f, pk);
            for (int j = 0; j < tp->prev->features && !found; ++j) {
                const int* q = tp->prev->point_nodes[j];
                found = q[0] == pk[0] && q[1] == pk[1] && q[2] == pk[2];
            }
            w->act[i] = (unsigned char)found;
            continue;
        }
        if (tp->warm_n <= 0) continue;
        unsigned int mine = 0;
        int all = 1;
        for (int k = 0; k < f->kind && all; ++k) {
            int node = s->node[f->v[k]], found = -1;
            for (int j = 0; j < tp->warm_n && j < 32 && found < 0; ++j)
                if (tp->warm_nodes[j] == node) found = j;
            all = found >= 0;
            if (all) mine |= 1u << found;
        }
        w->act[i] = (unsigned char)(all && (mine & ~covered) && w->delta[i] > 0);
        if (w->act[i]) covered |= mine;
    }
}

// Block principal pivoting first (every infeasible point changes side at once: two or three
// solves from a fair start), Murty's single least-index flips after BLOCK_PIVOTS (finite for a
// positive definite matrix whatever the start). Returns 1 converged, 0 not, -1 W_AA not SPD.
static int pivot(work* w, double r, int* passes, int* dropped /* [tools] */) {
    cols* wc = &w->wc;
    const int m = w->m;
    for (int piv = 0; piv < MAX_PIVOTS; ++piv) {
        *passes = piv + 1;
        for (int i = 0; i < m; ++i)
            if (w->act[i]) build_col(wc, i);
        if (solve_active(w) != 0) return -1;
        int flip = -1;
        for (int i = 0; i < m; ++i) {
            w->bad[i] = 0;
            if (w->act[i]) {
                w->bad[i] = w->lambda[i] < 0; // would pull: leaves the contact
            } else {
                double wi = -w->delta[i];
                for (int j = 0; j < m; ++j)
                    if (w->act[j]) wi += wc->w[i * w->cap + j] * w->lambda[j];
                w->bad[i] = wi < -1e-12 * r; // pushed into the sphere: joins the contact
            }
            if (w->bad[i] && flip < 0) flip = i;
        }
        if (flip < 0) return 1;
        for (int i = 0; i < m; ++i) {
            if (!(piv < BLOCK_PIVOTS ? w->bad[i] : i == flip)) continue;
            if (w->act[i]) ++dropped[w->owner[i]];
            w->act[i] = !w->act[i];
        }
    }
    return 0;
}

// The vertices' displacements under every tool's pushing points (w->ia[0..k)).
static void displacements(work* w, int k) {
    for (int a = 0; a < w->nv; ++a)
        for (int p = 0; p < 3; ++p) w->uv[3 * a + p] = 0;
    for (int i = 0; i < k; ++i) {
        int j = w->ia[i];
        for (int a = 0; a < w->nv; ++a)
            for (int p = 0; p < 3; ++p) w->uv[3 * a + p] += cn_at(&w->wc, a, j)[p] * w->lambda[j];
    }
}

// Tool t's part of the result: its pushing points' forces on their vertices, those vertices'
// displacements (under all tools' forces), the force on the tool.
static void tool_result(const hs_contact_snapshot* s, work* w, int k, int t, hs_contact* out) {
    int* used = w->used;
    for (int a = 0; a < w->nv; ++a) {
        used[a] = 0;
        for (int p = 0; p < 3; ++p) w->fv[3 * a + p] = 0;
    }
    for (int i = 0; i < k; ++i) {
        if (w->owner[w->ia[i]] != t) continue;
        const feat* f = &w->set[w->ia[i]];
        double l = w->lambda[w->ia[i]];
        point_nodes(s, f, out->point_nodes[out->features++]);
        for (int q = 0; q < f->kind; ++q) {
            used[f->lv[q]] = 1;
            for (int p = 0; p < 3; ++p) w->fv[3 * f->lv[q] + p] += f->w[q] * l * f->n[p];
        }
        for (int p = 0; p < 3; ++p) out->force_n[p] -= l * f->n[p];
    }
    for (int a = 0; a < w->nv; ++a) {
        if (!used[a] || out->n >= HS_MAX_CONTACT) continue;
        out->node[out->n] = s->node[w->vtx[a]];
        memcpy(out->f_n[out->n], w->fv + 3 * a, 3 * sizeof(double));
        memcpy(out->d_m[out->n], w->uv + 3 * a, 3 * sizeof(double));
        out->n++;
    }
}

// Stiffness K_t = -dF_t/dp_t of each tool with the active set and the points' features fixed.
// F_t = -sum_{i of t} lambda_i n_i, (W + eps I) lambda = delta over the active set (all tools),
// delta_i = r - rho_i + n_i . P_i (P_i = sum_a w_ia pre_a), d delta_i/dp_t = n_i^T + P_i^T Dn_i
// + sum_a (n_i . pre_a) dw_ia for a point of tool t (the point slides in its feature,
// perpendicular to n_i) and zero for the others, so with lambda held
//     d(W lambda - delta)_i/dp_t + [i of t] n_i^T = [i of t] ((U_i - P_i)^T Dn_i
//                        + sum_a (n_i . (u_a - pre_a)) dw_ia) + sum_b cn_bi^T E_b,
// U_i = sum_a w_ia u_a (the point's displacement), Dn_i = dn_i/dp, dw_ia = dw_ia/dp,
// E_b = sum_{j of t} lambda_j (n_j dw_jb + w_jb Dn_j) (= df_b/dp_t with lambda held): the last
// term is how tool t's push moves every point, the other tools' included. Then
//     dlambda/dp_t = (W + eps I)^-1 G,  G_i = [i of t] n_i^T - d(W lambda)_i/dp_t,
//     K_t = sum_{i of t} n_i (dlambda_i/dp_t) + lambda_i Dn_i.
// A faded point adds S_i = W_ii (1 / f_i - 1) to its diagonal, so lambda_i dS_i/dp to
// d(W lambda)_i/dp: dS_i = (1 / f_i - 1) dW_ii - W_ii / f_i^2 df_i, with
// dW_ii = 2 sum_a (n_i . cn_ai) dw_ia + 2 (sum_a w_ia cn_ai)^T Dn_i and, on the ramp,
// df_i = -N_i^T Dn_i / FADE_COS.
// The factor of W over the pushing points and their Dn_i, dw_ia. Returns -1 if not SPD.
static int stiffness_prepare(const hs_contact_snapshot* s, work* w, int k) {
    // Usually every active point pushes: the pivoting's last factor is this one.
    if (k != w->n_idx || memcmp(w->ia, w->idx, (size_t)k * sizeof *w->ia) != 0) {
        for (int i = 0; i < k; ++i)
            for (int j = 0; j < k; ++j) w->a[i * k + j] = w_sym(&w->wc, w->ia[i], w->ia[j]);
        if (hs_dense_cholesky(w->a, k) != 0) return -1;
    }
    for (int i = 0; i < k; ++i) {
        feat_dn(s, &w->set[w->ia[i]], w->dn + 9 * i);
        feat_dw(s, &w->set[w->ia[i]], (double(*)[3])(w->dw + 9 * i));
    }
    return 0;
}

// The own terms of G_i's component c for pushing point i (position in ia) of the tool.
static double own_terms(const hs_contact_snapshot* s, const work* w, int i, int c) {
    const feat* f = &w->set[w->ia[i]];
    const double *dn = w->dn + 9 * i, *dw = w->dw + 9 * i;
    double ui[3] = {0, 0, 0}, nq[3] = {0, 0, 0}; // nq[q] = n . (u - pre) at vertex q
    for (int q = 0; q < f->kind; ++q) {
        const double* u = w->uv + 3 * f->lv[q];
        for (int p = 0; p < 3; ++p) ui[p] += f->w[q] * u[p];
        nq[q] = hs_dot3(f->n, u) - hs_dot3(f->n, s->pre_m[f->v[q]]);
    }
    double d = 0;
    for (int p = 0; p < 3; ++p) d += (ui[p] - f->pre[p]) * dn[3 * p + c];
    for (int q = 0; q < f->kind; ++q) d += nq[q] * dw[3 * q + c];
    if (f->fade < 1) {
        const int j = w->ia[i];
        double own[3] = {0, 0, 0}, dwii = 0, dfi = 0; // own: the point's move per lambda_j
        for (int q = 0; q < f->kind; ++q) {
            const double* cq = cn_at(&w->wc, f->lv[q], j);
            for (int p = 0; p < 3; ++p) own[p] += f->w[q] * cq[p];
            dwii += 2 * hs_dot3(f->n, cq) * dw[3 * q + c];
        }
        for (int p = 0; p < 3; ++p) dwii += 2 * own[p] * dn[3 * p + c];
        if (f->fade > FADE_MIN)
            for (int p = 0; p < 3; ++p) dfi -= f->nt[p] * dn[3 * p + c] / FADE_COS;
        d += w->lambda[j] *
             ((1.0 / f->fade - 1.0) * dwii - w->wc.wjj[j] / (f->fade * f->fade) * dfi);
    }
    return d;
}

static void tool_stiffness(const hs_contact_snapshot* s, work* w, int k, int t, hs_contact* out) {
    double* e = w->e;
    memset(e, 0, (size_t)w->nv * 9 * sizeof(double));
    int* eb_list = w->used; // the vertices tool t pushes: E_b is zero elsewhere
    int ne = 0;
    for (int a = 0; a < w->nv; ++a) w->x[a] = 0; // 1: listed
    for (int i = 0; i < k; ++i) {
        const feat* f = &w->set[w->ia[i]];
        if (w->owner[w->ia[i]] != t) continue;
        double l = w->lambda[w->ia[i]];
        const double *dn = w->dn + 9 * i, *dw = w->dw + 9 * i;
        for (int q = 0; q < f->kind; ++q) {
            if (w->x[f->lv[q]] == 0) {
                w->x[f->lv[q]] = 1;
                eb_list[ne++] = f->lv[q];
            }
            double* eb = e + 9 * f->lv[q];
            for (int p = 0; p < 3; ++p)
                for (int c = 0; c < 3; ++c)
                    eb[3 * p + c] += l * (f->n[p] * dw[3 * q + c] + f->w[q] * dn[3 * p + c]);
        }
    }
    double* g = w->g; // g[p * cap + i]
    for (int i = 0; i < k; ++i) {
        const feat* f = &w->set[w->ia[i]];
        const int mine = w->owner[w->ia[i]] == t;
        for (int c = 0; c < 3; ++c) {
            double d = mine ? own_terms(s, w, i, c) : 0;
            for (int q = 0; q < ne; ++q) {
                const int b = eb_list[q];
                const double* cb = cn_at(&w->wc, b, w->ia[i]);
                d += cb[0] * e[9 * b + c] + cb[1] * e[9 * b + 3 + c] + cb[2] * e[9 * b + 6 + c];
            }
            g[c * w->cap + i] = (mine ? f->n[c] : 0) - d;
        }
    }
    for (int p = 0; p < 3; ++p) hs_dense_cholesky_solve(w->a, k, g + p * w->cap);
    memset(out->stiffness_n_m, 0, sizeof out->stiffness_n_m);
    for (int i = 0; i < k; ++i) {
        if (w->owner[w->ia[i]] != t) continue;
        const feat* f = &w->set[w->ia[i]];
        double l = w->lambda[w->ia[i]];
        for (int p = 0; p < 3; ++p)
            for (int q = 0; q < 3; ++q)
                out->stiffness_n_m[3 * p + q] +=
                    f->n[p] * g[q * w->cap + i] + l * w->dn[9 * i + 3 * p + q];
    }
}

static int snapshot_usable(const hs_contact_snapshot* s) {
    return s->n_cand >= 0 && s->n_cand <= HS_CONTACT_MAX_CAND && s->n_tri >= 0 &&
           s->n_tri <= HS_CONTACT_MAX_TRI;
}

// Each tool's points, appended to w's set; the tools' results started in out.
static void select_all(const hs_contact_snapshot* s, int n, tool_part* tp, work* w,
                       hs_contact* out) {
    feat cand[MAX_FEAT];
    int order[MAX_FEAT];
    w->m = w->nv = 0;
    for (int t = 0; t < n; ++t) {
        hs_contact* o = &out[t];
        memset(o, 0, sizeof *o);
        o->version = s->version;
        for (int k = 0; k < 3; ++k) o->tool_m[k] = tp[t].p[k];
        tp[t].r = tool_radius(s, t);
        tp[t].near = HS_CONTACT_BAND * tp[t].r;
        tp[t].m0 = w->m;
        tp[t].m = 0;
        if (t < HS_MAX_TOOLS && s->tool_off[t]) continue;
        if (!hs_vec3_finite(tp[t].p) || !(tp[t].r > 0) || !snapshot_usable(s)) {
            o->failed = s->n_cand > 0 || s->n_tri != 0; // an empty snapshot is just no contact
            continue;
        }
        // The tool must stay inside the region whose surface the snapshot lists.
        double clearance = fmin(DBL_MAX, tool_cover(s, t, tp[t].p, tp[t].r));
        int nc = gather(s, &tp[t], clearance, cand, order, o);
        if (nc == 0 || cand[order[0]].rho_e >= tp[t].r) continue; // nothing penetrates
        select_points(s, cand, order, nc, t, &tp[t], w);
        set_delta(&tp[t], w);
    }
}

// The one contact problem of n tools on snapshot s (tp[t].p their centres), in workspace w:
// every tool's points solved together, coupled through W's blocks between the tools' nodes.
static void solve_tools(const hs_contact_snapshot* s, int n, tool_part* tp, work* w,
                        hs_contact* out) {
    select_all(s, n, tp, w, out);
    if (w->m == 0) return;
    // Contact compliance: a constant of the snapshot (so it adds nothing to the stiffness).
    double eps = 0, r_tol = INFINITY;
    for (int i = 0; i < s->n_cand; ++i) {
        const double* b = s->c[i][i];
        eps += (b[0] + b[4] + b[8]) / 3;
    }
    eps = HS_CONTACT_SOFTNESS * eps / (s->n_cand > 0 ? s->n_cand : 1);
    // W by columns, on demand: column j (cn[.][j], W[.][j]) is built when point j first becomes
    // active; an inactive point's residual needs only the active columns, so the cost follows
    // the few points in contact, not all the points in the band.
    cols* wc = &w->wc;
    wc->s = s;
    wc->set = w->set;
    wc->vtx = w->vtx;
    wc->m = w->m;
    wc->nv = w->nv;
    wc->eps = eps;
    wc->approx = 0;
    for (int t = 0; t < n; ++t) {
        warm_start(s, &tp[t], w);
        if (tp[t].m > 0) r_tol = fmin(r_tol, tp[t].r);
    }
    int dropped[HS_MAX_TOOLS] = {0}, passes = 0;
    int converged = pivot(w, r_tol, &passes, dropped);
    for (int t = 0; t < n; ++t) {
        out[t].passes = passes;
        out[t].dropped = dropped[t];
        out[t].failed = out[t].failed || (converged < 0 && tp[t].m > 0);
        out[t].approx = wc->approx;
    }
    if (converged < 0) return;
    int k = 0;
    for (int i = 0; i < w->m; ++i) {
        if (!w->act[i] || (!converged && w->lambda[i] < 0)) w->lambda[i] = 0; // never pull
        if (w->lambda[i] > 0) w->ia[k++] = i;
    }
    displacements(w, k);
    for (int t = 0; t < n; ++t) tool_result(s, w, k, t, &out[t]);
    if (k == 0) return;
    if (stiffness_prepare(s, w, k) != 0) {
        for (int t = 0; t < n; ++t) out[t].failed = out[t].features > 0;
        return;
    }
    for (int t = 0; t < n; ++t)
        if (out[t].features > 0) tool_stiffness(s, w, k, t, &out[t]);
}

static void solve(const hs_contact_snapshot* s, const double tool_m[3], int warm_n,
                  const int* warm_nodes, const hs_contact* prev, hs_contact* out) {
    feat set[M];
    double d[WORK_DOUBLES(M)];
    int in[WORK_INTS(M)];
    unsigned char b[WORK_BYTES(M)];
    work w;
    work_carve(&w, M, set, d, in, b);
    tool_part tp = {.p = tool_m, .warm_n = warm_n, .warm_nodes = warm_nodes, .prev = prev};
    solve_tools(s, 1, &tp, &w, out);
}

void hs_contact_solve(const hs_contact_snapshot* s, const double tool_m[3], int warm_n,
                      const int* warm_nodes, hs_contact* out) {
    solve(s, tool_m, warm_n, warm_nodes, NULL, out);
}

void hs_contact_solve_from(const hs_contact_snapshot* s, const double tool_m[3],
                           const hs_contact* prev, hs_contact* out) {
    solve(s, tool_m, 0, NULL, prev, out);
}

hs_status hs_contact_work_create(int n_tools, hs_contact_work** out) {
    *out = NULL;
    if (n_tools < 1 || n_tools > HS_MAX_TOOLS) return HS_ERR_INVALID;
    const int cap = n_tools * M;
    hs_contact_work* w = hs_calloc(1, sizeof *w);
    if (!w) return HS_ERR_NOMEM;
    w->n_tools = n_tools;
    w->set = hs_calloc((size_t)cap, sizeof *w->set);
    w->d = hs_calloc((size_t)WORK_DOUBLES(cap), sizeof *w->d);
    w->in = hs_calloc((size_t)WORK_INTS(cap), sizeof *w->in);
    w->b = hs_calloc((size_t)WORK_BYTES(cap), 1);
    if (!w->set || !w->d || !w->in || !w->b) {
        hs_contact_work_destroy(&w);
        return HS_ERR_NOMEM;
    }
    *out = w;
    return HS_OK;
}

void hs_contact_work_destroy(hs_contact_work** w) {
    if (!w || !*w) return;
    hs_free((*w)->set);
    hs_free((*w)->d);
    hs_free((*w)->in);
    hs_free((*w)->b);
    hs_free(*w);
    *w = NULL;
}

int hs_contact_work_tools(const hs_contact_work* w) {
    return w ? w->n_tools : 0;
}

void hs_contact_solve_tools(const hs_contact_snapshot* s, int n_tools, const double* tool_m,
                            const hs_contact* prev, hs_contact_work* cw, hs_contact* out) {
    HS_ASSERT(cw && n_tools >= 1 && n_tools <= cw->n_tools);
    work w;
    work_carve(&w, n_tools * M, cw->set, cw->d, cw->in, cw->b);
    tool_part tp[HS_MAX_TOOLS];
    memset(tp, 0, sizeof tp);
    for (int t = 0; t < n_tools; ++t) {
        tp[t].p = tool_m + 3 * t;
        tp[t].prev = prev ? &prev[t] : NULL;
    }
    solve_tools(s, n_tools, tp, &w, out);
}

int hs_contact_snapshot_add_tris(hs_contact_snapshot* s, const hs_mesh* mesh) {
    s->n_tri = 0;
    for (int t = 0; t < mesh->n_tris && s->n_tri < HS_CONTACT_MAX_TRI; ++t) {
        int c[3], ok = 1;
        for (int k = 0; k < 3 && ok; ++k) {
            c[k] = -1;
            for (int i = 0; i < s->n_cand && c[k] < 0; ++i)
                if (s->node[i] == mesh->tris[3 * t + k]) c[k] = i;
            ok = c[k] >= 0;
        }
        if (!ok) continue;
        memcpy(s->tri[s->n_tri++], c, sizeof c);
    }
    hs_contact_snapshot_bound_tris(s);
    return s->n_tri;
}

void hs_contact_snapshot_bound_tris(hs_contact_snapshot* s) {
    for (int t = 0; t < s->n_tri && t < HS_CONTACT_MAX_TRI; ++t) {
        double* b = s->tri_bound[t];
        const int* tv = s->tri[t];
        int ok = 1;
        for (int k = 0; k < 3; ++k) ok = ok && tv[k] >= 0 && tv[k] < s->n_cand;
        if (!ok) { // ignored by the solve
            b[0] = b[1] = b[2] = b[3] = 0;
            continue;
        }
        for (int k = 0; k < 3; ++k)
            b[k] = (s->surf_m[tv[0]][k] + s->surf_m[tv[1]][k] + s->surf_m[tv[2]][k]) / 3;
        double r2 = 0;
        for (int j = 0; j < 3; ++j) {
            const double* q = s->surf_m[tv[j]];
            double d[3] = {q[0] - b[0], q[1] - b[1], q[2] - b[2]};
            r2 = fmax(r2, hs_dot3(d, d));
        }
        b[3] = sqrt(r2);
    }
}

void hs_contact_model(const hs_contact* c, double min_radius_m, double max_radius_m,
                      double timeout_s, hs_haptic_model* m) {
    memset(m, 0, sizeof *m);
    m->seq = c->version;
    for (int k = 0; k < 3; ++k) {
        m->force_n[k] = c->force_n[k];
        m->anchor_m[k] = c->tool_m[k];
    }
    // The contact field is not exactly conservative (the point geometry turns with the tool), so
    // -dF/dp has a small antisymmetric part and, near edges, negative directions: a driver
    // rendering it would gain energy. The model sent is its passive part, the nearest
    // symmetric positive semi-definite matrix (docs/protocol.md: dF/dp negative semi-definite).
    hs_mat3_psd_part(c->stiffness_n_m, m->stiffness_n_m);
    double rad = c->clearance_m;
    if (rad < min_radius_m) rad = min_radius_m;
    if (rad > max_radius_m) rad = max_radius_m;
    m->radius_m = rad;
    m->timeout_s = timeout_s;
}
