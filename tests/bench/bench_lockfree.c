// SPDX-License-Identifier: GPL-2.0-or-later
// hapsim-bench lockfree: the locking-free options against CalculiX's converged solution (C3D10
// on the 45x9x9 box, tests/accuracy/refs), with their cost. One row per mesh, load, model,
// option and SNS share alpha:
//   err_*_pct: 100 ||u - u_ref|| / ||u_ref|| over all nodes, against the converged small-strain
//              (lin), St. Venant-Kirchhoff (nlgeom) and Mooney-Rivlin (mr) solutions
//   reaction_x_N / ref_*_N: the bar's push force, hapsim and converged (lin, nlgeom, mr)
//   newton: Newton iterations of the static solve
//   nnz: stored entries of the tangent; update_ms / assemble_ms: median thread CPU time of one
//   hs_fem_update / hs_fem_assemble at the solution; solve_ms: the static solve (tol 1e-10)
#define _POSIX_C_SOURCE 200809L
#include "accuracy_refs.h"
#include "bench.h"
#include "fem.h"
#include "sparse.h"

#define REFDIR HS_SOURCE_DIR "/tests/accuracy/refs/"

// Median CPU time of update and assemble at state u.
static int cost(const ref_problem* p, const hs_fem_def* def, const double* u, int* nnz,
                double* upd_ms, double* asm_ms) {
    hs_err err = {0};
    int n = p->mesh->n_nodes, nf = 0;
    int* dof = malloc(3 * (size_t)n * sizeof(int));
    double* x = malloc(3 * (size_t)n * sizeof(double));
    if (!dof || !x) return 1;
    for (int i = 0; i < n; ++i)
        for (int c = 0; c < 3; ++c) dof[3 * i + c] = p->fixed[i] ? -1 : nf++;
    for (int k = 0; k < 3 * n; ++k) x[k] = p->mesh->x0[k] + u[k];
    hs_fem* fem = NULL;
    hs_csc* a = NULL;
    int rc =
        hs_fem_create(p->mesh, def, dof, nf, &fem, &err) < 0 || hs_fem_create_matrix(fem, &a) < 0;
    if (!rc) {
        double tu[9], ta[9];
        hs_fem_update(fem, x, NULL);
        for (int r = 0; r < 9; ++r) {
            double t0 = hs_bench_thread_ms();
            hs_fem_update(fem, x, NULL);
            double t1 = hs_bench_thread_ms();
            hs_fem_assemble(fem, 1.0, 0.0, a);
            double t2 = hs_bench_thread_ms();
            tu[r] = t1 - t0, ta[r] = t2 - t1;
        }
        *upd_ms = hs_bench_percentile(tu, 9, 50);
        *asm_ms = hs_bench_percentile(ta, 9, 50);
        *nnz = a->nnz;
    }
    hs_csc_destroy(&a);
    hs_fem_destroy(&fem);
    free(dof);
    free(x);
    return rc;
}

int hs_bench_lockfree(const hs_bench_args* a) {
    static const char* const meshes[] = {"1k", "5k", "20k"};
    static const char* const mats[] = {"lin", "nlgeom", "mr"};
    const double alphas_full[] = {0.3, 0.4, 0.5, 0.6, 0.7, 0.8};
    const double alpha_default[] = {HS_SNS_ALPHA_DEFAULT};
    // The converged push force of the bar per material (CalculiX's reaction at x = 0, which
    // balances the push at x = L).
    double fbar[3];
    for (int k = 0; k < 3; ++k)
        fbar[k] = fabs(ref_summary_reaction_x(REFDIR, "bar", mats[k], "c3d10", "20k"));
    printf(
        "mesh,load,model,option,alpha,tets,nnz,update_ms,assemble_ms,solve_ms,newton,err_lin_pct,"
        "err_nlgeom_pct,err_mr_pct,reaction_x_N,ref_lin_N,ref_nlgeom_N,ref_mr_N\n");
    for (int mi = 0; mi < (a->quick ? 2 : 3); ++mi)
        for (int l = 0; l < 3; ++l) {
            ref_problem p;
            if (ref_problem_init(&p, meshes[mi], (ref_load)l)) return 1;
            int n = p.mesh->n_nodes;
            double* u = calloc(3 * (size_t)n, sizeof(double));
            double* r[3];
            int have[3];
            for (int k = 0; k < 3; ++k) {
                char path[512];
                snprintf(path, sizeof path, REFDIR "%s_%s_conv_%s.txt", ref_load_name[l], mats[k],
                         meshes[mi]);
                r[k] = calloc(3 * (size_t)n, sizeof(double));
                have[k] = r[k] && ref_read_field(path, n, r[k]) == 0;
            }
            for (int model = 0; model < 2; ++model)
                for (int lf = 0; lf < 3; ++lf) {
                    const double* al = lf == 2 ? (a->quick ? alpha_default : alphas_full) : NULL;
                    int nal = lf == 2 ? (a->quick ? 1 : 6) : 1;
                    for (int ai = 0; ai < nal; ++ai) {
                        hs_fem_def def = hs_fem_default_def();
                        def.model = model == 0 ? HS_MODEL_LINEAR : HS_MODEL_COROTATED;
                        def.material = (hs_material){REF_E, REF_NU, REF_RHO, 0, 0};
                        def.locking_free = lf;
                        if (al) def.locking_free_alpha = al[ai];
                        double rx = NAN, t0 = hs_bench_thread_ms();
                        if (ref_solve_body_def(&p, &def, u, &rx)) {
                            fprintf(stderr, "hapsim-bench lockfree: %s %s failed\n", meshes[mi],
                                    ref_load_name[l]);
                            continue;
                        }
                        double ts = hs_bench_thread_ms() - t0, tu = NAN, ta = NAN;
                        int nnz = 0;
                        cost(&p, &def, u, &nnz, &tu, &ta);
                        double e[3];
                        for (int k = 0; k < 3; ++k)
                            e[k] = have[k] ? ref_rel_l2_pct(n, u, r[k]) : NAN;
                        const int bar = l == REF_BAR;
                        printf("%s,%s,%s,%s,%.2f,%d,%d,%.3f,%.3f,%.1f,%d,%.3f,%.3f,%.3f,%.5g,%.5g,"
                               "%.5g,%.5g\n",
                               meshes[mi], ref_load_name[l], model ? "corotated" : "linear",
                               lf == 0   ? "none"
                               : lf == 1 ? "anp"
                                         : "sns",
                               al ? al[ai] : 0.0, p.mesh->n_tets, nnz, tu, ta, ts,
                               ref_last_stats.iterations, e[0], e[1], e[2], bar ? fabs(rx) : NAN,
                               bar ? fbar[0] : NAN, bar ? fbar[1] : NAN, bar ? fbar[2] : NAN);
                        fflush(stdout);
                    }
                }
            free(u);
            for (int k = 0; k < 3; ++k) free(r[k]);
            ref_problem_free(&p);
        }
    return 0;
}
