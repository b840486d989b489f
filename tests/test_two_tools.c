// SPDX-License-Identifier: GPL-2.0-or-later
// Two tools in one contact problem (hs_contact_solve_tools): two probes pressing one block
// feel each other's press through the compliance between their contact nodes, as the linear
// FEM static solution of both contacts together predicts; one tool alone is the one-tool
// solve; the tick allocates nothing.
#define _POSIX_C_SOURCE 200809L
#include "alloc_counter.h"
#include "body.h"
#include "compliance.h"
#include "haptic_sim.h"
#include "haptic_rt.h"
#include "mesh.h"
#include "test_macros.h"

#include <stdlib.h>
#include <time.h>

#define R_M     0.008 // probe radius
#define TOP_M   0.024 // block height: top face at z = 24 mm
#define REACH_M 0.012 // candidates within this of each tool

static hs_fem_def soft_fem(void) {
    hs_fem_def d = hs_fem_default_def();
    d.model = HS_MODEL_LINEAR;
    d.material.youngs_pa = 5000;
    d.material.poisson = 0.45;
    d.material.density_kg_m3 = 1060;
    return d;
}

// 64 x 32 x 24 mm block in 4 mm cells, bottom fixed.
typedef struct block {
    hs_mesh* mesh;
    unsigned char* fixed;
    hs_compliance* comp;
} block;

static int block_create(block* b) {
    hs_err err = {0};
    memset(b, 0, sizeof *b);
    if (hs_mesh_create_box(0.064, 0.032, TOP_M, 16, 8, 6, &b->mesh, &err) < 0) return 1;
    b->fixed = calloc((size_t)b->mesh->n_nodes, 1);
    hs_mesh_select_plane(b->mesh, 2, -1, 1e-9, b->fixed);
    hs_fem_def fd = soft_fem();
    if (hs_compliance_create(b->mesh, &fd, b->fixed, 128, &b->comp, &err) != HS_OK) {
        printf("  compliance: %s\n", err.msg);
        return 1;
    }
    return 0;
}

static void block_destroy(block* b) {
    hs_compliance_destroy(&b->comp);
    hs_mesh_destroy(&b->mesh);
    free(b->fixed);
}

static double dist3(const double* a, const double* b) {
    double d[3] = {a[0] - b[0], a[1] - b[1], a[2] - b[2]};
    return sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2]);
}

// Node-contact snapshot at rest holding every contactable node within REACH_M of either tool
// centre (all coupled: every cross block exact).
static void make_snapshot(block* b, double tool[2][3], hs_contact_snapshot* s) {
    const hs_mesh* mesh = b->mesh;
    memset(s, 0, sizeof *s);
    s->version = 1;
    s->probe_radius_m = R_M;
    memcpy(s->centre_m, tool[0], sizeof s->centre_m);
    memcpy(s->tool_centre_m[1], tool[1], sizeof s->tool_centre_m[1]);
    s->reach_m = s->tool_reach_m[1] = REACH_M;
    int n = 0;
    for (int si = 0; si < mesh->n_surf_nodes && n < HS_CONTACT_MAX_CAND; ++si) {
        int v = mesh->surf_nodes[si];
        if (!hs_compliance_contactable(b->comp, v)) continue;
        if (dist3(mesh->x0 + 3 * v, tool[0]) < REACH_M ||
            dist3(mesh->x0 + 3 * v, tool[1]) < REACH_M)
            s->node[n++] = v;
    }
    s->n_cand = n;
    hs_compliance_begin_step(b->comp);
    hs_compliance_ensure(b->comp, n, s->node, n);
    for (int i = 0; i < n; ++i) {
        s->coupled[i] = (unsigned char)hs_compliance_has_column(b->comp, s->node[i]);
        memcpy(s->surf_m[i], mesh->x0 + 3 * s->node[i], 3 * sizeof(double));
        if (hs_mesh_rest_normal(mesh, s->node[i], s->normal[i]) != 0) s->normal[i][2] = 1;
        for (int j = 0; j < n; ++j)
            hs_compliance_block(b->comp, s->node[i], s->node[j], s->c[i][j]);
    }
}

// The reference: Green's functions of the linear FEM body (hs_body static solves, unit loads
// at every candidate node) and the frictionless node contact of both spheres on them, solved
// by projected Gauss-Seidel to a tight residual. g[(3i+a)*3n + 3j+c]: u_i,a under unit f_j,c.
static int fem_greens(block* b, const hs_contact_snapshot* s, double* g) {
    hs_err err = {0};
    hs_body_def bd = hs_body_default_def();
    bd.fem = soft_fem();
    bd.static_tol = 1e-12;
    hs_body* body = NULL;
    if (hs_body_create(b->mesh, &bd, b->fixed, &body, &err) != HS_OK) return 1;
    const int n = s->n_cand;
    for (int j = 0; j < n; ++j)
        for (int c = 0; c < 3; ++c) {
            double f[3] = {0, 0, 0};
            f[c] = 1;
            hs_body_clear_forces(body);
            hs_body_set_force(body, s->node[j], f);
            if (hs_body_solve_static(body, NULL) < 0) return 1;
            const double* u = hs_body_displacement(body);
            for (int i = 0; i < n; ++i)
                for (int a = 0; a < 3; ++a)
                    g[(3 * i + a) * 3 * n + 3 * j + c] = u[3 * s->node[i] + a];
        }
    hs_body_destroy(&body);
    return 0;
}

// Force on each tool (tools 0..n_tools) from the reference contact: points are the candidate
// nodes within 2 r of a tool centre, pushed away from it.
static void fem_contact(const hs_contact_snapshot* s, const double* g, int n_tools,
                        double tool[2][3], double force[2][3]) {
    enum { P = 2 * HS_CONTACT_MAX_CAND };
    int node[P], owner[P], m = 0;
    double nrm[P][3], delta[P], lam[P], w[P][P];
    const int n = s->n_cand;
    for (int t = 0; t < n_tools; ++t)
        for (int i = 0; i < n; ++i) {
            double d = dist3(s->surf_m[i], tool[t]);
            if (d >= 2 * R_M) continue;
            node[m] = i;
            owner[m] = t;
            for (int k = 0; k < 3; ++k) nrm[m][k] = (s->surf_m[i][k] - tool[t][k]) / d;
            delta[m] = R_M - d;
            lam[m] = 0;
            ++m;
        }
    for (int i = 0; i < m; ++i)
        for (int j = 0; j < m; ++j) {
            double sum = 0;
            for (int a = 0; a < 3; ++a)
                for (int c = 0; c < 3; ++c)
                    sum += nrm[i][a] * g[(3 * node[i] + a) * 3 * n + 3 * node[j] + c] * nrm[j][c];
            w[i][j] = sum;
        }
    for (int sweep = 0; sweep < 20000; ++sweep)
        for (int i = 0; i < m; ++i) {
            double r = delta[i];
            for (int j = 0; j < m; ++j) r -= w[i][j] * lam[j];
            lam[i] = fmax(0.0, lam[i] + r / w[i][i]);
        }
    memset(force, 0, 2 * 3 * sizeof(double));
    for (int i = 0; i < m; ++i)
        for (int k = 0; k < 3; ++k) force[owner[i]][k] -= lam[i] * nrm[i][k];
}

static double rel_err(const double* a, const double* b, double scale) {
    return dist3(a, b) / scale;
}

// Probe 1 holds a 3 mm press; probe 0, 16 mm away, presses 3 mm or stays above the block.
static int two_probes_feel_each_other(void) {
    block b;
    ENSURE(block_create(&b) == 0);
    const double z = TOP_M + R_M - 0.003;
    double both[2][3] = {{0.024, 0.016, z}, {0.040, 0.016, z}};
    double lifted[2][3] = {{0.024, 0.016, z + 0.02}, {0.040, 0.016, z}};
    hs_contact_snapshot* s = malloc(sizeof *s);
    make_snapshot(&b, both, s);
    ENSURE(s->n_cand > 20 && s->n_cand < HS_CONTACT_MAX_CAND);

    hs_contact_work* w = NULL;
    ENSURE(hs_contact_work_create(2, &w) == HS_OK);
    hs_contact c_both[2], c_lift[2], c_prev[2], alone;
    hs_contact_solve_tools(s, 2, (const double*)both, NULL, w, c_both);
    hs_contact_solve_tools(s, 2, (const double*)lifted, NULL, w, c_lift);
    hs_contact_solve(s, both[1], 0, NULL, &alone);
    ENSURE(!c_both[0].failed && !c_both[1].failed && !c_lift[1].failed);
    ENSURE(c_both[0].n > 0 && c_both[1].n > 0 && c_lift[0].n == 0);

    // One tool pressing: the same as the one-tool solve.
    ENSURE(rel_err(c_lift[1].force_n, alone.force_n, fabs(alone.force_n[2])) < 1e-12);

    // The reference: both contacts on the FEM body at once.
    int n = s->n_cand;
    double* g = malloc(sizeof(double) * 9 * (size_t)n * (size_t)n);
    ENSURE(fem_greens(&b, s, g) == 0);
    double ref_both[2][3], ref_lift[2][3];
    fem_contact(s, g, 2, both, ref_both);
    fem_contact(s, g, 2, lifted, ref_lift);
    double f1 = c_lift[1].force_n[2], f1b = c_both[1].force_n[2];
    double ref_change = ref_both[1][2] - ref_lift[1][2], change = f1b - f1;
    printf("  probe 1 alone %.5f N (FEM %.5f), with probe 0 pressing %.5f N (FEM %.5f): "
           "change %.5f N (FEM %.5f); probe 0 %.5f N (FEM %.5f); %d + %d contact nodes\n",
           f1, ref_lift[1][2], f1b, ref_both[1][2], change, ref_change, c_both[0].force_n[2],
           ref_both[0][2], c_both[0].n, c_both[1].n);
    // The press is felt: at least 3 % of the force, and as the FEM predicts within 2 %.
    ENSURE(fabs(ref_change) > 0.03 * fabs(ref_lift[1][2]));
    ENSURE(fabs(change - ref_change) <= 0.02 * fabs(ref_change));
    ENSURE(rel_err(c_both[1].force_n, ref_both[1], fabs(ref_both[1][2])) <= 0.02);
    ENSURE(rel_err(c_both[0].force_n, ref_both[0], fabs(ref_both[0][2])) <= 0.02);
    // Solved apart (no cross blocks), probe 1 would not feel probe 0 at all.
    ENSURE(fabs(alone.force_n[2] - f1b) > 0.5 * fabs(ref_change));

    // The tools' stiffness against finite differences of their own force (the other held).
    const double h = 1e-7;
    double worst = 0, kmax = 0;
    for (int t = 0; t < 2; ++t)
        for (int a = 0; a < 3; ++a) {
            double pp[2][3], pm[2][3];
            memcpy(pp, both, sizeof pp);
            memcpy(pm, both, sizeof pm);
            pp[t][a] += h;
            pm[t][a] -= h;
            hs_contact cp[2], cm[2];
            hs_contact_solve_tools(s, 2, (const double*)pp, c_both, w, cp);
            hs_contact_solve_tools(s, 2, (const double*)pm, c_both, w, cm);
            for (int q = 0; q < 3; ++q) {
                double fd = -(cp[t].force_n[q] - cm[t].force_n[q]) / (2 * h);
                worst = fmax(worst, fabs(fd - c_both[t].stiffness_n_m[3 * q + a]));
                kmax = fmax(kmax, fabs(c_both[t].stiffness_n_m[3 * q + a]));
            }
        }
    printf("  stiffness vs finite differences: worst %.2e of %.1f N/m\n", worst, kmax);
    ENSURE(worst <= 1e-4 * kmax);

    // Warm-started ticks allocate nothing and agree with the cold solve.
    memcpy(c_prev, c_both, sizeof c_prev);
    hs_contact c_warm[2];
    int64_t hs_before = hs_alloc_calls();
    long long before = atomic_load(&g_rt_allocs);
    count_on(NULL);
    for (int k = 0; k < 100; ++k)
        hs_contact_solve_tools(s, 2, (const double*)both, c_prev, w, c_warm);
    count_off(NULL);
    ENSURE(atomic_load(&g_rt_allocs) == before && hs_alloc_calls() == hs_before);
    ENSURE(rel_err(c_warm[1].force_n, c_both[1].force_n, fabs(f1b)) < 1e-12);

    free(g);
    free(s);
    hs_contact_work_destroy(&w);
    ENSURE(w == NULL);
    block_destroy(&b);
    return 0;
}

// The contact on the pressed shape, as the deformation thread finds it: the geometry taken on
// the surface the contact forces displace (pre_m = C f), iterated to its fixed point.
static int pressed_shape(const hs_contact_snapshot* rest, double tool[2][3], hs_contact_work* w,
                         hs_contact out[2]) {
    hs_contact_snapshot* s = malloc(sizeof *s);
    double(*pre)[3] = calloc(HS_CONTACT_MAX_CAND, sizeof *pre);
    hs_contact_solve_tools(rest, 2, (const double*)tool, NULL, w, out);
    double change = 1;
    for (int it = 0; it < 400 && change > 1e-9; ++it) {
        *s = *rest;
        for (int i = 0; i < s->n_cand; ++i) {
            double t[3] = {0, 0, 0};
            for (int q = 0; q < 2; ++q)
                for (int k = 0; k < out[q].n; ++k) {
                    int j = 0;
                    while (j < s->n_cand && s->node[j] != out[q].node[k]) ++j;
                    if (j == s->n_cand) return 1;
                    for (int a = 0; a < 3; ++a)
                        for (int c = 0; c < 3; ++c)
                            t[a] += s->c[i][j][3 * a + c] * out[q].f_n[k][c];
                }
            for (int a = 0; a < 3; ++a) { // relaxed, as the deformation thread does
                pre[i][a] += 0.5 * (t[a] - pre[i][a]);
                s->pre_m[i][a] = pre[i][a];
                s->surf_m[i][a] += pre[i][a];
            }
        }
        hs_contact_snapshot_bound_tris(s);
        double before = out[0].force_n[2] + out[1].force_n[2];
        hs_contact next[2];
        hs_contact_solve_tools(s, 2, (const double*)tool, out, w, next);
        memcpy(out, next, sizeof next);
        change = fabs(out[0].force_n[2] + out[1].force_n[2] - before);
    }
    free(s);
    free(pre);
    return change <= 1e-9 ? 0 : 1;
}

// Two devices on the running sim: every 1 ms each feeds its own pose and takes its own output.
typedef struct feeder {
    hs_haptic_sim* sim;
    struct timespec next;
    int64_t seq[2];
    double sum[2][3]; // force sums over the ticks since the last reset
    int n;
    hs_haptic_output out[2];
} feeder;

// One millisecond: feed tool t at p[t] unless alive[t] is 0 (its driver died), take outputs.
static void feed_tick(feeder* f, double p[2][3], const int alive[2]) {
    f->next.tv_nsec += 1000000;
    if (f->next.tv_nsec >= 1000000000L) {
        f->next.tv_nsec -= 1000000000L;
        f->next.tv_sec++;
    }
    clock_nanosleep(CLOCK_MONOTONIC, TIMER_ABSTIME, &f->next, NULL);
    for (int t = 0; t < 2; ++t) {
        if (alive[t]) {
            hs_haptic_pose pose;
            memset(&pose, 0, sizeof pose);
            pose.seq = ++f->seq[t];
            pose.stamp_ns = hs_now_ns();
            memcpy(pose.pos_m, p[t], sizeof pose.pos_m);
            pose.quat_wxyz[0] = 1;
            hs_haptic_sim_feed_tool_pose(f->sim, t, &pose);
        }
        hs_haptic_output o; // an output is new or kept (the buffer holds zeros before the first)
        if (hs_haptic_sim_take_tool_output(f->sim, t, &o)) f->out[t] = o;
        for (int k = 0; k < 3; ++k) f->sum[t][k] += f->out[t].force_n[k];
    }
    f->n++;
}

static void feed_for(feeder* f, double p[2][3], const int alive[2], int ms, double mean[2][3]) {
    for (int i = 0; i < ms; ++i) {
        if (i == ms - 50) {
            memset(f->sum, 0, sizeof f->sum);
            f->n = 0;
        }
        feed_tick(f, p, alive);
        hs_haptic_telemetry rec;
        while (hs_spsc_ring_pop(hs_haptic_sim_telemetry(f->sim), &rec)) {
        }
    }
    for (int t = 0; t < 2; ++t)
        for (int k = 0; k < 3; ++k) mean[t][k] = f->sum[t][k] / f->n;
}

// Feed p until probe 1's mean force over 100 ms changes by less than 1e-4 of it (at least 300
// ms, at most 5 s: a sanitizer build steps the body slower), its last means into mean.
static void feed_settled(feeder* f, double p[2][3], const int alive[2], double mean[2][3]) {
    double prev = INFINITY;
    feed_for(f, p, alive, 200, mean);
    for (int k = 0; k < 48; ++k) {
        feed_for(f, p, alive, 100, mean);
        if (fabs(mean[1][2] - prev) <= 1e-4 * fabs(mean[1][2])) break;
        prev = mean[1][2];
    }
}

// The sim with two devices: probe 1 holds a press, probe 0 presses beside it and probe 1's
// force changes as the one contact problem on the rest shape predicts; then probe 0's driver
// dies: its force ramps out (its own watchdog), probe 1's goes on unchanged.
static int sim_two_devices(void) {
    block b;
    ENSURE(block_create(&b) == 0);
    const double z = TOP_M + R_M - 0.003;
    double lifted[2][3] = {{0.024, 0.016, z + 0.02}, {0.040, 0.016, z}};
    double both[2][3] = {{0.024, 0.016, z}, {0.040, 0.016, z}};

    // The prediction: the triangle contact of both probes on the rest shape.
    hs_contact_snapshot* s = malloc(sizeof *s);
    make_snapshot(&b, both, s);
    hs_contact_snapshot_add_tris(s, b.mesh);
    hs_contact_work* w = NULL;
    ENSURE(hs_contact_work_create(2, &w) == HS_OK);
    hs_contact pred_both[2], pred_lift[2];
    ENSURE(pressed_shape(s, both, w, pred_both) == 0);
    ENSURE(pressed_shape(s, lifted, w, pred_lift) == 0);
    hs_contact_work_destroy(&w);
    free(s);

    hs_haptic_sim_def d = hs_haptic_sim_default_def();
    d.body.fem = soft_fem();
    d.probe.radius_m = R_M;
    d.fifo_priority = 0;
    d.lock_memory = 0;
    d.tools = 2;
    d.safety.watchdog_timeout_s = 0.15; // a loaded machine's stalls of this test's feeder
    d.rt_on_start = count_on;
    d.rt_on_stop = count_off;
    hs_haptic_sim* sim = NULL;
    hs_err err = {0};
    ENSURE(hs_haptic_sim_create(b.mesh, &d, b.fixed, &sim, &err) == HS_OK);
    ENSURE(hs_haptic_sim_tools(sim) == 2);
    long long allocs0 = atomic_load(&g_rt_allocs);
    ENSURE(hs_haptic_sim_start(sim, &err) == HS_OK);
    feeder f;
    memset(&f, 0, sizeof f);
    f.sim = sim;
    clock_gettime(CLOCK_MONOTONIC, &f.next);
    const int alive[2] = {1, 1}, dead0[2] = {0, 1};
    double m_lift[2][3], m_both[2][3], m_dead[2][3];
    feed_settled(&f, lifted, alive, m_lift);
    feed_settled(&f, both, alive, m_both);
    feed_for(&f, both, dead0, 500, m_dead);
    hs_haptic_rt_counters rc[2];
    for (int t = 0; t < 2; ++t) hs_haptic_sim_tool_counters(sim, t, &rc[t]);
    hs_haptic_sim_stop(sim);
    long long allocs = atomic_load(&g_rt_allocs) - allocs0;

    double change = m_both[1][2] - m_lift[1][2];
    double pchange = pred_both[1].force_n[2] - pred_lift[1].force_n[2];
    printf("  probe 1: %.4f N alone (predicted %.4f), %.4f N with probe 0 pressing (predicted "
           "%.4f; change %.4f, predicted %.4f); probe 0 %.4f N (predicted %.4f)\n",
           m_lift[1][2], pred_lift[1].force_n[2], m_both[1][2], pred_both[1].force_n[2], change,
           pchange, m_both[0][2], pred_both[0].force_n[2]);
    printf("  probe 0's driver gone: probe 0 %.4f N, probe 1 %.4f N; watchdog trips %lld / %lld; "
           "rt allocations %lld\n",
           m_dead[0][2], m_dead[1][2], (long long)rc[0].safety.watchdog_trips,
           (long long)rc[1].safety.watchdog_trips, allocs);
    ENSURE(fabs(pchange) > 0.03 * fabs(pred_lift[1].force_n[2]));
    ENSURE(fabs(m_lift[1][2] - pred_lift[1].force_n[2]) <= 0.02 * fabs(pred_lift[1].force_n[2]));
    ENSURE(fabs(m_both[1][2] - pred_both[1].force_n[2]) <= 0.02 * fabs(pred_both[1].force_n[2]));
    ENSURE(fabs(change - pchange) <= 0.02 * fabs(pchange));
    // Killing probe 0's driver: its force gone, probe 1's untouched, only probe 0's watchdog.
    ENSURE(fabs(m_dead[0][0]) + fabs(m_dead[0][1]) + fabs(m_dead[0][2]) == 0);
    ENSURE(fabs(m_dead[1][2] - m_both[1][2]) <= 1e-3 * fabs(m_both[1][2]));
    ENSURE(rc[0].safety.watchdog_trips == 1 && rc[1].safety.watchdog_trips == 0);
    if (HS_COUNT_MALLOC) ENSURE(allocs == 0);

    // A rebuild (as a new material or a reset makes): the new sim takes both tools over, and
    // probe 1's force goes on from where it was, no dip while the new sim starts.
    hs_haptic_sim* sim2 = NULL;
    ENSURE(hs_haptic_sim_create(b.mesh, &d, b.fixed, &sim2, &err) == HS_OK);
    ENSURE(hs_haptic_sim_take_over(sim2, sim, &err) == HS_OK);
    ENSURE(hs_haptic_sim_start(sim2, &err) == HS_OK);
    f.sim = sim2;
    double least = INFINITY;
    for (int i = 0; i < 300; ++i) {
        feed_tick(&f, both, dead0);
        least = fmin(least, f.out[1].force_n[2]);
        hs_haptic_telemetry rec;
        while (hs_spsc_ring_pop(hs_haptic_sim_telemetry(sim2), &rec)) {
        }
    }
    printf("  rebuilt: probe 1 at least %.4f N over the first 300 ms, %.4f N at the end\n", least,
           f.out[1].force_n[2]);
    ENSURE(least >= 0.95 * m_dead[1][2]);
    ENSURE(fabs(f.out[1].force_n[2] - m_dead[1][2]) <= 0.02 * m_dead[1][2]);
    hs_haptic_sim_destroy(&sim2);
    hs_haptic_sim_destroy(&sim);
    block_destroy(&b);
    return 0;
}

HS_TEST_MAIN(HS_CASE(two_probes_feel_each_other), HS_CASE(sim_two_devices))
