// SPDX-License-Identifier: GPL-2.0-or-later
// Static press of a rigid sphere with contact on the boundary surface (surface_press.h).
#define _POSIX_C_SOURCE 200809L
#include "surface_press.h"

#include "closest.h"
#include "dense.h"
#include "compliance.h"
#include "fem.h"

#include <float.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>

#define RELAX    0.5 // share of the newest contact forces per iteration
#define MAX_ITER 400 // per increment

typedef struct near_node {
    double dist;
    int node;
} near_node;

typedef struct press {
    const hs_mesh* m;
    hs_body* body;
    hs_compliance* comp;
    int corot;
    double* x;  // [3n] deformed positions
    double* f;  // [3n] contact forces applied to the body
    double* fn; // [3n] the newest contact's forces
    near_node* near;
    hs_contact_snapshot* s;
} press;

static int near_cmp(const void* pa, const void* pb) {
    const near_node *a = pa, *b = pb;
    if (a->dist != b->dist) return a->dist < b->dist ? -1 : 1;
    return (a->node > b->node) - (a->node < b->node);
}

static void node_rot(press* P, int node, double r[9]) {
    static const double id[9] = {1, 0, 0, 0, 1, 0, 0, 0, 1};
    if (P->corot)
        hs_fem_node_rotation(hs_body_fem(P->body), node, r);
    else
        memcpy(r, id, sizeof id);
}

// The snapshot at centre p about the body's current (exactly solved) state: the candidates
// nearest p on the deformed surface, their positions, rotated compliance blocks, and the
// displacement the applied forces cause there to first order (pre_m).
static void build(press* P, const double p[3], double r) {
    const hs_mesh* m = P->m;
    hs_body_elastic_energy(P->body); // the model (and its rotations) at the current state
    const double* u = hs_body_displacement(P->body);
    for (int k = 0; k < 3 * m->n_nodes; ++k) P->x[k] = m->x0[k] + u[k];
    int nn = 0;
    for (int si = 0; si < m->n_surf_nodes; ++si) {
        const int v = m->surf_nodes[si];
        if (!hs_compliance_contactable(P->comp, v)) continue;
        const double* xv = P->x + 3 * v;
        P->near[nn].dist = sqrt((xv[0] - p[0]) * (xv[0] - p[0]) + (xv[1] - p[1]) * (xv[1] - p[1]) +
                                (xv[2] - p[2]) * (xv[2] - p[2]));
        P->near[nn++].node = v;
    }
    qsort(P->near, (size_t)nn, sizeof *P->near, near_cmp);
    hs_contact_snapshot* s = P->s;
    memset(s, 0, sizeof *s);
    s->version = 1;
    s->probe_radius_m = r;
    memcpy(s->centre_m, p, sizeof s->centre_m);
    const double reach = 3 * r + 0.005;
    int n = 0;
    while (n < nn && n < HS_CONTACT_MAX_CAND && P->near[n].dist < reach) {
        s->node[n] = P->near[n].node;
        ++n;
    }
    s->n_cand = n;
    s->reach_m = n == HS_CONTACT_MAX_CAND ? P->near[n - 1].dist : reach;
    hs_compliance_begin_step(P->comp);
    hs_compliance_ensure(P->comp, n, s->node, n);
    double rot[HS_CONTACT_MAX_CAND][9];
    for (int i = 0; i < n; ++i) {
        s->coupled[i] = (unsigned char)hs_compliance_has_column(P->comp, s->node[i]);
        memcpy(s->surf_m[i], P->x + 3 * s->node[i], sizeof s->surf_m[i]);
        if (hs_mesh_rest_normal(m, s->node[i], s->normal[i]) != 0) s->normal[i][2] = 1;
        node_rot(P, s->node[i], rot[i]);
    }
    for (int i = 0; i < n; ++i)
        for (int j = 0; j < n; ++j) {
            double blk[9];
            if (!hs_compliance_block(P->comp, s->node[i], s->node[j], blk)) continue;
            hs_mat3_rotate(rot[i], blk, rot[j], s->c[i][j]);
        }
    for (int i = 0; i < n; ++i) { // exact symmetry for the contact's Cholesky
        double* b = s->c[i][i];
        for (int a = 0; a < 3; ++a)
            for (int c = a + 1; c < 3; ++c)
                b[3 * a + c] = b[3 * c + a] = 0.5 * (b[3 * a + c] + b[3 * c + a]);
    }
    for (int i = 0; i < n; ++i) {
        double* pre = s->pre_m[i];
        for (int v = 0; v < m->n_nodes; ++v) {
            const double* fv = P->f + 3 * v;
            if (fv[0] == 0 && fv[1] == 0 && fv[2] == 0) continue;
            double raw[9], blk[9], rv[9];
            if (!hs_compliance_block(P->comp, s->node[i], v, raw)) continue;
            node_rot(P, v, rv);
            hs_mat3_rotate(rot[i], raw, rv, blk);
            for (int a = 0; a < 3; ++a)
                pre[a] += blk[3 * a] * fv[0] + blk[3 * a + 1] * fv[1] + blk[3 * a + 2] * fv[2];
        }
    }
    hs_contact_snapshot_add_tris(s, m);
}

// Apply P->f and solve the body to equilibrium.
static hs_status solve_body(press* P) {
    hs_body_clear_forces(P->body);
    for (int v = 0; v < P->m->n_nodes; ++v) {
        const double* fv = P->f + 3 * v;
        if (fv[0] != 0 || fv[1] != 0 || fv[2] != 0) {
            hs_status s = hs_body_set_force(P->body, v, fv);
            if (s != HS_OK) return s;
        }
    }
    // Warm-started from the last equilibrium, the first residual is already small and the
    // relative tolerance may not be reached: usable while iterating (the end is checked cold).
    hs_status s = hs_body_solve_static(P->body, NULL);
    return s == HS_WARN_NOT_CONVERGED ? HS_OK : s;
}

// Deepest point of the solved surface inside the sphere (every boundary triangle), m.
static double penetration(const press* P, const double p[3], double r) {
    const hs_mesh* m = P->m;
    double worst = -DBL_MAX;
    for (int t = 0; t < m->n_tris; ++t) {
        const int* tv = m->tris + 3 * t;
        double w[3], c[3];
        if (!hs_tri_closest(p, P->x + 3 * tv[0], P->x + 3 * tv[1], P->x + 3 * tv[2], w, c))
            continue;
        double d = sqrt((c[0] - p[0]) * (c[0] - p[0]) + (c[1] - p[1]) * (c[1] - p[1]) +
                        (c[2] - p[2]) * (c[2] - p[2]));
        worst = fmax(worst, r - d);
    }
    return worst;
}

// The contact on the current solved shape at centre p into P->fn, and the fixed point's
// residual: |fn - f| / |fn| (0 when neither pushes). -1 when the contact solve failed.
static int contact_residual(press* P, const double p[3], double r, double* change) {
    const size_t n3 = 3 * (size_t)P->m->n_nodes;
    build(P, p, r);
    hs_contact c;
    hs_contact_solve(P->s, p, 0, NULL, &c);
    if (c.failed) return -1;
    memset(P->fn, 0, n3 * sizeof(double));
    for (int k = 0; k < c.n; ++k) memcpy(P->fn + 3 * c.node[k], c.f_n[k], 3 * sizeof(double));
    double res = 0, ref = 0;
    for (size_t k = 0; k < n3; ++k) {
        res += (P->fn[k] - P->f[k]) * (P->fn[k] - P->f[k]);
        ref += P->fn[k] * P->fn[k];
    }
    *change = ref > 0 ? sqrt(res / ref) : (res > 0);
    return 0;
}

static void destroy(press* P) {
    hs_body_destroy(&P->body);
    hs_compliance_destroy(&P->comp);
    hs_free(P->x);
    hs_free(P->f);
    hs_free(P->fn);
    hs_free(P->near);
    hs_free(P->s);
}

hs_status hs_surface_press(const hs_mesh* mesh, const hs_body_def* def, const unsigned char* fixed,
                           double radius_m, const double from[3], const double to[3],
                           int increments, double tol, hs_surface_press_stats* st, hs_err* err) {
    memset(st, 0, sizeof *st);
    const int64_t t0 = hs_now_ns();
    if (!mesh || !def || !fixed || !(radius_m > 0) || increments < 1 || !(tol > 0))
        return hs_err_set(err, HS_ERR_INVALID, "surface press: bad arguments");
    press P;
    memset(&P, 0, sizeof P);
    P.m = mesh;
    P.corot = def->fem.model == HS_MODEL_COROTATED;
    const size_t n3 = 3 * (size_t)mesh->n_nodes;
    hs_status s = hs_body_create(mesh, def, fixed, &P.body, err);
    if (s == HS_OK)
        s = hs_compliance_create(mesh, &def->fem, fixed, 2 * HS_CONTACT_MAX_CAND, &P.comp, err);
    if (s != HS_OK) {
        destroy(&P);
        return s;
    }
    P.x = hs_calloc(n3, sizeof(double));
    P.f = hs_calloc(n3, sizeof(double));
    P.fn = hs_calloc(n3, sizeof(double));
    P.near = hs_calloc((size_t)mesh->n_surf_nodes + 1, sizeof *P.near);
    P.s = hs_calloc(1, sizeof *P.s);
    if (!P.x || !P.f || !P.fn || !P.near || !P.s) {
        destroy(&P);
        return hs_err_set(err, HS_ERR_NOMEM, "surface press: out of memory");
    }
    s = solve_body(&P); // the loaded shape without the sphere
    for (int inc = 1; inc <= increments && s == HS_OK; ++inc) {
        double p[3];
        for (int a = 0; a < 3; ++a) p[a] = from[a] + (to[a] - from[a]) * inc / increments;
        const double want = inc == increments ? tol : fmax(tol, 1e-3);
        int it = 0;
        double w = RELAX, last = INFINITY;
        for (; it < MAX_ITER; ++it) {
            if (contact_residual(&P, p, radius_m, &st->change) != 0) {
                s = hs_err_set(err, HS_ERR_NOT_CONVERGED, "surface press: contact solve failed");
                break;
            }
            st->iterations++;
            if (st->change <= want) break; // also nothing touching yet (both zero)
            // Slower where the iteration swings (many points on a fine surface: the contact
            // set changes from step to step), faster again while it settles.
            w = st->change > last ? fmax(w * 0.5, RELAX / 64) : fmin(RELAX, w * 1.25);
            last = st->change;
            for (size_t k = 0; k < n3; ++k) P.f[k] += w * (P.fn[k] - P.f[k]);
            s = solve_body(&P);
            if (s != HS_OK) break;
        }
        if (s == HS_OK && it == MAX_ITER)
            s = hs_err_set(err, HS_ERR_NOT_CONVERGED,
                           "surface press: the contact forces did not settle in %d iterations "
                           "(change %.2g)",
                           MAX_ITER, st->change);
        else if (s != HS_OK && s != HS_ERR_NOT_CONVERGED)
            hs_err_set(err, s, "surface press: the static solve failed (%s) at increment %d of %d",
                       hs_status_str(s), inc, increments);
    }
    if (s == HS_OK) {
        // The check: the final forces solved cold, from rest (the relative tolerance then means
        // what it says), and the contact on that shape must give the same forces.
        hs_body_reset(P.body);
        hs_body_clear_forces(P.body);
        for (int v = 0; v < mesh->n_nodes; ++v)
            if (P.f[3 * v] != 0 || P.f[3 * v + 1] != 0 || P.f[3 * v + 2] != 0)
                hs_body_set_force(P.body, v, P.f + 3 * v);
        hs_step_stats ss;
        s = hs_body_solve_static(P.body, &ss);
        if (s != HS_OK) {
            s = hs_err_set(err, HS_ERR_NOT_CONVERGED,
                           "surface press: the final forces solved from rest did not converge "
                           "(%s, residual %.2g)",
                           hs_status_str(s), ss.residual);
        } else {
            if (contact_residual(&P, to, radius_m, &st->change) != 0 ||
                st->change > fmax(10 * tol, 1e-5))
                s = hs_err_set(err, HS_ERR_NOT_CONVERGED,
                               "surface press: solved from rest, the contact moves its forces by "
                               "%.2g (relative)",
                               st->change);
        }
    }
    if (s == HS_OK || s == HS_ERR_NOT_CONVERGED) {
        const double* u = hs_body_displacement(P.body);
        for (size_t k = 0; k < n3; ++k) P.x[k] = mesh->x0[k] + u[k];
        st->penetration_m = penetration(&P, to, radius_m);
        for (int v = 0; v < mesh->n_nodes; ++v) {
            const double* fv = P.f + 3 * v;
            if (fv[0] == 0 && fv[1] == 0 && fv[2] == 0) continue;
            st->contact_nodes++;
            for (int a = 0; a < 3; ++a) st->force_n[a] -= fv[a];
        }
        if (s == HS_OK && st->contact_nodes == 0)
            s = hs_err_set(err, HS_ERR_INVALID, "surface press: the sphere touches nothing");
        else if (s == HS_OK && st->penetration_m > 1e-3 * radius_m)
            s = hs_err_set(err, HS_ERR_NOT_CONVERGED,
                           "surface press: the solved surface is %.3g mm inside the sphere",
                           st->penetration_m * 1e3);
    }
    st->wall_ms = (double)(hs_now_ns() - t0) * 1e-6;
    destroy(&P);
    return s;
}
