// SPDX-License-Identifier: GPL-2.0-or-later
// hapsim-bench haptic: the 1 kHz loop with the condensed-compliance probe in contact, per mesh
// and contact size, against a bare clock_nanosleep loop with the same scheduling run in
// segments before and after each case (pooled), so the loop's own cost shows against what the
// machine allows.
#define _POSIX_C_SOURCE 200809L
#include "bench.h"
#include "../liver_haptic.h"
#include "compliance.h"
#include "haptic_sim.h"
#include "mesh.h"
#include "sparse.h"
#include "rt_thread.h"

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

typedef struct haptic_case {
    const char* name;
    const char* file;
} haptic_case;

static const haptic_case cases_full[] = {
    {"liver_coarse", "liver_coarse.msh"},
    {"liver2", "liver2.msh"},
    {"tongue", "tongue.msh"},
    {"skin_patch", "skin_patch_synthetic.msh"},
    {"vessel", "aneurysm_vessel.msh"},
};
static const haptic_case cases_quick[] = {{"liver2", "liver2.msh"}};
static const int targets[] = {1, 4, 16};

static hs_haptic_sim_def bench_def(double radius) {
    hs_haptic_sim_def d = hs_liver_haptic_def(HS_MODEL_COROTATED, radius);
    d.probe.reach_margin_m = fmax(0.005, 0.5 * radius);
    d.safety.max_force_n = 50; // measure the loop, not the clamp
    d.safety.max_rate_n_s = 1e5;
    return d;
}

// Contact nodes at rest for a sphere of radius r pressed `depth` at node k along -n (surface
// contact on the boundary triangles among the nearest nodes).
static int rest_contacts(hs_compliance* c, const hs_mesh* m, int k, const double n[3], double r,
                         double depth, hs_contact_snapshot* s) {
    double p[3];
    for (int a = 0; a < 3; ++a) p[a] = m->x0[3 * k + a] + (r - depth) * n[a];
    memset(s, 0, sizeof *s);
    s->version = 1;
    s->probe_radius_m = r;
    memcpy(s->centre_m, p, sizeof p);
    double dist[HS_CONTACT_MAX_CAND];
    int nc = 0;
    for (int si = 0; si < m->n_surf_nodes; ++si) {
        int v = m->surf_nodes[si];
        if (!hs_compliance_contactable(c, v)) continue;
        double d = sqrt(pow(m->x0[3 * v] - p[0], 2) + pow(m->x0[3 * v + 1] - p[1], 2) +
                        pow(m->x0[3 * v + 2] - p[2], 2));
        if (nc == HS_CONTACT_MAX_CAND && d >= dist[nc - 1]) continue;
        int at = nc < HS_CONTACT_MAX_CAND ? nc++ : nc - 1;
        while (at > 0 && dist[at - 1] > d) {
            dist[at] = dist[at - 1];
            s->node[at] = s->node[at - 1];
            --at;
        }
        dist[at] = d;
        s->node[at] = v;
    }
    s->n_cand = nc;
    s->reach_m = dist[nc - 1];
    hs_compliance_begin_step(c);
    hs_compliance_ensure(c, nc, s->node, nc);
    for (int i = 0; i < nc; ++i) {
        s->coupled[i] = (unsigned char)hs_compliance_has_column(c, s->node[i]);
        memcpy(s->surf_m[i], m->x0 + 3 * s->node[i], 3 * sizeof(double));
        memcpy(s->normal[i], n, 3 * sizeof(double));
        for (int j = 0; j < nc; ++j) hs_compliance_block(c, s->node[i], s->node[j], s->c[i][j]);
    }
    hs_contact_snapshot_add_tris(s, m); // surface contact, as the sim's snapshots
    hs_contact con;
    hs_contact_solve_from(s, p, NULL, &con);
    return con.n;
}

// Probed node: the free surface node highest in z; its outward normal from the surface.
static int probe_node(const hs_mesh* m, const unsigned char* fixed, double n[3]) {
    int k = -1;
    for (int s = 0; s < m->n_surf_nodes; ++s) {
        int v = m->surf_nodes[s];
        if (!fixed[v] && (k < 0 || m->x0[3 * v + 2] > m->x0[3 * k + 2])) k = v;
    }
    hs_mesh_rest_normal(m, k, n);
    return k;
}

static void sleep_until(struct timespec* t, long step_ns) {
    t->tv_nsec += step_ns;
    while (t->tv_nsec >= 1000000000L) {
        t->tv_nsec -= 1000000000L;
        t->tv_sec++;
    }
    clock_nanosleep(CLOCK_MONOTONIC, TIMER_ABSTIME, t, NULL);
}

static hs_rt_def bare_def(const hs_haptic_sim_def* d) {
    hs_rt_def r = hs_rt_default_def();
    r.rate_hz = d->rate_hz;
    r.fifo_priority = d->fifo_priority;
    r.lock_memory = d->lock_memory;
    return r;
}

// One case: press to `depth`, hold on a slow circle (0.1 r, 1 Hz) for `secs`; bare segments
// around it. contact_nodes is the median of the contact sizes sampled every 50 ms.
static int run_case(const hs_bench_args* a, const haptic_case* hc, const hs_mesh* m,
                    const unsigned char* fixed, int k, const double n[3], double r, double depth,
                    int target) {
    hs_err err = {0};
    hs_haptic_sim_def d = bench_def(r);
    const double secs = a->quick ? 2.0 : 4.0, bare_secs = a->quick ? 0.5 : 1.0;
    hs_rt_def bd = bare_def(&d);
    hs_rt_stats bare, seg;
    memset(&bare, 0, sizeof bare);
    if (hs_rt_bare_loop(&bd, (int64_t)(bare_secs * d.rate_hz), &seg, &err) != HS_OK) {
        fprintf(stderr, "hapsim-bench haptic: bare loop: %s\n", err.msg);
        return 1;
    }
    hs_rt_stats_accumulate(&bare, &seg);

    hs_haptic_sim* sim = NULL;
    if (hs_haptic_sim_create(m, &d, fixed, &sim, &err) != HS_OK ||
        hs_haptic_sim_start(sim, &err) != HS_OK) {
        fprintf(stderr, "hapsim-bench haptic: %s: %s\n", hc->name, err.msg);
        hs_haptic_sim_destroy(&sim);
        return 1;
    }
    // Two tangents for the circle.
    double t1[3] = {1 - n[0] * n[0], -n[0] * n[1], -n[0] * n[2]};
    if (sqrt(t1[0] * t1[0] + t1[1] * t1[1] + t1[2] * t1[2]) < 0.1) {
        t1[0] = -n[1] * n[0];
        t1[1] = 1 - n[1] * n[1];
        t1[2] = -n[1] * n[2];
    }
    double l = sqrt(t1[0] * t1[0] + t1[1] * t1[1] + t1[2] * t1[2]);
    for (int i = 0; i < 3; ++i) t1[i] /= l;
    double t2[3] = {n[1] * t1[2] - n[2] * t1[1], n[2] * t1[0] - n[0] * t1[2],
                    n[0] * t1[1] - n[1] * t1[0]};
    const double* x = m->x0 + 3 * k;
    struct timespec next;
    clock_gettime(CLOCK_MONOTONIC, &next);
    int64_t seq = 0;
    const int press = 300, hold = (int)(secs * 1000);
    int max_contact = 0, samples[1000], ns = 0;
    for (int i = 0; i < press + hold; ++i) {
        double dep = i < press ? -0.002 + (depth + 0.002) * i / press : depth;
        double ph = i < press ? 0 : 6.283185 * (i - press) / 1000.0;
        double rad = i < press ? 0 : 0.1 * r;
        hs_haptic_pose pose;
        memset(&pose, 0, sizeof pose);
        pose.seq = ++seq;
        pose.stamp_ns = hs_now_ns();
        pose.quat_wxyz[0] = 1;
        for (int c = 0; c < 3; ++c)
            pose.pos_m[c] = x[c] + (r - dep) * n[c] + rad * (cos(ph) * t1[c] + sin(ph) * t2[c]);
        hs_haptic_sim_feed_pose(sim, &pose);
        if (i % 50 == 0 && i >= press) {
            hs_haptic_sim_stats st;
            hs_haptic_sim_stats_get(sim, &st);
            if (st.contact.n > max_contact) max_contact = st.contact.n;
            if (ns < 1000) samples[ns++] = st.contact.n;
        }
        sleep_until(&next, 1000000L);
    }
    hs_haptic_sim_stats st;
    hs_haptic_sim_stats_get(sim, &st);
    hs_haptic_sim_stop(sim);
    hs_rt_stats rt = st.rt;
    if (hs_rt_bare_loop(&bd, (int64_t)(bare_secs * d.rate_hz), &seg, &err) == HS_OK)
        hs_rt_stats_accumulate(&bare, &seg);
    // Median of the sampled contact sizes (insertion sort: at most 1000 samples).
    for (int i = 1; i < ns; ++i)
        for (int j = i; j > 0 && samples[j - 1] > samples[j]; --j) {
            int t = samples[j];
            samples[j] = samples[j - 1];
            samples[j - 1] = t;
        }
    int median = ns ? samples[ns / 2] : 0;
    printf("%s,%d,%d,%.1f,%.1f,%.1f,%.1f,%.1f,%lld,%.1f,%.1f\n", hc->name, m->n_surf_nodes, median,
           hs_rt_hist_quantile_us(&rt.tick, 0.5), hs_rt_hist_quantile_us(&rt.tick, 0.99),
           hs_rt_hist_quantile_us(&rt.period_err, 0.5),
           hs_rt_hist_quantile_us(&rt.period_err, 0.99), (double)rt.period_err.max_ns * 1e-3,
           (long long)rt.overruns, hs_rt_hist_quantile_us(&bare.period_err, 0.99), st.setup_ms);
    fflush(stdout);
    fprintf(stderr,
            "  %s: target %d contacts, r %.1f mm, depth %.1f mm: contacts median %d (max %d), |F| "
            "%.3g N, "
            "steps %lld (step+snapshot last %.1f max %.1f ms, snapshot alone last %.1f max %.1f "
            "ms), %lld column solves, %d candidates (%d "
            "coupled), rt flags 0x%x\n",
            hc->name, target, r * 1e3, depth * 1e3, median, max_contact,
            sqrt(st.contact.force_n[0] * st.contact.force_n[0] +
                 st.contact.force_n[1] * st.contact.force_n[1] +
                 st.contact.force_n[2] * st.contact.force_n[2]),
            (long long)st.steps, st.step_ms_last, st.step_ms_max, st.snapshot_ms_last,
            st.snapshot_ms_max, (long long)st.column_solves, st.candidates, st.coupled,
            rt.obtained);
    hs_haptic_sim_destroy(&sim);
    return 0;
}

static int run_mesh(const hs_bench_args* a, const haptic_case* hc) {
    hs_err err = {0};
    hs_mesh* m = NULL;
    char path[1024];
    if (hs_mesh_load(hs_bench_mesh_path(a, hc->file, path, sizeof path), &m, &err) < 0) {
        fprintf(stderr, "hapsim-bench haptic: %s: %s\n", hc->name, err.msg);
        return 1;
    }
    // As hapsim-bench core: organs held along their lowest 10 % in z; probed at the top.
    unsigned char* fixed = calloc((size_t)m->n_nodes, 1);
    hs_mesh_select_plane(m, 2, -1, 0.1 * (m->bbox_max[2] - m->bbox_min[2]), fixed);
    double n[3];
    int k = probe_node(m, fixed, n);
    hs_fem_def fd = bench_def(0.01).body.fem;
    hs_compliance* c = NULL;
    if (hs_compliance_create(m, &fd, fixed, 96, &c, &err) != HS_OK) {
        fprintf(stderr, "hapsim-bench haptic: %s: %s\n", hc->name, err.msg);
        free(fixed);
        hs_mesh_destroy(&m);
        return 1;
    }
    static hs_contact_snapshot snap;
    double ext = fmax(m->bbox_max[0] - m->bbox_min[0],
                      fmax(m->bbox_max[1] - m->bbox_min[1], m->bbox_max[2] - m->bbox_min[2]));
    int rc = 0;
    for (size_t ti = 0; ti < sizeof targets / sizeof *targets; ++ti) {
        // The smallest sphere (radius, depth) whose contact at rest reaches the target, else the
        // one with the most contact nodes: a soft body dimples around a pushed node, so on a
        // coarse mesh fewer nodes touch than penetrate.
        double best_r = 0, best_dep = 0;
        int best = -1;
        for (double r = 0.001; r < 0.5 * ext && best < targets[ti]; r *= 1.1)
            for (int f = 0; f < 3 && best < targets[ti]; ++f) {
                double dep = (0.3 + 0.15 * f) * r;
                int got = rest_contacts(c, m, k, n, r, dep, &snap);
                if (got > best) best = got, best_r = r, best_dep = dep;
            }
        rc |= run_case(a, hc, m, fixed, k, n, best_r, best_dep, targets[ti]);
    }
    hs_compliance_destroy(&c);
    free(fixed);
    hs_mesh_destroy(&m);
    return rc;
}

// The rt contact solve alone at its worst size: 16 nodes on a sphere cap, all in contact
// (diagonal-dominant compliance), timed over many calls. Reported on stderr.
static void contact_worst_case(void) {
    static hs_contact_snapshot s;
    memset(&s, 0, sizeof s);
    s.version = 1;
    s.probe_radius_m = 0.01;
    s.reach_m = 0.05;
    s.n_cand = HS_MAX_CONTACT;
    for (int i = 0; i < HS_MAX_CONTACT; ++i) {
        double th = 0.5 * (i + 1) / HS_MAX_CONTACT, ph = 2.4 * i;
        s.node[i] = i;
        s.coupled[i] = 1;
        s.surf_m[i][0] = 0.008 * sin(th) * cos(ph);
        s.surf_m[i][1] = 0.008 * sin(th) * sin(ph);
        s.surf_m[i][2] = -0.008 * cos(th);
        s.normal[i][2] = 1;
        for (int j = 0; j < HS_MAX_CONTACT; ++j)
            for (int p = 0; p < 3; ++p)
                s.c[i][j][4 * p] = (i == j ? 1e-2 : 1e-3 / (1 + abs(i - j))); // m/N
    }
    const int n = 20000;
    double* us = malloc(sizeof(double) * n);
    double p[3] = {0, 0, 0};
    hs_contact con;
    int contacts = 0, warm[HS_MAX_CONTACT], wn = 0;
    for (int k = 0; k < n; ++k) {
        p[0] = 1e-4 * sin(k * 0.01);
        int64_t t0 = hs_now_ns();
        hs_contact_solve(&s, p, wn, warm, &con);
        us[k] = (double)(hs_now_ns() - t0) * 1e-3;
        contacts = wn = con.n;
        memcpy(warm, con.node, sizeof warm);
    }
    double p50 = hs_bench_percentile(us, (size_t)n, 50),
           p99 = hs_bench_percentile(us, (size_t)n, 99);
    fprintf(stderr,
            "  contact solve alone, %d of %d candidates in contact: p50 %.2f us, p99 %.2f us\n",
            contacts, HS_MAX_CONTACT, p50, p99);
    free(us);
}

int hs_bench_haptic(const hs_bench_args* a) {
    contact_worst_case();
    const haptic_case* cases = a->quick ? cases_quick : cases_full;
    size_t nc = a->quick ? sizeof cases_quick / sizeof *cases_quick
                         : sizeof cases_full / sizeof *cases_full;
    printf("mesh,surface_nodes,contact_nodes,tick_us_p50,tick_us_p99,period_err_us_p50,"
           "period_err_us_p99,period_err_us_max,overruns,bare_period_err_us_p99,"
           "compliance_setup_ms\n");
    int rc = 0;
    for (size_t i = 0; i < nc; ++i) rc |= run_mesh(a, &cases[i]);
    return rc;
}
