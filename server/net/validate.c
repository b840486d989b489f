// SPDX-License-Identifier: GPL-2.0-or-later
// Validation of inbound messages from raw LCM bytes. See validate.h for the design.
#include "validate.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "hapsim_command_ack_t.h"
#include "hapsim_command_rules.h"
#include "hapsim_command_t.h"
#include "hapsim_proto.h"
#include "hapsim_tool_pose_t.h"

_Static_assert(sizeof(((hs_net_command*)0)->keys) == sizeof(((hs_wire_command*)0)->keys) &&
                   sizeof(((hs_net_command*)0)->values) == sizeof(((hs_wire_command*)0)->values) &&
                   sizeof(((hs_net_command*)0)->sender) == sizeof(((hs_wire_command*)0)->sender),
               "hs_net_command keeps the protocol's limits");

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
// tool_pose

void hs_net_pose_state_init(hs_net_pose_state* s) {
    memset(s, 0, sizeof *s);
}

static hs_net_reject pose_check(const hs_net_limits* lim, hs_net_pose_state* st, const void* buf,
                                int64_t len, int64_t now_us, hs_net_pose* out) {
    hs_wire_pose w;
    if (buf == NULL || len < 0 || hs_wire_pose_decode(buf, (size_t)len, &w))
        return HS_NET_REJ_DECODE;
    hs_net_pose p;
    memset(&p, 0, sizeof p);
    p.utime = w.utime;
    p.seq = w.seq;
    p.session = w.session;
    int32_t device = w.device_id;
    int32_t tool = w.tool_id;
    memcpy(p.position, w.position, sizeof p.position);
    memcpy(p.orientation, w.orientation, sizeof p.orientation);
    int32_t buttons = w.buttons;

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
    hs_wire_command w;
    int r = hs_wire_command_decode(buf, (size_t)len, &w);
    c->request_id = w.request_id;
    c->kind = w.kind;
    c->utime = w.utime;
    c->seq = w.seq;
    if (r == HS_WIRE_MALFORMED) return HS_NET_REJ_DECODE;
    if (r == HS_WIRE_TOO_LONG) return HS_NET_REJ_LENGTH;
    c->n_args = w.n_args;
    memcpy(c->keys, w.keys, sizeof c->keys);
    memcpy(c->values, w.values, sizeof c->values);
    memcpy(c->sender, w.sender, sizeof c->sender);
    int64_t utime = w.utime, request_id = w.request_id;
    int32_t kind = w.kind;

    if (utime < 0 || request_id == 0) return HS_NET_REJ_RANGE;
    if (kind < HAPSIM_COMMAND_T_KIND_RESET || kind > HAPSIM_COMMAND_T_KIND_REQUEST_TOPOLOGY)
        return HS_NET_REJ_UNKNOWN_KIND;
    hs_net_reject a = command_args(c);
    if (a != HS_NET_ACCEPT) return a;

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
