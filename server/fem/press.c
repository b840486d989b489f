// SPDX-License-Identifier: GPL-2.0-or-later
// Static equilibrium under a frictionless rigid sphere (see server/fem/press.h): an
// active-set node-to-sphere contact around a Newton (SQP) solver of its own on hs_fem,
// independent of the body's solvers and of the haptic code it is a reference for.
#include "press.h"

#include "sparse.h"

#include <float.h>
#include <math.h>
#include <string.h>

#define HS_PRESS_COOKIE 0x50524553

struct hs_press {
    const hs_mesh* mesh;
    hs_press_def def;
    int n, nf;
    int* dof;          // [3n] free index or -1
    int* free_to_full; // [nf]
    unsigned char* fixed;
    hs_fem* fem;
    hs_csc* a;
    hs_cholesky* chol;
    double *u, *x, *f_el, *f_g, *r, *save, *rhs, *dx; // [3n] except rhs, dx [nf]
    int n_cand;                                       // free surface nodes
    int* cand;                                        // [n_cand] node
    int* cand_of;                                     // [n] candidate index or -1
    double *gap, *p;                                  // [n_cand] gap R - d, m; push along n, N
    unsigned char *act, *prev_act;                    // [n_cand]
    double k;                                         // penalty, N/m
    double centre[3];
    int engaged;      // a sphere is in place (centre valid)
    double* du_last;  // [3n] displacement change of the last increment (secant predictor)
    double last_len;  // its sphere travel, m (0: none)
    double pos_floor; // round-off floor of the residual from the positions, N
    double gap_max, fc_norm, fg_norm, r_norm, el_abs;
    // Surface contact (def.surface): one contact point per boundary triangle with a free
    // vertex, the triangle's point nearest the centre, pushed with p = max(0, lam + k g)
    // (augmented Lagrangian: lam is the multiplier of the last pass).
    int n_tc;          // candidate triangles
    int* tc;           // [n_tc] triangle index
    double* tlam;      // [n_tc] multiplier, N
    double* tp;        // [n_tc] push at the last evaluation, N
    double* tw;        // [3 n_tc] barycentric weights of the nearest point
    double* tn;        // [3 n_tc] outward normal (from the centre to the point)
    double* td;        // [n_tc] distance of the point from the centre, m
    double* te;        // [3 n_tc] unit edge direction when the point is on an edge (else 0)
    unsigned char* tf; // [n_tc] feature of the point (FEAT_*)
    double pen_max;    // deepest point of any candidate triangle inside the sphere, m
};

hs_press_def hs_press_default_def(void) {
    hs_press_def d;
    memset(&d, 0, sizeof d);
    d.fem = hs_fem_default_def();
    d.radius_m = 0.005;
    d.tol = 1e-8;
    d.pen_tol = 1e-3;
    d.max_step = 0.125;
    d.penalty_scale = 1e3;
    d.max_newton = 300;
    d.max_passes = 40;
    d.surface = 0;
    d.cookie = HS_PRESS_COOKIE;
    return d;
}

void hs_press_destroy(hs_press** pp) {
    if (!pp || !*pp) return;
    hs_press* p = *pp;
    hs_fem_destroy(&p->fem);
    hs_csc_destroy(&p->a);
    hs_cholesky_destroy(&p->chol);
    void* bufs[] = {p->du_last, p->dof, p->free_to_full, p->fixed,    p->u,  p->x,    p->f_el,
                    p->f_g,     p->r,   p->save,         p->rhs,      p->dx, p->cand, p->cand_of,
                    p->gap,     p->p,   p->act,          p->prev_act, p->tc, p->tlam, p->tp,
                    p->tw,      p->tn,  p->td,           p->te,       p->tf};
    for (size_t i = 0; i < sizeof bufs / sizeof bufs[0]; ++i) hs_free(bufs[i]);
    hs_free(p);
    *pp = NULL;
}

static hs_status check_def(const hs_press_def* d, hs_err* err) {
    if (d->cookie != HS_PRESS_COOKIE)
        return hs_err_set(err, HS_ERR_INVALID,
                          "hs_press_create: definition not initialised (hs_press_default_def)");
    if (!(d->radius_m > 0 && d->radius_m < 1e3))
        return hs_err_set(err, HS_ERR_INVALID, "hs_press_create: radius %g m (> 0)", d->radius_m);
    if (!(d->tol > 0 && d->tol < 1) || !(d->pen_tol > 0 && d->pen_tol < 1))
        return hs_err_set(err, HS_ERR_INVALID, "hs_press_create: tol %g, pen_tol %g (in (0, 1))",
                          d->tol, d->pen_tol);
    if (!(d->max_step > 0 && d->max_step <= 1) || !(d->penalty_scale > 0 && d->penalty_scale < 1e9))
        return hs_err_set(err, HS_ERR_INVALID,
                          "hs_press_create: max_step %g in (0, 1], penalty "
                          "scale %g > 0",
                          d->max_step, d->penalty_scale);
    if (d->max_newton < 1 || d->max_passes < 1)
        return hs_err_set(err, HS_ERR_INVALID, "hs_press_create: iteration counts must be >= 1");
    for (int c = 0; c < 3; ++c)
        if (!(fabs(d->gravity[c]) <= 1e3))
            return hs_err_set(err, HS_ERR_INVALID, "hs_press_create: gravity[%d] %g", c,
                              d->gravity[c]);
    return HS_OK;
}

// Penalty k from the mean diagonal of the rest stiffness over the free surface nodes: stiff
// against the nodes the sphere can touch, mild enough for the factorisation and for round-off
// (the largest diagonal, on a sliver somewhere, made k so large that k times the round-off of
// a distance exceeded the tolerance).
static hs_status init_penalty(hs_press* p) {
    double* x = p->x;
    memcpy(x, p->mesh->x0, 3 * (size_t)p->n * sizeof(double));
    hs_fem_update(p->fem, x, NULL);
    hs_fem_assemble(p->fem, 1.0, 0.0, p->a);
    double sum = 0;
    int cnt = 0;
    for (int j = 0; j < p->n_cand; ++j)
        for (int c = 0; c < 3; ++c) {
            int dof = p->dof[3 * p->cand[j] + c], q = hs_csc_find(p->a, dof, dof);
            if (q >= 0 && p->a->val[q] > 0) sum += p->a->val[q], ++cnt;
        }
    double dmean = cnt ? sum / cnt : 0, acc = 0;
    // The residual's round-off floor from the positions: 4 eps ||diag(K) x0|| over the free
    // dofs (forces are differences of terms of size K x; as hs_body's static solve).
    for (int j = 0; j < p->nf; ++j) {
        int q = hs_csc_find(p->a, j, j);
        double t = (q >= 0 ? p->a->val[q] : 0.0) * x[p->free_to_full[j]];
        acc += t * t;
    }
    p->pos_floor = 4 * DBL_EPSILON * sqrt(acc);
    if (!(dmean > 0) || !isfinite(dmean)) return HS_ERR_NUMERIC;
    p->k = p->def.penalty_scale * dmean;
    return HS_OK;
}

static hs_status alloc_arrays(hs_press* p) {
    size_t n3 = 3 * (size_t)p->n, ns = (size_t)p->mesh->n_surf_nodes + 1;
    p->dof = hs_alloc(n3 * sizeof(int));
    p->free_to_full = hs_alloc(n3 * sizeof(int));
    p->fixed = hs_calloc((size_t)p->n, 1);
    double** d3[] = {&p->du_last, &p->u,    &p->x,   &p->f_el, &p->f_g,
                     &p->r,       &p->save, &p->rhs, &p->dx};
    for (size_t i = 0; i < sizeof d3 / sizeof d3[0]; ++i) *d3[i] = hs_calloc(n3, sizeof(double));
    p->cand = hs_alloc(ns * sizeof(int));
    p->cand_of = hs_alloc(((size_t)p->n + 1) * sizeof(int));
    p->gap = hs_calloc(ns, sizeof(double));
    p->p = hs_calloc(ns, sizeof(double));
    p->act = hs_calloc(ns, 1);
    p->prev_act = hs_calloc(ns, 1);
    int ok = p->dof && p->free_to_full && p->fixed && p->cand && p->cand_of && p->gap && p->p &&
             p->act && p->prev_act;
    for (size_t i = 0; i < sizeof d3 / sizeof d3[0]; ++i) ok = ok && *d3[i];
    return ok ? HS_OK : HS_ERR_NOMEM;
}

hs_status hs_press_create(const hs_mesh* mesh, const hs_press_def* def, const unsigned char* fixed,
                          hs_press** out, hs_err* err) {
    if (out) *out = NULL;
    if (!mesh || !def || !fixed || !out)
        return hs_err_set(err, HS_ERR_INVALID, "hs_press_create: NULL argument");
    hs_status s = check_def(def, err);
    if (s != HS_OK) return s;
    if ((s = hs_fem_check_fixed(mesh, fixed, err)) != HS_OK) return s;
    hs_press* p = hs_calloc(1, sizeof *p);
    if (!p) return hs_err_set(err, HS_ERR_NOMEM, "hs_press_create: out of memory");
    p->mesh = mesh;
    p->def = *def;
    p->n = mesh->n_nodes;
    if (alloc_arrays(p) != HS_OK) {
        hs_press_destroy(&p);
        return hs_err_set(err, HS_ERR_NOMEM, "hs_press_create: out of memory");
    }
    for (int i = 0; i < p->n; ++i) {
        // Unused nodes carry no stiffness: held like fixed ones so the system stays SPD.
        p->fixed[i] = fixed[i] || !mesh->node_used[i];
        for (int c = 0; c < 3; ++c) {
            p->dof[3 * i + c] = p->fixed[i] ? -1 : p->nf;
            if (!p->fixed[i]) p->free_to_full[p->nf++] = 3 * i + c;
        }
    }
    for (int i = 0; i < p->n; ++i) p->cand_of[i] = -1;
    for (int si = 0; si < mesh->n_surf_nodes; ++si) {
        int i = mesh->surf_nodes[si];
        if (p->fixed[i]) continue;
        p->cand_of[i] = p->n_cand;
        p->cand[p->n_cand++] = i;
    }
    if (def->surface) {
        const size_t nt = (size_t)mesh->n_tris + 1;
        p->tc = hs_alloc(nt * sizeof(int));
        p->tlam = hs_calloc(nt, sizeof(double));
        p->tp = hs_calloc(nt, sizeof(double));
        p->tw = hs_calloc(3 * nt, sizeof(double));
        p->tn = hs_calloc(3 * nt, sizeof(double));
        p->td = hs_calloc(nt, sizeof(double));
        p->te = hs_calloc(3 * nt, sizeof(double));
        p->tf = hs_calloc(nt, 1);
        if (!p->tc || !p->tlam || !p->tp || !p->tw || !p->tn || !p->td || !p->te || !p->tf) {
            hs_press_destroy(&p);
            return hs_err_set(err, HS_ERR_NOMEM, "hs_press_create: out of memory");
        }
        for (int t = 0; t < mesh->n_tris; ++t) {
            const int* v = mesh->tris + 3 * t;
            if (!p->fixed[v[0]] || !p->fixed[v[1]] || !p->fixed[v[2]]) p->tc[p->n_tc++] = t;
        }
    }
    const double* m = NULL;
    // Co-rotated: rotations converged to 1e-10 at least; at the default 1e-6 the forces carry
    // an error of that order, and the residual stalled at 1e-7 of the load on the vessel.
    p->def.fem.polar_tol = fmin(def->fem.polar_tol, 1e-10);
    s = hs_fem_create(mesh, &p->def.fem, p->dof, p->nf, &p->fem, err);
    if (s == HS_OK) s = hs_fem_create_matrix(p->fem, &p->a);
    if (s == HS_OK && (s = init_penalty(p)) != HS_OK)
        hs_err_set(err, s, "hs_press_create: the rest stiffness has no positive diagonal");
    if (s != HS_OK) {
        hs_press_destroy(&p);
        return s;
    }
    m = hs_fem_lumped_mass(p->fem);
    for (int i = 0; i < p->n; ++i)
        for (int c = 0; c < 3; ++c) p->f_g[3 * i + c] = m[i] * def->gravity[c];
    *out = p;
    return HS_OK;
}

void hs_press_reset(hs_press* p) {
    memset(p->u, 0, 3 * (size_t)p->n * sizeof(double));
    memset(p->gap, 0, (size_t)p->n_cand * sizeof(double));
    memset(p->p, 0, (size_t)p->n_cand * sizeof(double));
    memset(p->act, 0, (size_t)p->n_cand);
    for (int j = 0; j < p->n_tc; ++j) p->tlam[j] = p->tp[j] = 0;
    p->engaged = 0;
    p->last_len = 0;
}

const double* hs_press_displacement(const hs_press* p) {
    return p->u;
}
double hs_press_penalty(const hs_press* p) {
    return p->k;
}

static double dist3(const double* a, const double* b) {
    return sqrt((a[0] - b[0]) * (a[0] - b[0]) + (a[1] - b[1]) * (a[1] - b[1]) +
                (a[2] - b[2]) * (a[2] - b[2]));
}

enum { FEAT_VERTEX = 1, FEAT_EDGE = 2, FEAT_FACE = 3 };

// Point of segment a-b nearest p: parameter t in [0, 1] and the squared distance.
static double seg_nearest(const double p[3], const double a[3], const double b[3], double* t) {
    double ab[3], ap[3], l2 = 0, dot = 0;
    for (int q = 0; q < 3; ++q) ab[q] = b[q] - a[q], ap[q] = p[q] - a[q];
    for (int q = 0; q < 3; ++q) l2 += ab[q] * ab[q], dot += ab[q] * ap[q];
    *t = l2 > 0 ? fmin(1.0, fmax(0.0, dot / l2)) : 0.0;
    double d2 = 0;
    for (int q = 0; q < 3; ++q) d2 += (ap[q] - *t * ab[q]) * (ap[q] - *t * ab[q]);
    return d2;
}

// Point y of triangle (v0, v1, v2) nearest p, y = sum w_a v_a: the projection on the plane when
// it falls inside (barycentric coordinates from the sub-areas), else the nearest of the three
// edges. Returns the feature (vertex, edge or face); 0 for a degenerate triangle.
static int tri_nearest(const double p[3], const double* v0, const double* v1, const double* v2,
                       double w[3], double y[3]) {
    const double* v[3] = {v0, v1, v2};
    double e1[3], e2[3], nrm[3], d[3];
    for (int q = 0; q < 3; ++q) e1[q] = v1[q] - v0[q], e2[q] = v2[q] - v0[q], d[q] = p[q] - v0[q];
    nrm[0] = e1[1] * e2[2] - e1[2] * e2[1];
    nrm[1] = e1[2] * e2[0] - e1[0] * e2[2];
    nrm[2] = e1[0] * e2[1] - e1[1] * e2[0];
    const double n2 = nrm[0] * nrm[0] + nrm[1] * nrm[1] + nrm[2] * nrm[2];
    const double s1 = e1[0] * e1[0] + e1[1] * e1[1] + e1[2] * e1[2];
    const double s2 = e2[0] * e2[0] + e2[1] * e2[1] + e2[2] * e2[2];
    if (!(n2 > 1e-24 * s1 * s2)) return 0;
    // Barycentric coordinates of the projection: (e1 x d) . n and (d x e2) . n over |n|^2.
    const double b2 =
        ((e1[1] * d[2] - e1[2] * d[1]) * nrm[0] + (e1[2] * d[0] - e1[0] * d[2]) * nrm[1] +
         (e1[0] * d[1] - e1[1] * d[0]) * nrm[2]) /
        n2;
    const double b1 =
        ((d[1] * e2[2] - d[2] * e2[1]) * nrm[0] + (d[2] * e2[0] - d[0] * e2[2]) * nrm[1] +
         (d[0] * e2[1] - d[1] * e2[0]) * nrm[2]) /
        n2;
    if (b1 > 0 && b2 > 0 && b1 + b2 < 1) {
        w[0] = 1 - b1 - b2, w[1] = b1, w[2] = b2;
    } else {
        double best = INFINITY;
        for (int e = 0; e < 3; ++e) {
            double t;
            const double d2 = seg_nearest(p, v[e], v[(e + 1) % 3], &t);
            if (d2 < best) {
                best = d2;
                w[e] = 1 - t, w[(e + 1) % 3] = t, w[(e + 2) % 3] = 0;
            }
        }
    }
    for (int q = 0; q < 3; ++q) y[q] = w[0] * v0[q] + w[1] * v1[q] + w[2] * v2[q];
    const int zeros = (w[0] == 0) + (w[1] == 0) + (w[2] == 0);
    return zeros == 0 ? FEAT_FACE : zeros == 1 ? FEAT_EDGE : FEAT_VERTEX;
}

// Evaluate at x0 + u with the sphere at c (NULL: none). For each node j of the active set:
// its sphere normal n_j, gap g_j = R - d_j (> 0: inside) and multiplier lam_j = -n_j . r_j
// (the push along n_j that balances the node's elastic and gravity forces). r: the residual
// with those pushes (free dofs), the frictionless equilibrium's; norms for the tolerance.
static void evaluate(hs_press* p, const double c[3]) {
    const int n3 = 3 * p->n;
    const double R = p->def.radius_m;
    for (int k = 0; k < n3; ++k) p->x[k] = p->mesh->x0[k] + p->u[k];
    hs_fem_update(p->fem, p->x, NULL);
    hs_fem_forces(p->fem, p->f_el);
    double fc2 = 0, fg2 = 0, r2 = 0, el = 0, gap = 0;
    for (int k = 0; k < n3; ++k) {
        int fr = p->dof[k] >= 0;
        p->r[k] = fr ? p->f_el[k] + p->f_g[k] : 0.0;
        fg2 += fr ? p->f_g[k] * p->f_g[k] : 0.0;
        el += fr ? fabs(p->f_el[k]) : 0.0;
    }
    if (p->def.surface) {
        p->pen_max = -INFINITY;
        for (int j = 0; j < p->n_tc; ++j) {
            p->tp[j] = 0;
            if (!c) continue;
            const int* v = p->mesh->tris + 3 * p->tc[j];
            double* w = p->tw + 3 * j;
            double* nv = p->tn + 3 * j;
            double y[3];
            const int feat =
                tri_nearest(c, p->x + 3 * v[0], p->x + 3 * v[1], p->x + 3 * v[2], w, y);
            if (!feat) continue;
            p->tf[j] = (unsigned char)feat;
            if (feat == FEAT_EDGE) { // the edge's two ends: the weights not zero
                const int a = w[0] == 0 ? 1 : 0, b = w[2] == 0 ? 1 : 2;
                const double le = dist3(p->x + 3 * v[a], p->x + 3 * v[b]);
                for (int q = 0; q < 3; ++q)
                    p->te[3 * j + q] = (p->x[3 * v[b] + q] - p->x[3 * v[a] + q]) / le;
            }
            const double d = dist3(y, c);
            p->td[j] = d;
            p->pen_max = fmax(p->pen_max, R - d);
            const double push = p->tlam[j] + p->k * (R - d);
            if (!(push > 0) || !(d > 0)) continue;
            p->tp[j] = push;
            fc2 += push * push;
            for (int q = 0; q < 3; ++q) nv[q] = (y[q] - c[q]) / d;
            for (int a = 0; a < 3; ++a)
                if (p->dof[3 * v[a]] >= 0)
                    for (int q = 0; q < 3; ++q) p->r[3 * v[a] + q] += push * w[a] * nv[q];
        }
    }
    for (int j = 0; j < p->n_cand && !p->def.surface; ++j) {
        p->p[j] = 0;
        if (!c || !p->act[j]) continue;
        const double* xi = p->x + 3 * p->cand[j];
        double* ri = p->r + 3 * p->cand[j];
        double d = dist3(xi, c), nv[3], lam = 0;
        for (int q = 0; q < 3; ++q) nv[q] = (xi[q] - c[q]) / d, lam -= nv[q] * ri[q];
        p->p[j] = lam;
        p->gap[j] = R - d;
        gap = fmax(gap, fabs(R - d));
        for (int q = 0; q < 3; ++q) ri[q] += lam * nv[q];
        fc2 += lam * lam;
    }
    for (int k = 0; k < n3; ++k) r2 += p->r[k] * p->r[k];
    p->fc_norm = sqrt(fc2);
    p->fg_norm = sqrt(fg2);
    p->r_norm = sqrt(r2);
    p->el_abs = el;
    p->gap_max = gap; // the largest |gap| of the active set, m
}

// A = K_t + sum over the active set of k n n^T (the linearised constraint n . dx = g, held by
// a stiff spring) - (lam/d)(I - n n^T) (the constraint's curvature in the Lagrangian's Hessian;
// curvature 0 leaves it out). shift: added to the diagonal.
static void assemble(hs_press* p, const double c[3], int curvature, double shift) {
    hs_fem_assemble(p->fem, 1.0, 0.0, p->a);
    for (int j = 0; j < p->a->n && shift > 0; ++j) p->a->val[hs_csc_find(p->a, j, j)] += shift;
    for (int j = 0; j < p->n_tc && c; ++j) {
        if (!(p->tp[j] > 0)) continue;
        const int* v = p->mesh->tris + 3 * p->tc[j];
        const double *w = p->tw + 3 * j, *nv = p->tn + 3 * j;
        // The push direction turns as the point moves across it: about the centre at a vertex,
        // about the centre and along the edge at an edge; a face's normal only with the face
        // (left out: the tangent need not be exact under the line search).
        const double t = curvature && p->tf[j] != FEAT_FACE ? p->tp[j] / p->td[j] : 0.0;
        const double* e = p->te + 3 * j;
        const double ee = p->tf[j] == FEAT_EDGE ? 1.0 : 0.0;
        for (int ia = 0; ia < 3; ++ia)
            for (int ib = 0; ib < 3; ++ib)
                for (int a = 0; a < 3; ++a)
                    for (int b = 0; b < 3; ++b) {
                        const int ra = p->dof[3 * v[ia] + a], cb = p->dof[3 * v[ib] + b];
                        if (ra < 0 || cb < 0) continue;
                        int at = hs_csc_find(p->a, ra, cb);
                        if (at < 0) continue;
                        p->a->val[at] += w[ia] * w[ib] *
                                         (p->k * nv[a] * nv[b] -
                                          t * ((a == b) - nv[a] * nv[b] - ee * e[a] * e[b]));
                    }
    }
    for (int j = 0; j < p->n_cand && c && !p->def.surface; ++j) {
        if (!p->act[j]) continue;
        const int i = p->cand[j];
        const double* xi = p->x + 3 * i;
        double d = dist3(xi, c), nv[3];
        for (int q = 0; q < 3; ++q) nv[q] = (xi[q] - c[q]) / d;
        double t = curvature ? p->p[j] / d : 0.0;
        for (int a = 0; a < 3; ++a)
            for (int b = 0; b < 3; ++b) {
                int at = hs_csc_find(p->a, p->dof[3 * i + a], p->dof[3 * i + b]);
                p->a->val[at] += p->k * nv[a] * nv[b] - t * ((a == b) - nv[a] * nv[b]);
            }
    }
}

static hs_status factor(hs_press* p) {
    if (!p->chol) return hs_cholesky_create(p->a, &p->chol, NULL);
    return hs_cholesky_refactor(p->chol, p->a);
}

// Newton (SQP) on the equilibrium with the active set held on the sphere, frictionless: each
// step solves the tangent system with the constraints linearised along the current normals,
// moving every active node onto the sphere (its gap) and leaving it free along the sphere.
static hs_status newton(hs_press* p, const double c[3], hs_press_stats* st) {
    evaluate(p, c);
    int refactor = 1;
    const double R = p->def.radius_m;
    for (int it = 0;; ++it) {
        // Round-off floors: the cancellation error of the elastic forces, and the force of a
        // 1e-12 R displacement of a surface node (no load at all: the rest state is it).
        double scale = p->fc_norm + p->fg_norm;
        double floor_abs = fmax(1e-13 * p->el_abs, 1e-12 * p->k / p->def.penalty_scale * R);
        floor_abs = fmax(floor_abs, p->pos_floor);
        if ((p->r_norm <= p->def.tol * scale || p->r_norm <= floor_abs) &&
            p->gap_max <= 0.1 * p->def.pen_tol * R)
            return HS_OK;
        if (it == p->def.max_newton) return HS_ERR_NOT_CONVERGED;
        hs_status s = HS_OK;
        // The tangent is refactored when the last step converged slowly or was cut; else the
        // factor is kept (the co-rotated tangent lacks dR/dx: its convergence is linear anyway,
        // and a solve costs a fraction of a factorisation).
        if (refactor) {
            assemble(p, c, 1, 0.0);
            s = factor(p);
            // Not SPD (the curvature with a large push, or StVK under compression): without
            // the curvature, then with a growing diagonal shift.
            for (int t = 0; t < 8 && s == HS_ERR_NOT_POSDEF; ++t) {
                ++st->fallbacks;
                assemble(p, c, 0, t == 0 ? 0.0 : p->k / p->def.penalty_scale * 1e-4 * pow(10.0, t));
                s = factor(p);
            }
            ++st->refactors;
        }
        if (s != HS_OK) return s;
        for (int j = 0; j < p->nf; ++j) p->rhs[j] = p->r[p->free_to_full[j]];
        for (int j = 0; j < p->n_cand && c && !p->def.surface; ++j) {
            if (!p->act[j]) continue;
            const int i = p->cand[j];
            double d = dist3(p->x + 3 * i, c);
            for (int q = 0; q < 3; ++q)
                p->rhs[p->dof[3 * i + q]] += p->k * p->gap[j] * (p->x[3 * i + q] - c[q]) / d;
        }
        if ((s = hs_cholesky_solve(p->chol, p->rhs, p->dx)) != HS_OK) return s;
        ++st->newton;
        // Backtracking on the merit ||r|| + k0 max|g| (k0 the stiffest node's stiffness): the
        // co-rotated tangent lacks the rotations' derivative, and the constraints curve.
        const double k0 = p->k / p->def.penalty_scale;
        double m0 = p->r_norm + k0 * p->gap_max, alpha = 1, prev = 0;
        for (int ls = 0; ls < 12; ++ls) {
            for (int j = 0; j < p->nf; ++j) p->u[p->free_to_full[j]] += (alpha - prev) * p->dx[j];
            prev = alpha;
            evaluate(p, c);
            if (isfinite(p->r_norm) && p->r_norm + k0 * p->gap_max < m0) break;
            alpha *= 0.5;
        }
        if (!isfinite(p->r_norm)) return HS_ERR_NUMERIC;
        refactor = 1;
    }
}

// Deepest penetration of a fixed node (which no force moves), and which.
static double fixed_penetration(const hs_press* p, const double c[3], int* fixed_node) {
    const double R = p->def.radius_m;
    double pen = 0;
    *fixed_node = -1;
    for (int i = 0; i < p->n; ++i)
        if (p->fixed[i] && p->mesh->node_used[i]) {
            double d = R - dist3(p->mesh->x0 + 3 * i, c);
            if (d > pen) pen = d, *fixed_node = i;
        }
    return pen;
}

// One Newton solve of an active-set pass, its failure named.
static hs_status newton_pass(hs_press* p, const double c[3], hs_press_stats* st, hs_err* err) {
    hs_status s = newton(p, c, st);
    ++st->passes;
    if (s == HS_ERR_NOT_CONVERGED)
        return hs_err_set(err, s,
                          "press: Newton did not converge in %d iterations at centre "
                          "%g,%g,%g (residual %.3g of the load)",
                          p->def.max_newton, c[0], c[1], c[2],
                          p->r_norm / (p->fc_norm + p->fg_norm + DBL_MIN));
    if (s != HS_OK) return hs_err_set(err, s, "press: solver failed: %s", hs_status_str(s));
    return HS_OK;
}

// Surface contact at one sphere position: Newton on the equilibrium with the pushes
// max(0, lam + k g) (the active set is whichever triangles push, re-decided at every
// evaluation), then lam <- the pushes, until no point of the surface is deeper than
// 0.1 pen_tol R inside the sphere.
static hs_status increment_surface(hs_press* p, const double c[3], hs_press_stats* st,
                                   hs_err* err) {
    const double R = p->def.radius_m;
    for (int pass = 0; pass < p->def.max_passes; ++pass) {
        hs_status s = newton_pass(p, c, st, err);
        if (s != HS_OK) return s;
        st->penetration_m = fmax(p->pen_max, 0.0);
        st->residual = p->r_norm / (p->fc_norm + p->fg_norm + DBL_MIN);
        if (st->penetration_m <= 0.1 * p->def.pen_tol * R) return HS_OK;
        for (int j = 0; j < p->n_tc; ++j) p->tlam[j] = p->tp[j];
    }
    return hs_err_set(err, HS_ERR_NOT_CONVERGED,
                      "press: the surface is still %.3g mm inside the sphere after %d passes at "
                      "centre %g,%g,%g",
                      p->pen_max * 1e3, p->def.max_passes, c[0], c[1], c[2]);
}

// One sphere position: Newton with the active set held, then release the nodes that pull and
// add the ones inside, until the set is unchanged.
static hs_status increment(hs_press* p, const double c[3], hs_press_stats* st, hs_err* err) {
    const double R = p->def.radius_m;
    int fnode;
    double fpen = fixed_penetration(p, c, &fnode);
    if (fpen > p->def.pen_tol * R)
        return hs_err_set(err, HS_ERR_INVALID,
                          "press: the sphere at %g,%g,%g reaches fixed "
                          "node %d (%.3g m deep): it cannot be pushed away",
                          c[0], c[1], c[2], fnode, fpen);
    if (p->def.surface) return increment_surface(p, c, st, err);
    for (int pass = 0; pass < p->def.max_passes; ++pass) {
        hs_status s = newton_pass(p, c, st, err);
        if (s != HS_OK) return s;
        // Release the node that pulls hardest (one at a time: releasing one changes the
        // others' pushes), else add every node inside.
        int changes = 0, worst = -1;
        double pen = 0;
        for (int j = 0; j < p->n_cand; ++j)
            if (p->act[j] && p->p[j] < 0 && (worst < 0 || p->p[j] < p->p[worst])) worst = j;
        if (worst >= 0) p->act[worst] = 0, changes = 1;
        for (int j = 0; j < p->n_cand; ++j) {
            double d = dist3(p->x + 3 * p->cand[j], c);
            if (!p->act[j]) pen = fmax(pen, R - d);
            if (worst < 0 && !p->act[j] && d < R * (1 - 0.1 * p->def.pen_tol))
                p->act[j] = 1, ++changes;
        }
        st->set_changes = changes;
        st->penetration_m = fmax(pen, p->gap_max);
        st->residual = p->r_norm / (p->fc_norm + p->fg_norm + DBL_MIN);
        if (changes == 0 && st->penetration_m <= p->def.pen_tol * R) return HS_OK;
    }
    return hs_err_set(err, HS_ERR_NOT_CONVERGED,
                      "press: contact set not stable after %d passes "
                      "at centre %g,%g,%g",
                      p->def.max_passes, c[0], c[1], c[2]);
}

// An increment of length h from the secant predictor: the last increment's displacement
// change, scaled to h (the path is smooth; a Newton start there keeps the elements next to the
// contact from folding over in the first step, which the co-rotated model's inversion fallback
// turns into a non-smooth problem).
static hs_status increment_predicted(hs_press* p, const double c[3], double h, hs_press_stats* st,
                                     hs_err* err) {
    const int n3 = 3 * p->n;
    memcpy(p->save, p->u, (size_t)n3 * sizeof(double));
    if (p->last_len > 0)
        for (int k = 0; k < n3; ++k) p->u[k] += p->du_last[k] * (h / p->last_len);
    hs_status s = increment(p, c, st, err);
    if (s == HS_OK) {
        for (int k = 0; k < n3; ++k) p->du_last[k] = p->u[k] - p->save[k];
        p->last_len = h;
    } else {
        p->last_len = 0;
    }
    return s;
}

// Travel s >= 0 back along dir from c at which the sphere first touches a free surface node
// (largest root of |x - c + s dir| = R); -1 when it meets none.
static double first_contact(const hs_press* p, const double c[3], const double dir[3]) {
    const double R = p->def.radius_m;
    double best = -1;
    for (int j = 0; j < p->n_cand; ++j) {
        const double* x = p->x + 3 * p->cand[j];
        double w[3] = {x[0] - c[0], x[1] - c[1], x[2] - c[2]};
        double b = w[0] * dir[0] + w[1] * dir[1] + w[2] * dir[2];
        double disc = b * b - (w[0] * w[0] + w[1] * w[1] + w[2] * w[2]) + R * R;
        if (disc < 0) continue;
        double s = -b + sqrt(disc);
        if (s >= 0 && s > best) best = s;
    }
    return best;
}

// Deepest point of the current surface (candidate triangles) inside a sphere at c, m.
static double surface_depth(const hs_press* p, const double c[3]) {
    const double R = p->def.radius_m;
    double pen = -INFINITY;
    for (int j = 0; j < p->n_tc; ++j) {
        const int* v = p->mesh->tris + 3 * p->tc[j];
        double w[3], y[3];
        if (tri_nearest(c, p->x + 3 * v[0], p->x + 3 * v[1], p->x + 3 * v[2], w, y))
            pen = fmax(pen, R - dist3(y, c));
    }
    return pen;
}

// Surface contact: the travel s >= 0 back along dir from c at which the sphere first touches
// the surface coming in from outside the bounding box (steps of R/8, then bisection to 1e-6 R);
// -1 when it meets nothing.
static double first_contact_surface(const hs_press* p, const double c[3], const double dir[3]) {
    const double R = p->def.radius_m, h = R / 8;
    const double* lo = p->mesh->bbox_min;
    const double* hi = p->mesh->bbox_max;
    double far = 2 * R + dist3(lo, hi);
    for (int q = 0; q < 3; ++q) far += fabs(c[q] - 0.5 * (lo[q] + hi[q]));
    double out = far, ck[3];
    for (double s = far; s >= 0; s -= h) {
        for (int q = 0; q < 3; ++q) ck[q] = c[q] - s * dir[q];
        if (surface_depth(p, ck) > 0) {
            double in = s;
            while (out - in > 1e-6 * R) {
                const double mid = 0.5 * (in + out);
                for (int q = 0; q < 3; ++q) ck[q] = c[q] - mid * dir[q];
                if (surface_depth(p, ck) > 0)
                    in = mid;
                else
                    out = mid;
            }
            return out;
        }
        out = s;
    }
    return -1;
}

// Default approach: minus the rest normal of the free surface node nearest c.
static int default_dir(const hs_press* p, const double c[3], double dir[3]) {
    int best = -1;
    double bd = INFINITY;
    for (int j = 0; j < p->n_cand; ++j) {
        double d = dist3(p->x + 3 * p->cand[j], c);
        if (d < bd) bd = d, best = p->cand[j];
    }
    if (best < 0 || hs_mesh_rest_normal(p->mesh, best, dir) != 0) return -1;
    for (int q = 0; q < 3; ++q) dir[q] = -dir[q];
    return 0;
}

// Longest rest surface edge with an end in contact: node contact resolves no finer.
static double longest_contact_edge(const hs_press* p) {
    const hs_mesh* m = p->mesh;
    double e = 0;
    for (int t = 0; t < m->n_tris; ++t)
        for (int a = 0; a < 3; ++a) {
            int i = m->tris[3 * t + a], j = m->tris[3 * t + (a + 1) % 3];
            int ci = p->cand_of[i], cj = p->cand_of[j];
            if ((ci >= 0 && p->act[ci]) || (cj >= 0 && p->act[cj]))
                e = fmax(e, dist3(m->x0 + 3 * i, m->x0 + 3 * j));
        }
    for (int t = 0; t < p->n_tc; ++t) {
        if (!(p->tp[t] > 0)) continue;
        const int* v = m->tris + 3 * p->tc[t];
        for (int a = 0; a < 3; ++a)
            e = fmax(e, dist3(m->x0 + 3 * v[a], m->x0 + 3 * v[(a + 1) % 3]));
    }
    return e;
}

// Where the sphere starts: its previous centre, or the first contact along dir.
static hs_status start_point(hs_press* p, const double c[3], const double* dir_in, double start[3],
                             hs_err* err) {
    if (p->engaged) {
        memcpy(start, p->centre, sizeof p->centre);
        return HS_OK;
    }
    for (int k = 0; k < 3 * p->n; ++k) p->x[k] = p->mesh->x0[k] + p->u[k];
    double dir[3];
    if (dir_in) {
        double l = sqrt(dir_in[0] * dir_in[0] + dir_in[1] * dir_in[1] + dir_in[2] * dir_in[2]);
        if (!(l > 0) || !isfinite(l))
            return hs_err_set(err, HS_ERR_INVALID,
                              "press: approach direction is zero or not finite");
        for (int q = 0; q < 3; ++q) dir[q] = dir_in[q] / l;
    } else if (default_dir(p, c, dir) != 0) {
        return hs_err_set(err, HS_ERR_INVALID, "press: no surface normal near %g,%g,%g", c[0], c[1],
                          c[2]);
    }
    double s = p->def.surface ? first_contact_surface(p, c, dir) : first_contact(p, c, dir);
    if (s < 0)
        return hs_err_set(err, HS_ERR_INVALID,
                          "press: a sphere of radius %g m coming along "
                          "%g,%g,%g to %g,%g,%g touches no free surface node",
                          p->def.radius_m, dir[0], dir[1], dir[2], c[0], c[1], c[2]);
    for (int q = 0; q < 3; ++q) start[q] = c[q] - s * dir[q];
    return HS_OK;
}

hs_status hs_press_solve(hs_press* p, const double c[3], const double* dir, hs_press_stats* stats,
                         hs_err* err) {
    hs_press_stats st;
    memset(&st, 0, sizeof st);
    int64_t t0 = hs_now_ns();
    hs_status s = HS_OK;
    if (!(isfinite(c[0]) && isfinite(c[1]) && isfinite(c[2])))
        s = hs_err_set(err, HS_ERR_INVALID, "press: centre not finite");
    double start[3];
    if (s == HS_OK) {
        if (!p->engaged) { // the body settles under gravity before the sphere arrives
            hs_press_reset(p);
            s = newton(p, NULL, &st);
            if (s != HS_OK)
                hs_err_set(err, s, "press: the contact-free equilibrium failed: %s",
                           hs_status_str(s));
        }
        if (s == HS_OK) s = start_point(p, c, dir, start, err);
    }
    if (s == HS_OK) {
        st.travel_m = dist3(start, c);
        int n = (int)ceil(st.travel_m / (p->def.max_step * p->def.radius_m) - 1e-9);
        if (n < 1) n = 1;
        const double h = st.travel_m / n;
        for (int k = 1; k <= n && s == HS_OK; ++k) {
            double ck[3];
            for (int q = 0; q < 3; ++q) ck[q] = start[q] + (c[q] - start[q]) * k / n;
            s = increment_predicted(p, ck, h, &st, err);
            ++st.increments;
        }
    }
    for (int j = 0; j < p->n_cand && !p->def.surface; ++j)
        st.active += p->act[j] && p->p[j] > 0 && s == HS_OK;
    for (int j = 0; j < p->n_tc; ++j) st.active += p->tp[j] > 0 && s == HS_OK;
    if (s == HS_OK && st.active == 0)
        s = hs_err_set(err, HS_ERR_INVALID,
                       "press: the sphere at %g,%g,%g touches no surface node "
                       "in equilibrium",
                       c[0], c[1], c[2]);
    if (s == HS_OK) {
        memcpy(p->centre, c, sizeof p->centre);
        p->engaged = 1;
    } else {
        p->engaged = 0;
    }
    for (int j = 0; j < p->n_cand && !p->def.surface; ++j) {
        if (!p->act[j]) continue;
        const double* xi = p->x + 3 * p->cand[j];
        double d = dist3(xi, c);
        for (int q = 0; q < 3; ++q) st.force_n[q] -= p->p[j] * (xi[q] - c[q]) / d;
    }
    for (int j = 0; j < p->n_tc; ++j)
        for (int q = 0; q < 3; ++q) st.force_n[q] -= p->tp[j] * p->tn[3 * j + q];
    st.max_edge_m = longest_contact_edge(p);
    st.wall_ms = (double)(hs_now_ns() - t0) * 1e-6;
    if (stats) *stats = st;
    return s;
}

void hs_press_contact_force(const hs_press* p, int node, double f[3]) {
    f[0] = f[1] = f[2] = 0;
    for (int t = 0; t < p->n_tc && p->engaged && node >= 0; ++t) {
        const int* v = p->mesh->tris + 3 * p->tc[t];
        for (int a = 0; a < 3; ++a)
            if (v[a] == node)
                for (int q = 0; q < 3; ++q) f[q] += p->tp[t] * p->tw[3 * t + a] * p->tn[3 * t + q];
    }
    if (p->def.surface) return;
    int j = node >= 0 && node < p->n ? p->cand_of[node] : -1;
    if (j < 0 || !p->engaged || !p->act[j]) return;
    const double* xi = p->x + 3 * node;
    double d = dist3(xi, p->centre);
    for (int q = 0; q < 3; ++q) f[q] = p->p[j] * (xi[q] - p->centre[q]) / d;
}

void hs_press_reaction(const hs_press* p, int node, double f[3]) {
    f[0] = f[1] = f[2] = 0;
    if (node < 0 || node >= p->n || !p->fixed[node]) return;
    for (int q = 0; q < 3; ++q) f[q] = -(p->f_el[3 * node + q] + p->f_g[3 * node + q]);
}

hs_status hs_press_reference_force(const hs_mesh* mesh, const hs_press_def* def,
                                   const unsigned char* fixed, const double centre_m[3],
                                   const double* dir, double force_n[3], hs_err* err) {
    hs_press* p = NULL;
    hs_status s = hs_press_create(mesh, def, fixed, &p, err);
    hs_press_stats st;
    if (s == HS_OK) s = hs_press_solve(p, centre_m, dir, &st, err);
    for (int q = 0; q < 3 && force_n; ++q) force_n[q] = s == HS_OK ? st.force_n[q] : 0.0;
    hs_press_destroy(&p);
    return s;
}
