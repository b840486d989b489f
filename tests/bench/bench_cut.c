// SPDX-License-Identifier: GPL-2.0-or-later
// hapsim-bench cut: the server's own cutting path. An hs_haptic_sim set up as hapsim-server sets
// it up for scenes/skin/skin.json (hs_scene_sim_def; cutting on, the released scalpel probes),
// driven by poses at 1 kHz: blade strokes with button 0 held, each followed by the same tool,
// released, pressing beside the cut (the sim drives one tool: there is no second device to probe
// with while the blade cuts). Per cut step: the step on the deformation thread (sweep + body
// update + compliance update + topology hand-over, stats cut_ms_last), and the time from the
// step's start until the compliance the rt thread uses is valid for that topology (the step
// itself when the compliance followed it, hs_compliance_change_elements; plus stats
// comp_swap_ns - cut_done_ns when it had to be rebuilt on a worker after the release). Over the
// run: the largest change between consecutive rt forces.
#define _POSIX_C_SOURCE 200809L
#include "bench.h"

#include "spsc_ring.h"
#include "haptic_sim.h"
#include "scene.h"
#include "haptic_rt.h"
#include "scene_sim.h"

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

enum { CUT_PLATE = 0, CUT_SKIN = 1, CUT_ORGAN = 2 };

typedef struct cut_case {
    const char* name;
    const char* file; // shared mesh (CUT_ORGAN); the skin comes from its scene
    int kind;
    int strokes;       // full run
    int quick_strokes; // --quick (0: not in --quick)
} cut_case;

#define MAX_CUTS 4096

typedef struct cut_run {
    hs_haptic_sim* sim;
    int64_t seq;
    double last_f[3];
    int have_last;
    double max_jump_n;
    int64_t cuts_seen, comp_seen;
    int n_cuts, n_valid, missed;
    double cut_ms[MAX_CUTS], sweep_ms[MAX_CUTS], valid_ms[MAX_CUTS];
    int64_t cut_ver[MAX_CUTS], cut_ns[MAX_CUTS];
    int64_t comp_version, cut_version;
    double rebuild_ms[MAX_CUTS]; // each swapped-in rebuild's own time (stats comp_ms_last)
    int n_rebuilds;
    double update_ms[MAX_CUTS]; // each followed step's compliance update (stats comp_ms_last)
    int n_updates;
    int64_t updates_seen;
    double probe_n[MAX_CUTS]; // per stroke: force felt at the end of the press beside the cut
    int n_probes;
} cut_run;

// One millisecond: feed the pose, drain the rt telemetry (tick jumps), note new cut steps and
// compliance swaps.
static void tick(cut_run* r, const double p[3], int button) {
    hs_haptic_pose pose;
    memset(&pose, 0, sizeof pose);
    pose.seq = ++r->seq;
    pose.stamp_ns = hs_now_ns();
    pose.quat_wxyz[0] = 1;
    pose.buttons = button ? 1u : 0u;
    memcpy(pose.pos_m, p, sizeof pose.pos_m);
    hs_haptic_sim_feed_pose(r->sim, &pose);
    hs_haptic_telemetry t;
    while (hs_spsc_ring_pop(hs_haptic_sim_telemetry(r->sim), &t)) {
        if (r->have_last) {
            double d = 0;
            for (int c = 0; c < 3; ++c) d += pow(t.force_n[c] - r->last_f[c], 2);
            if (sqrt(d) > r->max_jump_n) r->max_jump_n = sqrt(d);
        }
        memcpy(r->last_f, t.force_n, sizeof r->last_f);
        r->have_last = 1;
    }
    hs_haptic_sim_stats st;
    hs_haptic_sim_stats_get(r->sim, &st);
    if (st.cut_steps != r->cuts_seen) {
        r->missed += (int)(st.cut_steps - r->cuts_seen - 1); // more than one since the last ms
        r->cuts_seen = st.cut_steps;
        if (r->n_cuts < MAX_CUTS) {
            r->cut_ms[r->n_cuts] = st.cut_ms_last;
            r->sweep_ms[r->n_cuts] = st.sweep_ms_last;
            r->cut_ver[r->n_cuts] = st.topology_version;
            r->cut_ns[r->n_cuts] = st.cut_done_ns;
            r->valid_ms[r->n_cuts] = NAN;
            r->n_cuts++;
        }
        r->cut_version = st.topology_version;
    }
    if (st.comp_rebuilds != r->comp_seen || st.comp_updates != r->updates_seen) {
        if (st.comp_rebuilds != r->comp_seen && r->n_rebuilds < MAX_CUTS)
            r->rebuild_ms[r->n_rebuilds++] = st.comp_ms_last;
        else if (st.comp_updates != r->updates_seen && r->n_updates < MAX_CUTS)
            r->update_ms[r->n_updates++] = st.comp_ms_last;
        r->comp_seen = st.comp_rebuilds;
        r->updates_seen = st.comp_updates;
        r->comp_version = st.comp_version;
        for (int k = 0; k < r->n_cuts; ++k)
            if (isnan(r->valid_ms[k]) && r->cut_ver[k] <= st.comp_version) {
                r->valid_ms[k] = r->cut_ms[k] + (double)(st.comp_swap_ns - r->cut_ns[k]) * 1e-6;
                r->n_valid++;
            }
    }
}

// Move the tool point from a to b at speed m/s (at least one tick), button as given.
static void move(cut_run* r, struct timespec* clk, double a[3], const double b[3], double speed,
                 int button) {
    double d = sqrt(pow(b[0] - a[0], 2) + pow(b[1] - a[1], 2) + pow(b[2] - a[2], 2));
    int n = (int)ceil(d / speed * 1000);
    if (n < 1) n = 1;
    for (int i = 1; i <= n; ++i) {
        double p[3];
        for (int c = 0; c < 3; ++c) p[c] = a[c] + (b[c] - a[c]) * i / n;
        tick(r, p, button);
        hs_bench_next_ms(clk);
    }
    memcpy(a, b, 3 * sizeof(double));
}

// Hold the tool at p until the compliance matches the newest cut (then 300 ms more) or
// limit_s passed.
static void hold_until_valid(cut_run* r, struct timespec* clk, const double p[3], double limit_s) {
    int after = -1;
    for (int i = 0; i < (int)(limit_s * 1000) && after != 0; ++i) {
        tick(r, p, 0);
        hs_bench_next_ms(clk);
        if (after < 0 && r->comp_version >= r->cut_version) after = 300;
        if (after > 0) --after;
    }
    if (r->n_probes < MAX_CUTS)
        r->probe_n[r->n_probes++] = sqrt(r->last_f[0] * r->last_f[0] + r->last_f[1] * r->last_f[1] +
                                         r->last_f[2] * r->last_f[2]);
}

typedef struct cut_geometry {
    double x_cut, y0, y1, z_tool, z_above, probe_dx, probe_r;
} cut_geometry;

/// Tool height pressing the probe sphere (radius r) ~1 mm into the body at (x, y): the top of
/// the boundary straight below (x, y), + r - 1 mm. At rest, read before the sim runs (cuts move
/// x0).
static double probe_height(const hs_mesh* m, double x, double y, double r) {
    double top = m->bbox_max[2];
    int any = 0;
    for (int t = 0; t < m->n_tris; ++t) {
        const double* a = m->x0 + 3 * m->tris[3 * t];
        const double* b = m->x0 + 3 * m->tris[3 * t + 1];
        const double* c = m->x0 + 3 * m->tris[3 * t + 2];
        double det = (b[0] - a[0]) * (c[1] - a[1]) - (c[0] - a[0]) * (b[1] - a[1]);
        if (fabs(det) < 1e-18) continue; // a vertical face
        double u = ((x - a[0]) * (c[1] - a[1]) - (c[0] - a[0]) * (y - a[1])) / det;
        double v = ((b[0] - a[0]) * (y - a[1]) - (x - a[0]) * (b[1] - a[1])) / det;
        if (u < 0 || v < 0 || u + v > 1) continue;
        double z = a[2] + u * (b[2] - a[2]) + v * (c[2] - a[2]);
        if (!any || z > top) top = z;
        any = 1;
    }
    return top + r - 0.001;
}

/// The case's mesh, fixed nodes, blade (tool frame) and path. Returns 0 on success.
static int case_setup(const cut_case* cc, const hs_bench_args* args, const hs_scene* sc,
                      hs_mesh** m, unsigned char** fixed, hs_haptic_cut_def* cd, cut_geometry* g,
                      double probe_r) {
    hs_err e;
    hs_status s;
    char path[1024];
    if (cc->kind == CUT_SKIN)
        s = hs_mesh_load(sc->mesh_path, m, &e);
    else if (cc->kind == CUT_PLATE) // 200 x 200 x 10 mm, 40 x 40 x 2 cells: 5,043 vertices
        s = hs_mesh_create_box(0.2, 0.2, 0.01, 40, 40, 2, m, &e);
    else
        s = hs_mesh_load(hs_bench_mesh_path(args, cc->file, path, sizeof path), m, &e);
    if (s < 0) {
        fprintf(stderr, "bench cut: %s: %s\n", cc->name, e.msg);
        return 1;
    }
    const hs_mesh* mm = *m;
    *fixed = hs_calloc((size_t)mm->n_nodes, 1);
    if (!*fixed) return 1;
    const double *lo = mm->bbox_min, *hi = mm->bbox_max;
    const double cx = 0.5 * (lo[0] + hi[0]), ly = hi[1] - lo[1], lz = hi[2] - lo[2];
    if (cc->kind == CUT_SKIN) { // the scene's regions and its scalpel
        for (int k = 0; k < sc->n_fixed; ++k) {
            unsigned char* sel = hs_calloc((size_t)mm->n_nodes, 1);
            if (!sel || hs_scene_fixed_select(&sc->fixed[k], mm, sel, &e) != HS_OK) {
                hs_free(sel);
                return 1;
            }
            for (int i = 0; i < mm->n_nodes; ++i) (*fixed)[i] |= sel[i];
            hs_free(sel);
        }
        for (int t = 0; t < sc->n_tools; ++t)
            if (sc->tools[t].kind == HS_TOOL_SCALPEL) {
                memcpy(cd->blade_a, sc->tools[t].blade_a, sizeof cd->blade_a);
                memcpy(cd->blade_b, sc->tools[t].blade_b, sizeof cd->blade_b);
                break;
            }
        g->z_tool = lo[2] + 0.5 * lz;   // the scene's comment: tool point at z = 2 mm
    } else if (cc->kind == CUT_PLATE) { // held at both x ends, the blade spans the thickness
        hs_mesh_select_plane(mm, 0, -1, 1e-6, *fixed);
        unsigned char* far = hs_calloc((size_t)mm->n_nodes, 1);
        if (!far) return 1;
        hs_mesh_select_plane(mm, 0, +1, 1e-6, far);
        for (int i = 0; i < mm->n_nodes; ++i) (*fixed)[i] |= far[i];
        hs_free(far);
        cd->blade_a[2] = -(0.5 * lz + 0.003);
        cd->blade_b[2] = 0.5 * lz + 0.005;
        g->z_tool = lo[2] + 0.5 * lz;
    } else { // an organ held at its lowest fifth, cut from the top a third of its height deep
        hs_mesh_select_plane(mm, 2, -1, 0.2 * lz, *fixed);
        cd->blade_a[2] = -lz / 3;
        cd->blade_b[2] = 0.01;
        g->z_tool = hi[2];
    }
    g->x_cut = cx + 0.37e-3; // off the box's vertex planes
    g->y0 = lo[1] + 0.15 * ly;
    g->y1 = hi[1] - 0.15 * ly;
    g->z_above = hi[2] + cd->blade_b[2] - cd->blade_a[2] + 0.002; // whole blade above the body
    g->probe_dx = 2 * probe_r + 0.002;
    g->probe_r = probe_r;
    return 0;
}

static int cmp_d(const void* a, const void* b) {
    double x = *(const double*)a, y = *(const double*)b;
    return (x > y) - (x < y);
}

static double pct(const double* v, int n, double p) {
    double* s = malloc(sizeof(double) * (size_t)(n > 0 ? n : 1));
    int k = 0;
    for (int i = 0; i < n; ++i)
        if (!isnan(v[i])) s[k++] = v[i];
    qsort(s, (size_t)k, sizeof(double), cmp_d);
    double r = k > 0 ? hs_bench_percentile(s, (size_t)k, p) : NAN;
    free(s);
    return r;
}

static int run_case(const cut_case* cc, const hs_bench_args* args, const hs_scene* sc) {
    hs_haptic_sim_def d;
    hs_scene_sim_def(sc, 0, &d);
    hs_haptic_cut_def cd = hs_haptic_cut_default_def();
    cd.max_force_n = sc->force_max_n < cd.max_force_n ? sc->force_max_n : cd.max_force_n;
    cd.probe_when_released = 1; // the skin scene lists a probe
    cd.cut.fragment = sc->cut_free_pieces_fall ? HS_CUT_FRAGMENT_FIX : HS_CUT_FRAGMENT_DROP;
    hs_mesh* m = NULL;
    unsigned char* fixed = NULL;
    cut_geometry g;
    memset(&g, 0, sizeof g);
    hs_err e;
    int rc = case_setup(cc, args, sc, &m, &fixed, &cd, &g, d.probe.radius_m);
    const int strokes = args->quick ? cc->quick_strokes : cc->strokes;
    const double v_cut = 0.03, v_move = 0.1; // m/s: the blade, the hand between strokes
    const double stroke = (g.y1 - g.y0) / (cc->strokes > 0 ? cc->strokes : 1);
    double probe_z[64];
    for (int k = 0; k < strokes && k < 64 && !rc; ++k)
        probe_z[k] = probe_height(m, g.x_cut + g.probe_dx, g.y0 + (k + 0.5) * stroke, g.probe_r);
    cut_run* r = calloc(1, sizeof *r);
    int64_t t0 = hs_now_ns();
    if (!rc && (!r || hs_haptic_sim_create(m, &d, fixed, &r->sim, &e) != HS_OK ||
                hs_haptic_sim_enable_cutting(r->sim, m, &cd, &e) != HS_OK ||
                hs_haptic_sim_start(r->sim, &e) != HS_OK)) {
        fprintf(stderr, "bench cut: %s: %s\n", cc->name, e.msg);
        rc = 1;
    }
    double setup_ms = (double)(hs_now_ns() - t0) * 1e-6;
    if (!rc) {
        struct timespec clk;
        clock_gettime(CLOCK_MONOTONIC, &clk);
        double p[3] = {g.x_cut, g.y0, g.z_above}, b[3];
        for (int s = 0; s < strokes; ++s) {
            const double ys = g.y0 + s * stroke;
            b[0] = g.x_cut, b[1] = ys, b[2] = g.z_above; // above where the cut goes on
            move(r, &clk, p, b, v_move, 0);
            b[2] = g.z_tool; // down along the blade (no sweep area: nothing cut)
            move(r, &clk, p, b, v_move, 1);
            b[1] = ys + stroke; // the stroke, button held
            move(r, &clk, p, b, v_cut, 1);
            b[2] = g.z_above; // out along the blade, then released
            move(r, &clk, p, b, v_move, 1);
            b[0] = g.x_cut + g.probe_dx, b[1] = ys + 0.5 * stroke; // beside the cut, then press
            move(r, &clk, p, b, v_move, 0);
            b[2] = probe_z[s];
            move(r, &clk, p, b, 0.02, 0);
            hold_until_valid(r, &clk, p, 20.0);
            b[2] = g.z_above;
            move(r, &clk, p, b, 0.02, 0);
        }
        hs_haptic_sim_stats st;
        hs_haptic_sim_stats_get(r->sim, &st);
        hs_haptic_sim_stop(r->sim);
        fprintf(stderr,
                "cut: %s: %d strokes, %lld sweeps, %d cut steps (%d missed by the 1 ms poll), "
                "%lld tets removed; the sweep alone p50 %.2f ms, p99 %.2f ms; the compliance "
                "followed %lld steps (its update p50 %.2f ms, p99 %.2f ms, within the step); "
                "%lld compliance rebuilds (%lld dropped for a newer cut), "
                "each p50 %.0f ms, max %.0f ms on the worker; %d of the steps found valid; "
                "the press beside the cut felt p50 %.3f N, min %.3f N; watchdog trips %lld; set-up "
                "%.0f ms; cut failures %lld\n",
                cc->name, strokes, (long long)st.cut_sweeps, r->n_cuts, r->missed,
                (long long)st.cut_removed, pct(r->sweep_ms, r->n_cuts, 50),
                pct(r->sweep_ms, r->n_cuts, 99), (long long)st.comp_updates,
                pct(r->update_ms, r->n_updates, 50), pct(r->update_ms, r->n_updates, 99),
                (long long)st.comp_rebuilds, (long long)st.comp_discarded,
                pct(r->rebuild_ms, r->n_rebuilds, 50), pct(r->rebuild_ms, r->n_rebuilds, 100),
                r->n_valid, pct(r->probe_n, r->n_probes, 50), pct(r->probe_n, r->n_probes, 0),
                (long long)st.safety.watchdog_trips, setup_ms, (long long)st.cut_failures);
        printf("%s,%d,%d,%d,%lld,%.2f,%.2f,%.1f,%.1f,%.4f\n", cc->name, m->n_nodes, m->n_tets,
               r->n_cuts, (long long)st.cut_removed, pct(r->cut_ms, r->n_cuts, 50),
               pct(r->cut_ms, r->n_cuts, 99), pct(r->valid_ms, r->n_cuts, 50),
               pct(r->valid_ms, r->n_cuts, 99), r->max_jump_n);
        fflush(stdout);
        if (r->n_cuts == 0 || r->n_valid < r->n_cuts) rc = 1; // a step never felt: a failure
    }
    if (r) hs_haptic_sim_destroy(&r->sim);
    free(r);
    hs_free(fixed);
    hs_mesh_destroy(&m);
    return rc;
}

int hs_bench_cut(const hs_bench_args* a) {
    static const cut_case cases[] = {
        {"skin_patch", NULL, CUT_SKIN, 6, 3},
        {"plate5043", NULL, CUT_PLATE, 4, 0},
        {"tongue", "tongue.msh", CUT_ORGAN, 4, 0},
    };
    hs_scene sc;
    hs_err e;
    if (hs_scene_load(HS_SCENES_DIR "/skin/skin.json", &sc, &e) != HS_OK) {
        fprintf(stderr, "bench cut: %s\n", e.msg);
        return 1;
    }
    printf("mesh,vertices,tets,cut_steps,tets_removed,cut_step_ms_p50,cut_step_ms_p99,"
           "compliance_valid_ms_p50,compliance_valid_ms_p99,max_tick_jump_n\n");
    int rc = 0;
    for (size_t i = 0; i < sizeof cases / sizeof cases[0]; i++) {
        if (a->quick && !cases[i].quick_strokes) continue;
        rc |= run_case(&cases[i], a, &sc);
    }
    return rc;
}
