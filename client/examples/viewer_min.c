// SPDX-License-Identifier: MIT
// Minimal visualiser: keep a consistent copy of the server's mesh and print one line per new
// frame (at most 4 per second): topology version, nodes, triangles, largest displacement.
//   hapsim-example-viewer [SECONDS]      (default 5)
#include <hapsim/client.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

static void on_mesh(hs_client* c, const hs_client_mesh* m, void* user) {
    (void)c;
    int64_t* last_print = user;
    int64_t now = hs_client_now_us();
    if (now - *last_print < 250000) return;
    *last_print = now;
    double dmax = 0;
    for (int32_t i = 0; i < m->n_vis; i++) {
        double s = 0;
        for (int k = 0; k < 3; k++) {
            double d = (double)m->position[3 * i + k] - m->rest[3 * i + k];
            s += d * d;
        }
        dmax = fmax(dmax, sqrt(s));
    }
    printf("frame %lld  topology v%lld  keyframe %lld  %d nodes  %d triangles  t %.3f s  "
           "max displacement %.3f mm\n",
           (long long)m->frame, (long long)m->topology_version, (long long)m->keyframe_id, m->n_vis,
           m->n_tri, m->sim_time, dmax * 1e3);
}

int main(int argc, char** argv) {
    double seconds = 5.0;
    if (argc > 1 && (!strcmp(argv[1], "-h") || !strcmp(argv[1], "--help"))) {
        puts("usage: hapsim-example-viewer [SECONDS]   (default 5)");
        return 0;
    }
    if (argc > 1) { // strtod, not atof: a word must not read as 0 s
        char* end = NULL;
        seconds = strtod(argv[1], &end);
        if (argc > 2 || end == argv[1] || *end != '\0' || !isfinite(seconds) || seconds < 0) {
            fprintf(stderr, "viewer: expected [SECONDS], a number >= 0; got '%s'%s\n", argv[1],
                    argc > 2 ? " and more" : "");
            return 2;
        }
    }
    hs_client_config cfg;
    hs_client_config_default(&cfg);
    cfg.haptic_url = ""; // a visualiser needs only the mesh bus
    cfg.subscribe = HS_CLIENT_SUB_MESH;
    hs_client* c = NULL;
    hs_err err = {0};
    if (hs_client_create(&cfg, &c, &err) != HS_OK) {
        fprintf(stderr, "viewer: %s\n", err.msg);
        return 1;
    }
    int64_t last_print = 0, t0 = hs_client_now_us();
    hs_client_callbacks cb = {.on_mesh = on_mesh};
    hs_client_set_callbacks(c, &cb, &last_print);
    while (hs_client_now_us() - t0 < (int64_t)(seconds * 1e6))
        if (hs_client_poll(c, 100, &err) < 0) {
            fprintf(stderr, "viewer: %s\n", err.msg);
            break;
        }
    hs_sync_stats s;
    hs_client_mesh_stats(c, &s);
    printf("viewer: %lld mesh changes; lost %lld, malformed %lld\n", (long long)s.applied,
           (long long)(s.lost[0] + s.lost[1] + s.lost[2] + s.lost[3]), (long long)s.malformed);
    hs_client_destroy(&c);
    return 0;
}
