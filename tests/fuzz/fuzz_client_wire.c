// SPDX-License-Identifier: GPL-2.0-or-later
// libFuzzer target: the client library on the bytes a visualiser or a stylus driver receives.
// The input is split into up to 16 messages by 0xFF 0xFE separators; the first byte of each
// picks its kind: a mesh topology, keyframe, delta or topology event (fed in order to one mesh
// sync), a tool force (into a force renderer), a command ack or a server status. After every
// message: the counters add up, the visible mesh is one a renderer can draw (indices in range,
// coordinates finite), and the force rendered anywhere is finite.
#include <math.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include "hapsim/client.h"
#include "wire.h"

int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size);

static void check_mesh(const hs_client_mesh* m) {
    if (!m->ready) return;
    if (m->n_nodes < 0 || m->n_vis < 0 || m->n_vis > HS_CLIENT_MAX_VIS || m->n_tri < 0 ||
        m->n_tet < 0 || (m->n_tet > 0) != (m->tets != NULL))
        abort();
    for (int32_t i = 0; i < m->n_vis; i++) {
        if (m->vis_nodes[i] < 0 || m->vis_nodes[i] >= m->n_nodes) abort();
        for (int k = 0; k < 3; k++)
            if (!isfinite(m->rest[3 * i + k]) || !isfinite(m->position[3 * i + k])) abort();
        if (m->stress && !isfinite(m->stress[i])) abort();
    }
    for (int32_t i = 0; i < 3 * m->n_tri; i++)
        if (m->triangles[i] < 0 || m->triangles[i] >= m->n_vis) abort();
    for (int32_t i = 0; i < 4 * m->n_tet; i++)
        if (m->tets[i] < 0 || m->tets[i] >= m->n_vis) abort();
}

static void check_force(const hs_force_renderer* r, int64_t now) {
    static const double where[4][3] = {
        {0, 0, 0}, {1e3, -1e3, 1e3}, {1e308, 1e308, -1e308}, {NAN, 0, INFINITY}};
    for (int w = 0; w < 4; w++) {
        double f[3];
        hs_force_renderer_eval(r, where[w], now, f);
        for (int k = 0; k < 3; k++)
            if (!isfinite(f[k])) abort();
    }
}

int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
    hs_mesh_sync* sync = NULL;
    if (hs_mesh_sync_create(&sync, NULL) != HS_OK) return 0;
    hs_force_renderer r;
    hs_force_renderer_init(&r);
    int64_t fed[4] = {0}, applied = 0, stale = 0, mismatched = 0, malformed = 0, now = 1000;
    size_t start = 0;
    for (int n = 0; n < 16 && start < size; ++n) {
        size_t end = start;
        while (end + 1 < size && !(data[end] == 0xFF && data[end + 1] == 0xFE)) ++end;
        if (end + 1 >= size) end = size;
        if (end == start) { // no kind byte
            start = end + 2;
            continue;
        }
        const uint8_t* msg = data + start + 1;
        size_t len = end - start - 1;
        int kind = data[start] % 7;
        if (kind < 4) {
            hs_sync_result res = hs_mesh_sync_feed(sync, (hs_sync_kind)kind, msg, len);
            fed[kind]++;
            switch (res) {
            case HS_SYNC_APPLIED:
                applied++;
                break;
            case HS_SYNC_HELD:
                break;
            case HS_SYNC_STALE:
                stale++;
                break;
            case HS_SYNC_MISMATCH:
                mismatched++;
                break;
            case HS_SYNC_MALFORMED:
                malformed++;
                break;
            case HS_SYNC_NOMEM:
                break;
            default:
                abort();
            }
            hs_sync_stats st;
            hs_mesh_sync_stats(sync, &st);
            for (int k = 0; k < 4; k++)
                if (st.received[k] != fed[k] || st.lost[k] < 0) abort();
            if (st.applied != applied || st.stale != stale || st.mismatched != mismatched ||
                st.malformed != malformed)
                abort();
            const hs_client_mesh* m = hs_mesh_sync_mesh(sync);
            if (res == HS_SYNC_APPLIED && !m->ready) abort();
            check_mesh(m);
        } else if (kind == 4) {
            hs_wire_force w;
            if (hs_wire_force_decode(msg, len, &w) == 0) {
                hs_local_model m = hs_wire_local_model(&w);
                if (!m.valid || m.state < 0 || m.state > 3 || !(m.validity_radius >= 0)) abort();
                m.arrival_us = now;
                hs_force_renderer_push(&r, &m);
            }
            check_force(&r, now);
        } else if (kind == 5) {
            hs_wire_ack a;
            if (hs_wire_ack_decode(msg, len, &a) == 0 && !memchr(a.message, 0, sizeof a.message))
                abort();
        } else {
            hs_client_status s;
            if (hs_client_status_decode(msg, len, &s) == HS_OK) {
                if (!memchr(s.scene, 0, sizeof s.scene) ||
                    !memchr(s.warnings, 0, sizeof s.warnings) || s.n_loops < 0 || s.n_steps < 0 ||
                    s.n_devices < 0 || s.n_rejects < 0)
                    abort();
                for (int i = 0; i < s.n_loops && i < HS_CLIENT_STATUS_LOOPS; i++)
                    if (!memchr(s.loops[i].name, 0, sizeof s.loops[i].name) ||
                        !isfinite(s.loops[i].p99_us))
                        abort();
                for (int i = 0; i < s.n_steps && i < HS_CLIENT_STATUS_STEPS; i++)
                    if (!memchr(s.steps[i].name, 0, sizeof s.steps[i].name)) abort();
                for (int i = 0; i < s.n_rejects && i < HS_CLIENT_STATUS_REJECTS; i++)
                    if (!memchr(s.rejects[i].channel, 0, sizeof s.rejects[i].channel) ||
                        !memchr(s.rejects[i].reason, 0, sizeof s.rejects[i].reason))
                        abort();
            }
        }
        now += 1000;
        start = end + 2;
    }
    hs_mesh_sync_destroy(&sync);
    return 0;
}
