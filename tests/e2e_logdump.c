// SPDX-License-Identifier: GPL-2.0-or-later
// Read an LCM log of a hapsim session deterministically and print its poses and forces, for the
// end-to-end tests and docs/replay.md.
//
//   e2e_logdump LOG [PREFIX]
//
// The log is opened through LCM's own file provider, file://LOG?speed=0 (as fast as it can be
// read, in log order); time is each message's own utime (under file playback recv_utime is the
// playback clock). PREFIX defaults to HAPSIM_. Output, one line per message:
//   pose UTIME SEQ SESSION DEVICE X Y Z
//   force UTIME SEQ DEVICE STATE |F| POSE_UTIME
// then `count CHANNEL N` for every channel seen and `bad N` for messages that did not decode.
// Exit 0, or 1 when the log cannot be opened or is not complete (cut off inside an event, bytes
// that are not an event, or LCM delivered fewer events than the log holds; e2e_lcmlog.h).
// Any path works, '?' included (LCM gets it as /proc/self/fd/N).
#define _POSIX_C_SOURCE 200809L
#include "hapsim/version.h"
#include "e2e_lcmlog.h"
#include "hapsim_tool_force_t.h"
#include "hapsim_tool_pose_t.h"

#include <lcm/lcm.h>
#include <math.h>
#include <poll.h>
#include <stdio.h>
#include <string.h>

#define MAX_CHANNELS 32

typedef struct dump_state {
    char pose_ch[96], force_ch[96];
    int n_ch;
    char ch[MAX_CHANNELS][96];
    long count[MAX_CHANNELS];
    long bad, total;
} dump_state;

static void count_channel(dump_state* s, const char* channel) {
    for (int i = 0; i < s->n_ch; ++i)
        if (strcmp(s->ch[i], channel) == 0) {
            s->count[i]++;
            return;
        }
    if (s->n_ch < MAX_CHANNELS) {
        snprintf(s->ch[s->n_ch], sizeof s->ch[0], "%s", channel);
        s->count[s->n_ch++] = 1;
    }
}

static void on_message(const lcm_recv_buf_t* rb, const char* channel, void* user) {
    dump_state* s = user;
    s->total++;
    count_channel(s, channel);
    if (strcmp(channel, s->pose_ch) == 0) {
        hapsim_tool_pose_t p;
        if (hapsim_tool_pose_t_decode(rb->data, 0, (int)rb->data_size, &p) < 0) {
            s->bad++;
            return;
        }
        printf("pose %lld %lld %lld %d %.9g %.9g %.9g\n", (long long)p.utime, (long long)p.seq,
               (long long)p.session, p.device_id, p.position[0], p.position[1], p.position[2]);
        hapsim_tool_pose_t_decode_cleanup(&p);
    } else if (strcmp(channel, s->force_ch) == 0) {
        hapsim_tool_force_t f;
        if (hapsim_tool_force_t_decode(rb->data, 0, (int)rb->data_size, &f) < 0) {
            s->bad++;
            return;
        }
        double fn =
            sqrt(f.force[0] * f.force[0] + f.force[1] * f.force[1] + f.force[2] * f.force[2]);
        printf("force %lld %lld %d %d %.9g %lld\n", (long long)f.utime, (long long)f.seq,
               f.device_id, f.state, fn, (long long)f.pose_utime);
        hapsim_tool_force_t_decode_cleanup(&f);
    }
}

int main(int argc, char** argv) {
    if (hapsim_version_asked(argc, argv, "e2e_logdump")) return 0;
    for (int i = 1; i < argc; ++i)
        if (!strcmp(argv[i], "-h") || !strcmp(argv[i], "--help")) {
            printf("usage: e2e_logdump LOG [PREFIX]\n\nPrint the poses and forces of a hapsim "
                   "session's LCM log, read deterministically\n(LCM file provider, as fast as it "
                   "reads, time = each message's utime). PREFIX: the\nchannel prefix (HAPSIM_). "
                   "Exit status: 0 ok, 1 the log cannot be opened or is not\ncomplete, 2 bad "
                   "usage. See docs/replay.md.\n");
            return 0;
        }
    if (argc != 2 && argc != 3) {
        fprintf(stderr, "usage: %s LOG [PREFIX]\n", argv[0]);
        return 2;
    }
    const char* prefix = argc == 3 ? argv[2] : "HAPSIM_";
    static dump_state s;
    snprintf(s.pose_ch, sizeof s.pose_ch, "%sTOOL_POSE", prefix);
    snprintf(s.force_ch, sizeof s.force_ch, "%sTOOL_FORCE", prefix);
    hs_lcmlog log;
    if (hs_lcmlog_open(argv[1], "", &log) != 0) {
        fprintf(stderr, "%s: %s\n", argv[0], log.why);
        return 1;
    }
    lcm_t* lcm = lcm_create(log.url);
    if (!lcm) {
        fprintf(stderr, "%s: LCM cannot open %s (%s)\n", argv[0], log.url, argv[1]);
        hs_lcmlog_close(&log);
        return 1;
    }
    // Subscribe before anything is read: the file provider starts reading on the first handle.
    lcm_subscription_t* sub = lcm_subscribe(lcm, ".*", on_message, &s);
    lcm_subscription_set_queue_capacity(sub, 1 << 20);
    // poll() on the descriptor rather than lcm_handle_timeout (FD_SETSIZE abort, LCM-NOTES.md);
    // the file provider signals the end of the log by a handle error or by going quiet.
    for (;;) {
        struct pollfd pfd = {lcm_get_fileno(lcm), POLLIN, 0};
        int r = poll(&pfd, 1, 500);
        if (r <= 0) break;
        if (lcm_handle(lcm) != 0) break;
    }
    for (int i = 0; i < s.n_ch; ++i) printf("count %s %ld\n", s.ch[i], s.count[i]);
    printf("bad %ld\n", s.bad);
    lcm_unsubscribe(lcm, sub);
    lcm_destroy(lcm);
    hs_lcmlog_close(&log);
    if (s.total != log.events) {
        fprintf(stderr, "%s: %s: LCM delivered %ld of the log's %ld events\n", argv[0], argv[1],
                s.total, log.events);
        return 1;
    }
    return 0;
}
