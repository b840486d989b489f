// SPDX-License-Identifier: GPL-2.0-or-later
#define _POSIX_C_SOURCE 200809L
// hapsim-bench tools: the rt tick's contact solve with two tools in one problem
// (hs_contact_solve_tools, warm-started as the rt thread does): two probes pressing a block,
// and a synthetic snapshot where each has the cap's 16 contact nodes, against
// one tool alone on the same snapshot. CSV on stdout.
#include "bench.h"
#include "compliance.h"
#include "mesh.h"

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

// This thread's CPU time, ns: a call's cost without the time the thread was preempted (the
// benchmark machine may be shared).
static int64_t cpu_ns(void) {
    struct timespec t;
    clock_gettime(CLOCK_THREAD_CPUTIME_ID, &t);
    return (int64_t)t.tv_sec * 1000000000LL + t.tv_nsec;
}

#define TOP_M 0.02 // block 80 x 40 x 20 mm in 2.5 mm cells, bottom fixed

// Candidates: the contactable surface nodes nearest either tool centre (at most
// HS_CONTACT_MAX_CAND), every tool covered as far as the nearest node left out; the boundary
// triangles between them; exact blocks.
static void two_tool_snapshot(hs_compliance* c, const hs_mesh* m, const double* tool, double r,
                              hs_contact_snapshot* s) {
    memset(s, 0, sizeof *s);
    s->version = 1;
    s->probe_radius_m = r;
    double dist[HS_CONTACT_MAX_CAND + 1];
    int n = 0;
    for (int si = 0; si < m->n_surf_nodes; ++si) {
        int v = m->surf_nodes[si];
        if (!hs_compliance_contactable(c, v)) continue;
        double d = INFINITY;
        for (int t = 0; t < 2; ++t) {
            const double* x = m->x0 + 3 * v;
            const double* p = tool + 3 * t;
            d = fmin(d, sqrt((x[0] - p[0]) * (x[0] - p[0]) + (x[1] - p[1]) * (x[1] - p[1]) +
                             (x[2] - p[2]) * (x[2] - p[2])));
        }
        if (n == HS_CONTACT_MAX_CAND + 1 && d >= dist[n - 1]) continue;
        int at = n <= HS_CONTACT_MAX_CAND ? n++ : n - 1;
        while (at > 0 && dist[at - 1] > d) {
            dist[at] = dist[at - 1];
            s->node[at] = s->node[at - 1];
            --at;
        }
        dist[at] = d;
        s->node[at] = v;
    }
    const double cover = n > HS_CONTACT_MAX_CAND ? dist[HS_CONTACT_MAX_CAND] : 1.0;
    s->n_cand = n > HS_CONTACT_MAX_CAND ? HS_CONTACT_MAX_CAND : n;
    memcpy(s->centre_m, tool, sizeof s->centre_m);
    memcpy(s->tool_centre_m[1], tool + 3, sizeof s->tool_centre_m[1]);
    s->reach_m = s->tool_reach_m[1] = cover;
    hs_compliance_begin_step(c);
    hs_compliance_ensure(c, s->n_cand, s->node, s->n_cand);
    for (int i = 0; i < s->n_cand; ++i) {
        s->coupled[i] = (unsigned char)hs_compliance_has_column(c, s->node[i]);
        memcpy(s->surf_m[i], m->x0 + 3 * s->node[i], 3 * sizeof(double));
        if (hs_mesh_rest_normal(m, s->node[i], s->normal[i]) != 0) s->normal[i][2] = 1;
        for (int j = 0; j < s->n_cand; ++j)
            hs_compliance_block(c, s->node[i], s->node[j], s->c[i][j]);
    }
    hs_contact_snapshot_add_tris(s, m);
}

// The worst size (as hapsim-bench haptic's "contact solve alone"): for each of two tools 30 mm
// apart, 16 nodes on a cap 8 mm from its centre, inside its 10 mm sphere, all in contact; a
// diagonal-dominant compliance whose blocks couple every node, across the tools too.
static void cap_snapshot(hs_contact_snapshot* s, double* tool) {
    memset(s, 0, sizeof *s);
    s->version = 1;
    s->probe_radius_m = 0.01;
    const double t[6] = {0, 0, 0, 0.03, 0, 0};
    memcpy(tool, t, sizeof t);
    memcpy(s->tool_centre_m[1], tool + 3, sizeof s->tool_centre_m[1]);
    s->reach_m = s->tool_reach_m[1] = 0.05;
    s->n_cand = 2 * HS_MAX_CONTACT;
    for (int i = 0; i < s->n_cand; ++i) {
        const int k = i % HS_MAX_CONTACT, own = i / HS_MAX_CONTACT;
        double th = 0.5 * (k + 1) / HS_MAX_CONTACT, ph = 2.4 * k;
        s->node[i] = i;
        s->coupled[i] = 1;
        s->surf_m[i][0] = tool[3 * own] + 0.008 * sin(th) * cos(ph);
        s->surf_m[i][1] = 0.008 * sin(th) * sin(ph);
        s->surf_m[i][2] = -0.008 * cos(th);
        s->normal[i][2] = 1;
        for (int j = 0; j < s->n_cand; ++j) {
            const int same = own == j / HS_MAX_CONTACT;
            for (int p = 0; p < 3; ++p)
                s->c[i][j][4 * p] = i == j ? 1e-2 : (same ? 1e-3 : 2e-4) / (1 + abs(i - j)); // m/N
        }
    }
}

// n_tools tools (1 or 2) circling 0.1 mm about their presses for `ticks` ticks, warm-started
// from the previous tick: one CSV row.
static void time_ticks(const char* name, const hs_contact_snapshot* s, const double* tool,
                       int n_tools, int ticks, hs_contact_work* w) {
    double* us = malloc(sizeof(double) * (size_t)ticks);
    double* cpu = malloc(sizeof(double) * (size_t)ticks);
    hs_contact prev[2], cur[2];
    double p[6];
    memcpy(p, tool, sizeof p);
    hs_contact_solve_tools(s, n_tools, p, NULL, w, prev);
    int nodes[2] = {0, 0};
    for (int k = 0; k < ticks; ++k) {
        for (int t = 0; t < n_tools; ++t) {
            p[3 * t] = tool[3 * t] + 1e-4 * sin(k * 0.01 + t);
            p[3 * t + 1] = tool[3 * t + 1] + 1e-4 * cos(k * 0.013 + t);
        }
        int64_t c0 = cpu_ns(), t0 = hs_now_ns();
        hs_contact_solve_tools(s, n_tools, p, prev, w, cur);
        us[k] = (double)(hs_now_ns() - t0) * 1e-3;
        cpu[k] = (double)(cpu_ns() - c0) * 1e-3;
        memcpy(prev, cur, sizeof cur);
        for (int t = 0; t < n_tools; ++t) nodes[t] = cur[t].n > nodes[t] ? cur[t].n : nodes[t];
    }
    double mx = 0;
    for (int k = 0; k < ticks; ++k) mx = fmax(mx, us[k]);
    printf("%s,%d,%d,%d,%d,%.2f,%.2f,%.2f,%.2f,%.2f\n", name, n_tools, nodes[0],
           n_tools > 1 ? nodes[1] : 0, s->n_cand, hs_bench_percentile(us, (size_t)ticks, 50),
           hs_bench_percentile(us, (size_t)ticks, 99), mx,
           hs_bench_percentile(cpu, (size_t)ticks, 50),
           hs_bench_percentile(cpu, (size_t)ticks, 99));
    fflush(stdout);
    free(us);
    free(cpu);
}

int hs_bench_tools(const hs_bench_args* a) {
    hs_err err = {0};
    hs_mesh* m = NULL;
    if (hs_mesh_create_box(0.08, 0.04, TOP_M, 32, 16, 8, &m, &err) != HS_OK) {
        fprintf(stderr, "hapsim-bench tools: %s\n", err.msg);
        return 1;
    }
    unsigned char* fixed = calloc((size_t)m->n_nodes, 1);
    hs_mesh_select_plane(m, 2, -1, 1e-9, fixed);
    hs_fem_def fd = hs_fem_default_def();
    fd.model = HS_MODEL_LINEAR;
    fd.material.youngs_pa = 5000;
    fd.material.poisson = 0.45;
    hs_compliance* c = NULL;
    hs_contact_work* w = NULL;
    int rc = 1;
    if (hs_compliance_create(m, &fd, fixed, 2 * HS_CONTACT_MAX_CAND, &c, &err) != HS_OK ||
        hs_contact_work_create(2, &w) != HS_OK) {
        fprintf(stderr, "hapsim-bench tools: %s\n", err.msg);
        goto done;
    }
    // Two 10 mm spheres 40 mm apart, each pressed 3.5 mm: the contact a real block gives (a
    // soft block dimples around the pushed nodes: fewer nodes touch than penetrate); the cap16
    // case below has the cap's 16 contact nodes per tool.
    static hs_contact_snapshot s;
    const double r = 0.01, z = TOP_M + r - 0.0035;
    double tool[6] = {0.020, 0.020, z, 0.060, 0.020, z};
    two_tool_snapshot(c, m, tool, r, &s);
    const int ticks = a->quick ? 2000 : 20000;
    printf("case,tools,contact_nodes_tool0,contact_nodes_tool1,candidates,tick_us_p50,"
           "tick_us_p99,tick_us_max,cpu_us_p50,cpu_us_p99\n");
    time_ticks("block-2.5mm", &s, tool, 1, ticks, w);
    time_ticks("block-2.5mm", &s, tool, 2, ticks, w);
    cap_snapshot(&s, tool);
    time_ticks("cap16", &s, tool, 1, ticks, w);
    time_ticks("cap16", &s, tool, 2, ticks, w);
    rc = 0;
done:
    hs_contact_work_destroy(&w);
    hs_compliance_destroy(&c);
    free(fixed);
    hs_mesh_destroy(&m);
    return rc;
}
