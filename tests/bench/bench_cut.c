// SPDX-License-Identifier: GPL-2.0-or-later
// hapsim-bench cut: cost of one progressive cut step (crossing test, vertex moves, guard, piece
// detection, element shares and the update of K's factor: the partial refactor with the default
// threads in the CSV; on stderr its one-thread twin, the low-rank CHOLMOD update, AUTO and the
// update window) against a numeric refactorisation and, for small meshes, a dense inversion of K
// (the paper's method).
#define _GNU_SOURCE // nanosleep
#include "bench.h"

#include "hapsim/cut.h"
#include "rt/rt_thread.h"

#include <math.h>
#include <pthread.h>
#include <stdatomic.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#ifdef HS_BENCH_HAVE_LAPACK
// LAPACK (OpenBLAS): Cholesky factor and inverse of a dense SPD matrix.
void dpotrf_(const char* uplo, const int* n, double* a, const int* lda, int* info);
void dpotri_(const char* uplo, const int* n, double* a, const int* lda, int* info);
#endif

#define HS_BENCH_DENSE_MAX 4000 // dense inversion only below this many dofs

typedef struct cut_case {
    const char* name;
    const char* file; // shared mesh, or NULL for a box
    double lx, ly, lz;
    int nx, ny, nz;
    int quick;
    int rt;             // also run PARTIAL beside a 1 kHz loop, one and two factor threads
    int vertices, tets; // filled in when loaded
} cut_case;

/// The case's mesh: its shared file, or its box. Negative status (e.msg) on failure.
static hs_status load_mesh(const cut_case* cc, const hs_bench_args* args, hs_mesh** m, hs_err* e) {
    if (!cc->file) return hs_mesh_create_box(cc->lx, cc->ly, cc->lz, cc->nx, cc->ny, cc->nz, m, e);
    char path[1024];
    return hs_mesh_load(hs_bench_mesh_path(args, cc->file, path, sizeof path), m, e);
}

/// Dense inversion of K (dpotrf + dpotri), ms; negative when skipped or failed.
static double dense_inverse_ms(hs_cut* c) {
#ifndef HS_BENCH_HAVE_LAPACK
    (void)c;
    return -1;
#else
    int nf = hs_cut_free_dofs(c);
    if (nf > HS_BENCH_DENSE_MAX) return -1;
    hs_csc* a = NULL;
    if (hs_cut_create_matrix(c, &a) != HS_OK) return -1;
    hs_cut_assemble(c, a);
    double* d = calloc((size_t)nf * (size_t)nf, sizeof(double));
    if (!d) {
        hs_csc_destroy(&a);
        return -1;
    }
    for (int j = 0; j < nf; j++)
        for (int p = a->colp[j]; p < a->colp[j + 1]; p++)
            d[(size_t)j * nf + (size_t)a->rowi[p]] = a->val[p];
    int info = 0;
    int64_t t0 = hs_now_ns();
    dpotrf_("L", &nf, d, &nf, &info);
    if (info == 0) dpotri_("L", &nf, d, &nf, &info);
    double ms = (double)(hs_now_ns() - t0) * 1e-6;
    free(d);
    hs_csc_destroy(&a);
    return info == 0 ? ms : -1;
#endif
}

/// Median of a few numeric refactorisations of a fresh (supernodal) factor of K, ms.
static double refactor_ms(hs_cut* c) {
    hs_csc* a = NULL;
    hs_cholesky* f = NULL;
    hs_err e;
    if (hs_cut_create_matrix(c, &a) != HS_OK) return -1;
    hs_cut_assemble(c, a);
    double t[5];
    int k = 0;
    if (hs_cholesky_create(a, &f, &e) == HS_OK)
        for (; k < 5; k++) {
            int64_t t0 = hs_now_ns();
            if (hs_cholesky_refactor(f, a) != HS_OK) break;
            t[k] = (double)(hs_now_ns() - t0) * 1e-6;
        }
    hs_cholesky_destroy(&f);
    hs_csc_destroy(&a);
    return k > 0 ? hs_bench_percentile(t, (size_t)k, 50) : -1;
}

typedef struct pass_stats {
    double p50, p99, max, removed_per_step, geometry_ms, factor_ms, changes;
    double rank, union_dofs; // per updated step: columns sent, free dofs aggregated
    int updated, split;      // steps updated; of them not aggregated as one signed change
    int rewindows;           // steps that rebuilt the factor around a new window (or swapped one)
    int builds;              // background builds
    double build_ms;         // their mean time
    int steps, refactors;
    double dense_ms, refactor_ms;
    double share; // PARTIAL: mean share of a full factorisation's flops recomputed
    int reps;     // repetitions of the pass (fresh meshes)
    int off;      // window_accept_ratio's probe turned windows off
    double probe_default, probe_window; // its shares
} pass_stats;

/// A pass: two parallel partial cuts (80 % of the width, so no piece comes free) at 40 % and
/// 60 % of the length, each the wound forming step by step under the blade (about 0.6 element
/// of travel per step), with the given factor policy. window: 0 none; 1 rebuilt in the sweep when
/// left; 2 rebuilt by the cut's own window thread (window_thread: begin and finish count in the
/// sweep they run in, the build runs while the sweeps go on). paced: one sweep per 10 ms, as in a
/// 100 Hz deformation loop (the server runs up to 60 Hz), after 30 steps of the blade travelling
/// towards the plate; else sweeps back to back. threads: hs_cut_def.factor_threads. twin (no
/// window): a second cut with twin->threads factor threads takes every sweep too, the two in
/// alternating order, its times into twin->ps.
typedef struct twin_pass {
    int threads;
    pass_stats ps;
} twin_pass;

enum { MAX_STEPS = 512 };

/// A pass's samples and sums over its repetitions.
typedef struct pass_acc {
    double ms[MAX_STEPS], ms2[MAX_STEPS];
    double factor2, build_sum;
    long removed, chg;
    int build_n;
} pass_acc;

/// One repetition of a pass (a fresh mesh and cut), its samples appended to acc, sums to ps.
/// Returns 0 on success.
static int run_once(const cut_case* cc, const hs_bench_args* args, hs_cut_factor_policy policy,
                    int window, int paced, int threads, int measure_reference, twin_pass* twin,
                    pass_stats* ps, pass_acc* acc) {
    hs_mesh* m = NULL;
    hs_err e;
    hs_status st = load_mesh(cc, args, &m, &e);
    if (st < 0) {
        fprintf(stderr, "bench cut: %s: %s\n", cc->name, e.msg);
        return 1;
    }
    const int n = m->n_nodes;
    double lo[3], ext[3];
    for (int d = 0; d < 3; d++) {
        lo[d] = m->bbox_min[d];
        ext[d] = m->bbox_max[d] - m->bbox_min[d];
    }
    // Hold both x ends; the blade lies along the thinnest axis and sweeps along the other one.
    unsigned char* fixed = calloc((size_t)n, 1);
    unsigned char* far = calloc((size_t)n, 1);
    hs_mesh_select_plane(m, 0, -1, cc->file ? 0.05 * ext[0] : 1e-9, fixed);
    hs_mesh_select_plane(m, 0, +1, cc->file ? 0.05 * ext[0] : 1e-9, far);
    for (int i = 0; i < n; i++) fixed[i] |= far[i];
    free(far);
    int thin = ext[1] < ext[2] ? 1 : 2, sweep_axis = thin == 1 ? 2 : 1;
    hs_cut_def def = hs_cut_default_def();
    def.validate = 0;
    def.factor_policy = policy;
    def.factor_threads = threads;
    if (window && policy == HS_CUT_FACTOR_PARTIAL) {
        hs_cut_def_auto_window(&def, m); // kept only where it pays (window_accept_ratio)
        def.window_background = def.window_thread = window == 2;
    } else if (window) {
        // The low-rank policies: radius 2 h (the auto window's 3 h covers PARTIAL's wider
        // changes), 14 h ahead (a window lasts about 20 steps on plate5043), due halfway.
        hs_cut_def_auto_window(&def, m);
        def.window_radius_m *= 2.0 / 3.0;
        def.window_due_fraction = 0.5;
        def.window_accept_ratio = 0;
        def.window_background = def.window_thread = window == 2;
    }
    hs_cut *c = NULL, *c2 = NULL;
    st = hs_cut_create(m, fixed, &def, &c, &e);
    hs_mesh* m2 = NULL;
    if (st == HS_OK && twin) {
        hs_cut_def d2 = def;
        d2.factor_threads = twin->threads;
        st = load_mesh(cc, args, &m2, &e);
        if (st >= HS_OK) st = hs_cut_create(m2, fixed, &d2, &c2, &e);
    }
    if (st != HS_OK) {
        fprintf(stderr, "bench cut: %s: %s\n", cc->name, e.msg);
        free(fixed);
        hs_mesh_destroy(&m);
        return 1;
    }
    if (measure_reference) {
        ps->dense_ms = dense_inverse_ms(c);
        ps->refactor_ms = refactor_ms(c);
    }
    int n_steps = cc->file ? 30 : (sweep_axis == 1 ? cc->ny : cc->nz) * 2;
    double travel = 0.8 * ext[sweep_axis] / n_steps;
    int failures = 0;
    int64_t next = hs_now_ns();
    for (int cut = 0; cut < 2 && !failures; cut++) {
        double xc = lo[0] + (0.4 + 0.2 * cut) * ext[0] + 1e-4 * ext[0];
        // Paced: the blade first travels 30 steps towards the plate (placing the scalpel).
        for (int s = paced ? -30 : 0; s < n_steps && ps->steps < MAX_STEPS; s++) {
            if (paced) { // the rest of the deformation loop's period
                next += 10000000;
                int64_t wait = next - hs_now_ns();
                if (wait > 0) {
                    struct timespec ts = {wait / 1000000000, wait % 1000000000};
                    nanosleep(&ts, NULL);
                }
            }
            double a0 = lo[sweep_axis] - 0.05 * ext[sweep_axis] + travel * s, a1 = a0 + travel;
            double p0[3], q0[3], p1[3], q1[3];
            p0[0] = q0[0] = p1[0] = q1[0] = xc;
            p0[thin] = p1[thin] = lo[thin] - 0.1 * ext[thin];
            q0[thin] = q1[thin] = lo[thin] + 1.1 * ext[thin];
            p0[sweep_axis] = q0[sweep_axis] = a0;
            p1[sweep_axis] = q1[sweep_axis] = a1;
            hs_cut_result r, r2;
            memset(&r2, 0, sizeof r2);
            // With a twin, the first cut sweeps first on even steps, second on odd ones.
            for (int k = 0; k < (c2 ? 2 : 1); k++) {
                int second = c2 && (k ^ (s & 1));
                if (hs_cut_sweep(second ? c2 : c, p0, q0, p1, q1, NULL, second ? &r2 : &r, &e) !=
                    HS_OK) {
                    fprintf(stderr, "bench cut: %s: %s\n", cc->name, e.msg);
                    failures++;
                }
            }
            if (failures) break;
            // A sweep that cut nothing counts only if a window begin or finish ran in it.
            if (r.changed_elements == 0 && !r.rewindowed && !r.window_started) continue;
            if (c2) {
                acc->ms2[ps->steps] = r2.total_ms;
                acc->factor2 += r2.factor_ms;
            }
            acc->ms[ps->steps++] = r.total_ms;
            acc->removed += r.removed;
            acc->chg += r.changed_elements;
            ps->geometry_ms += r.geometry_ms;
            ps->factor_ms += r.factor_ms;
            ps->refactors += r.refactored;
            ps->rewindows += r.rewindowed;
            if (policy == HS_CUT_FACTOR_PARTIAL) {
                ps->share += hs_cholesky_partial_share(hs_cut_factor(c));
            } else if (!r.refactored) {
                hs_cholesky_update_info ui;
                hs_cholesky_last_update(hs_cut_factor(c), &ui);
                ps->rank += ui.rank;
                ps->union_dofs += ui.union_dofs;
                ps->updated++;
                ps->split += ui.method != HS_UPDATE_AGGREGATED;
            }
        }
    }
    if (window == 2) {
        hs_cut_window_stats ws;
        hs_cut_window_stats_get(c, &ws);
        ps->builds += ws.builds;
        acc->build_sum += ws.build_ms * (ws.swapped + ws.failed);
        acc->build_n += ws.swapped + ws.failed;
        ps->off = ws.off;
        ps->probe_default = ws.probe_share_default;
        ps->probe_window = ws.probe_share_window;
        failures += ws.failed;
    }
    free(fixed);
    hs_cut_destroy(&c);
    hs_cut_destroy(&c2);
    hs_mesh_destroy(&m);
    hs_mesh_destroy(&m2);
    return failures ? 1 : 0;
}

/// A pass repeated on fresh meshes: reps times, or (reps 0) until it has at least 100 sweep
/// times (at most 8 repetitions), so that its p99 is not just its slowest sweep.
static int run_pass(const cut_case* cc, const hs_bench_args* args, hs_cut_factor_policy policy,
                    int window, int paced, int threads, int measure_reference, twin_pass* twin,
                    int reps, pass_stats* ps) {
    memset(ps, 0, sizeof *ps);
    ps->dense_ms = ps->refactor_ms = -1;
    if (twin) memset(&twin->ps, 0, sizeof twin->ps);
    pass_acc* acc = calloc(1, sizeof *acc);
    if (!acc) return 1;
    int rc = 0;
    while (!rc && (reps > 0 ? ps->reps < reps : ps->reps < 8 && ps->steps < 100)) {
        int before = ps->steps;
        rc = run_once(cc, args, policy, window, paced, threads, measure_reference && ps->reps == 0,
                      twin, ps, acc);
        ps->reps++;
        // Stop when a pass adds nothing or another like it would not fit.
        if (ps->steps == before || ps->steps + (ps->steps - before) > MAX_STEPS) break;
    }
    if (ps->steps) {
        ps->removed_per_step = (double)acc->removed / ps->steps;
        ps->changes = (double)acc->chg / ps->steps;
        if (ps->updated) {
            ps->rank /= ps->updated;
            ps->union_dofs /= ps->updated;
        }
        ps->geometry_ms /= ps->steps;
        ps->share /= ps->steps;
        ps->factor_ms /= ps->steps;
        ps->p50 = hs_bench_percentile(acc->ms, (size_t)ps->steps, 50);
        if (twin) {
            twin->ps.steps = ps->steps;
            twin->ps.factor_ms = acc->factor2 / ps->steps;
            twin->ps.p50 = hs_bench_percentile(acc->ms2, (size_t)ps->steps, 50);
            twin->ps.p99 = hs_bench_percentile(acc->ms2, (size_t)ps->steps, 99);
            twin->ps.max = hs_bench_percentile(acc->ms2, (size_t)ps->steps, 100);
        }
        ps->p99 = hs_bench_percentile(acc->ms, (size_t)ps->steps, 99);
        ps->max = hs_bench_percentile(acc->ms, (size_t)ps->steps, 100);
    }
    if (acc->build_n) ps->build_ms = acc->build_sum / acc->build_n;
    free(acc);
    return rc;
}

static int run_case(const cut_case* cc, const hs_bench_args* args) {
    pass_stats up, au, wu, wa, wb, pa, pw, pp, pn;
    twin_pass one = {.threads = 1};
    int rc = run_pass(cc, args, HS_CUT_FACTOR_UPDATE, 0, 0, 0, 1, NULL, 1, &up);
    rc |= run_pass(cc, args, HS_CUT_FACTOR_PARTIAL, 0, 0, 0, 0, &one, 0, &pa);
    rc |= run_pass(cc, args, HS_CUT_FACTOR_AUTO, 0, 0, 0, 0, NULL, 1, &au);
    rc |= run_pass(cc, args, HS_CUT_FACTOR_UPDATE, 1, 0, 0, 0, NULL, 1, &wu);
    rc |= run_pass(cc, args, HS_CUT_FACTOR_AUTO, 1, 0, 0, 0, NULL, 1, &wa);
    rc |= run_pass(cc, args, HS_CUT_FACTOR_UPDATE, 2, 0, 0, 0, NULL, 1, &wb);
    // PARTIAL with the automatic window (hs_cut_def_auto_window): where its probe keeps
    // windows, partial refactors on one thread and the builds on the other core, else plain
    // PARTIAL on the default threads; paced, against the plain PARTIAL pass paced the same way.
    rc |= run_pass(cc, args, HS_CUT_FACTOR_PARTIAL, 2, 0, 0, 0, NULL, 1, &pw);
    rc |= run_pass(cc, args, HS_CUT_FACTOR_PARTIAL, 2, 1, 0, 0, NULL, 0, &pp);
    rc |= run_pass(cc, args, HS_CUT_FACTOR_PARTIAL, 0, 1, 0, 0, NULL, 0, &pn);
    const pass_stats* p1 = &one.ps;
    hs_mesh* m = NULL;
    char dense_s[32];
    if (up.dense_ms >= 0)
        snprintf(dense_s, sizeof dense_s, "%.2f", up.dense_ms);
    else
        snprintf(dense_s, sizeof dense_s, "NA");
    (void)m;
    // update_ms: the PARTIAL policy, the fastest exact path; the low-rank one is on stderr.
    printf("%s,%d,%d,%.1f,%.3f,%.3f,%.2f,%s\n", cc->name, cc->vertices, cc->tets,
           pa.removed_per_step, pa.p50, pa.p99, up.refactor_ms, dense_s);
    fflush(stdout);
    fprintf(stderr,
            "cut: %s: %d steps, %.1f element changes/step; low-rank update (UPDATE): step p50 "
            "%.3f ms p99 %.3f ms, geometry %.3f ms + factor %.3f ms, rank %.1f for %.1f free dofs "
            "touched (%d of %d steps split); AUTO policy: step p50 %.3f ms p99 %.3f ms (%d of %d "
            "steps refactored)\n",
            cc->name, up.steps, up.changes, up.p50, up.p99, up.geometry_ms, up.factor_ms, up.rank,
            up.union_dofs, up.split, up.updated, au.p50, au.p99, au.refactors, au.steps);
    fprintf(stderr,
            "cut: %s: PARTIAL policy (default factor threads): step p50 %.3f ms p99 %.3f ms max "
            "%.3f ms (geometry %.3f ms, "
            "factor %.3f ms, %.2f of a factorisation's flops, %d of %d steps refactored; %d "
            "passes on fresh meshes)\n",
            cc->name, pa.p50, pa.p99, pa.max, pa.geometry_ms, pa.factor_ms, pa.share, pa.refactors,
            pa.steps, pa.reps);
    fprintf(stderr,
            "cut: %s: PARTIAL on one thread (factor_threads 1), its sweeps alternating with the "
            "above: step p50 %.3f ms p99 %.3f ms max %.3f ms (factor %.3f ms); default threads "
            "/ one thread: factor time %.2f, step p50 %.2f\n",
            cc->name, p1->p50, p1->p99, p1->max, p1->factor_ms,
            p1->factor_ms > 0 ? pa.factor_ms / p1->factor_ms : 0,
            p1->p50 > 0 ? pa.p50 / p1->p50 : 0);
    fprintf(stderr,
            "cut: %s: with the update window: UPDATE step p50 %.3f ms p99 %.3f ms (%d of %d steps "
            "rebuilt the window, rank %.1f); AUTO step p50 %.3f ms p99 %.3f ms (%d refactored, "
            "%d of them new windows)\n",
            cc->name, wu.p50, wu.p99, wu.rewindows, wu.steps, wu.rank, wa.p50, wa.p99, wa.refactors,
            wa.rewindows);
    fprintf(stderr,
            "cut: %s: background window (UPDATE): step p50 %.3f ms p99 %.3f ms max %.3f ms, %d "
            "refactored; %d builds of %.1f ms on a second thread, %d swapped in\n",
            cc->name, wb.p50, wb.p99, wb.max, wb.refactors, wb.builds, wb.build_ms, wb.rewindows);
    for (int k = 0; k < 2; k++) {
        const pass_stats* w = k ? &pp : &pw;
        fprintf(stderr,
                "cut: %s: background window (PARTIAL%s): step p50 %.3f ms p99 %.3f ms max %.3f "
                "ms, %.2f of a factorisation's flops, %d refactored; %d builds of %.1f ms on a "
                "second thread, %d swapped in (probe: share %.3f in the window's order against "
                "%.3f: windows %s); %d steps in %d passes\n",
                cc->name, k ? ", one sweep per 10 ms" : ", sweeps back to back", w->p50, w->p99,
                w->max, w->share, w->refactors, w->builds, w->build_ms, w->rewindows,
                w->probe_window, w->probe_default, w->off ? "off" : "kept", w->steps, w->reps);
    }
    fprintf(stderr,
            "cut: %s: PARTIAL without a window (default factor threads), one sweep per 10 ms: "
            "step p50 %.3f ms p99 %.3f ms max %.3f ms, %.2f of a factorisation's flops; %d "
            "steps in %d passes\n",
            cc->name, pn.p50, pn.p99, pn.max, pn.share, pn.steps, pn.reps);
    // Does the helper thread disturb a haptic loop? The rt thread's own scheduling (SCHED_FIFO
    // when granted), an empty tick, beside a PARTIAL pass on one and on two threads.
    for (int t = 1; t <= 2 && cc->rt; t++) {
        hs_rt_def rd = hs_rt_default_def();
        hs_rt_loop* loop = NULL;
        hs_err e;
        pass_stats ps;
        if (hs_rt_loop_create(&rd, &loop, &e) != HS_OK || hs_rt_loop_start(loop, &e) != HS_OK) {
            fprintf(stderr, "bench cut: rt loop: %s\n", e.msg);
            hs_rt_loop_destroy(&loop);
            return 1;
        }
        rc |= run_pass(cc, args, HS_CUT_FACTOR_PARTIAL, 0, 0, t, 0, NULL, 1, &ps);
        hs_rt_loop_stop(loop);
        hs_rt_stats st;
        hs_rt_loop_stats(loop, &st);
        hs_rt_loop_destroy(&loop);
        fprintf(stderr,
                "cut: %s: 1 kHz loop (%s) beside PARTIAL on %d thread%s (step p50 %.3f ms): "
                "period error p50 %.0f us p99 %.0f us p99.9 %.0f us, worst wake-up %.0f us late, "
                "%lld of %lld deadlines missed\n",
                cc->name, (st.obtained & HS_RT_SCHED_FIFO) ? "SCHED_FIFO" : "ordinary scheduling",
                t, t > 1 ? "s" : "", ps.p50, hs_rt_hist_quantile_us(&st.period_err, 0.5),
                hs_rt_hist_quantile_us(&st.period_err, 0.99),
                hs_rt_hist_quantile_us(&st.period_err, 0.999), (double)st.wake_late_max_ns * 1e-3,
                (long long)st.missed_deadlines, (long long)(st.ticks + st.missed_deadlines));
    }
    return rc;
}

/// Whether this machine keeps a deformation step's data cached across a pause: median time to
/// read 1 MB (one load per 64-byte line) right after the previous read, and after 10 ms of
/// spinning (no sleep, so not the processor idling), us. Explains the paced passes.
static void cache_after_pause(double* hot_us, double* cold_us) {
    enum { BYTES = 1 << 20, READS = 31 };
    double* buf = malloc(BYTES);
    *hot_us = *cold_us = -1;
    if (!buf) return;
    const size_t n = BYTES / sizeof(double);
    for (size_t i = 0; i < n; i++) buf[i] = (double)i;
    volatile double sink = 0;
    double t[2][READS];
    for (int r = 0; r < READS; r++)
        for (int k = 0; k < 2; k++) {
            int64_t until = hs_now_ns() + (k ? 10000000 : 0);
            while (hs_now_ns() < until) {
            }
            int64_t t0 = hs_now_ns();
            double acc = 0;
            for (size_t i = 0; i < n; i += 8) acc += buf[i];
            t[k][r] = (double)(hs_now_ns() - t0) * 1e-3;
            sink += acc;
        }
    (void)sink;
    free(buf);
    *hot_us = hs_bench_percentile(t[0], READS, 50);
    *cold_us = hs_bench_percentile(t[1], READS, 50);
}

int hs_bench_cut(const hs_bench_args* a) {
    cut_case cases[] = {
        {"plate192", NULL, 0.2, 0.2, 0.01, 7, 7, 2, 0, 0, 0, 0},
        {"plate288", NULL, 0.2, 0.2, 0.01, 11, 11, 1, 0, 0, 0, 0},
        {"plate432", NULL, 0.2, 0.2, 0.01, 11, 11, 2, 1, 0, 0, 0},
        {"liver2", "liver2.msh", 0, 0, 0, 0, 0, 0, 0, 0, 0, 0},
        {"tongue", "tongue.msh", 0, 0, 0, 0, 0, 0, 0, 0, 0, 0},
        {"vessel", "aneurysm_vessel.msh", 0, 0, 0, 0, 0, 0, 0, 0, 0, 0},
        {"plate5043", NULL, 0.2, 0.2, 0.01, 40, 40, 2, 1, 1, 0, 0},
    };
    hs_sparse_set_threads(1);
    double hot_us, cold_us;
    cache_after_pause(&hot_us, &cold_us);
    fprintf(stderr,
            "cut: machine: reading 1 MB (a load per cache line) takes p50 %.0f us right after "
            "the last read, %.0f us after 10 ms of spinning (%.2fx): where this is well above 1, "
            "a sweep paced at 100 Hz finds its data out of cache and runs slower than back to "
            "back\n",
            hot_us, cold_us, hot_us > 0 ? cold_us / hot_us : 0);
    printf("mesh,vertices,tets,removed_per_step,update_ms_p50,update_ms_p99,refactor_ms,"
           "dense_inverse_ms\n");
    int rc = 0;
    for (size_t i = 0; i < sizeof cases / sizeof cases[0]; i++) {
        if (a->quick && !cases[i].quick) continue;
        fprintf(stderr, "cut: %s\n", cases[i].name);
        hs_mesh* m = NULL;
        hs_err e;
        if (load_mesh(&cases[i], a, &m, &e) < 0) {
            fprintf(stderr, "bench cut: %s: %s\n", cases[i].name, e.msg);
            rc = 1;
            continue;
        }
        cases[i].vertices = m->n_nodes;
        cases[i].tets = m->n_tets;
        hs_mesh_destroy(&m);
        rc |= run_case(&cases[i], a);
    }
    return rc;
}
