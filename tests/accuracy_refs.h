// SPDX-License-Identifier: GPL-2.0-or-later
// The CalculiX reference problems of tests/accuracy (ccx_refs.py) on hapsim's side: the same
// Kuhn box meshes, boundary conditions and loads, hapsim's models solved statically, and the
// relative L2 error of nodal displacements against a committed reference field. Shared by
// tests/test_accuracy.c and hapsim-bench accuracy.
#ifndef HS_ACCURACY_REFS_H
#define HS_ACCURACY_REFS_H

#include "body.h"
#include "mesh.h"
#include "mooney.h"

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

typedef enum ref_load { REF_GRAVITY, REF_TIP, REF_BAR } ref_load;

// Cantilever 0.10 x 0.02 x 0.02 m, E 1.5 MPa, nu 0.49, 960 kg/m^3, x = 0 clamped (ccx_refs.py).
#define REF_LX    0.10
#define REF_LY    0.02
#define REF_LZ    0.02
#define REF_E     1.5e6
#define REF_NU    0.49
#define REF_RHO   960.0
#define REF_TIP_N 0.5
#define REF_BAR_M 0.005

static const char* const ref_load_name[] = {"gravity", "tip", "bar"};

/// One loaded reference problem on hapsim's side.
typedef struct ref_problem {
    hs_mesh* mesh;
    ref_load load;
    unsigned char* fixed; // [n]
    double* up;           // [3n] prescribed displacement
    double* f;            // [3n] nodal forces (tip)
    unsigned char* end;   // [n] nodes of x = L (the bar's pushed face)
    double g[3];
} ref_problem;

/// Mesh sizes of ccx_refs.py: "1k" 20x3x3, "5k" 30x5x5, "20k" 45x9x9 cells (6 tets each).
static inline int ref_mesh_cells(const char* name, int c[3]) {
    if (!strcmp(name, "1k"))
        c[0] = 20, c[1] = 3, c[2] = 3;
    else if (!strcmp(name, "5k"))
        c[0] = 30, c[1] = 5, c[2] = 5;
    else if (!strcmp(name, "20k"))
        c[0] = 45, c[1] = 9, c[2] = 9;
    else
        return 0;
    return 1;
}

static inline void ref_problem_free(ref_problem* p) {
    hs_mesh_destroy(&p->mesh);
    free(p->fixed);
    free(p->up);
    free(p->f);
    free(p->end);
    memset(p, 0, sizeof *p);
}

/// Build the problem; 0 on success.
static inline int ref_problem_init(ref_problem* p, const char* mesh, ref_load load) {
    memset(p, 0, sizeof *p);
    int c[3];
    hs_err err = {0};
    if (!ref_mesh_cells(mesh, c) ||
        hs_mesh_create_box(REF_LX, REF_LY, REF_LZ, c[0], c[1], c[2], &p->mesh, &err) < 0)
        return 1;
    int n = p->mesh->n_nodes;
    p->load = load;
    p->fixed = calloc((size_t)n, 1);
    p->end = calloc((size_t)n, 1);
    p->up = calloc(3 * (size_t)n, sizeof(double));
    p->f = calloc(3 * (size_t)n, sizeof(double));
    if (!p->fixed || !p->end || !p->up || !p->f) return 1;
    hs_mesh_select_plane(p->mesh, 0, -1, 1e-9, p->fixed);
    hs_mesh_select_plane(p->mesh, 0, +1, 1e-9, p->end);
    if (load == REF_GRAVITY) p->g[2] = -9.81;
    if (load == REF_BAR)
        for (int i = 0; i < n; ++i)
            if (p->end[i]) p->fixed[i] = 1, p->up[3 * i] = -REF_BAR_M;
    if (load == REF_TIP) {
        // The consistent load of a uniform traction: area / 3 to each corner of a face on x = L.
        const hs_mesh* m = p->mesh;
        for (int t = 0; t < m->n_tets; ++t) {
            const int* tt = m->tets + 4 * t;
            int on[4], k = 0;
            for (int a = 0; a < 4; ++a)
                if (p->end[tt[a]]) on[k++] = tt[a];
            if (k != 3) continue;
            const double *a = m->x0 + 3 * on[0], *b = m->x0 + 3 * on[1], *cc = m->x0 + 3 * on[2];
            double u[3], v[3];
            for (int q = 0; q < 3; ++q) u[q] = b[q] - a[q], v[q] = cc[q] - a[q];
            double cr[3] = {u[1] * v[2] - u[2] * v[1], u[2] * v[0] - u[0] * v[2],
                            u[0] * v[1] - u[1] * v[0]};
            double area = 0.5 * sqrt(cr[0] * cr[0] + cr[1] * cr[1] + cr[2] * cr[2]);
            for (int q = 0; q < 3; ++q)
                p->f[3 * on[q] + 2] -= REF_TIP_N * area / (REF_LY * REF_LZ) / 3.0;
        }
    }
    return 0;
}

/// Statistics of the last ref_solve_body_def (iterations, line-search cuts).
static hs_step_stats ref_last_stats;

/// Solve with a real-time model (static, tolerance 1e-10); u_out [3n]; reaction_x (may be
/// NULL): the x reaction summed over the nodes of x = L, N.
static inline int ref_solve_body_def(const ref_problem* p, const hs_fem_def* fem, double* u_out,
                                     double* reaction_x) {
    hs_err err = {0};
    hs_body_def d = hs_body_default_def();
    d.fem = *fem;
    memcpy(d.gravity, p->g, sizeof p->g);
    d.static_tol = 1e-10;
    d.static_max_iter = 200;
    d.static_load_steps = 1;
    hs_body* b = NULL;
    if (hs_body_create(p->mesh, &d, p->fixed, &b, &err) < 0) {
        printf("  body: %s\n", err.msg);
        return 1;
    }
    int n = p->mesh->n_nodes, rc = 0;
    for (int i = 0; i < n && !rc; ++i) {
        if (p->f[3 * i + 2] != 0) rc |= hs_body_set_force(b, i, p->f + 3 * i) != HS_OK;
        if (p->fixed[i] && p->up[3 * i] != 0)
            rc |= hs_body_set_prescribed(b, i, p->up + 3 * i) != HS_OK;
    }
    hs_step_stats st;
    hs_status s = rc ? HS_ERR_INVALID : hs_body_solve_static(b, &st);
    ref_last_stats = st;
    if (s != HS_OK) {
        printf("  static solve: status %d after %d iterations, residual ratio %.3g\n", (int)s,
               st.iterations, st.residual);
        rc = 1;
    } else {
        memcpy(u_out, hs_body_displacement(b), 3 * (size_t)n * sizeof(double));
        if (reaction_x) {
            *reaction_x = 0;
            for (int i = 0; i < n; ++i)
                if (p->end[i]) {
                    double r[3];
                    hs_body_reaction(b, i, r);
                    *reaction_x += r[0];
                }
        }
    }
    hs_body_destroy(&b);
    return rc;
}

/// ref_solve_body_def with the problem's material; lf: hs_fem_def.locking_free.
static inline int ref_solve_body(const ref_problem* p, hs_model model, int lf, double* u_out,
                                 double* reaction_x) {
    hs_fem_def d = hs_fem_default_def();
    d.model = model;
    d.material = (hs_material){REF_E, REF_NU, REF_RHO, 0, 0};
    d.locking_free = lf;
    return ref_solve_body_def(p, &d, u_out, reaction_x);
}

/// The Mooney-Rivlin reference solver (beta as given; 0 = plain P1/P0, as CalculiX's C3D4).
static inline int ref_solve_mooney(const ref_problem* p, double beta, double* u_out) {
    hs_err err = {0};
    hs_mooney_def d = hs_mooney_default_def();
    d.youngs_pa = REF_E;
    d.poisson = REF_NU;
    d.density_kg_m3 = REF_RHO;
    d.beta = beta;
    d.tolerance = 1e-8; // its round-off floor at nu 0.49 is near 1e-8 (docs/mooney.md)
    d.load_steps = 2;
    d.max_newton_iter = 40;
    hs_mooney* m = NULL;
    if (hs_mooney_create(p->mesh, &d, p->fixed, &m, &err) < 0) {
        printf("  mooney: %s\n", err.msg);
        return 1;
    }
    hs_status s = hs_mooney_set_gravity(m, p->g);
    if (s == HS_OK) s = hs_mooney_set_prescribed(m, p->up);
    if (s == HS_OK) s = hs_mooney_set_forces(m, p->f);
    if (s == HS_OK) s = hs_mooney_solve_static(m, NULL, &err);
    if (s == HS_OK)
        memcpy(u_out, hs_mooney_displacement(m), 3 * (size_t)p->mesh->n_nodes * sizeof(double));
    else
        printf("  mooney solve: %s\n", err.msg);
    hs_mooney_destroy(&m);
    return s != HS_OK;
}

/// Read a reference field (ccx_refs.py's format: '#' comment, then "ux uy uz" per node) into
/// u [3n]; 0 on success, messages name the file and line.
static inline int ref_read_field(const char* path, int n, double* u) {
    FILE* fp = fopen(path, "r");
    if (!fp) {
        printf("  cannot open %s\n", path);
        return 1;
    }
    char line[256];
    int i = 0, ln = 0;
    while (fgets(line, sizeof line, fp)) {
        ln++;
        if (line[0] == '#') continue;
        if (i >= n || sscanf(line, "%lf %lf %lf", u + 3 * i, u + 3 * i + 1, u + 3 * i + 2) != 3) {
            printf("  %s:%d: expected 'ux uy uz' for node %d of %d\n", path, ln, i, n);
            fclose(fp);
            return 1;
        }
        i++;
    }
    fclose(fp);
    if (i != n) {
        printf("  %s: %d nodes, expected %d\n", path, i, n);
        return 1;
    }
    return 0;
}

/// CalculiX's total x reaction at x = 0 of one run, N, from summary.csv in dir (with the
/// trailing slash); NAN when absent.
static inline double ref_summary_reaction_x(const char* dir, const char* load, const char* mat,
                                            const char* elem, const char* mesh) {
    char path[512];
    snprintf(path, sizeof path, "%ssummary.csv", dir);
    FILE* f = fopen(path, "r");
    if (!f) return NAN;
    char line[512];
    double v = NAN;
    while (fgets(line, sizeof line, f)) {
        char l[32], m[32], e[32], me[32];
        double d[5];
        int tets;
        if (sscanf(line, "%31[^,],%31[^,],%31[^,],%31[^,],%d,%lf,%lf,%lf,%lf,%lf", l, m, e, me,
                   &tets, d, d + 1, d + 2, d + 3, d + 4) == 10 &&
            !strcmp(l, load) && !strcmp(m, mat) && !strcmp(e, elem) && !strcmp(me, mesh))
            v = d[3];
    }
    fclose(f);
    return v;
}

/// Relative L2 error of nodal displacements, %: 100 ||u - u_ref|| / ||u_ref|| over all nodes.
static inline double ref_rel_l2_pct(int n, const double* u, const double* uref) {
    double num = 0, den = 0;
    for (int k = 0; k < 3 * n; ++k) {
        num += (u[k] - uref[k]) * (u[k] - uref[k]);
        den += uref[k] * uref[k];
    }
    return 100.0 * sqrt(num / den);
}

#endif
