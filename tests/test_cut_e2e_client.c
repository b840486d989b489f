// SPDX-License-Identifier: GPL-2.0-or-later
// Client side of tests/test_cut_e2e.sh (real LCM, private namespace): a libhapsim-client
// connection that checks what a visualiser sees of the server's cuts.
//   test_cut_e2e_client watch SECONDS ORIG_TRIS
//     connected before the cut: counts topology events (each must go old -> old + 1, versions
//     increasing), and at the end its mesh must be at the newest event's version
//   test_cut_e2e_client late SECONDS ORIG_TRIS
//     joins after the cut (it missed every event): within SECONDS it must hold the server's
//     newest topology (status topology_version) with a keyframe
// Both then check the mesh: triangle count differs from ORIG_TRIS, every triangle index in
// range and non-degenerate, every visual node used by a triangle (no orphan), visual node ids
// distinct and within the volume mesh, positions finite. Prints "events N version V tris T".
// Exit 0 pass, 1 fail, 2 usage.
#include "hapsim/client.h"

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

typedef struct watch {
    int64_t events, last_new, bad_versions;
} watch;

static void on_event(hs_client* c, int64_t old_version, int64_t new_version, int32_t n_removed,
                     void* user) {
    (void)c;
    (void)n_removed;
    watch* w = user;
    if (new_version != old_version + 1 || new_version <= w->last_new) w->bad_versions++;
    w->last_new = new_version;
    w->events++;
}

static int check_mesh(const hs_client_mesh* m, int orig_tris) {
    if (!m || !m->ready) {
        printf("FAIL: no mesh\n");
        return 1;
    }
    if (m->n_tri == orig_tris) {
        printf("FAIL: %d triangles, as before the cut\n", m->n_tri);
        return 1;
    }
    char* used = calloc((size_t)m->n_vis + 1, 1);
    char* seen = calloc((size_t)m->n_nodes + 1, 1);
    if (!used || !seen) {
        free(used);
        free(seen);
        return 1;
    }
    int bad = 0;
    for (int t = 0; t < m->n_tri && !bad; ++t) {
        const int32_t* v = m->triangles + 3 * t;
        for (int k = 0; k < 3; ++k)
            if (v[k] < 0 || v[k] >= m->n_vis) bad = 1;
        if (!bad && (v[0] == v[1] || v[1] == v[2] || v[0] == v[2])) bad = 2;
        for (int k = 0; k < 3 && !bad; ++k) used[v[k]] = 1;
    }
    for (int i = 0; i < m->n_vis && !bad; ++i) {
        int id = m->vis_nodes[i];
        if (id < 0 || id >= m->n_nodes || seen[id])
            bad = 3;
        else
            seen[id] = 1;
        if (!used[i]) bad = 4;
        for (int k = 0; k < 3; ++k)
            if (!isfinite(m->position[3 * i + k]) || !isfinite(m->rest[3 * i + k])) bad = 5;
    }
    free(used);
    free(seen);
    static const char* what[] = {"",
                                 "triangle index out of range",
                                 "degenerate triangle",
                                 "visual node id repeated or out of range",
                                 "orphan visual node (no triangle)",
                                 "non-finite position"};
    if (bad) {
        printf("FAIL: mesh at version %lld: %s\n", (long long)m->topology_version, what[bad]);
        return 1;
    }
    return 0;
}

static int find(int* up, int i) {
    while (up[i] != i) i = up[i] = up[up[i]];
    return i;
}

// Connected pieces of the drawn surface (triangles sharing a visual node); -1 on no memory.
static int pieces(const hs_client_mesh* m) {
    int* up = malloc(((size_t)m->n_vis + 1) * sizeof(int));
    if (!up) return -1;
    for (int i = 0; i < m->n_vis; ++i) up[i] = i;
    for (int t = 0; t < m->n_tri; ++t) {
        const int32_t* v = m->triangles + 3 * t;
        for (int k = 1; k < 3; ++k) up[find(up, v[k])] = find(up, v[0]);
    }
    int n = 0;
    for (int i = 0; i < m->n_vis; ++i) n += find(up, i) == i;
    free(up);
    return n;
}

int main(int argc, char** argv) {
    if (argc != 4 || (strcmp(argv[1], "watch") && strcmp(argv[1], "late"))) {
        fprintf(stderr, "usage: %s watch|late SECONDS ORIG_TRIS\n", argv[0]);
        return 2;
    }
    int late = !strcmp(argv[1], "late");
    double secs = atof(argv[2]);
    int orig_tris = atoi(argv[3]);
    hs_client_config cfg;
    hs_client_config_default(&cfg);
    cfg.haptic_url = "";
    cfg.subscribe = HS_CLIENT_SUB_MESH | HS_CLIENT_SUB_STATUS;
    hs_client* c = NULL;
    hs_err err = {0};
    if (hs_client_create(&cfg, &c, &err) != HS_OK) {
        printf("FAIL: client: %s\n", err.msg);
        return 1;
    }
    watch w = {0, 0, 0};
    hs_client_callbacks cb;
    memset(&cb, 0, sizeof cb);
    cb.on_topology_event = on_event;
    hs_client_set_callbacks(c, &cb, &w);
    int64_t end = hs_client_now_us() + (int64_t)(secs * 1e6);
    int rc = 1;
    while (hs_client_now_us() < end) {
        if (hs_client_poll(c, 50, &err) < 0) {
            printf("FAIL: poll: %s\n", err.msg);
            break;
        }
        if (!late) continue;
        hs_client_status st;
        int64_t age = 0;
        const hs_client_mesh* m = hs_client_mesh_view(c);
        if (m && m->ready && hs_client_status_latest(c, &st, &age) && st.topology_version > 1 &&
            m->topology_version == st.topology_version) {
            rc = check_mesh(m, orig_tris);
            printf("late: version %lld tris %d vis %d surface pieces %d (%lld events seen)\n",
                   (long long)m->topology_version, m->n_tri, m->n_vis, pieces(m),
                   (long long)w.events);
            break;
        }
    }
    if (!late) {
        const hs_client_mesh* m = hs_client_mesh_view(c);
        rc = 0;
        if (w.events == 0) {
            printf("FAIL: no topology event\n");
            rc = 1;
        } else if (w.bad_versions) {
            printf("FAIL: %lld events with versions not old -> old + 1, increasing\n",
                   (long long)w.bad_versions);
            rc = 1;
        } else if (!m || m->topology_version != w.last_new) {
            printf("FAIL: mesh at version %lld, newest event %lld\n",
                   m ? (long long)m->topology_version : -1LL, (long long)w.last_new);
            rc = 1;
        } else {
            rc = check_mesh(m, orig_tris);
        }
        printf("events %lld version %lld tris %d\n", (long long)w.events, (long long)w.last_new,
               m ? m->n_tri : -1);
    } else if (rc == 1 && hs_client_now_us() >= end) {
        printf("FAIL: late client: no mesh at the server's topology version within %g s\n", secs);
    }
    hs_client_destroy(&c);
    return rc;
}
