// SPDX-License-Identifier: GPL-2.0-or-later
// hapsim-bench accuracy: run time against error for every model, rotation option, solver and
// time step, against a converged reference (docs/accuracy.md says which reference per scene).
//
// Errors are nodal displacement differences normalised by the bounding-box diagonal of the rest
// mesh (the paper's normalisation). Times are thread CPU times (CLOCK_THREAD_CPUTIME_ID; CHOLMOD
// and OpenBLAS run single-threaded, hs_platform_setup), so other jobs on the machine inflate
// them less than wall time would.
#define _POSIX_C_SOURCE 200809L
#include "accuracy_refs.h"
#include "bench.h"
#include "body.h"
#include "mesh.h"
#include "mooney.h"

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

static double cpu_ms(void) {
    struct timespec ts;
    clock_gettime(CLOCK_THREAD_CPUTIME_ID, &ts);
    return (double)ts.tv_sec * 1e3 + (double)ts.tv_nsec * 1e-6;
}

typedef enum scene_kind { SC_CANTILEVER, SC_VESSEL, SC_LIVER } scene_kind;

// One loaded problem: mesh, boundary conditions, loads and (once computed) the reference
// displacement at its own nodes.
typedef struct acc_problem {
    hs_mesh* mesh;
    unsigned char* fixed; // [n] clamped or prescribed
    double* up;           // [3n] prescribed displacement (0 on clamped nodes)
    unsigned char* probe; // [n] nodes whose reactions sum to the measured force, or NULL
    hs_material mat;
    double gravity[3];
    double diag;  // bounding-box diagonal, m
    double alpha; // Rayleigh mass damping for the dynamic settles, 1/s
    int ramp;     // increments of the prescribed motion in static solves
} acc_problem;

typedef struct acc_result {
    double step_ms;
    int iterations;
    double err_mean, err_max; // % of the diagonal
    double vol;               // mean element V/V0
    double force_err;         // %, NAN when the scene has no measured force
    double err_l2;            // %, 100 ||u - u_ref|| / ||u_ref|| against the row's `ref`
    int ok;
} acc_result;

static void problem_free(acc_problem* p) {
    hs_mesh_destroy(&p->mesh);
    free(p->fixed);
    free(p->up);
    free(p->probe);
    memset(p, 0, sizeof *p);
}

// Build the scene on a mesh: the same geometric rules for coarse and fine meshes.
// heavy: density factor of the cantilever.
static int problem_setup(acc_problem* p, scene_kind kind, double heavy) {
    hs_mesh* m = p->mesh;
    int n = m->n_nodes;
    p->fixed = calloc((size_t)n, 1);
    p->up = calloc(3 * (size_t)n, sizeof(double));
    if (!p->fixed || !p->up) return 1;
    double d[3];
    for (int c = 0; c < 3; ++c) d[c] = m->bbox_max[c] - m->bbox_min[c];
    p->diag = sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2]);
    p->ramp = 1;
    if (kind == SC_CANTILEVER) {
        // The paper's cantilever: 0.10 x 0.02 x 0.02 m, clamped at x = 0, under its own weight.
        hs_mesh_select_plane(m, 0, -1, 1e-9, p->fixed);
        p->mat = (hs_material){1.5e6, 0.49, 960.0 * heavy, 0, 0};
        p->gravity[2] = -9.81;
        p->alpha = heavy > 5 ? 50 : 160; // ~2x the first bending frequency, rad/s
        return 0;
    }
    if (kind == SC_VESSEL) {
        // Top 5 % (z) clamped; bottom 5 % pushed up by 30 % of the height.
        double h = d[2];
        unsigned char* bot = calloc((size_t)n, 1);
        if (!bot) return 1;
        hs_mesh_select_plane(m, 2, +1, 0.05 * h, p->fixed);
        hs_mesh_select_plane(m, 2, -1, 0.05 * h, bot);
        p->probe = bot;
        for (int i = 0; i < n; ++i)
            if (bot[i]) p->fixed[i] = 1, p->up[3 * i + 2] = 0.3 * h;
        p->mat = (hs_material){5e3, 0.45, 1060, 0, 0};
        p->alpha = 100;
        p->ramp = 10;
        return 0;
    }
    // Liver (scenes/liver/liver.json): nodes with y <= -0.0433 clamped; a 5 mm-radius probe
    // presses 5 mm down (-z) on the highest surface node in the half away from the support.
    unsigned char* probe = calloc((size_t)n, 1);
    if (!probe) return 1;
    p->probe = probe;
    for (int i = 0; i < n; ++i)
        if (m->node_used[i] && m->x0[3 * i + 1] <= -0.0433) p->fixed[i] = 1;
    int top = -1;
    for (int s = 0; s < m->n_surf_nodes; ++s) {
        int i = m->surf_nodes[s];
        if (m->x0[3 * i + 1] < 0.5 * (m->bbox_min[1] + m->bbox_max[1])) continue;
        if (top < 0 || m->x0[3 * i + 2] > m->x0[3 * top + 2]) top = i;
    }
    const double* c = m->x0 + 3 * top;
    for (int s = 0; s < m->n_surf_nodes; ++s) {
        int i = m->surf_nodes[s];
        const double* x = m->x0 + 3 * i;
        double r2 = (x[0] - c[0]) * (x[0] - c[0]) + (x[1] - c[1]) * (x[1] - c[1]);
        if (r2 <= 0.005 * 0.005 && x[2] >= c[2] - 0.005) {
            probe[i] = 1;
            p->fixed[i] = 1;
            p->up[3 * i + 2] = -0.005;
        }
    }
    int np = 0;
    for (int i = 0; i < n; ++i) np += probe[i];
    fprintf(stderr, "accuracy: liver probe at (%.4f, %.4f, %.4f) m on %d surface nodes\n", c[0],
            c[1], c[2], np);
    p->mat = (hs_material){5e3, 0.45, 1060, 0, 0};
    p->alpha = 40;
    p->ramp = 5;
    return 0;
}

static int problem_load(acc_problem* p, scene_kind kind, const char* path, int nx, int ny, int nz,
                        double heavy) {
    hs_err err = {0};
    memset(p, 0, sizeof *p);
    hs_status s = kind == SC_CANTILEVER
                      ? hs_mesh_create_box(0.1, 0.02, 0.02, nx, ny, nz, &p->mesh, &err)
                      : hs_mesh_load(path, &p->mesh, &err);
    if (s < 0) {
        fprintf(stderr, "hapsim-bench accuracy: %s\n", err.msg);
        return 1;
    }
    return problem_setup(p, kind, heavy);
}

// --- mapping a fine solution onto coarse nodes ------------------------------------------------

// P1 interpolation of the fine displacement at each coarse rest position: the fine tet that
// contains the point (largest smallest barycentric coordinate, so points on faces and slightly
// outside a curved boundary still find their nearest tet), found through a uniform bucket grid.
static int map_fine_to_coarse(const hs_mesh* fine, const double* uf, const hs_mesh* coarse,
                              double* uc) {
    const int nb = 24;
    double lo[3], w[3];
    for (int c = 0; c < 3; ++c) {
        lo[c] = fine->bbox_min[c];
        w[c] = (fine->bbox_max[c] - lo[c]) / nb + 1e-15;
    }
    int ncell = nb * nb * nb;
    int* start = calloc((size_t)ncell + 1, sizeof(int));
    if (!start) return 1;
    int* list = NULL;
    for (int pass = 0; pass < 2; ++pass) {
        for (int t = 0; t < fine->n_tets; ++t) {
            int a[3], b[3];
            for (int c = 0; c < 3; ++c) {
                double mn = INFINITY, mx = -INFINITY;
                for (int k = 0; k < 4; ++k) {
                    double x = fine->x0[3 * fine->tets[4 * t + k] + c];
                    mn = fmin(mn, x), mx = fmax(mx, x);
                }
                a[c] = (int)floor((mn - lo[c]) / w[c] - 1e-6);
                b[c] = (int)floor((mx - lo[c]) / w[c] + 1e-6);
                a[c] = a[c] < 0 ? 0 : a[c] >= nb ? nb - 1 : a[c];
                b[c] = b[c] < 0 ? 0 : b[c] >= nb ? nb - 1 : b[c];
            }
            for (int i = a[0]; i <= b[0]; ++i)
                for (int j = a[1]; j <= b[1]; ++j)
                    for (int k = a[2]; k <= b[2]; ++k) {
                        int cell = i + nb * (j + nb * k);
                        if (pass == 0)
                            start[cell + 1]++;
                        else
                            list[start[cell]++] = t;
                    }
        }
        if (pass == 0) {
            for (int c = 0; c < ncell; ++c) start[c + 1] += start[c];
            list = malloc((size_t)start[ncell] * sizeof(int) + 1);
            if (!list) {
                free(start);
                return 1;
            }
        } else {
            for (int c = ncell; c > 0; --c) start[c] = start[c - 1];
            start[0] = 0;
        }
    }
    int worst_missing = 0;
    for (int v = 0; v < coarse->n_nodes; ++v) {
        const double* x = coarse->x0 + 3 * v;
        int cc[3];
        for (int c = 0; c < 3; ++c) {
            cc[c] = (int)floor((x[c] - lo[c]) / w[c]);
            cc[c] = cc[c] < 0 ? 0 : cc[c] >= nb ? nb - 1 : cc[c];
        }
        double best = -INFINITY, bw[4] = {0};
        int bt = -1;
        // Search the cell, then its neighbours if the point lies outside every candidate.
        for (int rad = 0; rad <= 2 && best < -1e-9; ++rad)
            for (int i = cc[0] - rad; i <= cc[0] + rad; ++i)
                for (int j = cc[1] - rad; j <= cc[1] + rad; ++j)
                    for (int k = cc[2] - rad; k <= cc[2] + rad; ++k) {
                        if (i < 0 || j < 0 || k < 0 || i >= nb || j >= nb || k >= nb) continue;
                        int cell = i + nb * (j + nb * k);
                        for (int q = start[cell]; q < start[cell + 1]; ++q) {
                            int t = list[q];
                            const int* tt = fine->tets + 4 * t;
                            double xx[12];
                            for (int a = 0; a < 4; ++a)
                                memcpy(xx + 3 * a, fine->x0 + 3 * tt[a], 24);
                            double v0 = hs_tet_volume(fine->x0, tt), bary[4];
                            int idx[4] = {0, 3, 6, 9};
                            for (int a = 0; a < 4; ++a) {
                                double y[12];
                                memcpy(y, xx, sizeof y);
                                memcpy(y + idx[a], x, 24);
                                int id4[4] = {0, 1, 2, 3};
                                bary[a] = hs_tet_volume(y, id4) / v0;
                            }
                            double mn = fmin(fmin(bary[0], bary[1]), fmin(bary[2], bary[3]));
                            if (mn > best) best = mn, bt = t, memcpy(bw, bary, sizeof bw);
                        }
                    }
        if (bt < 0 || best < -0.05) worst_missing++;
        for (int c = 0; c < 3; ++c) {
            double s = 0;
            for (int a = 0; a < 4 && bt >= 0; ++a) s += bw[a] * uf[3 * fine->tets[4 * bt + a] + c];
            uc[3 * v + c] = s;
        }
    }
    free(list);
    free(start);
    if (worst_missing)
        fprintf(stderr, "hapsim-bench accuracy: %d coarse nodes outside the fine mesh\n",
                worst_missing);
    return worst_missing != 0;
}

// --- measures ---------------------------------------------------------------------------------

static double mean_volume_ratio(const hs_mesh* m, const double* u, double* scratch) {
    for (int k = 0; k < 3 * m->n_nodes; ++k) scratch[k] = m->x0[k] + u[k];
    double s = 0;
    for (int t = 0; t < m->n_tets; ++t)
        s += hs_tet_volume(scratch, m->tets + 4 * t) / hs_tet_volume(m->x0, m->tets + 4 * t);
    return s / m->n_tets;
}

static void errors(const acc_problem* p, const double* u, const double* uref, double* mean,
                   double* mx) {
    double s = 0, w = 0;
    int cnt = 0;
    for (int i = 0; i < p->mesh->n_nodes; ++i) {
        if (!p->mesh->node_used[i]) continue;
        double d2 = 0;
        for (int c = 0; c < 3; ++c)
            d2 += (u[3 * i + c] - uref[3 * i + c]) * (u[3 * i + c] - uref[3 * i + c]);
        double d = sqrt(d2);
        s += d, w = fmax(w, d), cnt++;
    }
    *mean = 100.0 * s / cnt / p->diag;
    *mx = 100.0 * w / p->diag;
}

static double force_error(const double f[3], const double fref[3]) {
    double d = 0, r = 0;
    for (int c = 0; c < 3; ++c) d += (f[c] - fref[c]) * (f[c] - fref[c]), r += fref[c] * fref[c];
    return r > 0 ? 100.0 * sqrt(d / r) : NAN;
}

// --- Mooney-Rivlin ------------------------------------------------------------------------

// beta = 0.2 kappa / mu (docs/mooney.md) unless beta_override >= 0.
static int solve_mooney(const acc_problem* p, double tol, double beta_override, double* u_out,
                        double force[3], acc_result* r) {
    hs_err err = {0};
    hs_mooney_def d = hs_mooney_default_def();
    d.youngs_pa = p->mat.youngs_pa;
    d.poisson = p->mat.poisson;
    d.density_kg_m3 = p->mat.density_kg_m3;
    double nu = p->mat.poisson;
    d.beta = beta_override >= 0 ? beta_override : 0.2 * 2 * (1 + nu) / (3 * (1 - 2 * nu));
    d.tolerance = tol;
    d.load_steps = p->probe ? p->ramp : 4;
    d.max_newton_iter = 40;
    hs_mooney* m = NULL;
    double t0 = cpu_ms();
    if (hs_mooney_create(p->mesh, &d, p->fixed, &m, &err) < 0) {
        fprintf(stderr, "hapsim-bench accuracy: mooney: %s\n", err.msg);
        return 1;
    }
    hs_status s = hs_mooney_set_gravity(m, p->gravity);
    if (s == HS_OK) s = hs_mooney_set_prescribed(m, p->up);
    hs_mooney_stats st;
    if (s == HS_OK) s = hs_mooney_solve_static(m, &st, &err);
    double t1 = cpu_ms();
    if (s != HS_OK) {
        fprintf(stderr, "hapsim-bench accuracy: mooney (%d tets): %s\n", p->mesh->n_tets, err.msg);
        hs_mooney_destroy(&m);
        return 1;
    }
    int n = p->mesh->n_nodes;
    memcpy(u_out, hs_mooney_displacement(m), 3 * (size_t)n * sizeof(double));
    if (force) {
        double* q = malloc(3 * (size_t)n * sizeof(double));
        hs_mooney_internal_forces(m, q);
        force[0] = force[1] = force[2] = 0;
        for (int i = 0; i < n; ++i)
            if (p->probe && p->probe[i])
                for (int c = 0; c < 3; ++c) force[c] += q[3 * i + c];
        free(q);
    }
    if (r) {
        r->step_ms = t1 - t0;
        r->iterations = st.newton_total;
    }
    hs_mooney_destroy(&m);
    return 0;
}

// --- real-time models ---------------------------------------------------------------------

typedef struct acc_cfg {
    const char* model; // CSV label
    const char* option;
    hs_model fem_model; // -1: Mooney-Rivlin
    hs_rotation rotation;
    double polar_tol;
    int locking_free;
    int dynamic;   // 0: static Newton; 1: implicit Euler steps to steady state
    int pcg_iters; // 0: direct solver
    double dt;     // s
    int jacobi;    // PCG with the Jacobi preconditioner to tolerance 1e-8 (the paper's CG)
} acc_cfg;

#define MR (-1)

static void body_force(hs_body* b, const acc_problem* p, double f[3]) {
    f[0] = f[1] = f[2] = 0;
    if (!p->probe) return;
    for (int i = 0; i < p->mesh->n_nodes; ++i) {
        if (!p->probe[i]) continue;
        double fi[3];
        hs_body_reaction(b, i, fi);
        for (int c = 0; c < 3; ++c) f[c] += fi[c];
    }
}

static void set_prescribed(hs_body* b, const acc_problem* p, double s) {
    for (int i = 0; i < p->mesh->n_nodes; ++i)
        if (p->fixed[i]) {
            double u[3] = {s * p->up[3 * i], s * p->up[3 * i + 1], s * p->up[3 * i + 2]};
            hs_body_set_prescribed(b, i, u);
        }
}

static int run_body(const acc_problem* p, const acc_cfg* cfg, double* u_out, double force[3],
                    acc_result* r, double settle_max_s) {
    hs_err err = {0};
    hs_body_def d = hs_body_default_def();
    d.fem.model = cfg->fem_model;
    d.fem.material = p->mat;
    d.fem.rotation = cfg->rotation;
    d.fem.polar_tol = cfg->polar_tol;
    d.fem.locking_free = cfg->locking_free;
    memcpy(d.gravity, p->gravity, sizeof d.gravity);
    d.static_tol = 1e-8;
    d.static_max_iter = 200;
    if (cfg->dynamic) {
        d.dt = cfg->dt;
        d.fem.material.rayleigh_mass = p->alpha;
        if (cfg->pcg_iters) {
            d.solver = HS_SOLVER_PCG;
            d.precond = cfg->jacobi ? HS_PRECOND_JACOBI : HS_PRECOND_FACTOR;
            d.pcg_max_iter = cfg->pcg_iters;
            d.pcg_tol = cfg->jacobi ? 1e-8 : 1e-12;
        }
    }
    hs_body* b = NULL;
    if (hs_body_create(p->mesh, &d, p->fixed, &b, &err) < 0) {
        fprintf(stderr, "hapsim-bench accuracy: %s\n", err.msg);
        return 1;
    }
    int n = p->mesh->n_nodes, iters = 0;
    hs_step_stats st;
    hs_status s = HS_OK;
    double total_ms = 0;
    if (!cfg->dynamic) {
        double t0 = cpu_ms();
        for (int k = 1; k <= p->ramp && s >= 0; ++k) {
            set_prescribed(b, p, (double)k / p->ramp);
            s = hs_body_solve_static(b, &st);
            iters += st.iterations;
        }
        total_ms = cpu_ms() - t0;
        r->step_ms = total_ms;
        r->iterations = iters;
    } else {
        // Steady state: max nodal speed below 1e-4 diagonals per second (the remaining offset
        // is then ~1e-4 / alpha of the diagonal), or settle_max_s of simulated time.
        int max_steps = (int)ceil(settle_max_s / cfg->dt), k;
        double vtol = 1e-4 * p->diag, ramp_s = 0.1;
        double* ms = malloc((size_t)max_steps * sizeof(double));
        for (k = 0; k < max_steps; ++k) {
            if (p->probe) set_prescribed(b, p, fmin(1.0, (k + 1) * cfg->dt / ramp_s));
            double t0 = cpu_ms();
            s = hs_body_step(b, &st);
            ms[k] = cpu_ms() - t0;
            if (s < 0) break;
            const double* v = hs_body_velocity(b);
            double vmax = 0;
            for (int i = 0; i < 3 * n; ++i) vmax = fmax(vmax, fabs(v[i]));
            if (vmax < vtol && (k + 1) * cfg->dt > ramp_s) {
                ++k;
                break;
            }
        }
        r->step_ms = k > 0 ? hs_bench_percentile(ms, (size_t)k, 50) : NAN;
        r->iterations = k;
        free(ms);
    }
    if (s < 0) {
        fprintf(stderr, "hapsim-bench accuracy: %s %s: %s\n", cfg->model, cfg->option,
                hs_status_str(s));
        hs_body_destroy(&b);
        return 1;
    }
    memcpy(u_out, hs_body_displacement(b), 3 * (size_t)n * sizeof(double));
    body_force(b, p, force);
    hs_body_destroy(&b);
    return 0;
}

static const acc_cfg static_cfgs[] = {
    {"linear", "static", HS_MODEL_LINEAR, HS_ROTATION_POLAR, 1e-6, 0, 0, 0, 0, 0},
    {"linear-lf", "static", HS_MODEL_LINEAR, HS_ROTATION_POLAR, 1e-6, 1, 0, 0, 0, 0},
    {"linear-sns", "static", HS_MODEL_LINEAR, HS_ROTATION_POLAR, 1e-6, 2, 0, 0, 0, 0},
    {"corotated", "static;polar1e-2", HS_MODEL_COROTATED, HS_ROTATION_POLAR, 1e-2, 0, 0, 0, 0, 0},
    {"corotated", "static;polar1e-4", HS_MODEL_COROTATED, HS_ROTATION_POLAR, 1e-4, 0, 0, 0, 0, 0},
    {"corotated", "static;polar1e-6", HS_MODEL_COROTATED, HS_ROTATION_POLAR, 1e-6, 0, 0, 0, 0, 0},
    {"corotated", "static;svd", HS_MODEL_COROTATED, HS_ROTATION_SVD, 1e-6, 0, 0, 0, 0, 0},
    {"corotated-lf", "static;polar1e-6", HS_MODEL_COROTATED, HS_ROTATION_POLAR, 1e-6, 1, 0, 0, 0,
     0},
    {"corotated-sns", "static;polar1e-6", HS_MODEL_COROTATED, HS_ROTATION_POLAR, 1e-6, 2, 0, 0, 0,
     0},
    {"stvk", "static", HS_MODEL_STVK, HS_ROTATION_POLAR, 1e-6, 0, 0, 0, 0, 0},
    {"stvk-lf", "static", HS_MODEL_STVK, HS_ROTATION_POLAR, 1e-6, 1, 0, 0, 0, 0},
    {"mooney", "static", (hs_model)MR, HS_ROTATION_POLAR, 0, 0, 0, 0, 0, 0},
};

static const acc_cfg dyn_cfgs[] = {
    {"corotated", "direct;dt1ms", HS_MODEL_COROTATED, HS_ROTATION_POLAR, 1e-6, 0, 1, 0, 0.001, 0},
    {"corotated", "direct;dt10ms", HS_MODEL_COROTATED, HS_ROTATION_POLAR, 1e-6, 0, 1, 0, 0.010, 0},
    {"corotated", "direct;dt33ms", HS_MODEL_COROTATED, HS_ROTATION_POLAR, 1e-6, 0, 1, 0, 0.033, 0},
    {"corotated", "pcg1;dt10ms", HS_MODEL_COROTATED, HS_ROTATION_POLAR, 1e-6, 0, 1, 1, 0.010, 0},
    {"corotated", "pcg2;dt10ms", HS_MODEL_COROTATED, HS_ROTATION_POLAR, 1e-6, 0, 1, 2, 0.010, 0},
    {"corotated", "pcg5;dt10ms", HS_MODEL_COROTATED, HS_ROTATION_POLAR, 1e-6, 0, 1, 5, 0.010, 0},
    {"corotated", "pcg20;dt10ms", HS_MODEL_COROTATED, HS_ROTATION_POLAR, 1e-6, 0, 1, 20, 0.010, 0},
    {"corotated", "pcg2;dt33ms", HS_MODEL_COROTATED, HS_ROTATION_POLAR, 1e-6, 0, 1, 2, 0.033, 0},
    {"linear", "direct;dt10ms", HS_MODEL_LINEAR, HS_ROTATION_POLAR, 1e-6, 0, 1, 0, 0.010, 0},
    {"corotated-lf", "pcg5;dt10ms", HS_MODEL_COROTATED, HS_ROTATION_POLAR, 1e-6, 1, 1, 5, 0.010, 0},
    {"corotated-sns", "pcg5;dt10ms", HS_MODEL_COROTATED, HS_ROTATION_POLAR, 1e-6, 2, 1, 5, 0.010,
     0},
};

static void print_row(const char* scene, const acc_cfg* c, int tets, const acc_result* r,
                      const char* ref) {
    printf("%s,%s,%s,%d,", scene, c->model, c->option, tets);
    if (!r->ok) {
        printf("failed,,,,,,%s,\n", ref);
        fflush(stdout);
        return;
    }
    printf("%.3f,%d,%.4f,%.4f,%.5f,", r->step_ms, r->iterations, r->err_mean, r->err_max, r->vol);
    if (!isnan(r->force_err)) printf("%.3f", r->force_err);
    printf(",%s,%.4f\n", ref, r->err_l2);
    fflush(stdout);
}

// Which reference err_l2_pct is measured against: `ref` names it; uconv is that field on the
// problem's nodes (NULL: the row's own reference uref).
typedef struct acc_ref {
    const char* ref;
    const double* uconv;
} acc_ref;

// Run one configuration on p against uref/fref and print its row.
// Returns 1 when the configuration failed (its row says `failed`).
static int run_cfg(const char* scene, const acc_problem* p, const acc_cfg* c, const double* uref,
                   const double* fref, double settle_max_s, acc_ref ar) {
    int n = p->mesh->n_nodes;
    double* u = calloc(3 * (size_t)n, sizeof(double));
    double* w = calloc(3 * (size_t)n, sizeof(double));
    acc_result r = {0};
    r.force_err = NAN;
    double f[3] = {0};
    int bad = (int)c->fem_model == MR ? solve_mooney(p, 1e-8, -1, u, f, &r)
                                      : run_body(p, c, u, f, &r, settle_max_s);
    if (!bad) {
        r.ok = 1;
        errors(p, u, uref, &r.err_mean, &r.err_max);
        r.vol = mean_volume_ratio(p->mesh, u, w);
        if (p->probe && fref) {
            r.force_err = force_error(f, fref);
            double fn = sqrt(f[0] * f[0] + f[1] * f[1] + f[2] * f[2]),
                   rn = sqrt(fref[0] * fref[0] + fref[1] * fref[1] + fref[2] * fref[2]);
            fprintf(stderr, "accuracy: %s %s %s: force %.4g N, reference %.4g N\n", scene, c->model,
                    c->option, fn, rn);
        }
        r.err_l2 = ref_rel_l2_pct(n, u, ar.uconv ? ar.uconv : uref);
    }
    print_row(scene, c, p->mesh->n_tets, &r, ar.ref);
    free(u);
    free(w);
    return bad != 0;
}

// Progress line with the reference's tip motion (largest downward displacement).
static void print_tip(const char* scene, const hs_mesh* m, const double* u) {
    int k = 0;
    for (int i = 0; i < m->n_nodes; ++i)
        if (u[3 * i + 2] < u[3 * k + 2]) k = i;
    fprintf(stderr, "accuracy: %s, %d tets: Mooney-Rivlin tip moves (%.4f, %.4f, %.4f) m\n", scene,
            m->n_tets, u[3 * k], u[3 * k + 1], u[3 * k + 2]);
}

// Cantilever: reference = Mooney-Rivlin on a finer box (tolerance 1e-10), interpolated to the
// coarse nodes. Rows for every static model on each coarse mesh; dynamic rows on `dyn_mesh`.
typedef struct box_dims {
    int nx, ny, nz;
} box_dims;

static int cantilever(const char* scene, double heavy, box_dims ref, const box_dims* meshes,
                      int n_meshes, int dyn_mesh, int quick) {
    acc_problem fine;
    if (problem_load(&fine, SC_CANTILEVER, NULL, ref.nx, ref.ny, ref.nz, heavy)) return 1;
    double* uf = calloc(3 * (size_t)fine.mesh->n_nodes, sizeof(double));
    fprintf(stderr, "accuracy: %s reference, Mooney-Rivlin on %d tets\n", scene, fine.mesh->n_tets);
    if (solve_mooney(&fine, 1e-10, -1, uf, NULL, NULL)) {
        free(uf);
        problem_free(&fine);
        return 1;
    }
    print_tip(scene, fine.mesh, uf);
    int rc = 0;
    // Under the paper's own weight (heavy 1): CalculiX's converged solution (tests/accuracy,
    // C3D10 on the 45x9x9 box, Mooney-Rivlin) at the 45x9x9 corners, P1-interpolated below.
    char refname[64];
    snprintf(refname, sizeof refname, "mooney-%dx%dx%d", ref.nx, ref.ny, ref.nz);
    acc_problem conv = {0};
    double* uc = NULL;
    if (heavy == 1.0) {
        if (problem_load(&conv, SC_CANTILEVER, NULL, 45, 9, 9, 1)) return 1;
        uc = calloc(3 * (size_t)conv.mesh->n_nodes, sizeof(double));
        if (!uc || ref_read_field(HS_SOURCE_DIR "/tests/accuracy/refs/gravity_mr_conv_20k.txt",
                                  conv.mesh->n_nodes, uc)) {
            free(uc);
            problem_free(&conv);
            return 1;
        }
        snprintf(refname, sizeof refname, "ccx-c3d10-mr-45x9x9");
    }
    for (int k = 0; k < n_meshes; ++k) {
        acc_problem p;
        if (problem_load(&p, SC_CANTILEVER, NULL, meshes[k].nx, meshes[k].ny, meshes[k].nz,
                         heavy)) {
            rc = 1;
            continue;
        }
        double* uref = calloc(3 * (size_t)p.mesh->n_nodes, sizeof(double));
        rc |= map_fine_to_coarse(fine.mesh, uf, p.mesh, uref);
        double* ucc = NULL;
        if (uc) {
            ucc = calloc(3 * (size_t)p.mesh->n_nodes, sizeof(double));
            rc |= map_fine_to_coarse(conv.mesh, uc, p.mesh, ucc);
        }
        acc_ref ar = {refname, ucc};
        fprintf(stderr, "accuracy: %s, %d tets\n", scene, p.mesh->n_tets);
        for (size_t c = 0; c < sizeof static_cfgs / sizeof *static_cfgs; ++c) {
            if (quick && (static_cfgs[c].locking_free == HS_LOCKING_FREE_ANP ||
                          !strcmp(static_cfgs[c].option, "static;polar1e-4")))
                continue;
            rc |= run_cfg(scene, &p, &static_cfgs[c], uref, NULL, 0, ar);
        }
        if (k == dyn_mesh)
            for (size_t c = 0; c < sizeof dyn_cfgs / sizeof *dyn_cfgs; ++c) {
                if (quick && (dyn_cfgs[c].dt < 0.005 || dyn_cfgs[c].locking_free)) continue;
                rc |= run_cfg(scene, &p, &dyn_cfgs[c], uref, NULL, 3.0, ar);
            }
        free(uref);
        free(ucc);
        problem_free(&p);
    }
    free(uc);
    problem_free(&conv);
    free(uf);
    problem_free(&fine);
    return rc;
}

// The paper's comparison: every model against Mooney-Rivlin on the same mesh (scene name
// suffixed "@mr"), for the 500 / 1k / 5k / 10k element cantilevers.
static int cantilever_vs_mr(const char* scene, double heavy, const box_dims* meshes, int n) {
    static const acc_cfg cfgs[] = {
        {"linear", "static", HS_MODEL_LINEAR, HS_ROTATION_POLAR, 1e-6, 0, 0, 0, 0, 0},
        {"corotated", "static;polar1e-6", HS_MODEL_COROTATED, HS_ROTATION_POLAR, 1e-6, 0, 0, 0, 0,
         0},
        {"stvk", "static", HS_MODEL_STVK, HS_ROTATION_POLAR, 1e-6, 0, 0, 0, 0, 0},
        {"corotated-lf", "static;polar1e-6", HS_MODEL_COROTATED, HS_ROTATION_POLAR, 1e-6, 1, 0, 0,
         0, 0},
        {"stvk-lf", "static", HS_MODEL_STVK, HS_ROTATION_POLAR, 1e-6, 1, 0, 0, 0, 0},
        {"mooney", "static", (hs_model)MR, HS_ROTATION_POLAR, 0, 0, 0, 0, 0, 0},
        // The paper's cost comparison is per dynamic step.
        {"linear", "direct;dt10ms", HS_MODEL_LINEAR, HS_ROTATION_POLAR, 1e-6, 0, 1, 0, 0.010, 0},
        {"corotated", "direct;dt10ms", HS_MODEL_COROTATED, HS_ROTATION_POLAR, 1e-6, 0, 1, 0, 0.010,
         0},
        {"linear", "cg-jacobi;dt10ms", HS_MODEL_LINEAR, HS_ROTATION_POLAR, 1e-6, 0, 1, 2000, 0.010,
         1},
        {"corotated", "cg-jacobi;dt10ms", HS_MODEL_COROTATED, HS_ROTATION_POLAR, 1e-6, 0, 1, 2000,
         0.010, 1},
    };
    int rc = 0;
    for (int k = 0; k < n; ++k) {
        acc_problem p;
        if (problem_load(&p, SC_CANTILEVER, NULL, meshes[k].nx, meshes[k].ny, meshes[k].nz, heavy))
            return 1;
        fprintf(stderr, "accuracy: %s, %d tets\n", scene, p.mesh->n_tets);
        double* uref = calloc(3 * (size_t)p.mesh->n_nodes, sizeof(double));
        if (solve_mooney(&p, 1e-10, -1, uref, NULL, NULL) == 0) {
            print_tip(scene, p.mesh, uref);
            for (size_t c = 0; c < sizeof cfgs / sizeof *cfgs; ++c)
                rc |= run_cfg(scene, &p, &cfgs[c], uref, NULL, 3.0,
                              (acc_ref){"mooney-same-mesh", NULL});
        } else {
            rc = 1;
        }
        free(uref);
        problem_free(&p);
    }
    return rc;
}

// Organ scenes: reference = Mooney-Rivlin on the same mesh (the paper's physics reference);
// its reaction force is the force reference.
static int organ(const char* scene, scene_kind kind, const char* path, int quick) {
    acc_problem p;
    if (problem_load(&p, kind, path, 0, 0, 0, 1)) return 1;
    int n = p.mesh->n_nodes, rc = 0;
    double* uref = calloc(3 * (size_t)n, sizeof(double));
    double fref[3];
    fprintf(stderr, "accuracy: %s reference, Mooney-Rivlin on %d tets\n", scene, p.mesh->n_tets);
    if (solve_mooney(&p, 1e-10, -1, uref, fref, NULL)) {
        free(uref);
        problem_free(&p);
        return 1;
    }
    for (size_t c = 0; c < sizeof static_cfgs / sizeof *static_cfgs; ++c) {
        if ((int)static_cfgs[c].fem_model == MR) continue; // it is the reference
        if (quick && (static_cfgs[c].locking_free == HS_LOCKING_FREE_ANP ||
                      static_cfgs[c].polar_tol == 1e-4))
            continue;
        rc |=
            run_cfg(scene, &p, &static_cfgs[c], uref, fref, 0, (acc_ref){"mooney-same-mesh", NULL});
    }
    if (kind == SC_LIVER)
        for (size_t c = 0; c < sizeof dyn_cfgs / sizeof *dyn_cfgs; ++c) {
            if (quick && (dyn_cfgs[c].dt < 0.005 || dyn_cfgs[c].locking_free)) continue;
            rc |= run_cfg(scene, &p, &dyn_cfgs[c], uref, fref, 3.0,
                          (acc_ref){"mooney-same-mesh", NULL});
        }
    free(uref);
    problem_free(&p);
    return rc;
}

int hs_bench_accuracy(const hs_bench_args* a) {
    printf("scene,model,option,tets,step_ms,iterations,err_mean_pct,err_max_pct,volume_ratio,"
           "force_err_pct,ref,err_l2_pct\n");
    fflush(stdout);
    int rc = 0;
    char vessel[1024], liver[1024];
    hs_bench_mesh_path(a, "aneurysm_vessel.msh", vessel, sizeof vessel);
    snprintf(liver, sizeof liver, "%s/liver2.msh", HS_SCENES_DIR "/liver");
    if (a->quick) {
        box_dims m[] = {{10, 2, 2}};
        rc |= cantilever("cantilever10x", 10, (box_dims){20, 4, 4}, m, 1, 0, 1);
        box_dims m1[] = {{30, 5, 5}};
        rc |= cantilever("cantilever", 1, (box_dims){20, 4, 4}, m1, 1, -1, 1);
        rc |= organ("liver-press", SC_LIVER, liver, 1);
        return rc;
    }
    // Coarse meshes nested in the 40x8x8 reference except the paper-size ones.
    box_dims m[] = {{10, 2, 2}, {20, 4, 4}, {10, 3, 3}, {20, 3, 3}, {30, 5, 5}, {35, 7, 7}};
    box_dims m1[] = {{10, 2, 2}, {20, 4, 4}, {30, 5, 5}, {45, 9, 9}};
    rc |= cantilever("cantilever", 1, (box_dims){40, 8, 8}, m1, 4, 1, 0);
    rc |= cantilever("cantilever10x", 10, (box_dims){40, 8, 8}, m, 6, 1, 0);
    box_dims paper[] = {{10, 3, 3}, {20, 3, 3}, {30, 5, 5}, {35, 7, 7}};
    rc |= cantilever_vs_mr("cantilever10x@mr", 10, paper, 4);
    rc |= cantilever_vs_mr("cantilever100x@mr", 100, paper, 2);
    rc |= organ("liver-press", SC_LIVER, liver, 0);
    rc |= organ("vessel", SC_VESSEL, vessel, 0);
    return rc;
}
