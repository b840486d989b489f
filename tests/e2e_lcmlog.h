// SPDX-License-Identifier: GPL-2.0-or-later
// Opening an LCM log for e2e_logdump and e2e_replay (docs/replay.md).
//
// LCM's file provider reads a log cut off inside its last event as a complete log (it stops at
// the short read without an error) and skips bytes that are not an event to the next sync word,
// so the framing is walked here first (lcm/eventlog.c): per event a big-endian header
// {u32 sync 0xEDA1DA01, i64 event number, i64 timestamp, i32 channel length, i32 data length},
// then the channel name and the data. The last event must end exactly at the end of the file.
//
// The provider's URL is file://PATH?OPTIONS with no escaping: a '?' in PATH would start the
// options. The log is opened here and handed to LCM as /proc/self/fd/N, so any path works and
// LCM reads the file that was checked.
#ifndef HS_E2E_LCMLOG_H
#define HS_E2E_LCMLOG_H

#include <fcntl.h>
#include <stdint.h>
#include <stdio.h>
#include <string.h>
#include <sys/stat.h>
#include <unistd.h>

typedef struct hs_lcmlog {
    int fd;              // open on the log, -1 when not
    long events;         // complete events in the log
    long channel_events; // of them on the channel asked for
    char url[4200];      // the file provider's URL (speed=0)
    char why[512];       // what is wrong, when hs_lcmlog_open fails
} hs_lcmlog;

static uint64_t hs_lcmlog_be(const unsigned char* p, int n) {
    uint64_t v = 0;
    for (int i = 0; i < n; ++i) v = v << 8 | p[i];
    return v;
}

/// Open PATH, check its event framing up to the end of the file and count the events (those on
/// CHANNEL apart). Returns 0, or -1 with the reason in log->why (the log closed).
static int hs_lcmlog_open(const char* path, const char* channel, hs_lcmlog* log) {
    memset(log, 0, sizeof *log);
    log->fd = open(path, O_RDONLY | O_CLOEXEC);
    struct stat st;
    if (log->fd < 0 || fstat(log->fd, &st) != 0 || !S_ISREG(st.st_mode)) {
        snprintf(log->why, sizeof log->why, "cannot open %s as a log file", path);
        if (log->fd >= 0) close(log->fd);
        log->fd = -1;
        return -1;
    }
    size_t chlen_want = strlen(channel);
    long long off = 0, size = (long long)st.st_size;
    while (off < size) {
        unsigned char h[28];
        char ch[1024];
        const char* bad = NULL;
        int64_t chlen = 0, dlen = 0;
        if (size - off < (long long)sizeof h) {
            bad = "cut off in its header";
        } else if (pread(log->fd, h, sizeof h, (off_t)off) != (ssize_t)sizeof h) {
            bad = "unreadable";
        } else if (hs_lcmlog_be(h, 4) != 0xEDA1DA01u) {
            bad = "not an event (no sync word)";
        } else {
            chlen = (int32_t)hs_lcmlog_be(h + 20, 4);
            dlen = (int32_t)hs_lcmlog_be(h + 24, 4);
            if (chlen <= 0 || chlen >= (int64_t)sizeof ch || dlen < 0)
                bad = "not an event (bad lengths)";
            else if (size - off - (long long)sizeof h < chlen + dlen)
                bad = "cut off (the log is truncated)";
            else if (pread(log->fd, ch, (size_t)chlen, (off_t)(off + 28)) != (ssize_t)chlen)
                bad = "unreadable";
        }
        if (bad) {
            snprintf(log->why, sizeof log->why,
                     "%s: event %ld at byte %lld of %lld is %s; the %ld complete events before it "
                     "end at byte %lld (head -c %lld keeps them)",
                     path, log->events + 1, off, size, bad, log->events, off, off);
            close(log->fd);
            log->fd = -1;
            return -1;
        }
        log->events++;
        if ((size_t)chlen == chlen_want && memcmp(ch, channel, chlen_want) == 0)
            log->channel_events++;
        off += 28 + chlen + dlen;
    }
    char proc[64];
    snprintf(proc, sizeof proc, "/proc/self/fd/%d", log->fd);
    snprintf(log->url, sizeof log->url, "file://%s?speed=0", proc);
    if (access(proc, R_OK) != 0) {
        // Without /proc the path itself goes into the URL, which cannot carry a '?'.
        if (strchr(path, '?') || strlen(path) + 16 > sizeof log->url) {
            snprintf(log->why, sizeof log->why,
                     "%s: no /proc/self/fd here, and LCM's file:// URL cannot carry this path "
                     "('?' starts its options; at most %zu bytes): copy or link the log to a "
                     "plain path",
                     path, sizeof log->url - 16);
            close(log->fd);
            log->fd = -1;
            return -1;
        }
        snprintf(log->url, sizeof log->url, "file://%s?speed=0", path);
    }
    return 0;
}

static void hs_lcmlog_close(hs_lcmlog* log) {
    if (log->fd >= 0) close(log->fd);
    log->fd = -1;
}

#endif
