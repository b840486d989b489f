// SPDX-License-Identifier: GPL-2.0-or-later
// hapsim-bench protocol: pose -> force round trip through a running hapsim-server (a child
// process on the bundled liver, probe pressed 2 mm into node 399) against a bare LCM echo (a
// child process that decodes each pose and publishes a tool_force back), measured in the same
// run in alternating blocks; plus the mesh traffic the server sent meanwhile (messages per
// second on the mesh bus, loss from seq gaps). Runs inside a private network namespace
// (tests/netns.sh): it re-runs itself there, so nothing leaves the machine.
#define _GNU_SOURCE
#include "bench.h"

#include <math.h>
#include <signal.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/wait.h>
#include <unistd.h>

#include "base.h"
#include "hapsim_mesh_delta_t.h"
#include "hapsim_mesh_state_t.h"
#include "hapsim_mesh_topology_t.h"
#include "hapsim_tool_force_t.h"
#include "hapsim_tool_pose_t.h"
#include "bus.h"

#define SRV_H  "udpm://239.255.76.101:7801?ttl=0"
#define SRV_M  "udpm://239.255.76.102:7802?ttl=0"
#define SRV_MR "udpm://239.255.76.102:7802?ttl=0&recv_buf_size=4194304"
#define ECHO_H "udpm://239.255.76.103:7803?ttl=0"
#define PFX    "B_"

static const double P399[3] = {-0.0601965072, 0.0632736481, -0.0146254244};
static const double N399[3] = {0.105, 0.993, -0.045};

typedef struct rtt_side {
    hs_net_bus* bus;
    int64_t want_seq;
    int64_t got_ns;
    int64_t pub_us; // the answer's utime: when it was published, on this machine's monotonic clock
} rtt_side;

static void on_force(const lcm_recv_buf_t* rb, const char* ch, const hapsim_tool_force_t* f,
                     void* u) {
    (void)rb;
    (void)ch;
    rtt_side* s = u;
    if (f->pose_seq == s->want_seq && !s->got_ns) {
        s->got_ns = hs_now_ns();
        s->pub_us = f->utime;
    }
}

typedef struct mesh_count {
    int64_t msgs, last_state_seq, last_delta_seq, lost, n_vis;
} mesh_count;

static void count_gap(int64_t* last, int64_t seq, int64_t* lost) {
    if (*last && seq > *last + 1) *lost += seq - *last - 1;
    if (seq > *last) *last = seq;
}

static void on_state(const lcm_recv_buf_t* rb, const char* ch, const hapsim_mesh_state_t* m,
                     void* u) {
    (void)rb;
    (void)ch;
    mesh_count* c = u;
    c->msgs++;
    c->n_vis = m->n_pos / 3;
    count_gap(&c->last_state_seq, m->seq, &c->lost);
}

static void on_delta(const lcm_recv_buf_t* rb, const char* ch, const hapsim_mesh_delta_t* m,
                     void* u) {
    (void)rb;
    (void)ch;
    mesh_count* c = u;
    c->msgs++;
    count_gap(&c->last_delta_seq, m->seq, &c->lost);
}

// The bare echo: a pose in, a tool_force with the pose's seq and utime out.
static void on_echo_pose(const lcm_recv_buf_t* rb, const char* ch, const hapsim_tool_pose_t* p,
                         void* u) {
    (void)rb;
    (void)ch;
    hs_net_bus* bus = u;
    hapsim_tool_force_t f;
    memset(&f, 0, sizeof f);
    f.utime = hs_now_ns() / 1000;
    f.seq = p->seq;
    f.pose_seq = p->seq;
    f.pose_utime = p->utime;
    for (int k = 0; k < 3; ++k) f.anchor[k] = p->position[k];
    hapsim_tool_force_t_publish(hs_net_bus_lcm(bus), PFX "TOOL_FORCE", &f);
}

static void echo_main(void) {
    hs_err err = {0};
    hs_net_bus* bus = NULL;
    if (hs_net_bus_create(ECHO_H, &bus, &err) != HS_OK) _exit(1);
    hapsim_tool_pose_t_subscribe(hs_net_bus_lcm(bus), PFX "TOOL_POSE", on_echo_pose, bus);
    for (;;)
        if (hs_net_bus_handle(bus, 100) < 0) _exit(1);
}

static void send_pose(hs_net_bus* bus, int64_t seq, const double p[3]) {
    hapsim_tool_pose_t m;
    memset(&m, 0, sizeof m);
    m.utime = hs_now_ns() / 1000;
    m.seq = seq;
    m.session = 4711;
    for (int k = 0; k < 3; ++k) m.position[k] = p[k];
    m.orientation[0] = 1;
    hapsim_tool_pose_t_publish(hs_net_bus_lcm(bus), PFX "TOOL_POSE", &m);
}

// One pose, wait for its force (at most 20 ms). Returns the round trip in us, or -1; *out_us
// gets the outbound part (send to the answer's publish), the rest is the return path.
static double one_rtt(rtt_side* s, hs_net_bus* mesh, int64_t seq, const double p[3],
                      double* out_us) {
    s->want_seq = seq;
    s->got_ns = 0;
    int64_t t0 = hs_now_ns();
    send_pose(s->bus, seq, p);
    while (!s->got_ns && hs_now_ns() - t0 < 20000000) {
        hs_net_bus_handle(s->bus, 1);
        if (mesh) hs_net_bus_handle(mesh, 0);
    }
    if (out_us) *out_us = (double)s->pub_us - (double)t0 * 1e-3;
    return s->got_ns ? (double)(s->got_ns - t0) * 1e-3 : -1;
}

static void wait_until(int64_t t, hs_net_bus* a, hs_net_bus* b) {
    while (hs_now_ns() < t) {
        hs_net_bus_handle(a, 0);
        if (b) hs_net_bus_handle(b, 0);
    }
}

static int run_inside(const hs_bench_args* a) {
    char self[1024];
    ssize_t n = readlink("/proc/self/exe", self, sizeof self - 32);
    if (n <= 0) return 1;
    self[n] = '\0';
    char* slash = strrchr(self, '/');
    snprintf(slash + 1, 32, "hapsim-server");
    if (access(self, X_OK) != 0) {
        fprintf(stderr, "protocol: %s not built\n", self);
        return 1;
    }
    // The bundled liver without gravity, so that the surface the probe presses is the rest
    // surface (the deformation thread does not settle under gravity before the first contact).
    char scene[256];
    snprintf(scene, sizeof scene, "/tmp/hs_bench_protocol_%d.json", (int)getpid());
    FILE* sf = fopen(scene, "w");
    if (!sf) return 1;
    fprintf(sf,
            "{ \"name\": \"liver (no gravity)\", \"mesh\": \"%s/liver/liver2.msh\",\n"
            "  \"material\": {\"youngs_pa\": 5000, \"poisson\": 0.45, \"density_kg_m3\": "
            "1060, \"rayleigh_mass\": 0.5, \"rayleigh_stiffness\": 0.01},\n"
            "  \"fixed\": [{\"type\": \"plane\", \"point\": [0, -0.0433, 0], \"normal\": "
            "[0, 1, 0]}],\n"
            "  \"gravity\": [0, 0, 0], \"tools\": [{\"kind\": \"probe\", \"radius\": "
            "0.005}],\n"
            "  \"workspace\": {\"min\": [-0.25, -0.2, -0.2], \"max\": [0.25, 0.25, 0.2]} }\n",
            HS_SCENES_DIR);
    fclose(sf);
    pid_t srv = fork();
    if (srv == 0) {
        execl(self, self, scene, "--haptic-url", SRV_H, "--mesh-url", SRV_M, "--prefix", PFX,
              "--quiet", "--duration", "600", (char*)NULL);
        _exit(127);
    }
    fflush(stdout);
    pid_t echo = fork();
    if (echo == 0) echo_main();

    hs_err err = {0};
    rtt_side sv = {0}, ec = {0};
    hs_net_bus* mesh = NULL;
    int rc = 1;
    // round trips, server (s) and echo (e), with their outbound and return ("back") parts
    double *rs = NULL, *re = NULL, *os = NULL, *bs = NULL, *oe = NULL, *be = NULL;
    mesh_count mc;
    memset(&mc, 0, sizeof mc);
    if (hs_net_bus_create(SRV_H, &sv.bus, &err) != HS_OK ||
        hs_net_bus_create(ECHO_H, &ec.bus, &err) != HS_OK ||
        hs_net_bus_create(SRV_MR, &mesh, &err) != HS_OK) {
        fprintf(stderr, "protocol: %s\n", err.msg);
        goto done;
    }
    hapsim_tool_force_t_subscribe(hs_net_bus_lcm(sv.bus), PFX "TOOL_FORCE", on_force, &sv);
    hapsim_tool_force_t_subscribe(hs_net_bus_lcm(ec.bus), PFX "TOOL_FORCE", on_force, &ec);
    hapsim_mesh_state_t_subscribe(hs_net_bus_lcm(mesh), PFX "MESH_STATE", on_state, &mc);
    hapsim_mesh_delta_t_subscribe(hs_net_bus_lcm(mesh), PFX "MESH_DELTA", on_delta, &mc);

    // Wait for both to answer (server set-up: mesh and compliance).
    double free_p[3], press[3];
    double l = sqrt(N399[0] * N399[0] + N399[1] * N399[1] + N399[2] * N399[2]);
    for (int k = 0; k < 3; ++k) {
        free_p[k] = P399[k] + 0.015 * N399[k] / l;
        press[k] = P399[k] + (0.005 - 0.002) * N399[k] / l;
    }
    int64_t seq = 0, eseq = 0;
    int64_t end = hs_now_ns() + 30000000000LL;
    while (hs_now_ns() < end && one_rtt(&sv, NULL, ++seq, free_p, NULL) < 0) {
    }
    while (hs_now_ns() < end && one_rtt(&ec, NULL, ++eseq, free_p, NULL) < 0) {
    }
    if (hs_now_ns() >= end) {
        fprintf(stderr, "protocol: server or echo did not answer within 30 s\n");
        goto done;
    }
    // Move into contact (1 s at 1 kHz), then measure in alternating blocks at 1 kHz.
    int64_t t = hs_now_ns();
    for (int i = 0; i < 1000; ++i) {
        double p[3];
        for (int k = 0; k < 3; ++k) p[k] = free_p[k] + (press[k] - free_p[k]) * (i + 1) / 1000.0;
        send_pose(sv.bus, ++seq, p);
        t += 1000000;
        wait_until(t, sv.bus, mesh);
    }
    const int n_rtt = a->quick ? 2000 : 10000, block = 250;
    rs = malloc(sizeof(double) * (size_t)n_rtt);
    re = malloc(sizeof(double) * (size_t)n_rtt);
    os = malloc(sizeof(double) * (size_t)n_rtt);
    bs = malloc(sizeof(double) * (size_t)n_rtt);
    oe = malloc(sizeof(double) * (size_t)n_rtt);
    be = malloc(sizeof(double) * (size_t)n_rtt);
    if (!rs || !re || !os || !bs || !oe || !be) {
        fprintf(stderr, "protocol: out of memory\n");
        goto done;
    }
    int ns = 0, ne = 0, lost_s = 0, lost_e = 0;
    memset(&mc, 0, sizeof mc);
    int64_t m0 = hs_now_ns();
    t = m0;
    for (int i = 0; i < 2 * n_rtt; ++i) {
        int server = (i / block) % 2 == 0;
        double p[3];
        // A slow 1 mm wobble keeps the tissue moving (mesh deltas) and the contact live.
        double w = 0.001 * sin(2 * M_PI * 0.5 * (double)i * 1e-3);
        for (int k = 0; k < 3; ++k) p[k] = press[k] + w * N399[k] / l;
        double out = 0;
        if (server) {
            double r = one_rtt(&sv, mesh, ++seq, p, &out);
            if (r >= 0) {
                os[ns] = out;
                bs[ns] = r - out;
                rs[ns++] = r;
            } else {
                lost_s++;
            }
        } else {
            double r = one_rtt(&ec, mesh, ++eseq, p, &out);
            // Keep the server's device live during echo blocks, after the echo's answer so
            // that the server's handling of it does not share the echo's round trip.
            send_pose(sv.bus, ++seq, p);
            if (r >= 0) {
                oe[ne] = out;
                be[ne] = r - out;
                re[ne++] = r;
            } else {
                lost_e++;
            }
        }
        t += 1000000;
        wait_until(t, sv.bus, mesh);
    }
    double mesh_s = (double)(hs_now_ns() - m0) * 1e-9;
    int64_t total = mc.msgs + mc.lost;
    printf("rtt_us_p50,rtt_us_p99,bare_lcm_rtt_us_p50,bare_lcm_rtt_us_p99,mesh_vertices,"
           "mesh_msgs_per_s,mesh_loss_pct,out_us_p50,back_us_p50,bare_out_us_p50,"
           "bare_back_us_p50,unanswered,bare_unanswered\n");
    // Percentiles are over the answered round trips; unanswered ones (20 ms) are counted apart.
    printf("%.1f,%.1f,%.1f,%.1f,%lld,%.1f,%.2f,%.1f,%.1f,%.1f,%.1f,%d,%d\n",
           hs_bench_percentile(rs, (size_t)ns, 50), hs_bench_percentile(rs, (size_t)ns, 99),
           hs_bench_percentile(re, (size_t)ne, 50), hs_bench_percentile(re, (size_t)ne, 99),
           (long long)mc.n_vis, (double)mc.msgs / mesh_s,
           total ? 100.0 * (double)mc.lost / (double)total : 0.0,
           hs_bench_percentile(os, (size_t)ns, 50), hs_bench_percentile(bs, (size_t)ns, 50),
           hs_bench_percentile(oe, (size_t)ne, 50), hs_bench_percentile(be, (size_t)ne, 50), lost_s,
           lost_e);
    fprintf(stderr, "protocol: %d server and %d echo round trips (%d / %d unanswered in 20 ms)\n",
            ns, ne, lost_s, lost_e);
    rc = 0;
done:
    free(rs);
    free(re);
    free(os);
    free(bs);
    free(oe);
    free(be);
    hs_net_bus_destroy(&sv.bus);
    hs_net_bus_destroy(&ec.bus);
    hs_net_bus_destroy(&mesh);
    kill(echo, SIGKILL);
    waitpid(echo, NULL, 0);
    kill(srv, SIGTERM);
    int st = 0;
    waitpid(srv, &st, 0);
    unlink(scene);
    return rc;
}

int hs_bench_protocol(const hs_bench_args* a) {
    const char* inside = getenv("HS_NETNS_INSIDE");
    if (inside && !strcmp(inside, "1")) return run_inside(a);
    // Re-run this subcommand through tests/netns.sh: a private network namespace.
    char self[1024];
    ssize_t n = readlink("/proc/self/exe", self, sizeof self - 1);
    if (n <= 0) return 1;
    self[n] = '\0';
    fflush(stdout);
    pid_t pid = fork();
    if (pid == 0) {
        execl(HS_NETNS_SH, HS_NETNS_SH, self, "protocol", a->quick ? "--quick" : (char*)NULL,
              (char*)NULL);
        _exit(127);
    }
    int st = 0;
    waitpid(pid, &st, 0);
    int code = WIFEXITED(st) ? WEXITSTATUS(st) : 1;
    if (code == 77)
        fprintf(stderr, "protocol: cannot create a private network namespace here (needs root or "
                        "CAP_SYS_ADMIN); not measured, so nothing is sent on the host's network\n");
    return code;
}
