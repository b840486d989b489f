// SPDX-License-Identifier: GPL-2.0-or-later
// Cutting through the in-process haptic simulation (the path hapsim-server runs): a scalpel
// dragged across the skin patch by poses fed at 1 kHz, real deformation and rt threads.
// The LCM end to end is tests/test_cut_e2e.sh.
#define _POSIX_C_SOURCE 200809L
#include "cut_surface.h"
#include "haptic_rt.h"
#include "haptic_sim.h"
#include "test_macros.h"

#include <limits.h>
#include <stdlib.h>
#include <time.h>

static double norm3(const double v[3]) {
    return sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2]);
}

// The sim a case runs, so that a case failing half-way (ENSURE returns at once) does not leave
// its threads running, and allocating, under the next case's byte count.
static hs_haptic_sim* g_running;

static hs_status create_sim(const hs_mesh* m, const hs_haptic_sim_def* d,
                            const unsigned char* fixed, hs_haptic_sim** sim, hs_err* err) {
    hs_status s = hs_haptic_sim_create(m, d, fixed, sim, err);
    if (s == HS_OK) g_running = *sim;
    return s;
}

static void destroy_sim(hs_haptic_sim** sim) {
    if (*sim == g_running) g_running = NULL;
    hs_haptic_sim_destroy(sim);
}

// A case, then the sim it left running if it failed (its mesh must still exist: every case
// destroys its sim before its mesh).
#define GUARDED(fn)                                                                                \
    static int fn##_guarded(void) {                                                                \
        int rc = fn();                                                                             \
        if (g_running) {                                                                           \
            printf("  (stopped the sim the case left running)\n");                                 \
            hs_haptic_sim_destroy(&g_running);                                                     \
        }                                                                                          \
        return rc;                                                                                 \
    }

static hs_mesh* load_skin(void) {
    hs_mesh* m = NULL;
    hs_err e;
    if (hs_mesh_load(HS_SOURCE_DIR "/scenes/skin/skin_patch_synthetic.msh", &m, &e) < 0) {
        printf("  cannot load the skin patch: %s\n", e.msg);
        return NULL;
    }
    return m;
}

// Both x ends held (the cut runs between them).
static unsigned char* ends_fixed(const hs_mesh* m) {
    unsigned char* fixed = hs_calloc((size_t)m->n_nodes, 1);
    unsigned char* far = hs_calloc((size_t)m->n_nodes, 1);
    if (fixed && far) {
        hs_mesh_select_plane(m, 0, -1, 1e-6, fixed);
        hs_mesh_select_plane(m, 0, +1, 1e-6, far);
        for (int i = 0; i < m->n_nodes; ++i) fixed[i] |= far[i];
    }
    hs_free(far);
    return fixed;
}

// The skin patch and its held ends; 0 on success (the caller frees both).
static int skin_with_ends_fixed(hs_mesh** m, unsigned char** fixed) {
    *m = load_skin();
    *fixed = *m ? ends_fixed(*m) : NULL;
    return *m && *fixed ? 0 : 1;
}

static hs_haptic_sim_def sim_def(void) {
    hs_haptic_sim_def d = hs_haptic_sim_default_def();
    d.fifo_priority = 0;
    d.lock_memory = 0;
    d.body.dt = 1.0 / 60;
    return d;
}

// With the tool point at z = 2 mm the blade spans the 4 mm thickness, with room for sagging.
static hs_haptic_cut_def blade_def(void) {
    hs_haptic_cut_def cd = hs_haptic_cut_default_def();
    cd.blade_a[2] = -0.02;
    cd.blade_b[2] = 0.005;
    return cd;
}

// Create a sim on m with cutting on and start it; 0 on success (*sim is set either way).
static int start_cutting_sim(hs_mesh* m, const unsigned char* fixed, const hs_haptic_sim_def* d,
                             const hs_haptic_cut_def* cd, hs_haptic_sim** sim) {
    hs_err err = {0};
    *sim = NULL;
    if (create_sim(m, d, fixed, sim, &err) != HS_OK ||
        hs_haptic_sim_enable_cutting(*sim, m, cd, &err) != HS_OK ||
        hs_haptic_sim_start(*sim, &err) != HS_OK) {
        printf("  cutting sim: %s\n", err.msg);
        return 1;
    }
    return 0;
}

/// Bad definitions are refused with a message and leave the sim usable and leak-free.
static int test_enable_errors(void) {
    int64_t bytes = hs_byte_count();
    hs_mesh* m = load_skin();
    ENSURE(m);
    hs_mesh* other = load_skin();
    ENSURE(other);
    unsigned char* fixed = ends_fixed(m);
    ENSURE(fixed);
    hs_haptic_sim_def d = sim_def();
    hs_haptic_sim* sim = NULL;
    hs_err err = {0};
    ENSURE(create_sim(m, &d, fixed, &sim, &err) == HS_OK);
    hs_haptic_cut_def cd = hs_haptic_cut_default_def();
    ENSURE(hs_haptic_sim_enable_cutting(sim, m, NULL, &err) == HS_ERR_INVALID);
    hs_haptic_cut_def raw;
    memset(&raw, 0, sizeof raw);
    ENSURE(hs_haptic_sim_enable_cutting(sim, m, &raw, &err) == HS_ERR_INVALID);
    ENSURE(strstr(err.msg, "hs_haptic_cut_default_def"));
    ENSURE(hs_haptic_sim_enable_cutting(sim, other, &cd, &err) == HS_ERR_INVALID);
    ENSURE(strstr(err.msg, "not the mesh"));
    hs_haptic_cut_def flat = cd;
    memcpy(flat.blade_b, flat.blade_a, sizeof flat.blade_b);
    ENSURE(hs_haptic_sim_enable_cutting(sim, m, &flat, &err) == HS_ERR_INVALID);
    ENSURE(strstr(err.msg, "blade"));
    hs_haptic_cut_def neg = cd;
    neg.toughness_n_m = -1;
    ENSURE(hs_haptic_sim_enable_cutting(sim, m, &neg, &err) == HS_ERR_INVALID);
    hs_haptic_cut_def rule = cd;
    rule.cut.fragment = (hs_cut_fragment)7;
    ENSURE(hs_haptic_sim_enable_cutting(sim, m, &rule, &err) == HS_ERR_INVALID);
    ENSURE(strstr(err.msg, "cut.fragment 7"));
    ENSURE(hs_haptic_sim_topology_version(sim) == 0);
    ENSURE(hs_haptic_sim_enable_cutting(sim, m, &cd, &err) == HS_OK);
    ENSURE(hs_haptic_sim_enable_cutting(sim, m, &cd, &err) == HS_ERR_INVALID); // once only
    // Before any cut the shared topology is the mesh's own.
    double* x0 = hs_alloc(3 * (size_t)m->n_nodes * sizeof(double));
    int* tris = hs_alloc(3 * 4 * (size_t)m->n_tets * sizeof(int));
    ENSURE(x0 && tris);
    int nt = -1;
    ENSURE(hs_haptic_sim_take_topology(sim, x0, tris, 4 * m->n_tets, &nt, NULL) == 0);
    ENSURE(nt == m->n_tris);
    ENSURE(!memcmp(x0, m->x0, 3 * (size_t)m->n_nodes * sizeof(double)));
    hs_free(x0);
    hs_free(tris);
    destroy_sim(&sim);
    ENSURE(sim == NULL);
    hs_free(fixed);
    hs_mesh_destroy(&m);
    hs_mesh_destroy(&other);
    ENSURE(hs_byte_count() == bytes);
    return 0;
}

static void sleep_until(struct timespec* t, long ns) {
    t->tv_nsec += ns;
    while (t->tv_nsec >= 1000000000L) {
        t->tv_nsec -= 1000000000L;
        t->tv_sec++;
    }
    clock_nanosleep(CLOCK_MONOTONIC, TIMER_ABSTIME, t, NULL);
}

// Feed the next pose (at, buttons) to sim as a device would, then wait for the next ms from t.
static void feed_ms(hs_haptic_sim* sim, hs_haptic_pose* pose, struct timespec* t,
                    const double at[3], unsigned buttons) {
    pose->seq++;
    pose->stamp_ns = hs_now_ns();
    memcpy(pose->pos_m, at, sizeof pose->pos_m);
    pose->buttons = buttons;
    hs_haptic_sim_feed_pose(sim, pose);
    sleep_until(t, 1000000);
}

static int cmp_tri(const void* pa, const void* pb) {
    const int *a = pa, *b = pb;
    for (int k = 0; k < 3; ++k)
        if (a[k] != b[k]) return a[k] < b[k] ? -1 : 1;
    return 0;
}

// Triangles rotated to start at their smallest node (orientation kept), then sorted.
static void canonical_tris(const int* in, int n, int* out) {
    for (int t = 0; t < n; ++t) {
        const int* v = in + 3 * t;
        int s = v[0] < v[1] ? (v[0] < v[2] ? 0 : 2) : (v[1] < v[2] ? 1 : 2);
        for (int k = 0; k < 3; ++k) out[3 * t + k] = v[(s + k) % 3];
    }
    qsort(out, (size_t)n, 3 * sizeof(int), cmp_tri);
}

// The status says the loop has taken the blade's release: no cutting force left.
static int released(const hs_haptic_sim_stats* st) {
    const double* f = st->cut_force_n;
    return f[0] == 0 && f[1] == 0 && f[2] == 0;
}

/// The blade dragged across the patch with the button held, then released: topology versions
/// grow, events list each removed tet once, the shared surface and rest positions are the
/// mesh's, the force is finite, shows resistance, changes by at most the cap over one blend
/// per tick, and returns to zero after the release; the compliance follows every cut step and
/// equals one built afresh on the cut mesh.
static int test_blade_drag(void) {
    int64_t bytes = hs_byte_count();
    hs_mesh* m = NULL;
    unsigned char* fixed = NULL;
    ENSURE(skin_with_ends_fixed(&m, &fixed) == 0);
    const int n = m->n_nodes, ntet = m->n_tets;
    hs_haptic_sim_def d = sim_def();
    hs_haptic_cut_def cd = blade_def();
    hs_haptic_sim* sim = NULL;
    hs_err err = {0};
    ENSURE(start_cutting_sim(m, fixed, &d, &cd, &sim) == 0);

    double* x0 = hs_alloc(3 * (size_t)n * sizeof(double));
    int* tris = hs_alloc(3 * 4 * (size_t)ntet * sizeof(int));
    int* removed = hs_alloc((size_t)ntet * sizeof(int));
    int* moved = hs_alloc((size_t)n * sizeof(int));
    unsigned char* gone = hs_calloc((size_t)ntet, 1);
    ENSURE(x0 && tris && removed && moved && gone);

    const double speed = 0.04, y0 = -0.05, y1 = 0.05;
    // Across the patch (y0 -> y1 at x = 1 mm), released until the loop has taken the release
    // (at least 10 ticks; the compliance followed every cut step, so it is valid by then), then
    // a second, partial cut back in from the y1 side at x = 21 mm, then released for good.
    const int drag_ticks = (int)((y1 - y0) / speed * 1000), min_gap = 10, max_gap = 5000;
    const int drag2 = 600, rest_ticks = 600;
    int gap_end = -1, end2 = INT_MAX - rest_ticks; // known once the rebuild has started
    // After the second release: once the loop has taken it (the status shows no cutting force)
    // and rt has blended that snapshot in, the blade must feel nothing. Bounded: 20 s.
    int release_k = -1, loop_end = INT_MAX, after_n = 0;
    const double y2 = 0.0405; // the second cut enters the patch (y <= 40 mm) after ~12 ms
    struct timespec t;
    clock_gettime(CLOCK_MONOTONIC, &t);
    hs_haptic_pose pose;
    memset(&pose, 0, sizeof pose);
    pose.quat_wxyz[0] = 1;
    double prev[3] = {0, 0, 0}, peak = 0, max_step = 0, after_release = 0;
    int64_t version = 0, events = 0, removed_total = 0;
    int have_prev = 0, bad_event = 0, step_pairs = 0;
    int64_t prev_seq = 0;
    for (int k = 0; k < loop_end; ++k) {
        if (gap_end < 0 && k >= drag_ticks + min_gap) {
            hs_haptic_sim_stats bs;
            hs_haptic_sim_stats_get(sim, &bs);
            if (bs.comp_version == bs.topology_version || k >= drag_ticks + max_gap) {
                gap_end = k;
                end2 = gap_end + drag2;
                loop_end = end2 + 20000;
            }
        }
        int second = gap_end >= 0 && k >= gap_end && k < end2;
        int cutting = k < drag_ticks || second;
        double y = k < drag_ticks ? y0 + speed * k * 1e-3
                   : second       ? y2 - speed * (k - gap_end) * 1e-3
                   : k < end2     ? y1
                                  : y2 - speed * drag2 * 1e-3;
        pose.seq++;
        pose.stamp_ns = hs_now_ns();
        pose.pos_m[0] = second || k >= end2 ? 0.021 : 0.001; // off the 2 mm grid lines
        pose.pos_m[1] = y;
        pose.pos_m[2] = 0.002;
        pose.buttons = cutting ? 1u : 0u;
        hs_haptic_sim_feed_pose(sim, &pose);
        sleep_until(&t, 1000000);
        // Force steps from the telemetry (every rt tick): the newest output alone missed ticks
        // when this thread woke in step with rt (as in the probe runs below).
        hs_haptic_telemetry tl;
        while (hs_spsc_ring_pop(hs_haptic_sim_telemetry(sim), &tl)) {
            const double* g = tl.force_n;
            if (have_prev && tl.tick == prev_seq + 1) { // consecutive ticks only
                double dd[3] = {g[0] - prev[0], g[1] - prev[1], g[2] - prev[2]};
                double s = sqrt(dd[0] * dd[0] + dd[1] * dd[1] + dd[2] * dd[2]);
                if (s > max_step) max_step = s;
                step_pairs++;
            }
            prev_seq = tl.tick;
            memcpy(prev, g, sizeof prev);
            have_prev = 1;
        }
        hs_haptic_output out;
        if (hs_haptic_sim_take_output(sim, &out)) {
            const double* f = out.force_n;
            ENSURE(isfinite(f[0]) && isfinite(f[1]) && isfinite(f[2]));
            double fn = sqrt(f[0] * f[0] + f[1] * f[1] + f[2] * f[2]);
            if (fn > peak) peak = fn;
            if (release_k >= 0 && k >= release_k + d.blend_ticks + 50) {
                after_release = fmax(after_release, fn);
                after_n++;
            }
        }
        if (!cutting) {
            hs_haptic_sim_stats bs;
            hs_haptic_sim_stats_get(sim, &bs);
            if (k >= end2 && release_k < 0 && released(&bs)) {
                release_k = k;
                loop_end = end2 + rest_ticks > k + d.blend_ticks + 250 ? end2 + rest_ticks
                                                                       : k + d.blend_ticks + 250;
            }
        }
        if (hs_haptic_sim_topology_version(sim) != version) {
            hs_haptic_cut_event ev;
            memset(&ev, 0, sizeof ev);
            ev.removed_tets = removed;
            ev.moved_nodes = moved;
            int nt = 0;
            int64_t v = hs_haptic_sim_take_topology(sim, x0, tris, 4 * ntet, &nt, &ev);
            if (v <= version || ev.old_version != version || ev.new_version != v) bad_event++;
            for (int i = 0; i < ev.n_removed; ++i) {
                int e = removed[i];
                if (e < 0 || e >= ntet || gone[e])
                    bad_event++;
                else
                    gone[e] = 1;
            }
            for (int i = 0; i < ev.n_moved; ++i)
                if (moved[i] < 0 || moved[i] >= n) bad_event++;
            for (int i = 0; i < 3 * nt; ++i)
                if (tris[i] < 0 || tris[i] >= n) bad_event++;
            if (nt == m->n_tris && ev.n_removed > 0) bad_event++; // cut faces must show
            removed_total += ev.n_removed;
            version = v;
            events++;
        }
    }
    // The compliance followed each cut step on the deformation thread: valid with the last one.
    hs_haptic_sim_stats st;
    hs_haptic_sim_stats_get(sim, &st);
    for (int i = 0; i < 12000 && st.comp_version != st.topology_version;
         ++i) { // <= 60 s (sanitizers)
        sleep_until(&t, 5000000);
        hs_haptic_sim_stats_get(sim, &st);
    }
    hs_haptic_sim_stop(sim);
    hs_haptic_sim_stats_get(sim, &st);
    int nt = 0;
    ENSURE(hs_haptic_sim_take_topology(sim, x0, tris, 4 * ntet, &nt, NULL) == version);
    printf("  %lld events, version %lld, %lld tets removed (%lld cut steps, %lld sweeps); "
           "peak %.3f N, largest step %.4f N/tick; cut step last %.1f ms max %.1f ms; "
           "compliance followed the last in %.1f ms\n",
           (long long)events, (long long)version, (long long)removed_total, (long long)st.cut_steps,
           (long long)st.cut_sweeps, peak, max_step, st.cut_ms_last, st.cut_ms_max,
           st.comp_ms_last);
    ENSURE(events > 0 && version == st.topology_version && version == st.cut_steps);
    ENSURE(bad_event == 0);
    ENSURE(removed_total == st.cut_removed && removed_total > 0);
    ENSURE(st.cut_failures == 0);
    ENSURE(!memcmp(x0, m->x0, 3 * (size_t)n * sizeof(double))); // rest positions shared as cut
    ENSURE(peak > 0.01 && peak <= cd.max_force_n + 1e-9);       // resistance, within the cap
#ifdef __SANITIZE_THREAD__
    // Under TSan the test thread misses rt outputs, so one sample spans several ticks: the
    // per-tick bound is not measurable there (checked in the normal build).
    printf("  (TSan build: the per-tick force step is not checked)\n");
#else
    ENSURE(step_pairs > drag_ticks / 2);
    ENSURE(max_step <= cd.max_force_n / d.blend_ticks + 1e-9); // blended, never a jump
#endif
    ENSURE(release_k >= 0 && after_n >= 100 && after_release < 1e-9); // released: none left
    // The shared surface (derived from the removed tets) is the boundary of the live tets, with
    // the same orientation: compared with a mesh built from them, as sets of triangles.
    {
        int* all = hs_alloc(4 * (size_t)ntet * sizeof(int));
        ENSURE(all);
        int na = 0;
        for (int e = 0; e < ntet; ++e)
            if (!gone[e]) memcpy(all + 4 * na++, m->tets + 4 * e, 4 * sizeof(int));
        hs_mesh* am = NULL;
        ENSURE(hs_mesh_create(n, m->x0, na, all, &am, &err) == HS_OK);
        ENSURE(am->n_tris == nt);
        int* a = hs_alloc(3 * (size_t)nt * sizeof(int));
        int* b = hs_alloc(3 * (size_t)nt * sizeof(int));
        ENSURE(a && b);
        canonical_tris(tris, nt, a);
        canonical_tris(am->tris, nt, b);
        ENSURE(!memcmp(a, b, 3 * (size_t)nt * sizeof(int)));
        printf("  shared surface: %d triangles, the live tets' boundary\n", nt);
        hs_free(a);
        hs_free(b);
        hs_free(all);
        hs_mesh_destroy(&am);
    }
    // Every cut step was followed at once: no rebuild, none dropped.
    printf("  compliance: %lld cut steps followed, %lld rebuilds, %lld dropped\n",
           (long long)st.comp_updates, (long long)st.comp_rebuilds, (long long)st.comp_discarded);
    ENSURE(st.comp_ms_last > 0 && st.comp_version == version && !st.comp_building);
    ENSURE(st.comp_updates == st.cut_steps && st.comp_rebuilds == 0);
    // ... and it is the compliance of the cut body: diagonal blocks as a fresh one's, on every
    // live tet, holding the fixed nodes and those no live tet uses. The cut pins only nodes
    // left without a tet (and drops pieces the fixed ends do not hold), so no live tet has one.
    unsigned char* pin = hs_calloc((size_t)n, 1);
    unsigned char* fix2 = hs_alloc((size_t)n);
    int* live = hs_alloc(4 * (size_t)ntet * sizeof(int));
    ENSURE(pin && fix2 && live);
    int pinned = hs_haptic_sim_cut_pinned(sim, pin);
    memset(fix2, 1, (size_t)n);
    int nlive = 0, on_pinned = 0;
    for (int e = 0; e < ntet; ++e) {
        const int* te = m->tets + 4 * e;
        if (gone[e]) continue;
        on_pinned += pin[te[0]] || pin[te[1]] || pin[te[2]] || pin[te[3]];
        memcpy(live + 4 * nlive++, te, 4 * sizeof(int));
    }
    for (int k = 0; k < 4 * nlive; ++k) fix2[live[k]] = 0;
    for (int i = 0; i < n; ++i) fix2[i] |= fixed[i];
    hs_mesh* lm = NULL;
    ENSURE(hs_mesh_create(n, m->x0, nlive, live, &lm, &err) == HS_OK);
    hs_compliance* fresh = NULL;
    printf("  %d pinned nodes, %d live tets, %d of them on a pinned node\n", pinned, nlive,
           on_pinned);
    ENSURE(on_pinned == 0);
    ENSURE(hs_compliance_create(lm, &d.body.fem, fix2, d.probe.cache_nodes, &fresh, &err) == HS_OK);
    hs_free(fix2);
    hs_compliance* cc = hs_haptic_sim_compliance(sim);
    double worst = 0;
    int compared = 0;
    for (int i = 0; i < n; ++i) {
        if (!hs_compliance_contactable(fresh, i)) continue;
        ENSURE(hs_compliance_contactable(cc, i));
        double a[9], b[9], na = 0, nd = 0;
        ENSURE(hs_compliance_ensure(cc, 1, &i, 0) == 0); // its stale diagonal block, afresh
        ENSURE(hs_compliance_block(cc, i, i, a) && hs_compliance_block(fresh, i, i, b));
        for (int k = 0; k < 9; ++k) {
            na += b[k] * b[k];
            nd += (a[k] - b[k]) * (a[k] - b[k]);
        }
        worst = fmax(worst, sqrt(nd / na));
        compared++;
    }
    printf("  followed compliance vs fresh on the cut mesh: %d surface nodes, worst block %.2e\n",
           compared, worst);
    ENSURE(compared > 0 && compared >= lm->n_surf_nodes / 2);
    ENSURE(worst <= 1e-8);
    hs_compliance_destroy(&fresh);
    hs_mesh_destroy(&lm);
    hs_free(live);
    hs_free(pin);
    hs_free(x0);
    hs_free(tris);
    hs_free(removed);
    hs_free(moved);
    hs_free(gone);
    destroy_sim(&sim);
    hs_free(fixed);
    hs_mesh_destroy(&m);
    ENSURE(hs_byte_count() == bytes);
    return 0;
}

// Reference: the contact force of a sphere at p (radius r) on the rest surface (x0, tris) with
// compliance c, as the sim computes it once the body has settled (linear, quasi-static).
static int rest_force(hs_compliance* c, const double* x0, const int* tris, int n_tris, int n,
                      const double p[3], double r, double f[3]) {
    static hs_contact_snapshot s;
    memset(&s, 0, sizeof s);
    double dist[HS_CONTACT_MAX_CAND];
    int nc = 0;
    for (int v = 0; v < n; ++v) {
        if (!hs_compliance_contactable(c, v)) continue;
        double d = sqrt(pow(x0[3 * v] - p[0], 2) + pow(x0[3 * v + 1] - p[1], 2) +
                        pow(x0[3 * v + 2] - p[2], 2));
        if (d > r + 0.01 || (nc == HS_CONTACT_MAX_CAND && d >= dist[nc - 1])) continue;
        int at = nc < HS_CONTACT_MAX_CAND ? nc++ : nc - 1;
        while (at > 0 && dist[at - 1] > d) {
            dist[at] = dist[at - 1];
            s.node[at] = s.node[at - 1];
            --at;
        }
        dist[at] = d;
        s.node[at] = v;
    }
    if (nc == 0) return 0;
    s.version = 1;
    s.probe_radius_m = r;
    memcpy(s.centre_m, p, sizeof s.centre_m);
    s.reach_m = r + 0.01;
    s.n_cand = nc;
    hs_compliance_begin_step(c);
    if (hs_compliance_ensure(c, nc, s.node, nc) != nc) return 0;
    for (int i = 0; i < nc; ++i) {
        s.coupled[i] = 1;
        memcpy(s.surf_m[i], x0 + 3 * s.node[i], sizeof s.surf_m[i]);
        s.normal[i][2] = 1; // only read for a node at the exact centre
        for (int j = 0; j < nc; ++j) hs_compliance_block(c, s.node[i], s.node[j], s.c[i][j]);
    }
    int slot[HS_CONTACT_MAX_CAND];
    for (int t = 0; t < n_tris && s.n_tri < HS_CONTACT_MAX_TRI; ++t) {
        int ok = 1;
        for (int k = 0; k < 3 && ok; ++k) {
            slot[k] = -1;
            for (int i = 0; i < nc && slot[k] < 0; ++i)
                if (s.node[i] == tris[3 * t + k]) slot[k] = i;
            ok = slot[k] >= 0;
        }
        if (!ok) continue;
        memcpy(s.tri[s.n_tri++], slot, 3 * sizeof(int));
    }
    hs_contact_snapshot_bound_tris(&s);
    hs_contact con;
    hs_contact_solve_from(&s, p, NULL, &con);
    memcpy(f, con.force_n, 3 * sizeof(double));
    return con.n;
}

typedef struct probe_run {
    hs_haptic_sim* sim;
    struct timespec t;
    hs_haptic_pose pose;
    double at[3];   // tool position now
    double prev[3]; // previous force output
    int have_prev;
    int64_t prev_seq; // rt tick of the previous output
    double max_step;  // largest tick-to-tick force change, N (consecutive ticks only)
    int step_pairs;   // consecutive-tick pairs seen
    // 1: force steps and stale-compliance forces count only once the blade's cutting force has
    // blended out after the release (below RESIDUAL_N: each new snapshot restarts the blend
    // from where it is, so that takes ~35 ticks here, not blend_ticks)
    int gated;
    int64_t release_ns;   // when the status first showed the release (0: not yet)
    int64_t gate_tick;    // first rt tick counted after the release (-1: not known yet)
    int stale_when_gated; // the compliance was still stale when steps began to count
    double fz_sum;        // sum of f_z over the averaging window
    int fz_n;
    int stale_in_tissue; // rt ticks with the probe over the patch on a stale compliance
    double stale_force;  // largest force at those ticks, N
} probe_run;

// What is left of the blade's cutting force (0.5 mN at the release) once it has blended out:
// it falls monotonically from there; a contact 1 mm deep would be ~0.01 N.
#define RESIDUAL_N 1e-6
// The probe may touch the tissue as soon as the blade is released (the compliance is valid):
// then the force never gets down to RESIDUAL_N, and steps count from this long after it.
#define GATE_LATE_NS 50000000

// Past the blend-out: from the gate on (or always, when nothing is gated).
static int counted(const probe_run* pr, int64_t tick) {
    return !pr->gated || (pr->gate_tick >= 0 && tick >= pr->gate_tick);
}

// Move the tool in a straight line to `to` over `ticks` ms (buttons held or not), then average
// f_z over the last `avg` of them. With tissue_top > 0, every rt tick is classified from the
// telemetry: a record popped before a status read that still says stale was computed on the
// stale compliance (the loop says so before it publishes the snapshot with the new contact),
// however late this thread runs.
static void probe_move(probe_run* pr, const double to[3], int ticks, unsigned buttons, int avg,
                       double tissue_top) {
    enum { BATCH = 4096 };
    static hs_haptic_telemetry batch[BATCH]; // one probe run at a time
    double from[3];
    memcpy(from, pr->at, sizeof from);
    pr->fz_sum = 0;
    pr->fz_n = 0;
    for (int k = 1; k <= ticks; ++k) {
        double a = (double)k / ticks;
        for (int i = 0; i < 3; ++i) pr->at[i] = from[i] + a * (to[i] - from[i]);
        feed_ms(pr->sim, &pr->pose, &pr->t, pr->at, buttons);
        // Every rt tick from the telemetry: the newest output alone missed ticks whenever this
        // thread's wake-ups fell in step with rt's (a run kept 249 of ~2200 consecutive pairs).
        int nb = 0;
        while (nb < BATCH && hs_spsc_ring_pop(hs_haptic_sim_telemetry(pr->sim), &batch[nb])) ++nb;
        int stale = 0;
        if (tissue_top > 0) {
            hs_haptic_sim_stats st;
            hs_haptic_sim_stats_get(pr->sim, &st);
            // Ticks that woke after this read took the snapshot without the blade's force.
            if (released(&st) && pr->release_ns == 0) pr->release_ns = hs_now_ns();
            stale =
                released(&st) && st.topology_version > 0 && st.comp_version != st.topology_version;
        }
        for (int b = 0; b < nb; ++b) {
            const hs_haptic_telemetry* tl = &batch[b];
            const double* g = tl->force_n;
            double fn = sqrt(g[0] * g[0] + g[1] * g[1] + g[2] * g[2]);
            // At full watchdog gain only: a stall of this thread past the watchdog timeout
            // ramps the force down, which is not the blade's force having faded.
            if (pr->gated && pr->gate_tick < 0 && pr->release_ns > 0 &&
                tl->now_ns >= pr->release_ns &&
                (fn <= RESIDUAL_N || tl->now_ns >= pr->release_ns + GATE_LATE_NS) &&
                tl->gain == 1 && !(tl->safety & HS_SAFETY_WATCHDOG)) {
                pr->gate_tick = tl->tick;
                pr->stale_when_gated = stale;
            }
            if (pr->have_prev && tl->tick == pr->prev_seq + 1 && counted(pr, tl->tick)) {
                double d[3] = {g[0] - pr->prev[0], g[1] - pr->prev[1], g[2] - pr->prev[2]};
                pr->max_step = fmax(pr->max_step, sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2]));
                pr->step_pairs++;
            }
            pr->prev_seq = tl->tick;
            memcpy(pr->prev, g, sizeof pr->prev);
            pr->have_prev = 1;
            // Over the patch (|y| < 40 mm) and low enough to touch it.
            if (stale && counted(pr, tl->tick) && tl->tool_m[2] < tissue_top &&
                fabs(tl->tool_m[1]) < 0.04) {
                pr->stale_in_tissue++;
                pr->stale_force =
                    fmax(pr->stale_force, sqrt(g[0] * g[0] + g[1] * g[1] + g[2] * g[2]));
            }
        }
        hs_haptic_output out;
        if (!hs_haptic_sim_take_output(pr->sim, &out)) continue;
        if (k > ticks - avg) {
            pr->fz_sum += out.force_n[2];
            pr->fz_n++;
        }
    }
}

/// With probe_when_released the released blade is a probe sphere: pressed 1 mm next to where
/// the cut will run, it feels the intact patch; after a full cut across it feels the cut tissue
/// at once, softer, and in both cases the force of the rest-state contact on that body. The
/// compliance followed every cut step, so it is never stale once the blade is out, and the
/// contact that appears is blended. min_travel_m: the blade's sweep step; tol: how far the cut
/// press may be from the rest contact on the followed compliance.
static int probe_after_cut(double min_travel_m, double tol) {
    (void)tol; // unchecked under TSan
    int64_t bytes = hs_byte_count();
    hs_mesh* m = NULL;
    unsigned char* fixed = NULL;
    ENSURE(skin_with_ends_fixed(&m, &fixed) == 0);
    const int n = m->n_nodes, ntet = m->n_tets;
    hs_haptic_sim_def d = sim_def();
    const double r = 0.003, top = 0.004, depth = 0.001;
    d.probe.radius_m = r;
    d.body.fem.material.youngs_pa = 50000; // the skin scene's
    hs_haptic_sim* sim = NULL;
    hs_err err = {0};
    ENSURE(create_sim(m, &d, fixed, &sim, &err) == HS_OK);
    hs_haptic_cut_def cd = blade_def();
    cd.probe_when_released = 1;
    cd.min_travel_m = min_travel_m;
    ENSURE(hs_haptic_sim_enable_cutting(sim, m, &cd, &err) == HS_OK);
    // Reference before the cut: the sim's own (uncut) compliance, read while stopped.
    double* x0 = hs_alloc(3 * (size_t)n * sizeof(double));
    int* tris = hs_alloc(3 * 4 * (size_t)ntet * sizeof(int));
    ENSURE(x0 && tris);
    const double press[3] = {0.012, 0.0, top + r - depth}; // 11 mm beside the cut line x = 1 mm
    double f_ref0[3], f_ref1[3];
    ENSURE(rest_force(hs_haptic_sim_compliance(sim), m->x0, m->tris, m->n_tris, n, press, r,
                      f_ref0) > 0);
    ENSURE(hs_haptic_sim_start(sim, &err) == HS_OK);

    probe_run pr;
    memset(&pr, 0, sizeof pr);
    pr.sim = sim;
    pr.pose.quat_wxyz[0] = 1;
    pr.at[0] = press[0];
    pr.at[1] = press[1];
    pr.at[2] = 0.012;
    clock_gettime(CLOCK_MONOTONIC, &pr.t);
    const double above[3] = {press[0], press[1], 0.012};
    probe_move(&pr, above, 100, 0, 0, 0);
    probe_move(&pr, press, 400, 0, 0, 0);
    probe_move(&pr, press, 1200, 0, 300, 0);
    double f_uncut = pr.fz_sum / pr.fz_n;
    double step_uncut = pr.max_step;
    probe_move(&pr, above, 300, 0, 0, 0);
    // The cut: across y at x = 1 mm, the blade spanning the thickness; entered and left
    // outside the patch (|y| <= 40 mm), so the probe touches nothing on the way.
    const double c0[3] = {0.001, -0.05, 0.012}, c1[3] = {0.001, -0.05, 0.002},
                 c2[3] = {0.001, 0.05, 0.002};
    probe_move(&pr, c0, 200, 0, 0, 0);
    probe_move(&pr, c1, 100, 0, 0, 0);
    probe_move(&pr, c2, 2500, 1u, 0, 0);
    // Quickly back and into the tissue (in 30 ms): the compliance is valid already.
    pr.max_step = 0;
    pr.step_pairs = 0;
    pr.gate_tick = -1;
    pr.gated = 1;
    probe_move(&pr, above, 20, 0, 0, top + r);
    probe_move(&pr, press, 10, 0, 0, top + r);
    hs_haptic_sim_stats st;
    int waited = 0;
    for (hs_haptic_sim_stats_get(sim, &st); st.comp_version != st.topology_version && waited < 60;
         hs_haptic_sim_stats_get(sim, &st), ++waited)
        probe_move(&pr, press, 1000, 0, 0, top + r);
    // Held until the body has settled under the probe: two consecutive 300 ms averages within
    // 1 % (a loaded machine steps the body late); at least 1.2 s, at most 4.8 s.
    probe_move(&pr, press, 900, 0, 300, top + r);
    double f_cut = pr.fz_sum / pr.fz_n, f_prev;
    int windows = 0;
    do {
        f_prev = f_cut;
        probe_move(&pr, press, 300, 0, 300, top + r);
        f_cut = pr.fz_sum / pr.fz_n;
    } while (++windows < 13 && fabs(f_cut - f_prev) > 0.01 * fabs(f_cut));
    double step_swap = pr.max_step;
    hs_haptic_sim_stop(sim);
    hs_haptic_sim_stats_get(sim, &st);
    int nt = 0;
    int64_t v = hs_haptic_sim_take_topology(sim, x0, tris, 4 * ntet, &nt, NULL);
    ENSURE(rest_force(hs_haptic_sim_compliance(sim), x0, tris, nt, n, press, r, f_ref1) > 0);
    printf("  probe 1 mm deep, 11 mm beside the cut line: intact %.5f N (rest contact %.5f N), "
           "cut %.5f N (rest contact on the cut body %.5f N); %lld tets removed, version %lld\n",
           f_uncut, f_ref0[2], f_cut, f_ref1[2], (long long)st.cut_removed, (long long)v);
    printf("  %d rt ticks in the tissue while the compliance was stale (largest force %.2g N); "
           "largest force step %.4f N/tick intact, %.4f N/tick across the swap; held %d ms\n",
           pr.stale_in_tissue, pr.stale_force, step_uncut, step_swap, 900 + 300 * windows);
    ENSURE(v > 0 && st.comp_version == v && st.cut_failures == 0);
    ENSURE(f_uncut > 0.005);                              // the probe feels the intact patch
    ENSURE(fabs(f_uncut - f_ref0[2]) <= 0.1 * f_ref0[2]); // as the rest-state contact
#ifndef __SANITIZE_THREAD__ // TSan slows the body ~10x: it has not settled within the hold
    // Softer: 0.40x when the cut separates the patch, up to 0.84x when vertices left on the cut
    // plane still join the halves (then the rest contact on that body is higher too).
    ENSURE(f_cut > 0.001 && f_cut < f_uncut);
    ENSURE(fabs(f_cut - f_ref1[2]) <= tol * f_ref1[2]); // and it is the cut body's answer
#endif
    // Valid with the cut's last step: not one rt tick in the tissue on a stale compliance.
    ENSURE(pr.stale_in_tissue == 0 && st.comp_updates == st.cut_steps && st.comp_rebuilds == 0);
#ifndef __SANITIZE_THREAD__
    ENSURE(pr.step_pairs >= 500);
    ENSURE(step_swap <= 0.5 * f_cut + 1e-3); // the contact blended in, not a jump of f_cut
#endif
    hs_free(x0);
    hs_free(tris);
    destroy_sim(&sim);
    hs_free(fixed);
    hs_mesh_destroy(&m);
    ENSURE(hs_byte_count() == bytes);
    return 0;
}

static int test_probe_after_cut(void) {
    return probe_after_cut(hs_haptic_cut_default_def().min_travel_m, 0.1);
}

/// The same in 0.2 mm sweeps, where many small element changes pile up under the held probe
/// (a contact-free correction that ran away kicked up to 10 N here); the same 10 % as above.
static int test_probe_after_fine_cut(void) {
    return probe_after_cut(0.0002, 0.1);
}

/// A strip of the sagging patch (the skin scene's material, gravity 2 m/s^2) cut free of both
/// held ends by two cuts across, at x = -9 and +11 mm: DROP (the default) takes its tets out
/// and holds its nodes exactly where they were; FIX (the scene's "free_pieces": "fall") keeps
/// its tets in the body, every node pinned in the cut, and the strip falls or swings. Either way
/// the
/// compliance leaves the strip out (no contactable node) and nothing goes non-finite.
static int free_piece(int fall) {
    int64_t bytes = hs_byte_count();
    hs_mesh* m = NULL;
    unsigned char* fixed = NULL;
    ENSURE(skin_with_ends_fixed(&m, &fixed) == 0);
    const int n = m->n_nodes, ntet = m->n_tets;
    hs_haptic_sim_def d = sim_def();
    d.body.fem.material.youngs_pa = 50000; // the skin scene's: sags ~10 mm, within the blade
    d.body.gravity[2] = -2.0;
    hs_haptic_cut_def cd = blade_def();
    cd.cut.fragment = fall ? HS_CUT_FRAGMENT_FIX : HS_CUT_FRAGMENT_DROP;
    hs_haptic_sim* sim = NULL;
    ENSURE(start_cutting_sim(m, fixed, &d, &cd, &sim) == 0);
    probe_run pr;
    memset(&pr, 0, sizeof pr);
    pr.sim = sim;
    pr.pose.quat_wxyz[0] = 1;
    const double start[3] = {-0.009, -0.05, 0.012};
    memcpy(pr.at, start, sizeof start);
    clock_gettime(CLOCK_MONOTONIC, &pr.t);
    probe_move(&pr, start, 100, 0, 0, 0);
    double* u0 = hs_alloc(3 * (size_t)n * sizeof(double));
    double* u1 = hs_alloc(3 * (size_t)n * sizeof(double));
    double* upre = hs_alloc(3 * (size_t)n * sizeof(double));
    unsigned char* pin = hs_calloc((size_t)n, 1);
    ENSURE(u0 && u1 && upre && pin);
    for (int k = 0; k < 2; ++k) {
        const double x = k ? 0.011 : -0.009;
        if (k == 1) hs_haptic_sim_read_frame(sim, upre, NULL); // before the second cut
        const double c0[3] = {x, -0.05, 0.012}, c1[3] = {x, -0.05, 0.002}, c2[3] = {x, 0.05, 0.002},
                     c3[3] = {x, 0.05, 0.012};
        probe_move(&pr, c0, 100, 0, 0, 0);
        probe_move(&pr, c1, 100, 0, 0, 0);
        probe_move(&pr, c2, 2500, 1u, 0, 0);
        probe_move(&pr, c3, 100, 0, 0, 0);
    }
    // The newest frame is the body's state (a body at rest publishes none: nothing changed);
    // then 30 body steps or more (0.5 s of its time, however slowly this machine runs them).
    hs_haptic_sim_stats st;
    hs_haptic_sim_stats_get(sim, &st);
    const int64_t steps0 = st.steps;
    hs_haptic_sim_read_frame(sim, u0, NULL);
    for (int k = 0; k < (fall ? 50 : 5) && st.steps < steps0 + 30; ++k) { // bounded: 5 s
        probe_move(&pr, pr.at, 100, 0, 0, 0);
        hs_haptic_sim_stats_get(sim, &st);
    }
    // The compliance of the cut body (rebuilt once the blade left; later under sanitizers).
    for (int k = 0; k < 100 && st.comp_version != st.topology_version; ++k) { // bounded: 10 s
        probe_move(&pr, pr.at, 100, 0, 0, 0);
        hs_haptic_sim_stats_get(sim, &st);
    }
    hs_haptic_sim_read_frame(sim, u1, NULL);
    hs_haptic_sim_stop(sim);
    hs_haptic_sim_stats_get(sim, &st);
    ENSURE(st.comp_version == st.topology_version);
    ENSURE(hs_haptic_sim_cut_pinned(sim, pin) >= 0);
    // A node the probe can touch must belong to a tet the compliance keeps: an active one with
    // a node that is not pinned (under FIX the strip's own tets stay active in the body; a
    // node it still shares with a lip, as the cut creates no vertex, stays touchable).
    const hs_fem* fem = hs_body_fem(hs_haptic_sim_body(sim));
    unsigned char* kept = hs_calloc((size_t)n, 1);
    ENSURE(kept);
    for (int e = 0; e < ntet; ++e) {
        const int* t = m->tets + 4 * e;
        if (!hs_fem_element_active(fem, e) || (pin[t[0]] && pin[t[1]] && pin[t[2]] && pin[t[3]]))
            continue;
        for (int a = 0; a < 4; ++a) kept[t[a]] = 1;
    }
    // The strip: nodes strictly between the cut lines, 2 mm clear of them. Those the cut freed
    // are pinned; a node of the sagging strip that the second cut met below its rest x can stay
    // with the lip (1 of 160, once under ASan).
    int strip = 0, contactable = 0, pinned = 0, hinges = 0;
    double moved = 0, fell = 0, since_pre = 0;
    hs_compliance* cc = hs_haptic_sim_compliance(sim);
    for (int i = 0; i < n; ++i) {
        for (int a = 0; a < 3; ++a) ENSURE(isfinite(u1[3 * i + a]));
        contactable += hs_compliance_contactable(cc, i) && !kept[i]; // anywhere
        double x = m->x0[3 * i];
        if (!(x > -0.007 && x < 0.009)) continue;
        strip++;
        if (!pin[i]) continue;
        pinned++;
        hinges += kept[i];
        fell += u1[3 * i + 2] - u0[3 * i + 2]; // summed here, the mean below
        for (int a = 0; a < 3; ++a) {
            moved = fmax(moved, fabs(u1[3 * i + a] - u0[3 * i + a]));
            since_pre = fmax(since_pre, fabs(u1[3 * i + a] - upre[3 * i + a]));
        }
    }
    hs_free(kept);
    fell = pinned > 0 ? fell / pinned : 0;
    printf("  %s: %lld tets removed of %d; the strip's %d nodes: %d pinned (%d still on a kept "
           "tet); %d contactable nodes on no kept tet; over %lld body steps after the cut the "
           "pinned strip nodes moved %.3g mm down on average, at most "
           "%.3g mm (%.3g mm since before the second cut)\n",
           fall ? "fall" : "drop", (long long)st.cut_removed, ntet, strip, pinned, hinges,
           contactable, (long long)(st.steps - steps0), -fell * 1e3, moved * 1e3, since_pre * 1e3);
    ENSURE(st.cut_failures == 0 && strip > 100 && contactable == 0);
#ifdef __SANITIZE_THREAD__
    // Under TSan the body takes a few steps while a cut runs, so the blade meets the sagging
    // strip where it hangs then: the second cut left it attached in one run of two with FALL,
    // and once with DROP (0 of 177 strip nodes pinned, 2026-11-27 CI). The threads ran (the
    // point of this build); the outcome is checked in the others.
    const int check_outcome = 0;
    printf("  (TSan build: whether the strip came free is not checked)\n");
#else
    const int check_outcome = 1;
#endif
    if (check_outcome && !fall) {
        ENSURE(pinned >= 0.95 * strip);
        ENSURE(st.cut_removed > 0.3 * ntet && moved == 0); // goes; its nodes held where they were
    } else if (check_outcome) {
        ENSURE(pinned >= 0.95 * strip);
        // The strip stays: only the two cut lines go, 680-1,038 tets in 44 runs (2026-11-27;
        // how much of the hanging strip the second cut meets depends on how far it swung),
        // against 1,565-1,813 when DROP takes the strip too.
        ENSURE(st.cut_removed < 0.3 * ntet);
        // and moves: it falls, or swings down on a node it still shares with a lip (the cut's
        // pieces are face-connected; the body also couples through nodes), perhaps already
        // while the second cut ran.
        ENSURE(st.steps >= steps0 + 30 && since_pre > 0.01);
    }
    hs_free(u0);
    hs_free(u1);
    hs_free(upre);
    hs_free(pin);
    destroy_sim(&sim);
    hs_free(fixed);
    hs_mesh_destroy(&m);
    ENSURE(hs_byte_count() == bytes);
    return 0;
}

static int test_free_piece_dropped(void) {
    return free_piece(0);
}

static int test_free_piece_fall_rule(void) {
    return free_piece(1);
}

// Feed engaged blade poses at x = 1 mm, z = 2 mm for `ticks` ms, y moving from ya to yb.
static void blade_feed(hs_haptic_sim* sim, hs_haptic_pose* pose, double ya, double yb, int ticks) {
    struct timespec t;
    clock_gettime(CLOCK_MONOTONIC, &t);
    for (int k = 1; k <= ticks; ++k) {
        pose->seq++;
        pose->stamp_ns = hs_now_ns();
        pose->pos_m[0] = 0.001;
        pose->pos_m[1] = ya + (yb - ya) * k / ticks;
        pose->pos_m[2] = 0.002;
        pose->buttons = 1u;
        hs_haptic_sim_feed_pose(sim, pose);
        sleep_until(&t, 1000000);
    }
}

// A sim stopped in a cut and started again (the server's pause and resume of a cut world)
// cuts on, but the blade starts afresh: no sweep spans the stop, even with the blade held down
// and moved 40 mm across the patch meanwhile.
static int test_restart_mid_cut(void) {
    int64_t bytes = hs_byte_count();
    hs_mesh* m = NULL;
    unsigned char* fixed = NULL;
    ENSURE(skin_with_ends_fixed(&m, &fixed) == 0);
    hs_haptic_sim_def d = sim_def();
    hs_haptic_cut_def cd = blade_def();
    hs_haptic_sim* sim = NULL;
    hs_err err = {0};
    ENSURE(start_cutting_sim(m, fixed, &d, &cd, &sim) == 0);
    hs_haptic_pose pose;
    memset(&pose, 0, sizeof pose);
    pose.quat_wxyz[0] = 1;
    blade_feed(sim, &pose, -0.05, -0.02, 750); // in from the edge (y = -40 mm), 20 mm deep
    hs_haptic_sim_stats st;
    hs_haptic_sim_stats_get(sim, &st);
    const double f_moving = norm3(st.cut_force_n);
    blade_feed(sim, &pose, -0.02, -0.02, 300);
    // Held still 0.3 s: no resistance (it kept the last sweep's as long as it stood).
    hs_haptic_sim_stats_get(sim, &st);
    const double f_still = norm3(st.cut_force_n);
    int64_t v1 = hs_haptic_sim_topology_version(sim);
    hs_haptic_sim_stop(sim);
    int64_t v_stop = hs_haptic_sim_topology_version(sim);
    // A resistance held over the stop came back at once on the restart, with the blade
    // anywhere by then: it starts from nothing, and so does rt (zero, then a ramp).
    ENSURE(hs_haptic_sim_start(sim, &err) == HS_OK);
    hs_haptic_output o;
    double f_restart = 0;
    struct timespec t0;
    clock_gettime(CLOCK_MONOTONIC, &t0);
    for (int k = 0; k < 50; ++k) { // 50 ms of outputs, the blade held down 40 mm on
        pose.seq++;
        pose.pos_m[1] = 0.02;
        hs_haptic_sim_feed_pose(sim, &pose);
        sleep_until(&t0, 1000000);
        while (hs_haptic_sim_take_output(sim, &o)) f_restart = fmax(f_restart, norm3(o.force_n));
    }
    blade_feed(sim, &pose, 0.02, 0.02, 350); // held still 40 mm on, the blade down
    int64_t v2 = hs_haptic_sim_topology_version(sim);
    blade_feed(sim, &pose, 0.02, 0.03, 250); // then moved: it cuts again
    blade_feed(sim, &pose, 0.03, 0.03, 300);
    int64_t v3 = hs_haptic_sim_topology_version(sim);
    hs_haptic_sim_stats_get(sim, &st);
    printf("  topology version: %lld after the first cut (%lld at the stop), %lld after the "
           "restart with the blade held 40 mm on, %lld after moving it 10 mm; %lld cut "
           "failures; resistance %.3f N moving, %.3f N held still; largest force in the 50 ms "
           "after the restart %.3f N\n",
           (long long)v1, (long long)v_stop, (long long)v2, (long long)v3,
           (long long)st.cut_failures, f_moving, f_still, f_restart);
    destroy_sim(&sim);
    hs_mesh_destroy(&m);
    hs_free(fixed);
    ENSURE(v1 > 0 && v2 == v_stop && v3 > v2 && st.cut_failures == 0);
    ENSURE(f_moving > 0.01 && f_still == 0 && f_restart == 0);
    ENSURE(hs_byte_count() == bytes);
    return 0;
}

// The resistance follows the tissue, not the speed: the same 60 mm cut at 20 and 80 mm/s
// (sweeps of 0.5 and 1.3 mm at 60 Hz) feels no more mean force when faster. Before the sweep's
// edge length was taken per min_travel of travel it grew with the sweep: 0.11 / 0.26 / 0.53 N
// for 0.5 / 1 / 2 mm sweeps (a review's replay).
static double mean_cut_force(double speed_m_s) {
    hs_mesh* m = NULL;
    unsigned char* fixed = NULL;
    if (skin_with_ends_fixed(&m, &fixed)) return -1;
    hs_haptic_sim_def d = sim_def();
    hs_haptic_cut_def cd = blade_def();
    hs_haptic_sim* sim = NULL;
    double mean = -1;
    if (start_cutting_sim(m, fixed, &d, &cd, &sim) == 0) {
        hs_haptic_pose pose;
        memset(&pose, 0, sizeof pose);
        pose.quat_wxyz[0] = 1;
        const int ticks = (int)(0.06 / speed_m_s * 1000);
        blade_feed(sim, &pose, -0.05, -0.045, 100); // in from outside the patch, slowly
        struct timespec t;
        clock_gettime(CLOCK_MONOTONIC, &t);
        double sum = 0;
        for (int k = 1; k <= ticks; ++k) {
            pose.seq++;
            pose.pos_m[1] = -0.045 + 0.06 * k / ticks;
            hs_haptic_sim_feed_pose(sim, &pose);
            sleep_until(&t, 1000000);
            hs_haptic_sim_stats st;
            hs_haptic_sim_stats_get(sim, &st);
            sum += norm3(st.cut_force_n);
        }
        mean = sum / ticks;
    }
    destroy_sim(&sim);
    hs_mesh_destroy(&m);
    hs_free(fixed);
    return mean;
}

static int test_force_speed(void) {
    // It must not grow with the speed (x1.77-1.97 before, unloaded). On a loaded machine the
    // late deformation loop sweeps otherwise (x0.34 to over 1.6 seen), so up to three tries.
    double best = 1e9;
    for (int attempt = 0; attempt < 3 && best >= 1.6; ++attempt) {
        double slow = mean_cut_force(0.02), fast = mean_cut_force(0.08);
        printf("  mean resistance over a 60 mm cut: %.4f N at 20 mm/s, %.4f N at 80 mm/s "
               "(x%.2f)\n",
               slow, fast, fast / slow);
        ENSURE(slow > 0.005 && fast > 0.005);
        best = fmin(best, fast / slow);
    }
#if !defined(__SANITIZE_THREAD__) && !defined(__SANITIZE_ADDRESS__)
    ENSURE(best < 1.6);
#else // the sanitizers slow the deformation loop, so its sweeps are not these (ASan: x2.08)
    printf("  (sanitizer build: the ratio is not checked)\n");
#endif
    return 0;
}

// ---------------------------------------------------------------------------------------------
// Releasing the blade inside the tissue: every rt answer (telemetry, every tick) against the
// scene's limits, as the skin scene sets them (scenes/skin/skin.json).

#define SKIN_FORCE_MAX 3.3   // N, haptics.force_max_n
#define SKIN_RATE_MAX  500.0 // N/s, haptics.force_rate_max_n_per_s

typedef struct wire_check {
    hs_haptic_sim* sim;
    hs_haptic_pose pose;
    struct timespec t;
    double prev[3];
    int64_t prev_tick;
    int have_prev;
    int64_t answers;         // rt answers checked
    double worst_mag;        // largest |f|, N
    double worst_step;       // largest |f_k - f_k-1| between consecutive answers, N
    double peak;             // largest |f| since the last wire_mark, N
    double win_min, win_max; // range of |f| since the last wire_mark, N
    double last;             // |f| of the newest answer, N
} wire_check;

static void wire_mark(wire_check* w) {
    w->peak = 0;
    w->win_min = 1e9;
    w->win_max = 0;
}

// Move the tool (point) in a straight line to `to` over `ticks` ms with `buttons` held, feeding
// a pose every ms and checking every rt answer.
static void wire_move(wire_check* w, const double to[3], int ticks, unsigned buttons) {
    enum { BATCH = 4096 };
    static hs_haptic_telemetry batch[BATCH]; // one run at a time
    double from[3];
    memcpy(from, w->pose.pos_m, sizeof from);
    for (int k = 1; k <= ticks; ++k) {
        for (int i = 0; i < 3; ++i)
            w->pose.pos_m[i] = from[i] + (to[i] - from[i]) * (double)k / ticks;
        w->pose.seq++;
        w->pose.stamp_ns = hs_now_ns();
        w->pose.buttons = buttons;
        hs_haptic_sim_feed_pose(w->sim, &w->pose);
        sleep_until(&w->t, 1000000);
        int nb = 0;
        while (nb < BATCH && hs_spsc_ring_pop(hs_haptic_sim_telemetry(w->sim), &batch[nb])) ++nb;
        for (int b = 0; b < nb; ++b) {
            const double* g = batch[b].force_n;
            double fn = norm3(g);
            w->worst_mag = fmax(w->worst_mag, fn);
            if (w->have_prev && batch[b].tick == w->prev_tick + 1) {
                double d[3] = {g[0] - w->prev[0], g[1] - w->prev[1], g[2] - w->prev[2]};
                w->worst_step = fmax(w->worst_step, norm3(d));
            }
            w->answers++;
            w->prev_tick = batch[b].tick;
            memcpy(w->prev, g, sizeof w->prev);
            w->have_prev = 1;
            w->peak = fmax(w->peak, fn);
            w->win_min = fmin(w->win_min, fn);
            w->win_max = fmax(w->win_max, fn);
            w->last = fn;
        }
    }
}

// The skin scene's sim: its material, probe, limits and blade (tool point at z = 2 mm: the
// blade spans the 4 mm thickness), released blade = probe.
static int start_skin_scene_sim(hs_mesh* m, const unsigned char* fixed, hs_haptic_sim** sim) {
    hs_haptic_sim_def d = sim_def();
    d.body.fem.material.youngs_pa = 50000;
    d.body.fem.material.poisson = 0.45;
    d.body.solver = HS_SOLVER_WARPED;
    d.probe.radius_m = 0.003;
    d.safety.max_force_n = SKIN_FORCE_MAX;
    d.safety.max_rate_n_s = SKIN_RATE_MAX;
    d.safety.watchdog_timeout_s = 0.1;
    hs_haptic_cut_def cd = hs_haptic_cut_default_def();
    cd.blade_a[2] = -0.003;
    cd.blade_b[2] = 0.005;
    cd.max_force_n = 1.5;
    cd.probe_when_released = 1;
    return start_cutting_sim(m, fixed, &d, &cd, sim);
}

/// A zig-zag cut (ends = 1) or a straight one (ends = 0) from the patch's edge to its middle,
/// the button released there with the blade inside, then held still: every rt answer within
/// the force and rate limits, no kick when the blade becomes the probe (the peak after the
/// release no more than where the force settles, plus the blend's share) and no chatter in the
/// last 0.5 s of the hold.
static int release_inside(int zigzag) {
    int64_t bytes = hs_byte_count();
    hs_mesh* m = NULL;
    unsigned char* fixed = NULL;
    ENSURE(skin_with_ends_fixed(&m, &fixed) == 0);
    wire_check w;
    memset(&w, 0, sizeof w);
    ENSURE(start_skin_scene_sim(m, fixed, &w.sim) == 0);
    w.pose.quat_wxyz[0] = 1;
    w.pose.pos_m[1] = -0.05;
    w.pose.pos_m[2] = 0.012;
    clock_gettime(CLOCK_MONOTONIC, &w.t);
    const double z = 0.002, x = zigzag ? 0.0 : 0.001; // off the mesh lines (a cut along one
    w.pose.pos_m[0] = x;                              // crosses few edges: no resistance)
    const double down[3] = {x, -0.05, z};
    wire_move(&w, down, 100, 0);
    if (zigzag) {
        for (int k = 1; k <= 5; ++k) {
            const double p[3] = {k == 5 ? 0.0 : (k % 2 ? 0.004 : -0.004), -0.05 + 0.01 * k, z};
            wire_move(&w, p, 250, 1u);
        }
    } else {
        const double mid[3] = {x, 0, z};
        wire_move(&w, mid, 1250, 1u);
    }
    hs_haptic_sim_stats st;
    hs_haptic_sim_stats_get(w.sim, &st);
    const int64_t cut_steps = st.cut_steps;
    const double here[3] = {w.pose.pos_m[0], w.pose.pos_m[1], w.pose.pos_m[2]};
    const double at_release = w.last; // the blade's resistance, blended out after the release
    wire_mark(&w);
    wire_move(&w, here, 1500, 0); // released inside: the probe appears once the compliance is
    const double peak = w.peak;   // rebuilt (~0.1-0.2 s)
    wire_mark(&w);
    wire_move(&w, here, 500, 0);
    hs_haptic_sim_stats_get(w.sim, &st);
    const double settled = w.last, range = w.win_max - w.win_min;
    // Then lifted out of the cut at 40 mm/s, and held above it.
    const double up[3] = {here[0], here[1], 0.02};
    wire_mark(&w);
    wire_move(&w, up, 450, 0);
    wire_move(&w, up, 100, 0);
    const double lift_peak = w.peak, out_of_it = w.last;
    // Out of the cut the tool is the full 3 mm probe again: 1 mm into the top surface (z = 4 mm)
    // 11 mm beside the cut it feels the tissue (about 0.01-0.02 N, test_probe_after_cut).
    const double beside[3] = {0.012, 0, 0.012}, press[3] = {0.012, 0, 0.006};
    wire_move(&w, beside, 300, 0);
    wire_move(&w, press, 300, 0);
    wire_mark(&w);
    wire_move(&w, press, 500, 0);
    const double pressed = w.last;
    printf(
        "  %s cut to the middle (%lld cut steps), released inside: %lld answers, largest "
        "|f| %.3f N (limit %.1f), largest step %.3f N (limit %.3f per 1 ms answer); after "
        "the release (from %.3f N): peak %.3f N, settled %.3f N, range over the last 0.5 s %.4f N; "
        "lifted out: peak %.3f N, out of it %.4f N; pressed 1 mm beside the cut: %.4f N; worst "
        "snapshot %.2f ms "
        "(settling included); compliance %s\n",
        zigzag ? "zig-zag" : "straight", (long long)cut_steps, (long long)w.answers, w.worst_mag,
        SKIN_FORCE_MAX, w.worst_step, SKIN_RATE_MAX * 1e-3, at_release, peak, settled, range,
        lift_peak, out_of_it, pressed, st.snapshot_ms_max,
        st.comp_version == st.topology_version ? "valid" : "still stale");
    destroy_sim(&w.sim);
    hs_free(fixed);
    hs_mesh_destroy(&m);
    // Every answer, on every path, within the limits (sanitizers too).
    ENSURE(w.worst_mag <= SKIN_FORCE_MAX + 1e-9);
    ENSURE(w.worst_step <= SKIN_RATE_MAX * 1e-3 + 1e-9);
#ifndef __SANITIZE_THREAD__ // TSan slows the sweeps, the rebuild and the body ~10x
    ENSURE(cut_steps > 5 && st.comp_version == st.topology_version);
    // No kick: from the force it had to where it settles, never well above both. Under load the
    // fit can come a step late and the probe pushes out gently first (0.131 N from 0.047 N in
    // one loaded run of the straight cut; the kicks this guards against were 0.4-2.4 N).
    ENSURE(peak <= 1.2 * fmax(at_release, settled) + 0.1);
    ENSURE(range <= 0.02); // no chatter while held
    // Lifted out: 16 mm above the patch it feels nothing. On the way out of the straight cut
    // the tissue still catches the sphere in most runs (0.1-0.16 N, 1.0-1.53 N in some, with
    // nothing held before: a known defect, docs/cutting.md), so the bound there is below the
    // scene's clamp, which the old code's spike reached (3.3 N).
    ENSURE(lift_peak < 0.9 * SKIN_FORCE_MAX);
    ENSURE(out_of_it <= 1e-3);
    ENSURE(pressed > 0.003); // the full probe again
#endif
    ENSURE(hs_byte_count() == bytes);
    return 0;
}

static int test_release_inside_zigzag(void) {
    return release_inside(1);
}

static int test_release_inside_halfway(void) {
    return release_inside(0);
}

// One millisecond of the press-beside-the-cut case: feed the pose, wait, then go through rt's
// telemetry. From `from_ns` on (0: not yet) every tick's force counts: the weakest, and the
// ticks below `min_n`.
typedef struct press_run {
    hs_haptic_sim* sim;
    struct timespec t;
    hs_haptic_pose pose;
    double at[3];
    int64_t from_ns;
    int weak, counted;
    double weakest;
    int64_t first_felt_ns; // first tick at or after from_ns with at least min_n (0: none)
} press_run;

#define PRESS_MIN_N 0.003 // a press 1 mm deep beside the cut is ~0.015-0.02 N

static void press_tick(press_run* pr, const double to[3], unsigned buttons) {
    memcpy(pr->at, to, sizeof pr->at);
    feed_ms(pr->sim, &pr->pose, &pr->t, pr->at, buttons);
    hs_haptic_telemetry tl;
    while (hs_spsc_ring_pop(hs_haptic_sim_telemetry(pr->sim), &tl)) {
        if (pr->from_ns <= 0 || tl.now_ns < pr->from_ns) continue;
        double fn = norm3(tl.force_n);
        pr->counted++;
        if (fn < PRESS_MIN_N) pr->weak++;
        if (fn >= PRESS_MIN_N && pr->first_felt_ns == 0) pr->first_felt_ns = tl.now_ns;
        if (pr->counted == 1 || fn < pr->weakest) pr->weakest = fn;
    }
}

static void press_move(press_run* pr, const double to[3], int ticks, unsigned buttons) {
    double from[3];
    memcpy(from, pr->at, sizeof from);
    for (int k = 1; k <= ticks; ++k) {
        double p[3];
        for (int i = 0; i < 3; ++i) p[i] = from[i] + (to[i] - from[i]) * k / ticks;
        press_tick(pr, p, buttons);
    }
}

/// The other hand presses beside the cut: one blade stroke through a 5,043-vertex plate (the
/// `hapsim-bench cut` plate), released, and the tool pressed 1 mm into the surface ~8 mm beside
/// the cut. The compliance followed the stroke's cut steps, so it is valid when the tool comes
/// down: the press is felt within grace_ms of the tool being in place (a snapshot and the blend)
/// and on every tick of the 300 ms after.
static int test_press_beside_cut(void) {
#ifdef __SANITIZE_THREAD__
    // TSan slows every solve ~10x: a coarser plate (1,323 vertices), looser timing.
    const int grace_ms = 1000, cells = 20;
#elif defined(__SANITIZE_ADDRESS__)
    // ASan slows the solves ~3x: a snapshot took up to 232 ms under load, felt after ~300 ms.
    const int grace_ms = 1000, cells = 40;
#else
    // The first snapshot after a cut: its candidates' diagonal blocks and 8 columns afresh,
    // 30-130 ms on this plate on a 2-core machine under load.
    const int grace_ms = 250;
    const int cells = 40;
#endif
    int64_t bytes = hs_byte_count();
    hs_mesh* m = NULL;
    hs_err err = {0};
    ENSURE(hs_mesh_create_box(0.2, 0.2, 0.01, cells, cells, 2, &m, &err) == HS_OK);
    unsigned char* fixed = ends_fixed(m);
    ENSURE(fixed);
    hs_haptic_sim_def d = sim_def();
    const double r = 0.003, top = 0.01;
    d.probe.radius_m = r;
    d.body.fem.material.youngs_pa = 50000; // the skin scene's
    hs_haptic_cut_def cd = hs_haptic_cut_default_def();
    cd.blade_a[2] = -0.008; // from the tool point at mid-thickness through the whole plate
    cd.blade_b[2] = 0.01;
    cd.probe_when_released = 1;
    hs_haptic_sim* sim = NULL;
    ENSURE(start_cutting_sim(m, fixed, &d, &cd, &sim) == 0);
    press_run pr;
    memset(&pr, 0, sizeof pr);
    pr.sim = sim;
    pr.pose.quat_wxyz[0] = 1;
    const double xc = 0.10037, up = 0.03; // off the vertex planes; the whole blade above
    // Beside the cut: the sphere clear of the removed tets' cell column, on intact tissue.
    const double beside = 0.2 / cells + r + 0.00037;
    const double a0[3] = {xc, 0.03, up}, a1[3] = {xc, 0.03, 0.005}, a2[3] = {xc, 0.065, 0.005},
                 a3[3] = {xc, 0.065, up}, b0[3] = {xc + beside, 0.0475, up},
                 b1[3] = {xc + beside, 0.0475, top + r - 0.001};
    memcpy(pr.at, a0, sizeof pr.at);
    clock_gettime(CLOCK_MONOTONIC, &pr.t);
    press_move(&pr, a0, 50, 0);
    press_move(&pr, a1, 250, 1u);  // down along the blade
    press_move(&pr, a2, 1200, 1u); // the stroke, 30 mm/s
    press_move(&pr, a3, 250, 1u);  // out along the blade
    press_move(&pr, b0, 100, 0);   // released, beside the cut
    // The last cut step may still run on a loaded machine (~50 ms a step on this plate): the
    // compliance is valid with it, no rebuild after the release.
    hs_haptic_sim_stats st;
    int waited = 0;
    for (hs_haptic_sim_stats_get(sim, &st);
         (st.topology_version == 0 || st.comp_version != st.topology_version) && waited < 2000;
         hs_haptic_sim_stats_get(sim, &st), ++waited)
        press_tick(&pr, b0, 0);
    const int valid_before = st.topology_version > 0 && st.comp_version == st.topology_version;
    press_move(&pr, b1, 150, 0); // down, 1 mm into the plate
    const int64_t valid_ns = hs_now_ns();
    pr.from_ns = valid_ns;
    press_move(&pr, b1, grace_ms, 0);
    const int64_t first = pr.first_felt_ns;
    pr.from_ns = hs_now_ns();
    pr.weak = pr.counted = 0;
    press_move(&pr, b1, 300, 0);
    hs_haptic_sim_stats_get(sim, &st);
    printf("  cut version %lld, compliance valid %s the press (waited %d ms); first felt %.1f ms "
           "after the tool "
           "was in place (allowed %d ms); then %d of %d ticks below %.3f N, weakest %.4f N; "
           "worst snapshot %.1f ms\n",
           (long long)st.topology_version, valid_before ? "before" : "NOT before", waited,
           first > 0 ? (double)(first - valid_ns) * 1e-6 : -1.0, grace_ms, pr.weak, pr.counted,
           PRESS_MIN_N, pr.weakest, st.snapshot_ms_max);
    printf("  at the end: %d candidates, %d coupled, %d contacts; %lld cut steps followed\n",
           st.candidates, st.coupled, st.contact.n, (long long)st.comp_updates);
    ENSURE(st.topology_version > 0 && st.comp_version == st.topology_version);
    ENSURE(st.cut_failures == 0 && st.comp_rebuilds == 0 && valid_before);
    ENSURE(first > 0 && first - valid_ns <= (int64_t)grace_ms * 1000000);
    ENSURE(pr.counted >= 250 && pr.weak == 0);
    destroy_sim(&sim);
    hs_free(fixed);
    hs_mesh_destroy(&m);
    ENSURE(hs_byte_count() == bytes);
    return 0;
}

// A compliance built afresh on the cut mesh: the live tets, holding the fixed nodes and those no
// live tet uses (as the rebuild does).
static hs_compliance* fresh_compliance(const hs_mesh* live, const unsigned char* fixed,
                                       const hs_fem_def* fd) {
    const int n = live->n_nodes;
    unsigned char* fix2 = hs_alloc((size_t)n);
    if (!fix2) return NULL;
    memset(fix2, 1, (size_t)n);
    for (int k = 0; k < 4 * live->n_tets; ++k) fix2[live->tets[k]] = 0;
    for (int i = 0; i < n; ++i) fix2[i] |= fixed[i];
    hs_compliance* c = NULL;
    hs_err err = {0};
    // On the cut's live mesh itself (same nodes and x0, the live tets and surface).
    if (hs_compliance_create(live, fd, fix2, 96, &c, &err) != HS_OK) c = NULL;
    hs_free(fix2);
    return c;
}

// Surface node nearest to p.
static int nearest_surface_node(const hs_mesh* m, const double p[3]) {
    int best = -1;
    double bd = INFINITY;
    for (int s = 0; s < m->n_surf_nodes; ++s) {
        const int v = m->surf_nodes[s];
        const double* x = m->x0 + 3 * v;
        double d = pow(x[0] - p[0], 2) + pow(x[1] - p[1], 2) + pow(x[2] - p[2], 2);
        if (d < bd) bd = d, best = v;
    }
    return best;
}

/// The compliance follows a cut across the skin patch (2 mm sweeps at rest, y from -45 to
/// 45 mm, blade through the thickness at x = 1 mm) by hs_compliance_change_elements after every
/// sweep. At 8, 24 and all 45 steps a 3 mm sphere pressed 1 mm deep 4 mm beside the cut, just
/// behind the blade, feels the force a compliance built afresh on the cut mesh gives, within 1 %.
/// Cut through, a press 5 mm on one side of it pulls nothing on the other: the cross block and
/// the force at the far node are zero to round-off (before the cut they were not).
static int test_follow_matches_fresh(void) {
    int64_t bytes = hs_byte_count();
    hs_mesh* m = NULL;
    unsigned char* fixed = NULL;
    ENSURE(skin_with_ends_fixed(&m, &fixed) == 0);
    hs_fem_def fd = sim_def().body.fem;
    fd.material.youngs_pa = 50000;
    hs_err err = {0};
    hs_compliance* c = NULL;
    ENSURE(hs_compliance_create(m, &fd, fixed, 96, &c, &err) == HS_OK);
    ENSURE(hs_compliance_prepare_changes(c) == HS_OK);
    // Across the cut line, 5 mm each side on the top surface at y = 0.
    const double top = 0.004, r = 0.003, pi[3] = {-0.004, 0, top}, pj[3] = {0.006, 0, top};
    const int ni = nearest_surface_node(m, pi), nj = nearest_surface_node(m, pj);
    double blk_before[9], dd[6] = {0, 0, -0.001, 0, 0, 0}, f_before[6];
    const int pair[2] = {ni, nj};
    ENSURE(hs_compliance_solve_set(c, 2, pair, NULL, dd, f_before) == HS_OK); // solves columns
    ENSURE(hs_compliance_block(c, ni, nj, blk_before) == 1);

    hs_cut_def cdef = hs_cut_default_def(); // as the server runs it
    cdef.orphan = HS_CUT_ORPHAN_PIN;
    cdef.fragment = HS_CUT_FRAGMENT_DROP;
    cdef.pins_hold = 0;
    hs_cut* cut = NULL;
    ENSURE(hs_cut_create(m, fixed, &cdef, &cut, &err) == HS_OK);
    hs_cut_surface* fs = NULL; // the live boundary as the sim follows it
    ENSURE(hs_cut_surface_create(m, &fs) == HS_OK);
    int* ta = hs_alloc(3 * 4 * (size_t)m->n_tets * sizeof(int));
    int* tb = hs_alloc(3 * 4 * (size_t)m->n_tets * sizeof(int));
    ENSURE(ta && tb);
    const double step = 0.002, xc = 0.001;
    int k = 0;
    double worst = 0;
    for (double y = -0.045; y < 0.045 - 1e-9; y += step) {
        const double p0[3] = {xc, y, -0.001}, q0[3] = {xc, y, 0.005};
        const double p1[3] = {xc, y + step, -0.001}, q1[3] = {xc, y + step, 0.005};
        hs_cut_result res;
        ENSURE(hs_cut_sweep(cut, p0, q0, p1, q1, NULL, &res, &err) == HS_OK);
        const hs_mesh* live = hs_cut_live_mesh(cut);
        ENSURE(live);
        const int *off, *mv;
        const int n_off = hs_cut_last_removed(cut, &off), n_mv = hs_cut_last_changed(cut, &mv);
        hs_cut_surface_remove(fs, n_off, off);
        const hs_mesh* fv = hs_cut_surface_mesh(fs);
        ENSURE(hs_compliance_change_elements(c, n_off, off, n_mv, mv, fv) == HS_OK);
        // The followed boundary is the live mesh's, triangle for triangle, same orientation.
        ENSURE(fv->n_tris == live->n_tris && fv->n_surf_nodes == live->n_surf_nodes);
        canonical_tris(fv->tris, fv->n_tris, ta);
        canonical_tris(live->tris, live->n_tris, tb);
        ENSURE(!memcmp(ta, tb, 3 * (size_t)fv->n_tris * sizeof(int)));
        ENSURE(!memcmp(fv->surf_nodes, live->surf_nodes, (size_t)fv->n_surf_nodes * sizeof(int)));
        ++k;
        if (k != 8 && k != 24 && k != 45) continue;
        hs_compliance* fresh = fresh_compliance(live, fixed, &fd);
        ENSURE(fresh);
        const double press[3] = {xc + 0.004, fmin(y, 0.035) - 0.004, top + r - 0.001};
        double fa[3], fb[3];
        ENSURE(rest_force(c, m->x0, live->tris, live->n_tris, m->n_nodes, press, r, fa) > 0);
        ENSURE(rest_force(fresh, m->x0, live->tris, live->n_tris, m->n_nodes, press, r, fb) > 0);
        const double rel =
            sqrt(pow(fa[0] - fb[0], 2) + pow(fa[1] - fb[1], 2) + pow(fa[2] - fb[2], 2)) /
            sqrt(fb[0] * fb[0] + fb[1] * fb[1] + fb[2] * fb[2]);
        printf("  after %d cut steps (%d tets removed): press beside the cut %.5f N followed, "
               "%.5f N fresh, difference %.1e\n",
               k, m->n_tets - live->n_tets, fa[2], fb[2], rel);
        worst = fmax(worst, rel);
        ENSURE(fb[2] > 0.001);
        hs_compliance_destroy(&fresh);
    }
    ENSURE(k == 45 && worst <= 0.01);
    ENSURE(hs_compliance_updates(c) == 45);
    // Cut through: no coupling across it.
    double blk[9], f_after[6], nb = 0, na = 0, ni2 = 0;
    ENSURE(hs_compliance_solve_set(c, 2, pair, NULL, dd, f_after) == HS_OK);
    ENSURE(hs_compliance_block(c, ni, nj, blk) == 1);
    double bii[9];
    ENSURE(hs_compliance_block(c, ni, ni, bii) == 1);
    for (int q = 0; q < 9; ++q)
        nb += blk_before[q] * blk_before[q], na += blk[q] * blk[q], ni2 += bii[q] * bii[q];
    const double pull_before = sqrt(f_before[3] * f_before[3] + f_before[4] * f_before[4] +
                                    f_before[5] * f_before[5]),
                 pull_after = sqrt(f_after[3] * f_after[3] + f_after[4] * f_after[4] +
                                   f_after[5] * f_after[5]);
    printf("  cut through: cross block %.2e -> %.2e m/N (own block %.2e); the far node's force "
           "for a 1 mm press on the near one %.2e -> %.2e N (press %.3f N)\n",
           sqrt(nb), sqrt(na), sqrt(ni2), pull_before, pull_after, fabs(f_after[2]));
    ENSURE(sqrt(nb) > 1e-3 * sqrt(ni2) && pull_before > 1e-3 * fabs(f_before[2]));
    ENSURE(sqrt(na) <= 1e-9 * sqrt(ni2));
    ENSURE(pull_after <= 1e-9 * fabs(f_after[2]));
    hs_cut_destroy(&cut);
    hs_cut_surface_destroy(&fs);
    hs_free(ta);
    hs_free(tb);
    hs_compliance_destroy(&c);
    hs_free(fixed);
    hs_mesh_destroy(&m);
    ENSURE(hs_byte_count() == bytes);
    return 0;
}

/// On a small plate (8 x 8 x 1 cells) the compliance follows a cut across: after every step
/// each surface node's diagonal block equals a fresh compliance's on the cut mesh (1e-8), the
/// followed surface's; cut through, the two sides do not couple.
static int test_follow_each_step(void) {
    int64_t bytes = hs_byte_count();
    hs_mesh* m = NULL;
    hs_err err = {0};
    ENSURE(hs_mesh_create_box(0.04, 0.04, 0.004, 8, 8, 1, &m, &err) == HS_OK);
    unsigned char* fixed = ends_fixed(m);
    ENSURE(fixed);
    hs_fem_def fd = sim_def().body.fem;
    fd.material.youngs_pa = 50000;
    hs_compliance* c = NULL;
    ENSURE(hs_compliance_create(m, &fd, fixed, 96, &c, &err) == HS_OK);
    hs_cut_def cdef = hs_cut_default_def();
    cdef.orphan = HS_CUT_ORPHAN_PIN;
    cdef.pins_hold = 0;
    hs_cut* cut = NULL;
    ENSURE(hs_cut_create(m, fixed, &cdef, &cut, &err) == HS_OK);
    hs_cut_surface* fs = NULL;
    ENSURE(hs_cut_surface_create(m, &fs) == HS_OK);
    const double xc = 0.02137, step = 0.005; // the box spans [0, 0.04] in x and y
    double worst = 0;
    int steps = 0;
    for (double y = -0.005; y < 0.045 - 1e-9; y += step) {
        const double p0[3] = {xc, y, -0.001}, q0[3] = {xc, y, 0.005};
        const double p1[3] = {xc, y + step, -0.001}, q1[3] = {xc, y + step, 0.005};
        hs_cut_result res;
        ENSURE(hs_cut_sweep(cut, p0, q0, p1, q1, NULL, &res, &err) == HS_OK);
        if (res.removed == 0 && res.moved == 0) continue;
        const int *off, *mv;
        const int n_off = hs_cut_last_removed(cut, &off), n_mv = hs_cut_last_changed(cut, &mv);
        hs_cut_surface_remove(fs, n_off, off);
        ENSURE(hs_compliance_change_elements(c, n_off, off, n_mv, mv, hs_cut_surface_mesh(fs)) ==
               HS_OK);
        ++steps;
        const hs_mesh* live = hs_cut_live_mesh(cut);
        hs_compliance* fresh = fresh_compliance(live, fixed, &fd);
        ENSURE(fresh);
        for (int i = 0; i < m->n_nodes; ++i) {
            if (!hs_compliance_contactable(fresh, i)) continue;
            ENSURE(hs_compliance_contactable(c, i));
            double a[9], b[9], na = 0, nd = 0;
            ENSURE(hs_compliance_ensure(c, 1, &i, 0) == 0);
            ENSURE(hs_compliance_block(c, i, i, a) && hs_compliance_block(fresh, i, i, b));
            for (int k = 0; k < 9; ++k) na += b[k] * b[k], nd += (a[k] - b[k]) * (a[k] - b[k]);
            worst = fmax(worst, sqrt(nd / na));
        }
        hs_compliance_destroy(&fresh);
    }
    const double pi[3] = {0.015, 0.02, 0.004}, pj[3] = {0.03, 0.02, 0.004};
    const int pair[2] = {nearest_surface_node(m, pi), nearest_surface_node(m, pj)};
    double blk[9], bii[9], na = 0, ni = 0;
    const double dd[6] = {0, 0, -0.001, 0, 0, 0};
    double f[6];
    ENSURE(hs_compliance_solve_set(c, 2, pair, NULL, dd, f) == HS_OK);
    ENSURE(hs_compliance_block(c, pair[0], pair[1], blk) &&
           hs_compliance_block(c, pair[0], pair[0], bii));
    for (int q = 0; q < 9; ++q) na += blk[q] * blk[q], ni += bii[q] * bii[q];
    printf("  %d cut steps followed: diagonal blocks as fresh to %.1e; cut through, cross block "
           "%.1e of the own block\n",
           steps, worst, sqrt(na / ni));
    ENSURE(steps >= 5 && worst <= 1e-8);
    ENSURE(sqrt(na) <= 1e-9 * sqrt(ni) && hs_cut_components(cut) == 2);
    hs_cut_destroy(&cut);
    hs_cut_surface_destroy(&fs);
    hs_compliance_destroy(&c);
    hs_free(fixed);
    hs_mesh_destroy(&m);
    ENSURE(hs_byte_count() == bytes);
    return 0;
}

GUARDED(test_enable_errors)
GUARDED(test_follow_each_step)
GUARDED(test_follow_matches_fresh)
GUARDED(test_blade_drag)
GUARDED(test_probe_after_cut)
GUARDED(test_probe_after_fine_cut)
GUARDED(test_free_piece_dropped)
GUARDED(test_free_piece_fall_rule)
GUARDED(test_restart_mid_cut)
GUARDED(test_force_speed)
GUARDED(test_release_inside_zigzag)
GUARDED(test_release_inside_halfway)
GUARDED(test_press_beside_cut)

#define GUARDED_CASE(fn)                                                                           \
    { #fn, fn##_guarded }

HS_TEST_MAIN(GUARDED_CASE(test_enable_errors), GUARDED_CASE(test_follow_matches_fresh),
             GUARDED_CASE(test_follow_each_step), GUARDED_CASE(test_blade_drag),
             GUARDED_CASE(test_probe_after_cut), GUARDED_CASE(test_probe_after_fine_cut),
             GUARDED_CASE(test_free_piece_dropped), GUARDED_CASE(test_free_piece_fall_rule),
             GUARDED_CASE(test_restart_mid_cut), GUARDED_CASE(test_force_speed),
             GUARDED_CASE(test_release_inside_zigzag), GUARDED_CASE(test_release_inside_halfway),
             GUARDED_CASE(test_press_beside_cut))
