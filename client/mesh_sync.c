// SPDX-License-Identifier: MIT
// Mesh synchronisation state machine (docs/protocol.md "Watching the mesh", docs/client.md).
// Two topologies are kept: the one shown and a newer one waiting for its first keyframe, so the
// visible mesh is always a topology with positions that belong to it.
#include <math.h>
#include <string.h>

#include "wire.h"

typedef struct topo {
    int64_t version;
    int32_t n_nodes, n_vis, n_tri, n_tet;
    int32_t* vis;
    float* rest;
    int32_t* tri;
    int32_t* tet;
    size_t cap_vis, cap_rest, cap_tri, cap_tet; // elements of vis, rest/3, tri/3, tet/4
} topo;

struct hs_mesh_sync {
    topo shown, pending;
    int ready, has_pending;
    float *kf, *pos, *stress; // [3 cap_kf], [3 cap_pos], [cap_stress]
    size_t cap_kf, cap_pos, cap_stress;
    int has_stress;
    uint64_t shown_hash; // of the positions and stress at the last frame
    int64_t kf_id, last_delta_seq;
    int64_t kf_seq, kf_utime; // seq and utime of the keyframe shown
    int have_seq[4];
    int64_t last_seq[4];
    // Restart detection: seq and utime of the newest topology in order, and whether a keyframe
    // showed a restarted server (its topology is then taken whatever its version).
    int have_topo, restart_seen;
    int64_t topo_seq, topo_utime;
    hs_client_mesh view;
    hs_sync_stats st;
};

// One array that may have to grow: to n elements of size sz, keeping the first keep.
typedef struct growth {
    void** p;
    size_t* cap;
    size_t n, sz, keep;
    void* q; // the new block, until swapped in
} growth;

// Allocate every block that must grow, then swap them all in; a failed allocation frees the
// new blocks and changes nothing (HS_SYNC_NOMEM keeps the state).
static int grow_all(growth* g, int n) {
    for (int i = 0; i < n; i++) {
        g[i].q = NULL;
        if (g[i].n <= *g[i].cap) continue;
        g[i].q = hs_proto_calloc(g[i].n, g[i].sz);
        if (!g[i].q) {
            for (int j = 0; j < i; j++) hs_proto_free(g[j].q);
            return -1;
        }
    }
    for (int i = 0; i < n; i++) {
        if (!g[i].q) continue;
        if (*g[i].p && g[i].keep) memcpy(g[i].q, *g[i].p, g[i].keep * g[i].sz);
        hs_proto_free(*g[i].p);
        *g[i].p = g[i].q;
        *g[i].cap = g[i].n;
    }
    return 0;
}

static void topo_free(topo* t) {
    hs_proto_free(t->vis);
    hs_proto_free(t->rest);
    hs_proto_free(t->tri);
    hs_proto_free(t->tet);
    memset(t, 0, sizeof *t);
}

hs_status hs_mesh_sync_create(hs_mesh_sync** out, hs_err* err) {
    if (!out) {
        if (err) err->code = HS_ERR_INVALID;
        return HS_ERR_INVALID;
    }
    *out = hs_proto_calloc(1, sizeof **out);
    if (!*out) {
        if (err) {
            err->code = HS_ERR_NOMEM;
            strcpy(err->msg, "hs_mesh_sync_create: out of memory");
        }
        return HS_ERR_NOMEM;
    }
    (*out)->kf_id = -1;
    (*out)->last_delta_seq = -1;
    (*out)->view.delta_seq = -1;
    (*out)->st.last_event_old = -1;
    (*out)->st.last_event_new = -1;
    return HS_OK;
}

void hs_mesh_sync_destroy(hs_mesh_sync** s) {
    if (!s || !*s) return;
    topo_free(&(*s)->shown);
    topo_free(&(*s)->pending);
    hs_proto_free((*s)->kf);
    hs_proto_free((*s)->pos);
    hs_proto_free((*s)->stress);
    hs_proto_free(*s);
    *s = NULL;
}

const hs_client_mesh* hs_mesh_sync_mesh(const hs_mesh_sync* s) {
    return &s->view;
}
void hs_mesh_sync_stats(const hs_mesh_sync* s, hs_sync_stats* out) {
    *out = s->st;
}
int64_t hs_mesh_sync_newest_topology(const hs_mesh_sync* s) {
    if (s->has_pending) return s->pending.version;
    return s->ready ? s->shown.version : -1;
}

// FNV-1a over n bytes, continuing from h.
static uint64_t fnv1a(uint64_t h, const void* p, size_t n) {
    const unsigned char* b = p;
    for (size_t i = 0; i < n; i++) h = (h ^ b[i]) * 1099511628211ull;
    return h;
}

static void update_view(hs_mesh_sync* s, int64_t utime, int64_t sim_step, double sim_time) {
    hs_client_mesh* v = &s->view;
    const topo* t = &s->shown;
    // A frame is a change of what is shown: the periodic keyframe of a mesh at rest is not one.
    uint64_t h = fnv1a(14695981039346656037ull, s->pos, (size_t)t->n_vis * 3 * sizeof(float));
    if (s->has_stress) h = fnv1a(h, s->stress, (size_t)t->n_vis * sizeof(float));
    if (!v->ready || v->topology_version != t->version || h != s->shown_hash) v->frame++;
    s->shown_hash = h;
    v->ready = 1;
    v->topology_version = t->version;
    v->keyframe_id = s->kf_id;
    v->delta_seq = s->last_delta_seq;
    v->sim_step = sim_step;
    v->sim_time = sim_time;
    v->utime = utime;
    v->n_nodes = t->n_nodes;
    v->n_vis = t->n_vis;
    v->n_tri = t->n_tri;
    v->n_tet = t->n_tet;
    v->vis_nodes = t->vis;
    v->rest = t->rest;
    v->position = s->pos;
    v->triangles = t->tri;
    v->tets = t->n_tet ? t->tet : NULL;
    v->stress = s->has_stress ? s->stress : NULL;
    s->st.applied++;
}

// The shown arrays may move when they grow.
static void update_pointers(hs_mesh_sync* s) {
    s->view.position = s->pos;
    s->view.stress = s->has_stress ? s->stress : NULL;
}

// A keyframe id or topology version (counted one by one by the server) more than this ahead,
// plus one per ms of server time since the reference message, is a corrupt message: taken, it
// would make every later keyframe stale or topology older (as the server's pose seq check).
#define MAX_JUMP 1000000

static int too_far(int64_t from, int64_t to, int64_t utime, int64_t ref_utime) {
    if (to <= from) return 0;
    uint64_t ms = utime > ref_utime ? ((uint64_t)utime - (uint64_t)ref_utime) / 1000 : 0;
    return (uint64_t)to - (uint64_t)from > MAX_JUMP + ms;
}

// Seq bookkeeping per channel: gaps count as loss; returns 1 when seq went backwards.
static int track_seq(hs_mesh_sync* s, int kind, int64_t seq) {
    int back = 0;
    if (s->have_seq[kind]) {
        if (seq > s->last_seq[kind]) {
            int64_t gap = seq - s->last_seq[kind] - 1;
            if (gap > 0 && gap < 1000000) s->st.lost[kind] += gap;
        } else if (seq < s->last_seq[kind]) {
            back = 1;
        }
    }
    s->have_seq[kind] = 1;
    s->last_seq[kind] = seq;
    return back;
}

static hs_sync_result on_topology(hs_mesh_sync* s, const void* buf, size_t len) {
    hs_wire_topology w;
    if (hs_wire_topology_decode(buf, len, &w)) return HS_SYNC_MALFORMED;
    int64_t newest = hs_mesh_sync_newest_topology(s);
    // One server's seq and utime grow together and its version never goes back; a reordered
    // message is at most HS_WIRE_REORDER_US older. Anything else is a restarted server (seq
    // from 1, its clock later, or unrelated after a reboot or on another host): its topology
    // is taken whatever its version.
    int restarted = s->restart_seen;
    int reordered =
        s->have_topo && w.seq <= s->topo_seq && hs_wire_reordered(w.utime, s->topo_utime);
    if (!reordered && s->have_topo &&
        (w.seq <= s->topo_seq || w.utime < s->topo_utime ||
         (newest >= 0 && w.topology_version < newest)))
        restarted = 1;
    if (!restarted && newest >= 0 && too_far(newest, w.topology_version, w.utime, s->topo_utime))
        return HS_SYNC_MALFORMED;
    track_seq(s, HS_SYNC_TOPOLOGY, w.seq);
    if (!reordered) {
        s->have_topo = 1;
        s->topo_seq = w.seq;
        s->topo_utime = w.utime;
    }
    if (!restarted && newest >= 0 && w.topology_version <= newest)
        return w.topology_version == newest ? HS_SYNC_HELD : HS_SYNC_STALE;
    // Make room first; a failed allocation leaves the visible mesh as it was.
    topo* p = &s->pending;
    size_t nv = (size_t)w.n_vis, nt = (size_t)w.n_tri, ntet = (size_t)w.n_tet;
    size_t keep = s->ready ? (size_t)s->shown.n_vis : 0; // kf/pos/stress hold the shown mesh
    growth g[] = {{(void**)&p->vis, &p->cap_vis, nv, sizeof(int32_t), 0, NULL},
                  {(void**)&p->rest, &p->cap_rest, nv, 3 * sizeof(float), 0, NULL},
                  {(void**)&p->tri, &p->cap_tri, nt, 3 * sizeof(int32_t), 0, NULL},
                  {(void**)&p->tet, &p->cap_tet, ntet, 4 * sizeof(int32_t), 0, NULL},
                  {(void**)&s->kf, &s->cap_kf, nv, 3 * sizeof(float), keep, NULL},
                  {(void**)&s->pos, &s->cap_pos, nv, 3 * sizeof(float), keep, NULL},
                  {(void**)&s->stress, &s->cap_stress, nv, sizeof(float), keep, NULL}};
    if (grow_all(g, (int)(sizeof g / sizeof g[0]))) {
        s->restart_seen = restarted; // so the next copy is taken
        return HS_SYNC_NOMEM;
    }
    if (s->ready) update_pointers(s);
    p->version = w.topology_version;
    p->n_nodes = w.n_nodes;
    p->n_vis = w.n_vis;
    p->n_tri = w.n_tri;
    p->n_tet = w.n_tet;
    for (int32_t i = 0; i < w.n_vis; i++) p->vis[i] = hs_wire_i32_at(w.vis_nodes, i);
    for (int32_t i = 0; i < 3 * w.n_vis; i++) p->rest[i] = hs_wire_f32_at(w.rest, i);
    for (int32_t i = 0; i < 3 * w.n_tri; i++) p->tri[i] = hs_wire_i32_at(w.tri, i);
    for (int32_t i = 0; i < 4 * w.n_tet; i++) p->tet[i] = hs_wire_i32_at(w.tet, i);
    s->has_pending = 1;
    s->restart_seen = 0;
    s->st.topologies++;
    return HS_SYNC_HELD;
}

static void take_keyframe(hs_mesh_sync* s, const hs_wire_state* w) {
    for (int32_t i = 0; i < w->pos.n; i++) s->kf[i] = hs_wire_f32_at(w->pos, i);
    if (w->pos.n) memcpy(s->pos, s->kf, (size_t)w->pos.n * sizeof(float));
    s->has_stress = w->stress.n > 0;
    for (int32_t i = 0; i < w->stress.n; i++) s->stress[i] = hs_wire_f32_at(w->stress, i);
    s->kf_id = w->keyframe_id;
    s->kf_seq = w->seq;
    s->kf_utime = w->utime;
    s->last_delta_seq = -1;
    update_view(s, w->utime, w->sim_step, w->sim_time);
}

static hs_sync_result on_state(hs_mesh_sync* s, const void* buf, size_t len) {
    hs_wire_state w;
    if (hs_wire_state_decode(buf, len, &w)) return HS_SYNC_MALFORMED;
    int promote = s->has_pending && w.topology_version == s->pending.version;
    if (!promote && s->ready && w.topology_version == s->shown.version &&
        too_far(s->kf_id, w.keyframe_id, w.utime, s->kf_utime))
        return HS_SYNC_MALFORMED;
    track_seq(s, HS_SYNC_STATE, w.seq);
    if (promote) {
        if (w.pos.n != 3 * s->pending.n_vis) return HS_SYNC_MALFORMED;
        topo t = s->shown; // promote: swap storage, no allocation
        s->shown = s->pending;
        s->pending = t;
        s->has_pending = 0;
        s->ready = 1;
        take_keyframe(s, &w);
        return HS_SYNC_APPLIED;
    }
    if (!s->ready || w.topology_version != s->shown.version || s->restart_seen)
        return HS_SYNC_MISMATCH;
    if (w.pos.n != 3 * s->shown.n_vis) return HS_SYNC_MALFORMED;
    if (w.keyframe_id <= s->kf_id) {
        // Reordered or repeated; else a keyframe id that went back while seq or utime did not
        // is a restarted server: wait for its topology (the held one is the old server's).
        if (w.seq <= s->kf_seq && hs_wire_reordered(w.utime, s->kf_utime)) return HS_SYNC_STALE;
        s->restart_seen = 1;
        s->has_pending = 0;
        return HS_SYNC_MISMATCH;
    }
    take_keyframe(s, &w);
    return HS_SYNC_APPLIED;
}

static hs_sync_result on_delta(hs_mesh_sync* s, const void* buf, size_t len) {
    hs_wire_delta w;
    if (hs_wire_delta_decode(buf, len, &w)) return HS_SYNC_MALFORMED;
    track_seq(s, HS_SYNC_DELTA, w.seq);
    if (!s->ready || w.topology_version != s->shown.version || w.keyframe_id != s->kf_id ||
        s->restart_seen)
        return HS_SYNC_MISMATCH;
    if (w.index.n > 0 && hs_wire_i32_at(w.index, w.index.n - 1) >= s->shown.n_vis)
        return HS_SYNC_MALFORMED; // indices increase: the last is the largest
    if (w.seq <= s->last_delta_seq) return HS_SYNC_STALE;
    // Keyframe and delta are each finite, but their float sum can overflow: check first.
    for (int32_t j = 0; j < w.index.n; j++) {
        int32_t i = hs_wire_i32_at(w.index, j);
        for (int k = 0; k < 3; k++)
            if (!isfinite(s->kf[3 * i + k] + hs_wire_f32_at(w.delta, 3 * j + k)))
                return HS_SYNC_MALFORMED;
    }
    if (s->shown.n_vis) memcpy(s->pos, s->kf, (size_t)s->shown.n_vis * 3 * sizeof(float));
    for (int32_t j = 0; j < w.index.n; j++) {
        int32_t i = hs_wire_i32_at(w.index, j);
        for (int k = 0; k < 3; k++)
            s->pos[3 * i + k] = s->kf[3 * i + k] + hs_wire_f32_at(w.delta, 3 * j + k);
    }
    s->last_delta_seq = w.seq;
    update_view(s, w.utime, w.sim_step, w.sim_time);
    return HS_SYNC_APPLIED;
}

static hs_sync_result on_event(hs_mesh_sync* s, const void* buf, size_t len) {
    hs_wire_event w;
    if (hs_wire_event_decode(buf, len, &w)) return HS_SYNC_MALFORMED;
    track_seq(s, HS_SYNC_EVENT, w.seq);
    s->st.events++;
    s->st.last_event_old = w.old_version;
    s->st.last_event_new = w.new_version;
    s->st.last_event_removed = w.n_removed;
    return HS_SYNC_HELD;
}

hs_sync_result hs_mesh_sync_feed(hs_mesh_sync* s, hs_sync_kind kind, const void* buf, size_t len) {
    hs_sync_result r;
    if (kind < HS_SYNC_TOPOLOGY || kind > HS_SYNC_EVENT) {
        s->st.malformed++;
        return HS_SYNC_MALFORMED;
    }
    s->st.received[kind]++;
    switch (kind) {
    case HS_SYNC_TOPOLOGY:
        r = on_topology(s, buf, len);
        break;
    case HS_SYNC_STATE:
        r = on_state(s, buf, len);
        break;
    case HS_SYNC_DELTA:
        r = on_delta(s, buf, len);
        break;
    default:
        r = on_event(s, buf, len);
        break;
    }
    if (r == HS_SYNC_STALE) s->st.stale++;
    if (r == HS_SYNC_MISMATCH) s->st.mismatched++;
    if (r == HS_SYNC_MALFORMED) s->st.malformed++;
    return r;
}
