// SPDX-License-Identifier: GPL-2.0-or-later
// Deterministic replay of a recorded hapsim session: the tool poses of an LCM log, read through
// LCM's file provider (file://LOG?speed=0) with time from each pose's own utime, answered by the
// library's probe contact against the scene's rest-state (linear, quasi-static) compliance.
//
//   e2e_replay SCENE LOG [PREFIX]
//
// Prints one line per pose of device 0: `replay T_S FX FY FZ |F| POSE_UTIME`, T_S = seconds since
// the first pose's utime; then `poses N`. Exit 1 when the log is not complete (e2e_lcmlog.h:
// cut off, not an event, fewer pose messages delivered than it holds); any path works, '?'
// included. The same log gives the same output bit for bit (no
// threads, no clocks). It is not the live server: no body dynamics and no co-rotation (the
// server's co-rotated equilibrium differs by a few per cent at millimetre indentations,
// docs/haptics.md), so it checks a recorded session's forces, not reproduce them exactly.
#define _POSIX_C_SOURCE 200809L
#include "hapsim/version.h"
#include "e2e_lcmlog.h"
#include "compliance.h"
#include "mesh.h"
#include "scene.h"
#include "hapsim_tool_pose_t.h"

#include <lcm/lcm.h>
#include <math.h>
#include <poll.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

typedef struct replay {
    const hs_mesh* mesh;
    hs_compliance* comp;
    double radius_m, reach_m;
    double* normal; // [3 n_nodes] area-weighted outward vertex normals of surface nodes
    hs_contact_snapshot snap;
    hs_contact contact;
    int have_snap;
    int64_t t0_us;
    long poses, messages; // device-0 poses answered, messages on the channel
    char channel[96];
} replay;

static double dist2(const double* a, const double* b) {
    double d0 = a[0] - b[0], d1 = a[1] - b[1], d2 = a[2] - b[2];
    return d0 * d0 + d1 * d1 + d2 * d2;
}

// Candidates: the contactable surface nodes nearest the tool within reach (insertion order by
// distance, ties by node index, so the choice depends on the pose only), and the boundary
// triangles among them.
static void build_snapshot(replay* r, const double p[3]) {
    hs_contact_snapshot* s = &r->snap;
    const hs_mesh* m = r->mesh;
    int cand[HS_CONTACT_MAX_CAND];
    double cd[HS_CONTACT_MAX_CAND];
    int n = 0;
    double reach2 = r->reach_m * r->reach_m;
    for (int k = 0; k < m->n_surf_nodes; ++k) {
        int node = m->surf_nodes[k];
        if (!hs_compliance_contactable(r->comp, node)) continue;
        double d = dist2(m->x0 + 3 * node, p);
        if (d > reach2) continue;
        if (n == HS_CONTACT_MAX_CAND && d >= cd[n - 1]) continue;
        int i = n < HS_CONTACT_MAX_CAND ? n++ : n - 1;
        while (i > 0 && cd[i - 1] > d) {
            cand[i] = cand[i - 1];
            cd[i] = cd[i - 1];
            --i;
        }
        cand[i] = node;
        cd[i] = d;
    }
    hs_compliance_begin_step(r->comp);
    int have = n ? hs_compliance_ensure(r->comp, n, cand, n) : 0;
    s->version++;
    s->stamp_ns = 0;
    s->probe_radius_m = r->radius_m;
    memcpy(s->centre_m, p, sizeof s->centre_m);
    s->reach_m = r->reach_m;
    s->n_cand = n;
    for (int i = 0; i < n; ++i) {
        s->node[i] = cand[i];
        s->coupled[i] = (unsigned char)(have == n);
        memcpy(s->surf_m[i], m->x0 + 3 * cand[i], sizeof s->surf_m[i]);
        memcpy(s->normal[i], r->normal + 3 * cand[i], sizeof s->normal[i]);
        for (int j = 0; j < n; ++j) hs_compliance_block(r->comp, cand[i], cand[j], s->c[i][j]);
    }
    hs_contact_snapshot_add_tris(s, m); // surface contact, as the server's
    r->have_snap = 1;
}

static void on_pose(const lcm_recv_buf_t* rb, const char* channel, void* user) {
    (void)channel;
    replay* r = user;
    r->messages++;
    hapsim_tool_pose_t p;
    if (hapsim_tool_pose_t_decode(rb->data, 0, (int)rb->data_size, &p) < 0) return;
    if (p.device_id == 0) {
        if (!r->poses) r->t0_us = p.utime;
        r->poses++;
        // A new candidate set once the tool moved a quarter of the margin from the last centre.
        double margin = r->reach_m - 1.25 * r->radius_m;
        if (!r->have_snap || dist2(p.position, r->snap.centre_m) > 0.0625 * margin * margin)
            build_snapshot(r, p.position);
        hs_contact prev = r->contact;
        hs_contact_solve_from(&r->snap, p.position, &prev, &r->contact);
        const double* f = r->contact.force_n;
        printf("replay %.6f %.9g %.9g %.9g %.9g %lld\n", (double)(p.utime - r->t0_us) * 1e-6, f[0],
               f[1], f[2], sqrt(f[0] * f[0] + f[1] * f[1] + f[2] * f[2]), (long long)p.utime);
    }
    hapsim_tool_pose_t_decode_cleanup(&p);
}

// Area-weighted vertex normals of the boundary (only used by the contact for a node at the
// exact centre of the sphere).
static double* vertex_normals(const hs_mesh* m) {
    double* nrm = hs_calloc(3 * (size_t)m->n_nodes, sizeof(double));
    if (!nrm) return NULL;
    for (int t = 0; t < m->n_tris; ++t) {
        const int* v = m->tris + 3 * t;
        const double *a = m->x0 + 3 * v[0], *b = m->x0 + 3 * v[1], *c = m->x0 + 3 * v[2];
        double e1[3] = {b[0] - a[0], b[1] - a[1], b[2] - a[2]};
        double e2[3] = {c[0] - a[0], c[1] - a[1], c[2] - a[2]};
        double x[3] = {e1[1] * e2[2] - e1[2] * e2[1], e1[2] * e2[0] - e1[0] * e2[2],
                       e1[0] * e2[1] - e1[1] * e2[0]};
        for (int k = 0; k < 3; ++k)
            for (int a2 = 0; a2 < 3; ++a2) nrm[3 * v[k] + a2] += x[a2];
    }
    for (int i = 0; i < m->n_nodes; ++i) {
        double* q = nrm + 3 * i;
        double l = sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2]);
        if (l > 0)
            for (int a = 0; a < 3; ++a) q[a] /= l;
        else
            q[1] = 1;
    }
    return nrm;
}

static void fixed_mask(const hs_scene* sc, const hs_mesh* m, unsigned char* fixed,
                       unsigned char* sel) {
    memset(fixed, 0, (size_t)m->n_nodes);
    for (int r = 0; r < sc->n_fixed; ++r) {
        const hs_scene_fixed* f = &sc->fixed[r];
        memset(sel, 0, (size_t)m->n_nodes);
        if (f->kind == HS_FIXED_PLANE) {
            double l = sqrt(f->normal[0] * f->normal[0] + f->normal[1] * f->normal[1] +
                            f->normal[2] * f->normal[2]);
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

int main(int argc, char** argv) {
    if (hapsim_version_asked(argc, argv, "e2e_replay")) return 0;
    for (int i = 1; i < argc; ++i)
        if (!strcmp(argv[i], "-h") || !strcmp(argv[i], "--help")) {
            printf("usage: e2e_replay SCENE LOG [PREFIX]\n\nReplay the tool poses of a hapsim "
                   "session's LCM log against SCENE's rest-state\ncompliance and print the force "
                   "for each pose of device 0, bit for bit the same on\nevery run. PREFIX: the "
                   "channel prefix (the scene's). Exit status: 0 ok, 1 bad scene\nor log, 2 bad "
                   "usage. See docs/replay.md.\n");
            return 0;
        }
    if (argc != 3 && argc != 4) {
        fprintf(stderr, "usage: %s SCENE LOG [PREFIX]\n", argv[0]);
        return 2;
    }
    hs_err err = {0};
    hs_scene sc;
    if (hs_scene_load(argv[1], &sc, &err) != HS_OK) {
        fprintf(stderr, "%s\n", err.msg);
        return 1;
    }
    // The log is checked before the scene's compliance is built (seconds).
    static replay r;
    snprintf(r.channel, sizeof r.channel, "%sTOOL_POSE", argc == 4 ? argv[3] : sc.prefix);
    hs_lcmlog log;
    if (hs_lcmlog_open(argv[2], r.channel, &log) != 0) {
        fprintf(stderr, "%s: %s\n", argv[0], log.why);
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
    r.mesh = mesh;
    r.radius_m = 0.005;
    for (int t = 0; t < sc.n_tools; ++t)
        if (sc.tools[t].kind == HS_TOOL_PROBE) {
            r.radius_m = sc.tools[t].radius;
            break;
        }
    r.reach_m = 1.25 * r.radius_m + 0.010;
    unsigned char* fixed = hs_calloc((size_t)mesh->n_nodes, 1);
    unsigned char* sel = hs_calloc((size_t)mesh->n_nodes, 1);
    r.normal = vertex_normals(mesh);
    if (!fixed || !sel || !r.normal) return 1;
    fixed_mask(&sc, mesh, fixed, sel);
    hs_fem_def fd = hs_fem_default_def();
    fd.material = sc.material;
    if (hs_compliance_create(mesh, &fd, fixed, 4 * HS_CONTACT_MAX_CAND, &r.comp, &err) != HS_OK) {
        fprintf(stderr, "%s\n", err.msg);
        return 1;
    }
    lcm_t* lcm = lcm_create(log.url);
    if (!lcm) {
        fprintf(stderr, "%s: LCM cannot open %s (%s)\n", argv[0], log.url, argv[2]);
        return 1;
    }
    lcm_subscription_t* sub = lcm_subscribe(lcm, r.channel, on_pose, &r);
    lcm_subscription_set_queue_capacity(sub, 1 << 20);
    for (;;) {
        struct pollfd pfd = {lcm_get_fileno(lcm), POLLIN, 0};
        if (poll(&pfd, 1, 500) <= 0) break;
        if (lcm_handle(lcm) != 0) break;
    }
    printf("poses %ld\n", r.poses);
    lcm_unsubscribe(lcm, sub);
    lcm_destroy(lcm);
    hs_compliance_destroy(&r.comp);
    hs_free(r.normal);
    hs_free(fixed);
    hs_free(sel);
    hs_mesh_destroy(&mesh);
    hs_lcmlog_close(&log);
    if (r.messages != log.channel_events) {
        fprintf(stderr, "%s: %s: LCM delivered %ld of the log's %ld %s messages\n", argv[0],
                argv[2], r.messages, log.channel_events, r.channel);
        return 1;
    }
    return 0;
}
