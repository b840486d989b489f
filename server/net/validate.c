// SPDX-License-Identifier: GPL-2.0-or-later
// Validation of inbound messages from raw LCM bytes. See validate.h for the design.
#include "validate.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "hapsim_command_rules.h"
#include "hapsim_command_t.h"
#include "hapsim_command_ack_t.h"
#include "hapsim_tool_pose_t.h"

static const char* const reject_names[HS_NET_REJ_COUNT] = {
    "accept", "decode",         "length",       "nonfinite",    "quaternion",
    "range",  "unknown_device", "unknown_tool", "unknown_kind", "argument",
    "seq",    "session",        "duplicate",
};

const char* hs_net_reject_name(hs_net_reject r) {
    if ((int)r < 0 || r >= HS_NET_REJ_COUNT) return "invalid_reason";
    return reject_names[r];
}

uint64_t hs_net_counters_rejected(const hs_net_counters* c) {
    uint64_t sum = 0;
    for (int i = 0; i < HS_NET_REJ_COUNT; ++i) sum += c->rejected[i];
    return sum;
}

static hs_net_reject count(hs_net_counters* c, hs_net_reject r) {
    c->received++;
    if (r == HS_NET_ACCEPT)
        c->accepted++;
    else
        c->rejected[r]++;
    return r;
}

hs_net_limits hs_net_default_limits(void) {
    hs_net_limits l;
    memset(&l, 0, sizeof l);
    l.n_devices = 1;
    l.n_tools = 1;
    for (int i = 0; i < 3; ++i) {
        l.workspace_min[i] = -1.0;
        l.workspace_max[i] = 1.0;
    }
    l.quat_tol = 1e-3;
    l.max_seq_jump = 1000000;
    l.session_takeover_us = 500000;
    return l;
}

// ---------------------------------------------------------------------------------------------
// A bounds-checked reader of LCM's big-endian wire format. Every read checks the remaining
// length first; after the first failure the reader stays failed and returns zeros.

typedef struct wire {
    const uint8_t* p;
    int64_t len;
    int64_t pos;
    int bad;
} wire;

static int wire_need(wire* w, int64_t n) {
    if (w->bad || n < 0 || n > w->len - w->pos) {
        w->bad = 1;
        return 0;
    }
    return 1;
}

static uint64_t wire_u64(wire* w) {
    if (!wire_need(w, 8)) return 0;
    uint64_t v = 0;
    for (int i = 0; i < 8; ++i) v = (v << 8) | w->p[w->pos + i];
    w->pos += 8;
    return v;
}

static uint32_t wire_u32(wire* w) {
    if (!wire_need(w, 4)) return 0;
    uint32_t v = 0;
    for (int i = 0; i < 4; ++i) v = (v << 8) | w->p[w->pos + i];
    w->pos += 4;
    return v;
}

static int64_t wire_i64(wire* w) {
    return (int64_t)wire_u64(w);
}
static int32_t wire_i32(wire* w) {
    return (int32_t)wire_u32(w);
}

static double wire_f64(wire* w) {
    uint64_t u = wire_u64(w);
    double d;
    memcpy(&d, &u, sizeof d);
    return d;
}

// An LCM string: int32 length including the NUL, the bytes, the NUL. Copies into out[cap].
// Returns the reason: DECODE for a broken encoding (no NUL at the end, a NUL inside, length
// < 1 or beyond the buffer), LENGTH when it is well formed but longer than cap - 1.
static hs_net_reject wire_string(wire* w, char* out, int cap) {
    out[0] = '\0';
    int32_t n = wire_i32(w);
    if (w->bad) return HS_NET_REJ_DECODE;
    if (n < 1 || !wire_need(w, n)) {
        w->bad = 1;
        return HS_NET_REJ_DECODE;
    }
    const uint8_t* s = w->p + w->pos;
    if (s[n - 1] != 0 || memchr(s, 0, (size_t)(n - 1)) != NULL) {
        w->bad = 1;
        return HS_NET_REJ_DECODE;
    }
    w->pos += n;
    if (n > cap) return HS_NET_REJ_LENGTH;
    memcpy(out, s, (size_t)n);
    return HS_NET_ACCEPT;
}

// ---------------------------------------------------------------------------------------------
// tool_pose

void hs_net_pose_state_init(hs_net_pose_state* s) {
    memset(s, 0, sizeof *s);
}

// Wire size of tool_pose: fingerprint, 3 int64, 2 int32, 3 + 4 doubles, int32.
enum { POSE_WIRE_BYTES = 8 + 3 * 8 + 2 * 4 + 7 * 8 + 4 };

static hs_net_reject pose_check(const hs_net_limits* lim, hs_net_pose_state* st, const void* buf,
                                int64_t len, int64_t now_us, hs_net_pose* out) {
    if (buf == NULL || len != POSE_WIRE_BYTES) return HS_NET_REJ_DECODE;
    wire w = {(const uint8_t*)buf, len, 0, 0};
    if (wire_i64(&w) != __hapsim_tool_pose_t_get_hash()) return HS_NET_REJ_DECODE;
    hs_net_pose p;
    memset(&p, 0, sizeof p);
    p.utime = wire_i64(&w);
    p.seq = wire_i64(&w);
    p.session = wire_i64(&w);
    int32_t device = wire_i32(&w);
    int32_t tool = wire_i32(&w);
    for (int i = 0; i < 3; ++i) p.position[i] = wire_f64(&w);
    for (int i = 0; i < 4; ++i) p.orientation[i] = wire_f64(&w);
    int32_t buttons = wire_i32(&w);
    if (w.bad || w.pos != len) return HS_NET_REJ_DECODE;

    for (int i = 0; i < 3; ++i)
        if (!isfinite(p.position[i])) return HS_NET_REJ_NONFINITE;
    for (int i = 0; i < 4; ++i)
        if (!isfinite(p.orientation[i])) return HS_NET_REJ_NONFINITE;
    double qn = 0.0;
    for (int i = 0; i < 4; ++i) qn += p.orientation[i] * p.orientation[i];
    qn = sqrt(qn);
    if (!(fabs(qn - 1.0) <= lim->quat_tol)) return HS_NET_REJ_QUATERNION;
    for (int i = 0; i < 4; ++i) p.orientation[i] /= qn;

    const uint32_t known = HAPSIM_TOOL_POSE_T_BUTTON_PRIMARY | HAPSIM_TOOL_POSE_T_BUTTON_CLUTCH;
    if (p.utime < 0 || p.seq < 0 || p.session == 0 || ((uint32_t)buttons & ~known) != 0)
        return HS_NET_REJ_RANGE;
    for (int i = 0; i < 3; ++i)
        if (p.position[i] < lim->workspace_min[i] || p.position[i] > lim->workspace_max[i])
            return HS_NET_REJ_RANGE;

    int n_dev = lim->n_devices < HS_NET_MAX_DEVICES ? lim->n_devices : HS_NET_MAX_DEVICES;
    if (device < 0 || device >= n_dev) return HS_NET_REJ_UNKNOWN_DEVICE;
    if (tool < 0 || tool >= lim->n_tools) return HS_NET_REJ_UNKNOWN_TOOL;

    hs_net_device_track* t = &st->dev[device];
    if (t->session != 0 && p.session != t->session) {
        // A restarted driver comes back with a new session; let it in only once the old one
        // has gone quiet, so two live drivers cannot fight over one device.
        if (now_us - t->last_rx_us < lim->session_takeover_us) return HS_NET_REJ_SESSION;
    } else if (t->session != 0) {
        if (p.seq <= t->last_seq) return HS_NET_REJ_SEQ;
        if (p.seq - t->last_seq > lim->max_seq_jump) return HS_NET_REJ_SEQ;
        p.lost = p.seq - t->last_seq - 1;
    }

    p.device_id = device;
    p.tool_id = tool;
    p.buttons = (uint32_t)buttons;
    p.rx_us = now_us;
    t->session = p.session;
    t->last_seq = p.seq;
    t->last_rx_us = now_us;
    t->accepted++;
    t->lost += p.lost;
    if (out) *out = p;
    return HS_NET_ACCEPT;
}

hs_net_reject hs_net_validate_pose(const hs_net_limits* lim, hs_net_pose_state* st, const void* buf,
                                   int64_t len, int64_t now_us, hs_net_pose* out) {
    return count(&st->counters, pose_check(lim, st, buf, len, now_us, out));
}

// ---------------------------------------------------------------------------------------------
// command

void hs_net_command_state_init(hs_net_command_state* s) {
    memset(s, 0, sizeof *s);
}

const char* hs_net_command_arg(const hs_net_command* c, const char* key) {
    for (int i = 0; i < c->n_args; ++i)
        if (strcmp(c->keys[i], key) == 0) return c->values[i];
    return NULL;
}

static int dedup_find(const hs_net_dedup* d, int64_t id) {
    for (int i = 0; i < d->count; ++i)
        if (d->id[i] == id) return i;
    return -1;
}

int hs_net_dedup_set_status(hs_net_dedup* d, int64_t request_id, int32_t status) {
    int i = dedup_find(d, request_id);
    if (i < 0) return -1;
    d->status[i] = status;
    return 0;
}

// Overwrites the oldest entry, but keeps one still PENDING (a scene being loaded, a command
// queued behind it) while a finished one can go instead: its final status must find it, and
// a retry of it must not run it again (64 e-stops during a load pushed it out).
static void dedup_add(hs_net_dedup* d, int64_t id, int32_t kind) {
    int slot = d->head;
    if (d->count == HS_NET_DEDUP_SIZE)
        for (int k = 0; k < HS_NET_DEDUP_SIZE; ++k) {
            int j = (d->head + k) % HS_NET_DEDUP_SIZE;
            if (d->status[j] != HAPSIM_COMMAND_ACK_T_STATUS_PENDING) {
                slot = j;
                break;
            }
        }
    d->id[slot] = id;
    d->kind[slot] = kind;
    d->status[slot] = HAPSIM_COMMAND_ACK_T_STATUS_PENDING;
    d->head = (slot + 1) % HS_NET_DEDUP_SIZE;
    if (d->count < HS_NET_DEDUP_SIZE) d->count++;
}

// Arguments each kind requires (exactly these keys, nothing else): the rules the client
// library checks too (hapsim_command_rules.h).
static hs_net_reject command_args(hs_net_command* c) {
    const char *k[HS_NET_CMD_MAX_ARGS], *v[HS_NET_CMD_MAX_ARGS];
    for (int i = 0; i < c->n_args; ++i) {
        k[i] = c->keys[i];
        v[i] = c->values[i];
    }
    if (!hapsim_cmd_text_ok(c->sender)) {
        c->why = "the sender has control bytes";
        return HS_NET_REJ_ARGUMENT;
    }
    const char* why;
    int r = hapsim_cmd_args_check(c->kind, c->n_args, k, v, &c->number, &why);
    if (r == HAPSIM_CMD_ARGS_OK) return HS_NET_ACCEPT;
    c->why = why;
    return r == HAPSIM_CMD_ARGS_NONFINITE ? HS_NET_REJ_NONFINITE : HS_NET_REJ_ARGUMENT;
}

static hs_net_reject command_check(hs_net_command_state* st, const void* buf, int64_t len,
                                   hs_net_command* c, int32_t* prev_status) {
    memset(c, 0, sizeof *c);
    if (buf == NULL || len <= 0) return HS_NET_REJ_DECODE;
    wire w = {(const uint8_t*)buf, len, 0, 0};
    if (wire_i64(&w) != __hapsim_command_t_get_hash() || w.bad) return HS_NET_REJ_DECODE;
    int64_t utime = wire_i64(&w);
    int64_t seq = wire_i64(&w);
    int64_t request_id = wire_i64(&w);
    int32_t kind = wire_i32(&w);
    int32_t n_args = wire_i32(&w);
    if (w.bad) return HS_NET_REJ_DECODE;
    c->request_id = request_id;
    c->kind = kind;
    c->utime = utime;
    c->seq = seq;
    if (n_args < 0 || n_args > HS_NET_CMD_MAX_ARGS) return HS_NET_REJ_LENGTH;
    c->n_args = n_args;

    // Walk every string before judging any, so a long key cannot hide a broken encoding.
    hs_net_reject worst = HS_NET_ACCEPT;
    for (int i = 0; i < n_args; ++i) {
        hs_net_reject r = wire_string(&w, c->keys[i], HS_NET_CMD_KEY_MAX);
        if (r == HS_NET_REJ_DECODE) return r;
        if (r != HS_NET_ACCEPT) worst = r;
    }
    for (int i = 0; i < n_args; ++i) {
        hs_net_reject r = wire_string(&w, c->values[i], HS_NET_CMD_VALUE_MAX);
        if (r == HS_NET_REJ_DECODE) return r;
        if (r != HS_NET_ACCEPT) worst = r;
    }
    hs_net_reject r = wire_string(&w, c->sender, HS_NET_CMD_SENDER_MAX);
    if (r == HS_NET_REJ_DECODE) return r;
    if (r != HS_NET_ACCEPT) worst = r;
    if (w.pos != len) return HS_NET_REJ_DECODE;
    if (worst != HS_NET_ACCEPT) return worst;

    if (utime < 0 || request_id == 0) return HS_NET_REJ_RANGE;
    if (kind < HAPSIM_COMMAND_T_KIND_RESET || kind > HAPSIM_COMMAND_T_KIND_REQUEST_TOPOLOGY)
        return HS_NET_REJ_UNKNOWN_KIND;
    r = command_args(c);
    if (r != HS_NET_ACCEPT) return r;

    int slot = dedup_find(&st->dedup, request_id);
    if (slot >= 0) {
        if (prev_status) *prev_status = st->dedup.status[slot];
        return HS_NET_REJ_DUPLICATE;
    }
    dedup_add(&st->dedup, request_id, kind);
    return HS_NET_ACCEPT;
}

hs_net_reject hs_net_validate_command(hs_net_command_state* st, const void* buf, int64_t len,
                                      hs_net_command* out, int32_t* prev_status) {
    hs_net_command scratch;
    hs_net_command* c = out ? out : &scratch;
    return count(&st->counters, command_check(st, buf, len, c, prev_status));
}
