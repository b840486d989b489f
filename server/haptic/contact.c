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
// shallower than 3/4 r (docs/haptics.md, "Presses a radius deep").
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

// W's columns as they are needed (see hs_contact_solve).
typedef struct cols {
    const hs_contact_snapshot* s;
    const feat* set;
    const int* vtx; // local vertex -> candidate index
    int m, nv;
    double eps;
    int approx;
    unsigned char have[M];
    double wjj[M];      // W_jj before a faded point's softening (W_jj (1 / fade - 1) added)
    double cn[M][M][3]; // cn[a][j] = sum_k w_jk C(a, v_jk) n_j: vertex a's move per unit lambda_j
    double w[M * M];    // w[i * M + j] = n_i . sum_k w_ik cn[v_ik][j] (+ eps on the diagonal)
} cols;

static void build_col(cols* c, int j) {
    if (c->have[j]) return;
    const feat* f = &c->set[j];
    for (int a = 0; a < c->nv; ++a) {
        double* o = c->cn[a][j];
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
        for (int k = 0; k < g->kind; ++k) sum += g->w[k] * hs_dot3(g->n, c->cn[g->lv[k]][j]);
        c->w[i * M + j] = sum;
    }
    // A faded point: its compliance grows to W_jj / fade, so it pushes about fade times as hard.
    c->wjj[j] = c->w[j * M + j];
    c->w[j * M + j] += c->wjj[j] * (1.0 / f->fade - 1.0) + c->eps;
    c->have[j] = 1;
}

// Symmetric entry of W for two built columns.
static double w_sym(const cols* c, int i, int j) {
    return 0.5 * (c->w[i * M + j] + c->w[j * M + i]);
}

// Solve W_AA lambda_A = delta_A for the active set (columns built); lambda = 0 elsewhere.
// Returns -1 if W_AA is not positive definite.
static int solve_active(const cols* c, const double* delta, const unsigned char* act, int m,
                        double* lambda) {
    double a[M * M], x[M];
    int idx[M], k = 0;
    for (int i = 0; i < m; ++i)
        if (act[i]) idx[k++] = i;
    for (int i = 0; i < k; ++i) {
        for (int j = 0; j < k; ++j) a[i * k + j] = w_sym(c, idx[i], idx[j]);
        x[i] = delta[idx[i]];
    }
    for (int i = 0; i < m; ++i) lambda[i] = 0;
    if (k == 0) return 0;
    if (hs_dense_cholesky(a, k) != 0) return -1;
    hs_dense_cholesky_solve(a, k, x);
    for (int i = 0; i < k; ++i) lambda[idx[i]] = x[i];
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

static void solve(const hs_contact_snapshot* s, const double tool_m[3], int warm_n,
                  const int* warm_nodes, const hs_contact* prev, hs_contact* out) {
    memset(out, 0, sizeof *out);
    out->version = s->version;
    for (int k = 0; k < 3; ++k) out->tool_m[k] = tool_m[k];
    const double r = s->probe_radius_m;
    double clearance = DBL_MAX;
    if (!isfinite(tool_m[0]) || !isfinite(tool_m[1]) || !isfinite(tool_m[2]) || !(r > 0) ||
        s->n_cand < 0 || s->n_cand > HS_CONTACT_MAX_CAND || s->n_tri < 0 ||
        s->n_tri > HS_CONTACT_MAX_TRI) {
        out->failed = s->n_cand > 0 || s->n_tri != 0; // an empty snapshot is just no contact
        return;
    }

    // The tool must stay inside the region whose surface the snapshot lists.
    double off[3] = {tool_m[0] - s->centre_m[0], tool_m[1] - s->centre_m[1],
                     tool_m[2] - s->centre_m[2]};
    double cover = s->reach_m - r - sqrt(hs_dot3(off, off));
    if (cover < clearance) clearance = cover;

    // Contact points: penetrating ones and those outside the sphere within the band (which the
    // push on their neighbours may carry into the sphere: on liver2 a point 1.25 r from the
    // centre on the sphere's flank was), deepest first, each geometric point once.
    const double near = HS_CONTACT_BAND * r;
    feat cand[MAX_FEAT];
    int order[MAX_FEAT], nc = 0; // cand[order[k]]: deepest first, key[k] its rho
    double key[MAX_FEAT];
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
            double d[3] = {b[0] - tool_m[0], b[1] - tool_m[1], b[2] - tool_m[2]};
            double lim = near + b[3] + pre_max, d2 = hs_dot3(d, d);
            if (d2 >= lim * lim) {
                double far = clearance + r + b[3] + pre_max;
                if (d2 < far * far) clearance = sqrt(d2) - b[3] - r - pre_max;
                continue;
            }
            if (!tri_feature(s, i, tool_m, r, f)) continue;
        } else { // node contact: every candidate node is a contact point
            f->kind = HS_FEAT_VERTEX;
            f->v[0] = i;
            f->w[0] = 1;
            f->tri = -1;
            f->raw = 0;
            f->fade = 1;
            double d[3] = {s->surf_m[i][0] - tool_m[0], s->surf_m[i][1] - tool_m[1],
                           s->surf_m[i][2] - tool_m[2]};
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
    if (nc == 0 || cand[order[0]].rho_e >= r) return; // nothing penetrates

    // The deepest points whose vertices fit in M nodes. A point outside the sphere joins only
    // if the push can carry it in: it moves by about the deepest penetration at most, so the
    // band narrows to r + 1.5 x that when it is less than HS_CONTACT_BAND r (continuous in p:
    // a point crossing its edge carries no force).
    const double band = fmin(near, r + 1.5 * (r - cand[order[0]].rho_e));
    feat set[M];
    int m = 0, nv = 0, vtx[M]; // local vertices: candidate indices
    double rho_out = INFINITY; // the deepest point in the band the cap left out
    int sel = 0;
    for (; sel < nc && m < M && cand[order[sel]].rho_e < band; ++sel) {
        feat* f = &cand[order[sel]];
        int add = 0;
        for (int k = 0; k < f->kind; ++k) {
            int j = 0;
            while (j < nv && vtx[j] != f->v[k]) ++j;
            if (j == nv) ++add;
        }
        if (nv + add > M) {
            if (rho_out == INFINITY) rho_out = f->rho_e;
            continue;
        }
        for (int k = 0; k < f->kind; ++k) {
            int j = 0;
            while (j < nv && vtx[j] != f->v[k]) ++j;
            if (j == nv) vtx[nv++] = f->v[k];
            f->lv[k] = j;
        }
        set[m] = *f;
        if (f->raw) {
            double inv = 1.0 / f->rho;
            for (int k = 0; k < 3; ++k) set[m].n[k] *= inv;
            set[m].raw = 0;
            // the fade, for the few points selected (n now unit)
            const int* tv = s->tri[f->tri];
            tri_normal(s->surf_m[tv[0]], s->surf_m[tv[1]], s->surf_m[tv[2]], set[m].nt);
            double in = -hs_dot3(set[m].n, set[m].nt); // cosine to the inward normal
            set[m].fade = fmax(FADE_MIN, fmin(1.0, in / FADE_COS));
        }
        ++m;
    }

    // Contact compliance: a constant of the snapshot (so it adds nothing to the stiffness).
    double eps = 0;
    for (int i = 0; i < s->n_cand; ++i) {
        const double* b = s->c[i][i];
        eps += (b[0] + b[4] + b[8]) / 3;
    }
    eps = HS_CONTACT_SOFTNESS * eps / (s->n_cand > 0 ? s->n_cand : 1);

    // W by columns, on demand: column j (cn[.][j], W[.][j]) is built when point j first becomes
    // active; an inactive point's residual needs only the active columns, so the cost follows
    // the few points in contact, not all the points in the band.
    cols wc;
    wc.s = s;
    wc.set = set;
    wc.vtx = vtx;
    wc.m = m;
    wc.nv = nv;
    wc.eps = eps;
    wc.approx = 0;
    if (sel < nc && m == M && cand[order[sel]].rho_e < band && cand[order[sel]].rho_e < rho_out)
        rho_out = cand[order[sel]].rho_e;
    // Past the cap, which points are solved changes with the tool (the deepest swap places):
    // a point's penetration is tapered to zero as its depth nears that of the deepest point
    // left out, so a swap at equal depth moves no force (it jumped 0.1 N for 1 um). The taper
    // is at most band - r wide, so a point entering the band and left out moves none either.
    const double taper = fmin(HS_CONTACT_TAPER * r, band - r);
    double delta[M];
    for (int k = 0; k < m; ++k) {
        delta[k] = r - set[k].rho_e;
        if (delta[k] > 0 && rho_out < INFINITY)
            delta[k] *= fmin(1.0, fmax(0.0, (rho_out - set[k].rho_e) / taper));
        wc.have[k] = 0;
    }

    // Start from the previous tick's contact when given (it rarely changes between ticks:
    // usually one solve): its pushing points (prev), or else, deepest first, each point whose
    // vertices were all contact nodes and that reaches a contact node no earlier one did (a
    // few points cover the old contact); with neither, from the penetrating set.
    unsigned char act[M];
    double lambda[M];
    unsigned int covered = 0; // bit j: warm_nodes[j] reached
    for (int i = 0; i < m; ++i) {
        act[i] = delta[i] > 0;
        if (prev && prev->features > 0) {
            int pk[3], found = 0;
            point_nodes(s, &set[i], pk);
            for (int j = 0; j < prev->features && !found; ++j)
                found = prev->point_nodes[j][0] == pk[0] && prev->point_nodes[j][1] == pk[1] &&
                        prev->point_nodes[j][2] == pk[2];
            act[i] = (unsigned char)found;
            continue;
        }
        if (warm_n <= 0) continue;
        unsigned int mine = 0;
        int all = 1;
        for (int k = 0; k < set[i].kind && all; ++k) {
            int node = s->node[set[i].v[k]], found = -1;
            for (int j = 0; j < warm_n && j < 32 && found < 0; ++j)
                if (warm_nodes[j] == node) found = j;
            all = found >= 0;
            if (all) mine |= 1u << found;
        }
        act[i] = (unsigned char)(all && (mine & ~covered) && delta[i] > 0);
        if (act[i]) covered |= mine;
    }
    // Block principal pivoting first (every infeasible point changes side at once: two or
    // three solves from a fair start), Murty's single least-index flips after BLOCK_PIVOTS
    // (finite for a positive definite matrix whatever the start).
    int converged = 0;
    for (int piv = 0; piv < MAX_PIVOTS; ++piv) {
        out->passes = piv + 1;
        for (int i = 0; i < m; ++i)
            if (act[i]) build_col(&wc, i);
        if (solve_active(&wc, delta, act, m, lambda) != 0) {
            out->failed = 1;
            return;
        }
        unsigned char bad[M];
        int flip = -1;
        for (int i = 0; i < m; ++i) {
            bad[i] = 0;
            if (act[i]) {
                bad[i] = lambda[i] < 0; // would pull: leaves the contact
            } else {
                double wi = -delta[i];
                for (int j = 0; j < m; ++j)
                    if (act[j]) wi += wc.w[i * M + j] * lambda[j];
                bad[i] = wi < -1e-12 * r; // pushed into the sphere: joins the contact
            }
            if (bad[i] && flip < 0) flip = i;
        }
        if (flip < 0) {
            converged = 1;
            break;
        }
        for (int i = 0; i < m; ++i) {
            if (!(piv < BLOCK_PIVOTS ? bad[i] : i == flip)) continue;
            if (act[i]) ++out->dropped;
            act[i] = !act[i];
        }
    }
    for (int i = 0; i < m; ++i)
        if (!act[i] || (!converged && lambda[i] < 0)) lambda[i] = 0; // never pull
    out->approx = wc.approx;

    // Result: the active points' forces on their vertices, the vertices' displacements.
    int ia[M], k = 0;
    for (int i = 0; i < m; ++i)
        if (lambda[i] > 0) ia[k++] = i;
    out->features = k;
    for (int i = 0; i < k; ++i) point_nodes(s, &set[ia[i]], out->point_nodes[i]);
    if (k == 0) return;
    double fv[M][3], uv[M][3];
    int used[M];
    for (int a = 0; a < nv; ++a) {
        used[a] = 0;
        for (int p = 0; p < 3; ++p) fv[a][p] = uv[a][p] = 0;
    }
    for (int i = 0; i < k; ++i) {
        int j = ia[i];
        for (int a = 0; a < nv; ++a)
            for (int p = 0; p < 3; ++p) uv[a][p] += wc.cn[a][j][p] * lambda[j];
    }
    for (int i = 0; i < k; ++i) {
        const feat* f = &set[ia[i]];
        double l = lambda[ia[i]];
        for (int q = 0; q < f->kind; ++q) {
            used[f->lv[q]] = 1;
            for (int p = 0; p < 3; ++p) fv[f->lv[q]][p] += f->w[q] * l * f->n[p];
        }
        for (int p = 0; p < 3; ++p) out->force_n[p] -= l * f->n[p];
    }
    for (int a = 0; a < nv; ++a) {
        if (!used[a]) continue;
        out->node[out->n] = s->node[vtx[a]];
        memcpy(out->f_n[out->n], fv[a], sizeof fv[a]);
        memcpy(out->d_m[out->n], uv[a], sizeof uv[a]);
        out->n++;
    }

    // Stiffness K = -dF/dp with the active set and the points' features fixed. F = -sum_i
    // lambda_i n_i, (W + eps I) lambda = delta over the active set, delta_i = r - rho_i +
    // n_i . P_i (P_i = sum_a w_ia pre_a), d delta_i/dp = n_i^T + P_i^T Dn_i + sum_a (n_i .
    // pre_a) dw_ia (the point slides in its feature, perpendicular to n_i), so with lambda held
    //     d(W lambda - delta)_i/dp + n_i^T = (U_i - P_i)^T Dn_i + sum_a (n_i . (u_a - pre_a)) dw_ia
    //                                         + sum_b cn_bi^T E_b,
    // U_i = sum_a w_ia u_a (the point's displacement), Dn_i = dn_i/dp, dw_ia = dw_ia/dp,
    // E_b = sum_j lambda_j (n_j dw_jb + w_jb Dn_j) (= df_b/dp with lambda held), and
    //     dlambda/dp = (W + eps I)^-1 G,  G_i = n_i^T - d(W lambda)_i/dp,
    //     K = sum_i n_i (dlambda_i/dp) + sum_i lambda_i Dn_i.
    // A faded point adds S_i = W_ii (1 / f_i - 1) to its diagonal, so lambda_i dS_i/dp to
    // d(W lambda)_i/dp: dS_i = (1 / f_i - 1) dW_ii - W_ii / f_i^2 df_i, with
    // dW_ii = 2 sum_a (n_i . cn_ai) dw_ia + 2 (sum_a w_ia cn_ai)^T Dn_i and, on the ramp,
    // df_i = -N_i^T Dn_i / FADE_COS.
    double a[M * M], g[3][M], dn[M][9], dw[M][3][3], e[M][9];
    for (int i = 0; i < k; ++i)
        for (int j = 0; j < k; ++j) a[i * k + j] = w_sym(&wc, ia[i], ia[j]);
    if (hs_dense_cholesky(a, k) != 0) {
        out->failed = 1;
        return;
    }
    memset(e, 0, sizeof e);
    for (int i = 0; i < k; ++i) {
        const feat* f = &set[ia[i]];
        double l = lambda[ia[i]];
        feat_dn(s, f, dn[i]);
        feat_dw(s, f, dw[i]);
        for (int q = 0; q < f->kind; ++q) {
            double* eb = e[f->lv[q]];
            for (int p = 0; p < 3; ++p)
                for (int c = 0; c < 3; ++c)
                    eb[3 * p + c] += l * (f->n[p] * dw[i][q][c] + f->w[q] * dn[i][3 * p + c]);
        }
    }
    for (int i = 0; i < k; ++i) {
        const feat* f = &set[ia[i]];
        double gi[3], ui[3] = {0, 0, 0}, nq[3] = {0, 0, 0}; // nq[q] = n . (u - pre) at vertex q
        for (int q = 0; q < f->kind; ++q) {
            const double* pq = s->pre_m[f->v[q]];
            for (int p = 0; p < 3; ++p) ui[p] += f->w[q] * uv[f->lv[q]][p];
            nq[q] = hs_dot3(f->n, uv[f->lv[q]]) - hs_dot3(f->n, pq);
        }
        for (int p = 0; p < 3; ++p) ui[p] -= f->pre[p];
        for (int c = 0; c < 3; ++c) {
            double d = 0;
            for (int p = 0; p < 3; ++p) d += ui[p] * dn[i][3 * p + c];
            for (int q = 0; q < f->kind; ++q) d += nq[q] * dw[i][q][c];
            for (int b = 0; b < nv; ++b) {
                const double* cb = wc.cn[b][ia[i]];
                d += cb[0] * e[b][c] + cb[1] * e[b][3 + c] + cb[2] * e[b][6 + c];
            }
            if (f->fade < 1) {
                const int j = ia[i];
                const double l = lambda[j];
                double own[3] = {0, 0, 0}, dwii = 0, dfi = 0; // own: the point's move per lambda_j
                for (int q = 0; q < f->kind; ++q) {
                    const double* cq = wc.cn[f->lv[q]][j];
                    for (int p = 0; p < 3; ++p) own[p] += f->w[q] * cq[p];
                    dwii += 2 * hs_dot3(f->n, cq) * dw[i][q][c];
                }
                for (int p = 0; p < 3; ++p) dwii += 2 * own[p] * dn[i][3 * p + c];
                if (f->fade > FADE_MIN)
                    for (int p = 0; p < 3; ++p) dfi -= f->nt[p] * dn[i][3 * p + c] / FADE_COS;
                d += l * ((1.0 / f->fade - 1.0) * dwii - wc.wjj[j] / (f->fade * f->fade) * dfi);
            }
            gi[c] = f->n[c] - d;
        }
        for (int p = 0; p < 3; ++p) g[p][i] = gi[p];
    }
    for (int p = 0; p < 3; ++p) hs_dense_cholesky_solve(a, k, g[p]);
    memset(out->stiffness_n_m, 0, sizeof out->stiffness_n_m);
    for (int i = 0; i < k; ++i) {
        const feat* f = &set[ia[i]];
        double l = lambda[ia[i]];
        for (int p = 0; p < 3; ++p)
            for (int q = 0; q < 3; ++q)
                out->stiffness_n_m[3 * p + q] += f->n[p] * g[q][i] + l * dn[i][3 * p + q];
    }
}

void hs_contact_solve(const hs_contact_snapshot* s, const double tool_m[3], int warm_n,
                      const int* warm_nodes, hs_contact* out) {
    solve(s, tool_m, warm_n, warm_nodes, NULL, out);
}

void hs_contact_solve_from(const hs_contact_snapshot* s, const double tool_m[3],
                           const hs_contact* prev, hs_contact* out) {
    solve(s, tool_m, 0, NULL, prev, out);
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
