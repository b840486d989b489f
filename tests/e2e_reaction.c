// SPDX-License-Identifier: GPL-2.0-or-later
// Reference for the end-to-end press test (tests/test_e2e_stylus.sh): the static FEM reaction of
// a scene's tissue for the probe held at one position.
//
//   e2e_reaction SCENE X Y Z NX NY NZ [HOLD_S]
//
// The contact set is found the way the server finds it: the library's in-process haptic
// simulation (hs_haptic_sim, built from the scene exactly as hapsim-server builds it) is driven
// from 10 mm outside along (NX, NY, NZ) to (X, Y, Z) over 1 s and held HOLD_S (default 3) s.
// Then a full static solve of the scene's model (hs_body, co-rotated for the liver) with the
// final contact nodes prescribed at the body's own final displacement gives the reactions;
// minus their sum is the static force on the tool. Printed as key=value lines:
//   contact_nodes=N  sim_force=FX,FY,FZ  reaction_force=FX,FY,FZ  reaction_norm=F
#define _POSIX_C_SOURCE 200809L
#include "body.h"
#include "haptic_sim.h"
#include "mesh.h"
#include "scene.h"

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

static double norm3(const double v[3]) {
    return sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2]);
}

static int parse_num(const char* s, double* out) {
    char* end = NULL;
    *out = strtod(s, &end);
    return end != s && *end == '\0' && isfinite(*out);
}

// The scene's fixed regions, selected as hapsim-server selects them (docs/scenes.md).
static void fixed_mask(const hs_scene* sc, const hs_mesh* m, unsigned char* fixed,
                       unsigned char* sel) {
    memset(fixed, 0, (size_t)m->n_nodes);
    for (int r = 0; r < sc->n_fixed; ++r) {
        const hs_scene_fixed* f = &sc->fixed[r];
        memset(sel, 0, (size_t)m->n_nodes);
        if (f->kind == HS_FIXED_PLANE) {
            double l = norm3(f->normal);
            for (int i = 0; i < m->n_nodes; ++i) {
                const double* x = m->x0 + 3 * i;
                double d =
                    ((x[0] - f->point[0]) * f->normal[0] + (x[1] - f->point[1]) * f->normal[1] +
                     (x[2] - f->point[2]) * f->normal[2]) /
                    l;
                sel[i] = d <= f->tolerance;
            }
        } else if (f->kind == HS_FIXED_BOX) {
            hs_mesh_select_box(m, f->min, f->max, sel);
        } else {
            hs_mesh_select_plane(m, f->axis, f->side, f->depth, sel);
        }
        for (int i = 0; i < m->n_nodes; ++i) fixed[i] |= sel[i] && m->node_used[i];
    }
}

static void sleep_until(int64_t t_ns) {
    struct timespec ts = {(time_t)(t_ns / 1000000000), (long)(t_ns % 1000000000)};
    while (clock_nanosleep(CLOCK_MONOTONIC, TIMER_ABSTIME, &ts, NULL) != 0) {
    }
}

int main(int argc, char** argv) {
    if (argc != 8 && argc != 9) {
        fprintf(stderr, "usage: %s SCENE X Y Z NX NY NZ [HOLD_S]\n", argv[0]);
        return 2;
    }
    double p[3], n[3], hold_s = 3.0;
    for (int a = 0; a < 3; ++a)
        if (!parse_num(argv[2 + a], &p[a]) || !parse_num(argv[5 + a], &n[a])) {
            fprintf(stderr, "%s: positions and normal must be finite numbers\n", argv[0]);
            return 2;
        }
    if (argc == 9 && (!parse_num(argv[8], &hold_s) || hold_s <= 0 || hold_s > 30)) {
        fprintf(stderr, "%s: HOLD_S must be in (0, 30]\n", argv[0]);
        return 2;
    }
    double ln = norm3(n);
    if (ln == 0) {
        fprintf(stderr, "%s: zero normal\n", argv[0]);
        return 2;
    }
    for (int a = 0; a < 3; ++a) n[a] /= ln;

    hs_err err = {0};
    hs_scene sc;
    if (hs_scene_load(argv[1], &sc, &err) != HS_OK) {
        fprintf(stderr, "%s\n", err.msg);
        return 1;
    }
    hs_mesh* mesh = NULL;
    if (hs_mesh_load(sc.mesh_path, &mesh, &err) < 0) {
        fprintf(stderr, "%s\n", err.msg);
        return 1;
    }
    if (sc.units_scale != 1.0) {
        for (int i = 0; i < 3 * mesh->n_nodes; ++i) mesh->x0[i] *= sc.units_scale;
        if (hs_mesh_finalize(mesh, &err) < 0) {
            fprintf(stderr, "%s\n", err.msg);
            return 1;
        }
    }
    int nn = mesh->n_nodes;
    unsigned char* fixed = calloc((size_t)nn, 1);
    unsigned char* sel = calloc((size_t)nn, 1);
    double* u = calloc(3 * (size_t)nn, sizeof(double));
    if (!fixed || !sel || !u) return 1;
    fixed_mask(&sc, mesh, fixed, sel);

    // The sim exactly as the daemon configures it (server/daemon/server.c), minus real-time.
    hs_haptic_sim_def d = hs_haptic_sim_default_def();
    d.body.fem.model = sc.model;
    d.body.fem.material = sc.material;
    d.body.fem.rotation = sc.rotation;
    d.body.fem.inversion = sc.inversion;
    d.body.fem.locking_free = sc.locking_free;
    memcpy(d.body.gravity, sc.gravity, sizeof d.body.gravity);
    d.body.dt = 1.0 / sc.sim_hz;
    for (int t = 0; t < sc.n_tools; ++t)
        if (sc.tools[t].kind == HS_TOOL_PROBE) {
            d.probe.radius_m = sc.tools[t].radius;
            break;
        }
    d.safety.max_force_n = sc.force_max_n;
    d.safety.max_rate_n_s = sc.force_rate_max;
    d.safety.watchdog_timeout_s = sc.watchdog_s;
    d.rate_hz = sc.haptic_hz;
    d.fifo_priority = 0;
    d.lock_memory = 0;

    hs_haptic_sim* sim = NULL;
    if (hs_haptic_sim_create(mesh, &d, fixed, &sim, &err) != HS_OK ||
        hs_haptic_sim_start(sim, &err) != HS_OK) {
        fprintf(stderr, "%s\n", err.msg);
        return 1;
    }
    // 1 s approach from 10 mm out along n, then hold; poses at 1 kHz.
    const int64_t period = 1000000;
    int64_t t0 = hs_now_ns(), seq = 0;
    int ticks = 1000 + (int)(hold_s * 1000);
    hs_haptic_output out;
    memset(&out, 0, sizeof out);
    for (int k = 0; k < ticks; ++k) {
        double s = k < 1000 ? 1.0 - k / 1000.0 : 0.0;
        hs_haptic_pose pose;
        memset(&pose, 0, sizeof pose);
        pose.seq = ++seq;
        pose.stamp_ns = hs_now_ns();
        for (int a = 0; a < 3; ++a) pose.pos_m[a] = p[a] + 0.010 * s * n[a];
        pose.quat_wxyz[0] = 1;
        hs_haptic_sim_feed_pose(sim, &pose);
        hs_haptic_sim_take_output(sim, &out);
        sleep_until(t0 + (k + 1) * period);
    }
    hs_haptic_sim_take_output(sim, &out);
    hs_haptic_sim_stats st;
    hs_haptic_sim_stats_get(sim, &st);
    hs_haptic_sim_stop(sim);
    memcpy(u, hs_body_displacement(hs_haptic_sim_body(sim)), 3 * (size_t)nn * sizeof(double));
    hs_haptic_sim_destroy(&sim);
    if (st.contact.n < 1) {
        fprintf(stderr, "e2e_reaction: no contact at (%g, %g, %g)\n", p[0], p[1], p[2]);
        printf("contact_nodes=0\n");
        return 3;
    }

    // Full static solve with the contact nodes prescribed at the body's own displacement.
    for (int i = 0; i < st.contact.n; ++i) fixed[st.contact.node[i]] = 1;
    hs_body* b = NULL;
    if (hs_body_create(mesh, &d.body, fixed, &b, &err) != HS_OK) {
        fprintf(stderr, "%s\n", err.msg);
        return 1;
    }
    for (int i = 0; i < st.contact.n; ++i)
        if (hs_body_set_prescribed(b, st.contact.node[i], u + 3 * st.contact.node[i]) != HS_OK)
            return 1;
    hs_step_stats ss;
    if (hs_body_solve_static(b, &ss) < 0) {
        fprintf(stderr, "e2e_reaction: static solve failed\n");
        return 1;
    }
    double r[3] = {0, 0, 0};
    for (int i = 0; i < st.contact.n; ++i) {
        double rr[3];
        hs_body_reaction(b, st.contact.node[i], rr);
        for (int a = 0; a < 3; ++a) r[a] -= rr[a]; // reaction on the tissue -> force on the tool
    }
    printf("contact_nodes=%d\n", st.contact.n);
    printf("contact_node_ids=");
    for (int i = 0; i < st.contact.n; ++i) printf(i ? ",%d" : "%d", st.contact.node[i]);
    printf("\nsim_force=%.9g,%.9g,%.9g\n", out.force_n[0], out.force_n[1], out.force_n[2]);
    printf("sim_force_norm=%.9g\n", norm3(out.force_n));
    printf("reaction_force=%.9g,%.9g,%.9g\n", r[0], r[1], r[2]);
    printf("reaction_norm=%.9g\n", norm3(r));
    printf("static_iterations=%d\n", ss.iterations);
    hs_body_destroy(&b);
    hs_mesh_destroy(&mesh);
    free(fixed);
    free(sel);
    free(u);
    return 0;
}
