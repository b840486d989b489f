// SPDX-License-Identifier: GPL-2.0-or-later
// Condensed compliance and probe contact: exactness against full FEM solves, the column cache,
// the contact solve (active set, cap, stiffness) on the bundled liver.
#include "body.h"
#include "compliance.h"
#include "mesh.h"
#include "test_macros.h"

#include <stdlib.h>

// The default scene (scenes/liver/liver.json): liver2 held by its y-min face (10 mm slab).
static hs_mesh* load_liver(unsigned char** fixed) {
    hs_err err = {0};
    hs_mesh* m = NULL;
    if (hs_mesh_load(HS_SOURCE_DIR "/scenes/liver/liver2.msh", &m, &err) < 0 &&
        hs_mesh_load(HS_SHARED_MESHES "/liver2.msh", &m, &err) < 0) {
        printf("  cannot load liver2: %s\n", err.msg);
        return NULL;
    }
    *fixed = calloc((size_t)m->n_nodes, 1);
    hs_mesh_select_plane(m, 1, -1, 0.010, *fixed);
    return m;
}

static hs_fem_def liver_fem(hs_model model) {
    hs_fem_def d = hs_fem_default_def();
    d.model = model;
    d.material.youngs_pa = 5000;
    d.material.poisson = 0.45;
    d.material.density_kg_m3 = 1060;
    return d;
}

// Surface node farthest along +y (opposite the fixed face) and its outward normal estimate.
static int far_node(const hs_mesh* m, const unsigned char* fixed) {
    int best = -1;
    for (int s = 0; s < m->n_surf_nodes; ++s) {
        int k = m->surf_nodes[s];
        if (fixed[k]) continue;
        if (best < 0 || m->x0[3 * k + 1] > m->x0[3 * best + 1]) best = k;
    }
    return best;
}

// The k surface nodes nearest to node c (c first), excluding fixed ones.
static int nearest_surface(const hs_mesh* m, const unsigned char* fixed, int c, int k, int* out) {
    int n = 0;
    double* dist = malloc(sizeof(double) * (size_t)k);
    for (int s = 0; s < m->n_surf_nodes; ++s) {
        int v = m->surf_nodes[s];
        if (fixed[v]) continue;
        double d = 0;
        for (int a = 0; a < 3; ++a) d += pow(m->x0[3 * v + a] - m->x0[3 * c + a], 2);
        if (n == k && d >= dist[n - 1]) continue;
        int at = n < k ? n++ : n - 1;
        while (at > 0 && dist[at - 1] > d) {
            dist[at] = dist[at - 1];
            out[at] = out[at - 1];
            --at;
        }
        dist[at] = d;
        out[at] = v;
    }
    free(dist);
    return n;
}

// Reactions of a full static solve with nodes[m] prescribed to d[3m] (the force the support
// exerts on the tissue, i.e. the force on the tissue at the pressed nodes).
static int full_reaction(const hs_mesh* mesh, const unsigned char* fixed, hs_model model, int m,
                         const int* nodes, const double* d, double* react, double* rot) {
    hs_err err = {0};
    unsigned char* fx = malloc((size_t)mesh->n_nodes);
    memcpy(fx, fixed, (size_t)mesh->n_nodes);
    for (int i = 0; i < m; ++i) fx[nodes[i]] = 1;
    hs_body_def bd = hs_body_default_def();
    bd.fem = liver_fem(model);
    bd.static_load_steps = model == HS_MODEL_LINEAR ? 1 : 5;
    bd.static_tol = 1e-10;
    hs_body* b = NULL;
    hs_status s = hs_body_create(mesh, &bd, fx, &b, &err);
    free(fx);
    if (s != HS_OK) {
        printf("  body: %s\n", err.msg);
        return 1;
    }
    for (int i = 0; i < m; ++i) hs_body_set_prescribed(b, nodes[i], d + 3 * i);
    hs_step_stats st;
    s = hs_body_solve_static(b, &st);
    if (s < 0) {
        printf("  static solve failed: %s\n", hs_status_str(s));
        hs_body_destroy(&b);
        return 1;
    }
    for (int i = 0; i < m; ++i) {
        hs_body_reaction(b, nodes[i], react + 3 * i);
        if (rot) hs_fem_node_rotation(hs_body_fem(b), nodes[i], rot + 9 * i);
    }
    hs_body_destroy(&b);
    return 0;
}

static double vnorm(const double* v, int n) {
    double s = 0;
    for (int i = 0; i < n; ++i) s += v[i] * v[i];
    return sqrt(s);
}

static double rel_diff(const double* a, const double* b, int n) {
    double s = 0;
    for (int i = 0; i < n; ++i) s += (a[i] - b[i]) * (a[i] - b[i]);
    return sqrt(s) / vnorm(b, n);
}

static int exact_single_node(void) {
    int64_t bytes0 = hs_byte_count();
    unsigned char* fixed = NULL;
    hs_mesh* mesh = load_liver(&fixed);
    ENSURE(mesh);
    hs_fem_def fd = liver_fem(HS_MODEL_LINEAR);
    hs_compliance* c = NULL;
    hs_err err = {0};
    ENSURE(hs_compliance_create(mesh, &fd, fixed, 32, &c, &err) == HS_OK);
    printf("  liver2: %d surface nodes, set-up %.1f ms\n", mesh->n_surf_nodes,
           hs_compliance_setup_ms(c));
    int k = far_node(mesh, fixed);
    double n[3];
    hs_mesh_rest_normal(mesh, k, n);
    double d[3] = {-0.002 * n[0] + 0.0005, -0.002 * n[1], -0.002 * n[2] - 0.0003};
    double f[3], react[3];
    ENSURE(hs_compliance_solve_set(c, 1, &k, NULL, d, f) == HS_OK);
    ENSURE(full_reaction(mesh, fixed, HS_MODEL_LINEAR, 1, &k, d, react, NULL) == 0);
    printf("  node %d: condensed f = (%.6g %.6g %.6g) N, full (%.6g %.6g %.6g) N\n", k, f[0], f[1],
           f[2], react[0], react[1], react[2]);
    ENSURE(vnorm(react, 3) > 1e-3); // a real force, not a trivial zero
    ENSURE_SMALL(rel_diff(f, react, 3), 1e-6);
    // The diagonal block is symmetric positive definite.
    double blk[9];
    hs_compliance_diag(c, k, blk);
    ENSURE_SMALL(blk[1] - blk[3], 1e-12 * fabs(blk[0]));
    ENSURE(blk[0] > 0 && blk[4] > 0 && blk[8] > 0);
    // A fixed node is not contactable; an interior node neither.
    int fixed_node = -1;
    for (int i = 0; i < mesh->n_nodes && fixed_node < 0; ++i)
        if (fixed[i]) fixed_node = i;
    ENSURE(!hs_compliance_contactable(c, fixed_node));
    ENSURE(hs_compliance_contactable(c, k));
    hs_compliance_destroy(&c);
    ENSURE(c == NULL);
    hs_mesh_destroy(&mesh);
    free(fixed);
    ENSURE(hs_byte_count() == bytes0);
    return 0;
}

static int exact_several_nodes(void) {
    unsigned char* fixed = NULL;
    hs_mesh* mesh = load_liver(&fixed);
    ENSURE(mesh);
    hs_fem_def fd = liver_fem(HS_MODEL_LINEAR);
    hs_compliance* c = NULL;
    hs_err err = {0};
    ENSURE(hs_compliance_create(mesh, &fd, fixed, 32, &c, &err) == HS_OK);
    int nodes[8];
    int m = nearest_surface(mesh, fixed, far_node(mesh, fixed), 8, nodes);
    ENSURE(m == 8);
    double d[24], f[24], react[24];
    srand(7);
    for (int i = 0; i < 24; ++i) d[i] = 0.002 * ((double)rand() / RAND_MAX - 0.5);
    ENSURE(hs_compliance_solve_set(c, m, nodes, NULL, d, f) == HS_OK);
    ENSURE(full_reaction(mesh, fixed, HS_MODEL_LINEAR, m, nodes, d, react, NULL) == 0);
    double worst = 0;
    for (int i = 0; i < m; ++i) {
        double r = rel_diff(f + 3 * i, react + 3 * i, 3);
        if (r > worst) worst = r;
    }
    printf("  %d nodes: worst per-node relative difference %.3g\n", m, worst);
    ENSURE_SMALL(worst, 1e-6);
    // The coupling matters: the diagonal-only answer is clearly different.
    double fd0[24];
    for (int i = 0; i < m; ++i)
        ENSURE(hs_compliance_solve_set(c, 1, nodes + i, NULL, d + 3 * i, fd0 + 3 * i) == HS_OK);
    ENSURE(rel_diff(fd0, react, 24) > 0.05);
    hs_compliance_destroy(&c);
    hs_mesh_destroy(&mesh);
    free(fixed);
    return 0;
}

// Co-rotated, 5 mm along the inward normal at one node. The rest-state compliance alone is
// the linear answer; the haptic loop removes what the current forces displaced (the contact-
// free position), which makes each deformation step one defect-correction iteration
//     f <- f + (R C R^T)^-1 (d - u_k(f)),  u_k(f) = co-rotated static displacement under f,
// whose fixed point is the exact co-rotated reaction. Three iterations must be within 2 %.
static int corotated_5mm(void) {
    unsigned char* fixed = NULL;
    hs_mesh* mesh = load_liver(&fixed);
    ENSURE(mesh);
    hs_fem_def fd = liver_fem(HS_MODEL_COROTATED);
    hs_compliance* c = NULL;
    hs_err err = {0};
    ENSURE(hs_compliance_create(mesh, &fd, fixed, 32, &c, &err) == HS_OK);
    int k = far_node(mesh, fixed);
    double n[3], d[3], f[3], react[3], rot[9];
    hs_mesh_rest_normal(mesh, k, n);
    for (int a = 0; a < 3; ++a) d[a] = -0.005 * n[a];
    ENSURE(full_reaction(mesh, fixed, HS_MODEL_COROTATED, 1, &k, d, react, rot) == 0);
    ENSURE(hs_compliance_solve_set(c, 1, &k, NULL, d, f) == HS_OK);
    double e0 = rel_diff(f, react, 3);
    printf("  5 mm at node %d: full co-rotated |f| = %.4g N; rest-state condensed %.3g %% off\n", k,
           vnorm(react, 3), 100 * e0);

    hs_body_def bd = hs_body_default_def();
    bd.fem = fd;
    bd.static_load_steps = 3;
    bd.static_tol = 1e-10;
    hs_body* b = NULL;
    ENSURE(hs_body_create(mesh, &bd, fixed, &b, &err) == HS_OK);
    double e = e0;
    for (int it = 1; it <= 3; ++it) {
        hs_body_set_force(b, k, f);
        ENSURE(hs_body_solve_static(b, NULL) >= 0);
        const double* u = hs_body_displacement(b);
        double r[3], df[3];
        for (int a = 0; a < 3; ++a) r[a] = d[a] - u[3 * k + a];
        hs_fem_node_rotation(hs_body_fem(b), k, rot);
        ENSURE(hs_compliance_solve_set(c, 1, &k, rot, r, df) == HS_OK);
        for (int a = 0; a < 3; ++a) f[a] += df[a];
        double en = rel_diff(f, react, 3);
        printf("  iteration %d: %.3g %% off\n", it, 100 * en);
        ENSURE(en < e); // contracts
        e = en;
    }
    ENSURE_SMALL(e, 0.02);
    hs_body_destroy(&b);
    hs_compliance_destroy(&c);
    hs_mesh_destroy(&mesh);
    free(fixed);
    return 0;
}

// Columns: the displacement of the whole surface under contact forces equals a full solve, the
// cache evicts least recently used unpinned columns, and C_ij = C_ji^T.
static int columns_and_cache(void) {
    unsigned char* fixed = NULL;
    hs_mesh* mesh = load_liver(&fixed);
    ENSURE(mesh);
    hs_fem_def fd = liver_fem(HS_MODEL_LINEAR);
    hs_compliance* c = NULL;
    hs_err err = {0};
    ENSURE(hs_compliance_create(mesh, &fd, fixed, 4, &c, &err) == HS_OK);
    ENSURE(hs_compliance_cache_capacity(c) == 4);
    int nodes[6];
    ENSURE(nearest_surface(mesh, fixed, far_node(mesh, fixed), 6, nodes) == 6);
    double f[9] = {0.01, -0.02, 0.005, 0, 0.01, -0.01, -0.004, 0, 0.02};
    hs_compliance_begin_step(c);
    ENSURE(hs_compliance_ensure(c, 3, nodes, 3) == 3);
    ENSURE(hs_compliance_column_solves(c) == 3);
    ENSURE(hs_compliance_ensure(c, 3, nodes, 3) == 3); // cached: no new solve
    ENSURE(hs_compliance_column_solves(c) == 3);
    double* us = malloc(sizeof(double) * 3 * (size_t)mesh->n_surf_nodes);
    ENSURE(hs_compliance_surface_displacement(c, 3, nodes, f, us) == 0);

    hs_body_def bd = hs_body_default_def();
    bd.fem = fd;
    hs_body* b = NULL;
    ENSURE(hs_body_create(mesh, &bd, fixed, &b, &err) == HS_OK);
    for (int i = 0; i < 3; ++i) hs_body_set_force(b, nodes[i], f + 3 * i);
    ENSURE(hs_body_solve_static(b, NULL) >= 0);
    const double* u = hs_body_displacement(b);
    double num = 0, den = 0;
    for (int s = 0; s < mesh->n_surf_nodes; ++s)
        for (int a = 0; a < 3; ++a) {
            double e = us[3 * s + a] - u[3 * mesh->surf_nodes[s] + a];
            num += e * e;
            den += u[3 * mesh->surf_nodes[s] + a] * u[3 * mesh->surf_nodes[s] + a];
        }
    printf("  surface displacement from 3 columns vs full solve: %.3g relative\n", sqrt(num / den));
    ENSURE_SMALL(sqrt(num / den), 1e-8);
    hs_body_destroy(&b);

    // C_ij from column j equals (C_ji from column i)^T.
    double bij[9], bji[9];
    ENSURE(hs_compliance_block(c, nodes[0], nodes[1], bij) == 1);
    ENSURE(hs_compliance_block(c, nodes[1], nodes[0], bji) == 1);
    for (int p = 0; p < 3; ++p)
        for (int q = 0; q < 3; ++q)
            ENSURE_SMALL(bij[3 * p + q] - bji[3 * q + p], 1e-9 * fabs(bij[0]));
    // Nodes 3..5 are not cached: their mutual block is unknown (zero, returns 0).
    ENSURE(hs_compliance_block(c, nodes[4], nodes[5], bij) == 0);
    ENSURE(bij[0] == 0 && bij[4] == 0);

    // Pinned this step: only 1 free slot left, so 1 of the 3 new ones gets a column.
    ENSURE(hs_compliance_ensure(c, 3, nodes + 3, 3) == 1);
    // Next step: the pins are released and the least recently used columns are evicted.
    hs_compliance_begin_step(c);
    ENSURE(hs_compliance_ensure(c, 3, nodes + 3, 3) == 3);
    int cached = 0;
    for (int i = 0; i < 6; ++i) cached += hs_compliance_has_column(c, nodes[i]);
    ENSURE(cached == 4);
    ENSURE(hs_compliance_has_column(c, nodes[3]) && hs_compliance_has_column(c, nodes[4]) &&
           hs_compliance_has_column(c, nodes[5]));
    // A missing column: the displacement refuses rather than guessing.
    int absent = -1;
    for (int i = 0; i < 3; ++i)
        if (!hs_compliance_has_column(c, nodes[i])) absent = i;
    ENSURE(absent >= 0);
    ENSURE(hs_compliance_surface_displacement(c, 1, nodes + absent, f, us) == -1);
    // A new column must not evict one asked for later in the same call (B below was the least
    // recently used when A needed a slot: evicted, while C and D, not asked for, stayed).
    hs_compliance_destroy(&c);
    ENSURE(hs_compliance_create(mesh, &fd, fixed, 3, &c, &err) == HS_OK);
    const int A = nodes[0], B = nodes[1], cd[2] = {nodes[2], nodes[3]}, ab[2] = {A, B};
    hs_compliance_begin_step(c);
    ENSURE(hs_compliance_ensure(c, 1, &B, 8) == 1);
    hs_compliance_begin_step(c);
    ENSURE(hs_compliance_ensure(c, 2, cd, 8) == 2);
    hs_compliance_begin_step(c);
    ENSURE(hs_compliance_ensure(c, 2, ab, 1) == 2);
    ENSURE(hs_compliance_has_column(c, A) && hs_compliance_has_column(c, B));
    free(us);
    hs_compliance_destroy(&c);
    hs_mesh_destroy(&mesh);
    free(fixed);
    return 0;
}

// A snapshot at rest around tool position p: the nearest contactable surface nodes, all
// coupled (rotation identity).
static void rest_snapshot(hs_compliance* c, const hs_mesh* mesh, const double p[3], double r,
                          hs_contact_snapshot* s) {
    memset(s, 0, sizeof *s);
    s->version = 1;
    s->probe_radius_m = r;
    memcpy(s->centre_m, p, sizeof s->centre_m);
    int n = 0;
    double dist[HS_CONTACT_MAX_CAND];
    for (int si = 0; si < mesh->n_surf_nodes; ++si) {
        int v = mesh->surf_nodes[si];
        if (!hs_compliance_contactable(c, v)) continue;
        double d = sqrt(pow(mesh->x0[3 * v] - p[0], 2) + pow(mesh->x0[3 * v + 1] - p[1], 2) +
                        pow(mesh->x0[3 * v + 2] - p[2], 2));
        if (n == HS_CONTACT_MAX_CAND && d >= dist[n - 1]) continue;
        int at = n < HS_CONTACT_MAX_CAND ? n++ : n - 1;
        while (at > 0 && dist[at - 1] > d) {
            dist[at] = dist[at - 1];
            s->node[at] = s->node[at - 1];
            --at;
        }
        dist[at] = d;
        s->node[at] = v;
    }
    s->n_cand = n;
    s->reach_m = dist[n - 1];
    hs_compliance_begin_step(c);
    hs_compliance_ensure(c, n, s->node, n);
    for (int i = 0; i < n; ++i) {
        s->coupled[i] = (unsigned char)hs_compliance_has_column(c, s->node[i]);
        memcpy(s->surf_m[i], mesh->x0 + 3 * s->node[i], 3 * sizeof(double));
        hs_mesh_rest_normal(mesh, s->node[i], s->normal[i]);
        for (int j = 0; j < n; ++j) hs_compliance_block(c, s->node[i], s->node[j], s->c[i][j]);
    }
}

static int contact_solve(void) {
    unsigned char* fixed = NULL;
    hs_mesh* mesh = load_liver(&fixed);
    ENSURE(mesh);
    hs_fem_def fd = liver_fem(HS_MODEL_LINEAR);
    hs_compliance* c = NULL;
    hs_err err = {0};
    ENSURE(hs_compliance_create(mesh, &fd, fixed, 96, &c, &err) == HS_OK);
    int k = far_node(mesh, fixed);
    double n[3];
    hs_mesh_rest_normal(mesh, k, n);
    static hs_contact_snapshot snap;
    const double r = 0.03;
    // Sphere pressed 8 mm into the surface at node k along -n.
    double p[3];
    for (int a = 0; a < 3; ++a) p[a] = mesh->x0[3 * k + a] + (r - 0.008) * n[a];
    rest_snapshot(c, mesh, p, r, &snap);
    hs_contact con;
    int64_t calls0 = hs_alloc_calls();
    hs_contact_solve(&snap, p, 0, NULL, &con);
    ENSURE(hs_alloc_calls() == calls0);
    printf("  r %.0f mm, 8 mm deep: %d penetrating, %d in contact, %d pivots, |F| = %.4g N\n",
           r * 1e3, con.penetrating, con.n, con.passes, vnorm(con.force_n, 3));
    ENSURE(con.n >= 2 && !con.failed && !con.approx);
    // Pushes the tool back out: along +n.
    ENSURE(con.force_n[0] * n[0] + con.force_n[1] * n[1] + con.force_n[2] * n[2] > 0);
    // Complementarity, checked with the compliance itself: displacement of every candidate
    // under the contact forces (d_m of the contact nodes must agree); contact nodes end on the
    // sphere (to first order in the radial direction), all others on or outside it, and every
    // force pushes radially away from the centre.
    double sum[3] = {0, 0, 0}, eps = 0;
    for (int i = 0; i < snap.n_cand; ++i)
        eps += (snap.c[i][i][0] + snap.c[i][i][4] + snap.c[i][i][8]) / 3 / snap.n_cand;
    eps *= HS_CONTACT_SOFTNESS;
    for (int i = 0; i < snap.n_cand; ++i) {
        double u[3] = {0, 0, 0};
        for (int j = 0; j < con.n; ++j) {
            double blk[9];
            ENSURE(hs_compliance_block(c, snap.node[i], con.node[j], blk) == 1);
            for (int a = 0; a < 3; ++a)
                for (int b = 0; b < 3; ++b) u[a] += blk[3 * a + b] * con.f_n[j][b];
        }
        double q[3], rho, nn[3];
        for (int a = 0; a < 3; ++a) q[a] = snap.surf_m[i][a] - p[a];
        rho = vnorm(q, 3);
        for (int a = 0; a < 3; ++a) nn[a] = q[a] / rho;
        double dist = rho + nn[0] * u[0] + nn[1] * u[1] + nn[2] * u[2];
        int in = -1;
        for (int j = 0; j < con.n; ++j)
            if (con.node[j] == snap.node[i]) in = j;
        if (rho >= HS_CONTACT_BAND * r) continue; // not an LCP candidate
        if (in >= 0) {
            // On the sphere up to the contact compliance eps: r - eps lambda.
            ENSURE_NEAR(dist, r - eps * vnorm(con.f_n[in], 3), 1e-9);
            ENSURE_SMALL(rel_diff(u, con.d_m[in], 3), 1e-9);
            double fr = con.f_n[in][0] * nn[0] + con.f_n[in][1] * nn[1] + con.f_n[in][2] * nn[2];
            ENSURE(fr > 0);
            ENSURE_SMALL(fr - vnorm(con.f_n[in], 3), 1e-12); // radial
            for (int a = 0; a < 3; ++a) sum[a] -= con.f_n[in][a];
        } else {
            ENSURE(dist >= r - 1e-9);
        }
    }
    ENSURE_SMALL(rel_diff(sum, con.force_n, 3), 1e-12);

    // Stiffness = -dF/dp by central differences (contact set unchanged for small steps).
    const double h = 1e-7;
    double kmax = 0;
    for (int q = 0; q < 9; ++q) kmax = fmax(kmax, fabs(con.stiffness_n_m[q]));
    for (int b = 0; b < 3; ++b) {
        double pp[3], pm[3];
        memcpy(pp, p, sizeof pp);
        memcpy(pm, p, sizeof pm);
        pp[b] += h;
        pm[b] -= h;
        hs_contact cp, cm;
        hs_contact_solve(&snap, pp, 0, NULL, &cp);
        hs_contact_solve(&snap, pm, 0, NULL, &cm);
        ENSURE(cp.n == con.n && cm.n == con.n);
        for (int a = 0; a < 3; ++a) {
            double fdiff = -(cp.force_n[a] - cm.force_n[a]) / (2 * h);
            ENSURE_SMALL(fdiff - con.stiffness_n_m[3 * a + b], 1e-5 * kmax);
        }
    }
    // The normal stiffness is positive: pressing deeper raises the force.
    double knn = 0;
    for (int a = 0; a < 3; ++a)
        for (int b = 0; b < 3; ++b) knn += n[a] * con.stiffness_n_m[3 * a + b] * n[b];
    ENSURE(knn > 0);
    printf("  normal stiffness %.4g N/m, clearance %.3g mm\n", knn, con.clearance_m * 1e3);

    // No jump when nodes enter or leave the contact: sweep 20 mm sideways and 8 mm in depth in
    // 10 um steps; every step's force change stays within 2x the largest stiffness seen times
    // the step (the force is continuous and piecewise smooth in the tool position).
    {
        double t[3] = {1 - n[0] * n[0], -n[0] * n[1], -n[0] * n[2]};
        double tl = vnorm(t, 3);
        for (int a = 0; a < 3; ++a) t[a] /= tl;
        hs_contact prev, cur;
        double pp[3], worst = 0, kb = 0, fprev[3] = {0, 0, 0};
        int changes = 0, prev_n = -1, warm_passes = 0, cold_passes = 0;
        const int steps = 2000;
        for (int i = 0; i <= steps; ++i) {
            double sx = -0.01 + 0.02 * i / steps, dz = 0.004 * sin(6.28 * i / steps);
            for (int a = 0; a < 3; ++a) pp[a] = p[a] + sx * t[a] - dz * n[a];
            hs_contact_solve(&snap, pp, prev_n > 0 ? prev.n : 0, prev.node, &cur);
            ENSURE(!cur.failed);
            // The warm start changes where the pivoting starts, not the answer.
            hs_contact cold;
            hs_contact_solve(&snap, pp, 0, NULL, &cold);
            ENSURE(cold.n == cur.n);
            ENSURE_SMALL(rel_diff(cold.force_n, cur.force_n, 3), 1e-9);
            warm_passes += cur.passes;
            cold_passes += cold.passes;
            for (int q = 0; q < 9; ++q) kb = fmax(kb, fabs(cur.stiffness_n_m[q]));
            if (i > 0) {
                double df[3] = {cur.force_n[0] - fprev[0], cur.force_n[1] - fprev[1],
                                cur.force_n[2] - fprev[2]};
                double dp[3] = {cur.tool_m[0] - prev.tool_m[0], cur.tool_m[1] - prev.tool_m[1],
                                cur.tool_m[2] - prev.tool_m[2]};
                worst = fmax(worst, vnorm(df, 3) / vnorm(dp, 3));
                changes += cur.n != prev_n;
            }
            prev = cur;
            prev_n = cur.n;
            memcpy(fprev, cur.force_n, sizeof fprev);
        }
        printf("  sweep: contact set size changed %d times, largest |dF|/|dp| %.4g N/m, "
               "largest |K| entry %.4g N/m; solves warm %d, cold %d\n",
               changes, worst, kb, warm_passes, cold_passes);
        ENSURE(warm_passes < cold_passes);
        ENSURE(changes >= 4);
        ENSURE(worst <= 2 * 3 * kb);
    }

    // The local model reproduces the force at its anchor and stays within its clamps.
    hs_haptic_model hm;
    hs_contact_model(&con, 0.0002, 0.005, 0.05, &hm);
    ENSURE(hm.seq == snap.version);
    ENSURE(hm.radius_m >= 0.0002 && hm.radius_m <= 0.005);
    double fe[3];
    ENSURE(hs_haptic_model_eval(&hm, p, fe) == 1);
    ENSURE_SMALL(rel_diff(fe, con.force_n, 3), 1e-12);

    // Big sphere deep in: more than 16 penetrate, the deepest 16 are kept.
    const double rb = 0.06;
    for (int a = 0; a < 3; ++a) p[a] = mesh->x0[3 * k + a] + (rb - 0.025) * n[a];
    rest_snapshot(c, mesh, p, rb, &snap);
    hs_contact_solve(&snap, p, 0, NULL, &con);
    printf("  r %.0f mm, 25 mm deep: %d penetrating, %d in contact, %d pivots\n", rb * 1e3,
           con.penetrating, con.n, con.passes);
    ENSURE(con.penetrating > HS_MAX_CONTACT);
    ENSURE(con.n <= HS_MAX_CONTACT && con.n > 0 && !con.failed);

    // Away from the surface: no contact, zero force, and the clearance says how far it is.
    for (int a = 0; a < 3; ++a) p[a] = mesh->x0[3 * k + a] + (r + 0.003) * n[a];
    rest_snapshot(c, mesh, p, r, &snap);
    hs_contact_solve(&snap, p, 0, NULL, &con);
    ENSURE(con.n == 0 && vnorm(con.force_n, 3) == 0);
    ENSURE(con.clearance_m > 0.001 && con.clearance_m <= 0.0031);

    // Diagonal-only approximation when no off-diagonal block is known: flagged.
    for (int a = 0; a < 3; ++a) p[a] = mesh->x0[3 * k + a] + (r - 0.008) * n[a];
    rest_snapshot(c, mesh, p, r, &snap);
    for (int i = 0; i < snap.n_cand; ++i) {
        snap.coupled[i] = 0;
        for (int j = 0; j < snap.n_cand; ++j)
            if (i != j) memset(snap.c[i][j], 0, sizeof snap.c[i][j]);
    }
    hs_contact_solve(&snap, p, 0, NULL, &con);
    ENSURE(con.approx == 1 && con.n >= 1);
    // An empty snapshot gives nothing.
    memset(&snap, 0, sizeof snap);
    hs_contact_solve(&snap, p, 0, NULL, &con);
    ENSURE(con.n == 0 && con.force_n[0] == 0);

    hs_compliance_destroy(&c);
    hs_mesh_destroy(&mesh);
    free(fixed);
    return 0;
}

static int bad_input(void) {
    int64_t bytes0 = hs_byte_count();
    unsigned char* fixed = NULL;
    hs_mesh* mesh = load_liver(&fixed);
    ENSURE(mesh);
    hs_fem_def fd = liver_fem(HS_MODEL_LINEAR);
    hs_compliance* c = (hs_compliance*)1;
    hs_err err = {0};
    ENSURE(hs_compliance_create(mesh, &fd, fixed, 0, &c, &err) == HS_ERR_INVALID);
    ENSURE(c == NULL && strstr(err.msg, "cache_nodes"));
    unsigned char* all = malloc((size_t)mesh->n_nodes);
    memset(all, 1, (size_t)mesh->n_nodes);
    ENSURE(hs_compliance_create(mesh, &fd, all, 8, &c, &err) == HS_ERR_INVALID);
    ENSURE(strstr(err.msg, "fixed"));
    ENSURE(hs_compliance_create(NULL, &fd, fixed, 8, &c, &err) == HS_ERR_INVALID);
    // Allocation failures anywhere in create are reported and leak nothing: every failure
    // point in turn until create gets through (it has ~60 allocations).
    int failures = 0, reached_ok = 0;
    for (int64_t nth = 1; nth < 400 && !reached_ok; ++nth) {
        int64_t b = hs_byte_count();
        hs_alloc_fail_after(nth);
        hs_status s = hs_compliance_create(mesh, &fd, fixed, 8, &c, &err);
        hs_alloc_fail_after(0);
        if (s == HS_OK) {
            hs_compliance_destroy(&c);
            reached_ok = 1;
        } else {
            ENSURE(s < 0 && c == NULL);
            ++failures;
        }
        ENSURE(hs_byte_count() == b);
    }
    ENSURE(reached_ok && failures > 40);
    // A non-finite force is refused and v left as it was (NaN went through as a result).
    ENSURE(hs_compliance_create(mesh, &fd, fixed, 8, &c, &err) == HS_OK);
    const size_t n3 = 3 * (size_t)mesh->n_nodes;
    double* g = calloc(n3, sizeof(double));
    double* v = calloc(n3, sizeof(double));
    int free_node = 0;
    while (fixed[free_node]) free_node++;
    g[3 * free_node + 2] = NAN;
    ENSURE(hs_compliance_apply(c, g, v) == HS_ERR_INVALID);
    for (size_t k = 0; k < n3; ++k) ENSURE(v[k] == 0);
    g[3 * free_node + 2] = -1.0;
    ENSURE(hs_compliance_apply(c, g, v) == HS_OK && v[3 * free_node + 2] < 0);
    free(g);
    free(v);
    hs_compliance_destroy(&c);
    free(all);
    hs_mesh_destroy(&mesh);
    free(fixed);
    ENSURE(hs_byte_count() == bytes0);
    return 0;
}

HS_TEST_MAIN(HS_CASE(exact_single_node), HS_CASE(exact_several_nodes), HS_CASE(corotated_5mm),
             HS_CASE(columns_and_cache), HS_CASE(contact_solve), HS_CASE(bad_input))
