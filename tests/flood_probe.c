// SPDX-License-Identifier: GPL-2.0-or-later
// flood_probe: what a pose flood from another process does to a live 1 kHz driver. Starts
// hapsim-server on the bundled liver, drives device 0 at 1 kHz pressing 2 mm into node 399, and
// for each flood rate runs a child process that publishes well-formed tool_pose messages for a
// device the scene does not have (refused as `unknown_device`) at that rate on the same bus: a
// foreign driver's traffic that the server decodes and refuses, without the session takeover a
// foreign session of device 0 could make after the driver's silence.
// Per rate: the driver's poses the server lost (its seq gaps), the datagrams the kernel dropped
// on the server's haptic socket, the driver's answers missing, and the age of the driver's
// newest answer at each of its ticks. Each receive-buffer setting gets its own server, so a
// mitigation is measured before and after in one run. A measurement tool, run inside
// tests/netns.sh by scripts/flood.sh (writes docs/data/flood.csv), not a test:
//   flood_probe SERVER_BIN SOURCE_DIR SECONDS RATES RCVBUFS
// RATES and RCVBUFS are comma lists (messages/s; bytes for the server's haptic URL's
// recv_buf_size, 0 = none: the server's own choice).
#define _GNU_SOURCE
#include <lcm/lcm.h>
#include <math.h>
#include <poll.h>
#include <signal.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/wait.h>
#include <time.h>
#include <unistd.h>

#include "hapsim_server_status_t.h"
#include "hapsim_tool_force_t.h"
#include "hapsim_tool_pose_t.h"

#define URL_H  "udpm://239.255.76.121:7821?ttl=0"
#define URL_M  "udpm://239.255.76.122:7822?ttl=0"
#define PREFIX "FLOOD_"
#define MAXN   20

static const double P399[3] = {-0.0601965072, 0.0632736481, -0.0146254244};
static const double N399[3] = {0.105, 0.993, -0.045};

static int64_t now_ns(void) {
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (int64_t)ts.tv_sec * 1000000000LL + ts.tv_nsec;
}

typedef struct driver {
    lcm_t* h;
    lcm_t* m;
    int64_t seq, session;
    int64_t answers;                     // answers to our poses
    int64_t pub_fail;                    // poses the driver's publish call refused
    int64_t win_lo, win_hi, win_answers; // poses seq (win_lo, win_hi] answered (once each)
    unsigned char* answered;             // [win_hi - win_lo]
    int64_t answer_ns;                   // newest answer received
    int64_t st_lost;                     // server status: poses_lost[0]
    int64_t st_kdrop;                    // server status: HAPTIC_BUS kernel_drop
    int64_t st_session;                  // server status: TOOL_POSE rejects, every reason
    int64_t st_utime;                    // newest status, server clock
    int64_t n_status;
    int up; // status without a compliance set-up warning seen
} driver;

static void on_force(const lcm_recv_buf_t* rb, const char* ch, const hapsim_tool_force_t* f,
                     void* u) {
    (void)rb;
    (void)ch;
    driver* d = u;
    if (f->device_id != 0 || f->pose_seq <= 0 || f->pose_seq > d->seq) return;
    d->answers++;
    if (f->pose_seq > d->win_lo && f->pose_seq <= d->win_hi &&
        !d->answered[f->pose_seq - d->win_lo - 1]) { // rt outputs may answer a pose again
        d->answered[f->pose_seq - d->win_lo - 1] = 1;
        d->win_answers++;
    }
    d->answer_ns = now_ns();
}

static void on_status(const lcm_recv_buf_t* rb, const char* ch, const hapsim_server_status_t* s,
                      void* u) {
    (void)rb;
    (void)ch;
    driver* d = u;
    if (s->n_devices > 0) d->st_lost = s->poses_lost[0];
    d->st_kdrop = d->st_session = 0;
    for (int k = 0; k < s->n_rejects; ++k) {
        if (!strcmp(s->reject_channel[k], "HAPTIC_BUS") &&
            !strcmp(s->reject_reason[k], "kernel_drop"))
            d->st_kdrop = s->reject_count[k];
        if (!strcmp(s->reject_channel[k], "TOOL_POSE")) d->st_session += s->reject_count[k];
    }
    d->st_utime = s->utime;
    d->up = !strstr(s->warnings, "compliance set-up");
    d->n_status++;
}

static void pose_msg(hapsim_tool_pose_t* m, int64_t seq, int64_t session, const double p[3]) {
    memset(m, 0, sizeof *m);
    m->utime = now_ns() / 1000;
    m->seq = seq;
    m->session = session;
    for (int k = 0; k < 3; ++k) m->position[k] = p[k];
    m->orientation[0] = 1;
}

static void press_point(double depth, double p[3]) {
    double l = sqrt(N399[0] * N399[0] + N399[1] * N399[1] + N399[2] * N399[2]);
    for (int k = 0; k < 3; ++k) p[k] = P399[k] + (0.005 - depth) * N399[k] / l;
}

// Handle both buses until t (poll, no spinning).
static void serve_until(driver* d, int64_t t) {
    struct pollfd pf[2] = {{lcm_get_fileno(d->h), POLLIN, 0}, {lcm_get_fileno(d->m), POLLIN, 0}};
    for (;;) {
        int64_t left = t - now_ns();
        if (left <= 0) return;
        int ms = (int)(left / 1000000);
        if (poll(pf, 2, ms) > 0) {
            if (pf[0].revents & POLLIN) lcm_handle(d->h);
            if (pf[1].revents & POLLIN) lcm_handle(d->m);
        } else if (ms == 0) {
            // under 1 ms left: spin the rest with zero-timeout polls
            while (now_ns() < t) {
                if (poll(pf, 2, 0) > 0) {
                    if (pf[0].revents & POLLIN) lcm_handle(d->h);
                    if (pf[1].revents & POLLIN) lcm_handle(d->m);
                }
            }
            return;
        }
    }
}

// Drive at 1 kHz for ms; with ages != NULL, record the newest answer's age at each tick (ms).
static void drive(driver* d, int ms, double* ages, int* n_ages) {
    double p[3];
    press_point(0.002, p);
    int64_t t0 = now_ns();
    for (int i = 0; i < ms; ++i) {
        if (ages && d->answer_ns > 0) ages[(*n_ages)++] = (double)(now_ns() - d->answer_ns) * 1e-6;
        hapsim_tool_pose_t m;
        pose_msg(&m, ++d->seq, d->session, p);
        if (hapsim_tool_pose_t_publish(d->h, PREFIX "TOOL_POSE", &m) != 0) d->pub_fail++;
        serve_until(d, t0 + (int64_t)(i + 1) * 1000000);
    }
}

// The flood: rate messages/s for seconds, another session, device 0. Writes the count sent.
static void flood_child(int rate, double seconds, int fd) {
    lcm_t* l = lcm_create(URL_H);
    int64_t sent = 0;
    if (l) {
        double p[3];
        press_point(0.0, p);
        int64_t t0 = now_ns(), end = t0 + (int64_t)(seconds * 1e9);
        for (int64_t ms = 0; now_ns() < end; ++ms) {
            int64_t want = (int64_t)((double)rate * (double)(ms + 1) * 1e-3);
            while (sent < want && now_ns() < end) {
                hapsim_tool_pose_t m;
                pose_msg(&m, sent + 1, 0x5eed, p);
                m.device_id = 1; // not in the scene: refused (unknown_device), cannot take device 0
                hapsim_tool_pose_t_publish(l, PREFIX "TOOL_POSE", &m);
                sent++;
            }
            int64_t next = t0 + (ms + 1) * 1000000;
            int64_t left = next - now_ns();
            if (left > 0) {
                struct timespec ts = {0, left};
                nanosleep(&ts, NULL);
            }
        }
        lcm_destroy(l);
    }
    if (write(fd, &sent, sizeof sent) != (ssize_t)sizeof sent) _exit(1);
    _exit(0);
}

// Packets the kernel dropped from its per-CPU input backlogs (loopback multicast passes through
// them), all CPUs: /proc/net/softnet_stat's second column; -1 when unreadable.
static long long softnet_drops(void) {
    FILE* f = fopen("/proc/net/softnet_stat", "r");
    if (!f) return -1;
    long long sum = 0;
    unsigned a, b;
    char line[512];
    while (fgets(line, sizeof line, f))
        if (sscanf(line, "%x %x", &a, &b) == 2) sum += b;
    fclose(f);
    return sum;
}

static int cmp_d(const void* a, const void* b) {
    double x = *(const double*)a, y = *(const double*)b;
    return x < y ? -1 : x > y;
}

static int parse_list(const char* s, long long* out) {
    int n = 0;
    while (*s && n < MAXN) {
        char* e = NULL;
        out[n++] = strtoll(s, &e, 10);
        if (e == s) return -1;
        s = *e == ',' ? e + 1 : e;
    }
    return n;
}

// Wait (driving) for a status published after t_us (server clock); 0 when one came.
static int fresh_status(driver* d, int64_t after_us, int max_ms) {
    for (int waited = 0; waited < max_ms; waited += 100) {
        if (d->st_utime > after_us) return 0;
        drive(d, 100, NULL, NULL);
    }
    return -1;
}

static int run_config(const char* server, const char* src, double seconds, const long long* rates,
                      int n_rates, long long rcvbuf) {
    char dir[] = "/tmp/hs_flood.XXXXXX";
    if (!mkdtemp(dir)) return 1;
    char scene[600], url_h[300], log[600];
    snprintf(scene, sizeof scene, "%s/liver.json", dir);
    snprintf(log, sizeof log, "%s/server.log", dir);
    FILE* f = fopen(scene, "w");
    if (!f) return 1;
    fprintf(f,
            "{ \"mesh\": \"%s/scenes/liver/liver2.msh\",\n"
            "  \"material\": {\"youngs_pa\": 5000, \"poisson\": 0.45, \"density_kg_m3\": 1060},\n"
            "  \"fixed\": [{\"type\": \"plane\", \"point\": [0, -0.0433, 0], \"normal\": [0, 1, "
            "0]}],\n"
            "  \"gravity\": [0, 0, 0],\n"
            "  \"tools\": [{\"kind\": \"probe\", \"radius\": 0.005}] }\n",
            src);
    fclose(f);
    if (rcvbuf > 0)
        snprintf(url_h, sizeof url_h, "%s&recv_buf_size=%lld", URL_H, rcvbuf);
    else
        snprintf(url_h, sizeof url_h, "%s", URL_H);
    fflush(stdout);
    pid_t srv = fork();
    if (srv < 0) return 1;
    if (srv == 0) {
        if (!freopen(log, "w", stdout)) _exit(127);
        dup2(fileno(stdout), 2);
        execl(server, server, scene, "--haptic-url", url_h, "--mesh-url", URL_M, "--prefix", PREFIX,
              "--duration", "600", (char*)NULL);
        _exit(127);
    }
    static driver d;
    memset(&d, 0, sizeof d);
    d.session = 0x1234567;
    d.h = lcm_create(URL_H);
    d.m = lcm_create(URL_M);
    int rc = 1;
    if (!d.h || !d.m) goto out;
    hapsim_tool_force_t_subscribe(d.h, PREFIX "TOOL_FORCE", on_force, &d);
    hapsim_server_status_t_subscribe(d.m, PREFIX "SERVER_STATUS", on_status, &d);
    for (int waited = 0; !(d.n_status && d.up); waited += 100) {
        if (waited > 60000) {
            fprintf(stderr, "flood_probe: the server did not come up (log %s)\n", log);
            goto out;
        }
        drive(&d, 100, NULL, NULL);
    }
    drive(&d, 1000, NULL, NULL); // pressed in, steady
    static double ages[600000];
    for (int r = 0; r < n_rates; ++r) {
        int ms = (int)(seconds * 1000);
        if (fresh_status(&d, d.st_utime, 3000) != 0) goto out;
        int64_t lost0 = d.st_lost, kd0 = d.st_kdrop, ses0 = d.st_session;
        int64_t seq0 = d.seq, pf0 = d.pub_fail;
        long long sn0 = softnet_drops();
        static unsigned char answered[60000];
        memset(answered, 0, sizeof answered);
        d.answered = answered;
        d.win_lo = seq0;
        d.win_hi = seq0 + ms;
        d.win_answers = 0;
        int fds[2];
        if (pipe(fds) != 0) goto out;
        pid_t fl = rates[r] > 0 ? fork() : 0;
        if (rates[r] > 0 && fl == 0) {
            close(fds[0]);
            flood_child((int)rates[r], seconds, fds[1]);
        }
        close(fds[1]);
        int n_ages = 0;
        int64_t t0 = now_ns();
        drive(&d, ms, ages, &n_ages);
        double wall = (double)(now_ns() - t0) * 1e-9;
        int64_t sent = 0;
        if (rates[r] > 0) {
            if (read(fds[0], &sent, sizeof sent) != (ssize_t)sizeof sent) sent = -1;
            waitpid(fl, NULL, 0);
        }
        close(fds[0]);
        int64_t poses = d.seq - seq0;
        long long sn1 = softnet_drops();
        drive(&d, 200, NULL, NULL); // late answers land
        int64_t got = d.win_answers;
        int64_t t_us = d.st_utime;
        if (fresh_status(&d, t_us, 3000) != 0) goto out;
        if (fresh_status(&d, d.st_utime, 3000) != 0) goto out; // one full period after
        qsort(ages, (size_t)n_ages, sizeof ages[0], cmp_d);
        double p50 = n_ages ? ages[n_ages / 2] : NAN;
        double p99 = n_ages ? ages[(int)(0.99 * (n_ages - 1))] : NAN;
        double mx = n_ages ? ages[n_ages - 1] : NAN;
        int64_t lost = d.st_lost - lost0;
        printf("%lld,%lld,%.0f,%.1f,%lld,%lld,%.3f,%lld,%lld,%lld,%lld,%lld,%.3f,%.3f,%.3f\n",
               rcvbuf, rates[r], sent > 0 ? (double)sent / wall : 0.0, wall, (long long)poses,
               (long long)lost, 100.0 * (double)lost / (double)(poses > 0 ? poses : 1),
               (long long)(d.st_kdrop - kd0), sn0 >= 0 && sn1 >= 0 ? sn1 - sn0 : -1,
               (long long)(d.pub_fail - pf0), (long long)(d.st_session - ses0),
               (long long)(poses - got), p50, p99, mx);
        fflush(stdout);
    }
    rc = 0;
out:
    kill(srv, SIGTERM);
    waitpid(srv, NULL, 0);
    if (d.h) lcm_destroy(d.h);
    if (d.m) lcm_destroy(d.m);
    unlink(scene);
    if (rc) {
        char cmd[700];
        snprintf(cmd, sizeof cmd, "tail -5 %s >&2", log);
        if (system(cmd) != 0) fprintf(stderr, "flood_probe: no server log\n");
    }
    unlink(log);
    rmdir(dir);
    return rc;
}

int main(int argc, char** argv) {
    if (argc != 6) {
        fprintf(stderr, "usage: flood_probe SERVER_BIN SOURCE_DIR SECONDS RATES RCVBUFS\n");
        return 2;
    }
    double seconds = atof(argv[3]);
    long long rates[MAXN], bufs[MAXN];
    int nr = parse_list(argv[4], rates), nb = parse_list(argv[5], bufs);
    if (!(seconds > 0 && seconds <= 60) || nr <= 0 || nb <= 0) {
        fprintf(stderr, "flood_probe: SECONDS in (0, 60], RATES and RCVBUFS comma lists\n");
        return 2;
    }
    signal(SIGPIPE, SIG_IGN);
    printf("server_rcvbuf_bytes,flood_target_per_s,flood_sent_per_s,seconds,driver_poses,"
           "poses_lost,poses_lost_pct,server_kernel_drops,backlog_drops,publish_failed,foreign_"
           "refused,"
           "answers_missing,"
           "model_age_p50_ms,model_age_p99_ms,model_age_max_ms\n");
    for (int b = 0; b < nb; ++b)
        if (run_config(argv[1], argv[2], seconds, rates, nr, bufs[b]) != 0) return 1;
    return 0;
}
