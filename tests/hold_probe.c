// SPDX-License-Identifier: GPL-2.0-or-later
// hold_probe: press the default liver (scenes/liver/liver.json: material, fixed face, no
// gravity) at one surface node along its normal in 0.5 s, hold, and report how the felt force
// settles against the full static reaction, for the linear and the co-rotated model. A
// measurement tool (docs/haptics.md), not a test:
//   hold_probe NODE RADIUS_M DEPTH_M [HOLD_MS [FREE_RELAX]]
// e.g. `build/bin/hold_probe 399 0.005 0.005` is the scene's scripted press.
#define _POSIX_C_SOURCE 200809L
#include "body.h"
#include "haptic_sim.h"
#include "liver_haptic.h"
#include "mesh.h"
#include "spsc_ring.h"
#include "haptic_rt.h"

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

static double norm3(const double* v) {
    return sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2]);
}

// One hold with `model`; prints a line, returns 0 or 1 (could not run).
static int hold(const hs_mesh* m, const unsigned char* fixed, hs_model model, int node, double r,
                double depth, int hold_ms, double free_relax) {
    hs_haptic_sim_def d = hs_liver_haptic_def(model, r);
    if (free_relax > 0) d.probe.free_relax = free_relax;
    hs_err err = {0};
    hs_haptic_sim* sim = NULL;
    if (hs_haptic_sim_create(m, &d, fixed, &sim, &err) != HS_OK ||
        hs_haptic_sim_start(sim, &err) != HS_OK) {
        fprintf(stderr, "hold_probe: %s\n", err.msg);
        hs_haptic_sim_destroy(&sim);
        return 1;
    }
    double n[3];
    hs_mesh_rest_normal(m, node, n); // a surface node: checked in main
    const double* x = m->x0 + 3 * node;
    struct timespec next;
    clock_gettime(CLOCK_MONOTONIC, &next);
    hs_haptic_output out;
    memset(&out, 0, sizeof out);
    hs_haptic_pose pose;
    memset(&pose, 0, sizeof pose);
    pose.quat_wxyz[0] = 1;
    double f_lo = INFINITY, f_hi = 0;
    const int total = 500 + hold_ms;
    for (int i = 0; i < total; ++i) {
        double dd = i < 500 ? -0.005 + (depth + 0.005) * i / 500.0 : depth;
        for (int a = 0; a < 3; ++a) pose.pos_m[a] = x[a] + (r - dd) * n[a];
        pose.seq++;
        pose.stamp_ns = hs_now_ns();
        hs_haptic_sim_feed_pose(sim, &pose);
        next.tv_nsec += 1000000;
        if (next.tv_nsec >= 1000000000L) {
            next.tv_nsec -= 1000000000L;
            next.tv_sec++;
        }
        clock_nanosleep(CLOCK_MONOTONIC, TIMER_ABSTIME, &next, NULL);
        hs_haptic_sim_take_output(sim, &out);
        if (i >= total - 500) {
            double f = norm3(out.force_n);
            f_lo = f_lo < f ? f_lo : f;
            f_hi = f_hi > f ? f_hi : f;
        }
        hs_haptic_telemetry t;
        while (hs_spsc_ring_pop(hs_haptic_sim_telemetry(sim), &t)) {
        }
    }
    hs_haptic_sim_stats st;
    hs_haptic_sim_stats_get(sim, &st);
    double* u = malloc(sizeof(double) * 3 * (size_t)m->n_nodes);
    unsigned char* fx = malloc((size_t)m->n_nodes);
    hs_haptic_sim_read_frame(sim, u, NULL);
    hs_haptic_sim_stop(sim);

    // The full static reaction with the contact nodes held where the sim left them.
    hs_body_def bd = d.body;
    bd.static_load_steps = 3;
    hs_body* b = NULL;
    double sum[3] = {0, 0, 0}, umax = 0;
    hs_status solved = u && fx ? HS_OK : HS_ERR_NOMEM; // the first failure, for the message
    if (solved == HS_OK) {
        memcpy(fx, fixed, (size_t)m->n_nodes);
        for (int i = 0; i < st.contact.n; ++i) fx[st.contact.node[i]] = 1;
        solved = hs_body_create(m, &bd, fx, &b, &err);
    }
    for (int i = 0; solved == HS_OK && i < st.contact.n; ++i)
        solved = hs_body_set_prescribed(b, st.contact.node[i], u + 3 * st.contact.node[i]);
    if (solved == HS_OK) solved = hs_body_solve_static(b, NULL);
    int ok = solved >= 0;
    for (int i = 0; ok && i < st.contact.n; ++i) {
        double rr[3];
        hs_body_reaction(b, st.contact.node[i], rr);
        for (int a = 0; a < 3; ++a) sum[a] += rr[a];
        umax = fmax(umax, norm3(u + 3 * st.contact.node[i]));
    }
    if (!ok) {
        fprintf(stderr, "hold_probe: the static reference failed (status %d)%s%s\n", (int)solved,
                err.msg[0] ? ": " : "", err.msg);
        hs_body_destroy(&b);
        free(fx);
        free(u);
        hs_haptic_sim_destroy(&sim);
        return 1;
    }
    printf("%-10s |F| %.4f N, last 0.5 s range %.4f N; %d contact nodes (largest |u| %.2f mm), "
           "full static reaction %.4f N; relaxation w %.3g (%lld cuts), %lld steps\n",
           model == HS_MODEL_LINEAR ? "linear" : "corotated", norm3(out.force_n), f_hi - f_lo,
           st.contact.n, umax * 1e3, norm3(sum), st.free_relax_w, (long long)st.free_relax_cuts,
           (long long)st.steps);
    if (solved == HS_WARN_NOT_CONVERGED)
        printf("           (the static reference did not converge)\n");
    hs_body_destroy(&b);
    free(fx);
    free(u);
    hs_haptic_sim_destroy(&sim);
    return 0;
}

// A whole argument as a finite number.
static int number(const char* s, double* out) {
    char* end = NULL;
    *out = strtod(s, &end);
    return end != s && *end == 0 && isfinite(*out);
}

int main(int argc, char** argv) {
    if (argc < 4) {
        fprintf(stderr, "usage: hold_probe NODE RADIUS_M DEPTH_M [HOLD_MS [FREE_RELAX]]\n");
        return 2;
    }
    double node_d = 0, r = 0, depth = 0, hold_d = 5000, free_relax = 0;
    if (!number(argv[1], &node_d) || !number(argv[2], &r) || !number(argv[3], &depth) ||
        (argc > 4 && !number(argv[4], &hold_d)) || (argc > 5 && !number(argv[5], &free_relax)) ||
        node_d < 0 || node_d > 1e8 || hold_d < 0 || hold_d > 600000 || node_d != floor(node_d) ||
        hold_d != floor(hold_d) || fabs(depth) > 0.1 || free_relax < 0 || free_relax > 1) {
        fprintf(stderr, "hold_probe: NODE and HOLD_MS are integers, |DEPTH_M| <= 0.1, HOLD_MS "
                        "<= 600000, FREE_RELAX in [0, 1] (0: the default)\n");
        return 2;
    }
    int node = (int)node_d, hold_ms = (int)hold_d;
    hs_err err = {0};
    hs_mesh* m = NULL;
    if (hs_mesh_load(HS_SOURCE_DIR "/scenes/liver/liver2.msh", &m, &err) < 0) {
        fprintf(stderr, "hold_probe: %s\n", err.msg);
        return 1;
    }
    unsigned char* fixed = calloc((size_t)m->n_nodes, 1);
    if (!fixed) {
        hs_mesh_destroy(&m);
        return 1;
    }
    hs_mesh_select_plane(m, 1, -1, 0.010, fixed); // as scenes/liver/liver.json
    int on_surface = 0;
    for (int s = 0; s < m->n_surf_nodes; ++s) on_surface |= m->surf_nodes[s] == node;
    if (!on_surface || fixed[node] || !(r > 0) || r > 0.1 || hold_ms < 500) {
        fprintf(stderr,
                "hold_probe: NODE must be a free surface node of liver2 (0..%d), "
                "RADIUS_M in (0, 0.1], HOLD_MS >= 500\n",
                m->n_nodes - 1);
        free(fixed);
        hs_mesh_destroy(&m);
        return 2;
    }
    const double* x = m->x0 + 3 * node;
    printf("node %d at (%.1f, %.1f, %.1f) mm, sphere r %.1f mm pressed %.1f mm deep, held %d ms\n",
           node, x[0] * 1e3, x[1] * 1e3, x[2] * 1e3, r * 1e3, depth * 1e3, hold_ms);
    int rc = hold(m, fixed, HS_MODEL_LINEAR, node, r, depth, hold_ms, free_relax) ||
             hold(m, fixed, HS_MODEL_COROTATED, node, r, depth, hold_ms, free_relax);
    free(fixed);
    hs_mesh_destroy(&m);
    return rc;
}
