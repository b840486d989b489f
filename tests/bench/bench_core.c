// SPDX-License-Identifier: GPL-2.0-or-later
// hapsim-bench core: cost of one implicit step per model and mesh, with tip deflection and
// volume ratio so that speed and accuracy are read together.
#include "bench.h"
#include "body.h"
#include "mesh.h"

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

typedef struct core_case {
    const char* name;
    int nx, ny, nz; // structured cantilever 0.1 x 0.02 x 0.02 m when file == NULL
    const char* file;
} core_case;

typedef struct core_cfg {
    const char* label; // model label in the CSV
    hs_model model;
    int locking_free;
    hs_solver_kind solver;
    int pcg_iters;
    hs_precond precond;
    const char* solver_label;
} core_cfg;

static const core_case cases_full[] = {
    {"cantilever-1k", 15, 3, 3, NULL},
    {"cantilever-5k", 30, 5, 5, NULL},
    {"cantilever-10k", 35, 7, 7, NULL},
    {"cantilever-50k", 60, 12, 12, NULL},
    {"liver_coarse", 0, 0, 0, "liver_coarse.msh"},
    {"liver2", 0, 0, 0, "liver2.msh"},
    {"skin_patch", 0, 0, 0, "skin_patch_synthetic.msh"},
    {"tongue", 0, 0, 0, "tongue.msh"},
    {"vessel", 0, 0, 0, "aneurysm_vessel.msh"},
};
static const core_case cases_quick[] = {{"cantilever-10k", 35, 7, 7, NULL}};

static const core_cfg cfgs[] = {
    {"linear", HS_MODEL_LINEAR, 0, HS_SOLVER_DIRECT, 0, HS_PRECOND_NONE, "cholmod"},
    {"linear", HS_MODEL_LINEAR, 0, HS_SOLVER_PCG, 3, HS_PRECOND_WARPED, "pcg3-warped"},
    {"corotated", HS_MODEL_COROTATED, 0, HS_SOLVER_DIRECT, 0, HS_PRECOND_NONE, "cholmod"},
    {"corotated", HS_MODEL_COROTATED, 0, HS_SOLVER_PCG, 3, HS_PRECOND_WARPED, "pcg3-warped"},
    {"corotated", HS_MODEL_COROTATED, 0, HS_SOLVER_PCG, 3, HS_PRECOND_FACTOR, "pcg3-restfactor"},
    {"corotated", HS_MODEL_COROTATED, 0, HS_SOLVER_WARPED, 0, HS_PRECOND_NONE, "warped"},
    {"corotated-lf", HS_MODEL_COROTATED, 1, HS_SOLVER_PCG, 3, HS_PRECOND_WARPED, "pcg3-warped"},
    {"corotated-sns", HS_MODEL_COROTATED, 2, HS_SOLVER_PCG, 3, HS_PRECOND_WARPED, "pcg3-warped"},
    {"corotated-sns", HS_MODEL_COROTATED, 2, HS_SOLVER_WARPED, 0, HS_PRECOND_NONE, "warped"},
    {"stvk", HS_MODEL_STVK, 0, HS_SOLVER_DIRECT, 0, HS_PRECOND_NONE, "cholmod"},
};

// The case's mesh, its fixed nodes and a body with cfg; NULL (message printed) on failure.
static hs_body* make_body(const hs_bench_args* a, const core_case* c, const core_cfg* cfg,
                          hs_mesh** mesh_out, unsigned char** fixed_out) {
    hs_err err = {0};
    hs_mesh* mesh = NULL;
    hs_status s;
    *mesh_out = NULL;
    *fixed_out = NULL;
    if (c->file) {
        char path[1024];
        s = hs_mesh_load(hs_bench_mesh_path(a, c->file, path, sizeof path), &mesh, &err);
    } else {
        s = hs_mesh_create_box(0.1, 0.02, 0.02, c->nx, c->ny, c->nz, &mesh, &err);
    }
    if (s < 0) {
        fprintf(stderr, "hapsim-bench: %s: %s\n", c->name, err.msg);
        return NULL;
    }
    // Cantilevers hang from x = 0; organ meshes are held along their lowest 10 % in z.
    unsigned char* fixed = calloc((size_t)mesh->n_nodes, 1);
    if (c->file) {
        double tol = 0.1 * (mesh->bbox_max[2] - mesh->bbox_min[2]);
        hs_mesh_select_plane(mesh, 2, -1, tol, fixed);
    } else {
        hs_mesh_select_plane(mesh, 0, -1, 1e-9, fixed);
    }
    hs_body_def def = hs_body_default_def();
    def.fem.model = cfg->model;
    def.fem.locking_free = cfg->locking_free;
    def.fem.material.youngs_pa = 1.5e6; // the paper's cantilever
    def.fem.material.poisson = 0.45;
    def.fem.material.density_kg_m3 = 960 * 10.0; // 10x heavier: large rotations
    def.gravity[2] = -9.81;
    def.dt = 0.01;
    def.solver = cfg->solver;
    def.precond = cfg->precond;
    if (cfg->pcg_iters) def.pcg_max_iter = cfg->pcg_iters;
    def.pcg_tol = 1e-10;
    // Organs stand on their lowest 10 % under gravity: 50 kPa keeps the strain near 4 %.
    if (c->file) def.fem.material.youngs_pa = 5e4, def.fem.material.density_kg_m3 = 1060;
    hs_body* body = NULL;
    if (hs_body_create(mesh, &def, fixed, &body, &err) < 0) {
        fprintf(stderr, "hapsim-bench: %s: %s\n", c->name, err.msg);
        free(fixed);
        hs_mesh_destroy(&mesh);
        return NULL;
    }
    *mesh_out = mesh;
    *fixed_out = fixed;
    return body;
}

static int run_case(const hs_bench_args* a, const core_case* c, const core_cfg* cfg,
                    double* step_ms_out, int print) {
    hs_mesh* mesh = NULL;
    unsigned char* fixed = NULL;
    hs_body* body = make_body(a, c, cfg, &mesh, &fixed);
    if (!body) return 1;
    hs_status s = HS_OK;
    int steps = a->quick ? 20 : 40, warm = 3, iters = 0;
    double* ms = calloc((size_t)steps, sizeof(double));
    hs_step_stats st = {0};
    for (int k = 0; k < warm + steps; ++k) {
        // Thread CPU time: robust on a shared machine, and the step is single-threaded.
        double t0 = hs_bench_thread_ms();
        s = hs_body_step(body, &st);
        double t1 = hs_bench_thread_ms();
        if (s < 0) {
            fprintf(stderr, "%s (%s, %s): step %d failed: %s\n", c->name, cfg->label,
                    cfg->solver_label, k, hs_status_str(s));
            break;
        }
        if (k >= warm) ms[k - warm] = t1 - t0, iters += st.linear_iterations;
    }
    double tip = 0;
    const double* u = hs_body_displacement(body);
    for (int i = 0; i < mesh->n_nodes; ++i)
        tip = fmax(tip, sqrt(u[3 * i] * u[3 * i] + u[3 * i + 1] * u[3 * i + 1] +
                             u[3 * i + 2] * u[3 * i + 2]));
    double mem_mb = (double)hs_byte_count() / (1024.0 * 1024.0);
    double step_ms = s < 0 ? NAN : hs_bench_percentile(ms, (size_t)steps, 50);
    if (print)
        printf("%s,%d,%d,%s,%.3f,%.1f,%.6e,%.5f,%.1f,%s\n", cfg->label, mesh->n_tets,
               hs_body_free_dofs(body), cfg->solver_label, step_ms, (double)iters / steps, tip,
               st.fem.volume_ratio_mean, mem_mb, c->name);
    fflush(stdout);
    *step_ms_out = step_ms;
    free(ms);
    free(fixed);
    hs_body_destroy(&body);
    hs_mesh_destroy(&mesh);
    return s < 0;
}

static int cmp_double(const void* x, const void* y) {
    double p = *(const double*)x, q = *(const double*)y;
    return (p > q) - (p < q);
}

// Cost of co-rotation from runs as above (one body at a time, so each keeps the caches to
// itself) but alternated, linear then warped, `pairs` times: the median ratio of the pairs is
// less at the mercy of a load change between two runs than the single pair above.
static int alternating_ratio(const hs_bench_args* a, const core_case* c, const core_cfg* lin,
                             const core_cfg* cor, int pairs) {
    double tl[8], tw[8], r[8];
    if (pairs > 8) pairs = 8;
    for (int p = 0; p < pairs; ++p) {
        if (run_case(a, c, lin, &tl[p], 0) || run_case(a, c, cor, &tw[p], 0)) {
            fprintf(stderr, "%s: alternating runs: a run failed, no ratio\n", c->name);
            return 1;
        }
        r[p] = tw[p] / tl[p];
    }
    qsort(tl, (size_t)pairs, sizeof(double), cmp_double);
    qsort(tw, (size_t)pairs, sizeof(double), cmp_double);
    qsort(r, (size_t)pairs, sizeof(double), cmp_double);
    fprintf(stderr,
            "%s: %d alternating runs: linear (%s) %.3f-%.3f ms, corotated (%s) %.3f-%.3f ms; "
            "ratio per pair: median %.2fx (%.2f-%.2f)\n",
            c->name, pairs, lin->solver_label, tl[0], tl[pairs - 1], cor->solver_label, tw[0],
            tw[pairs - 1], r[pairs / 2], r[0], r[pairs - 1]);
    return 0;
}

// Cost of co-rotation with the load shared: the linear body (constant factor) and the warped
// co-rotated body are stepped alternately, step k of one right after step k of the other, so
// both see the same machine; the ratio of each pair, then its median. Caveat: the two bodies'
// factors (13 MB each at 10k tets) evict each other, so the back-solve, the same on both sides,
// is slower than in single-body runs and the ratio reads lower than theirs.
static int paired_ratio(const hs_bench_args* a, const core_case* c, const core_cfg* lin,
                        const core_cfg* cor) {
    hs_mesh *m0 = NULL, *m1 = NULL;
    unsigned char *f0 = NULL, *f1 = NULL;
    hs_body* b0 = make_body(a, c, lin, &m0, &f0);
    hs_body* b1 = b0 ? make_body(a, c, cor, &m1, &f1) : NULL;
    int steps = a->quick ? 20 : 40, warm = 3, n = 0;
    double* t = calloc(3 * (size_t)steps, sizeof(double)); // linear, warped, ratio
    for (int k = 0; b1 && t && k < warm + steps; ++k) {
        hs_step_stats st;
        double t0 = hs_bench_thread_ms();
        hs_status s0 = hs_body_step(b0, &st);
        double t1 = hs_bench_thread_ms();
        hs_status s1 = hs_body_step(b1, &st);
        double t2 = hs_bench_thread_ms();
        if (s0 < 0 || s1 < 0) break;
        if (k < warm) continue;
        t[n] = t1 - t0;
        t[steps + n] = t2 - t1;
        t[2 * steps + n] = (t2 - t1) / (t1 - t0);
        ++n;
    }
    if (n == steps) {
        for (int j = 0; j < 3; ++j) qsort(t + j * steps, (size_t)steps, sizeof(double), cmp_double);
        fprintf(stderr,
                "%s: stepped alternately: linear (%s) %.3f ms, corotated (%s) %.3f ms (medians); "
                "ratio per pair: median %.2fx (quartiles %.2f-%.2f)\n",
                c->name, lin->solver_label, t[steps / 2], cor->solver_label, t[steps + steps / 2],
                t[2 * steps + steps / 2], t[2 * steps + steps / 4], t[2 * steps + 3 * steps / 4]);
    } else {
        fprintf(stderr, "%s: stepped alternately: %s after %d of %d steps, no ratio\n", c->name,
                b1 && t ? "a step failed" : "set-up failed", n, steps);
    }
    int rc = n != steps;
    free(t);
    hs_body_destroy(&b1);
    hs_body_destroy(&b0);
    free(f1);
    free(f0);
    hs_mesh_destroy(&m1);
    hs_mesh_destroy(&m0);
    return rc;
}

int hs_bench_core(const hs_bench_args* a) {
    const core_case* cases = a->quick ? cases_quick : cases_full;
    size_t nc = a->quick ? sizeof cases_quick / sizeof *cases_quick
                         : sizeof cases_full / sizeof *cases_full;
    printf("model,tets,dofs,solver,step_ms,iterations,tip_m,volume_ratio,mem_mb,mesh\n");
    int rc = 0;
    enum { NCFG = sizeof cfgs / sizeof *cfgs };
    for (size_t i = 0; i < nc; ++i) {
        double t[NCFG];
        for (size_t j = 0; j < NCFG; ++j) {
            t[j] = NAN;
            if (a->quick && cfgs[j].model == HS_MODEL_STVK) continue;
            rc |= run_case(a, &cases[i], &cfgs[j], &t[j], 1);
        }
        // The cost of co-rotation, measured in this run (rows 0, 1, 3, 5 of cfgs): against the
        // linear step with the same PCG, and against linear with its constant factor (one
        // back-solve per step, as the warped solver).
        fprintf(stderr,
                "%s: corotated/linear step time: pcg3-warped %.2fx the same pcg3-warped solver, "
                "%.2fx linear's constant factor; warped %.2fx linear's constant factor\n",
                cases[i].name, t[3] / t[1], t[3] / t[0], t[5] / t[0]);
        rc |= alternating_ratio(a, &cases[i], &cfgs[0], &cfgs[5], 5);
        rc |= paired_ratio(a, &cases[i], &cfgs[0], &cfgs[5]);
    }
    return rc;
}
