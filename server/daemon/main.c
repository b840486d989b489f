// SPDX-License-Identifier: GPL-2.0-or-later
// hapsim-server: command line. See docs/server.md.
#define _GNU_SOURCE
#include "hapsim/version.h"
#include <signal.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include <fcntl.h>
#include <unistd.h>

#include "server.h"
#include "platform.h"

static int stop_pipe[2] = {-1, -1};

static void on_stop_signal(int sig) {
    (void)sig;
    char b = 1;
    ssize_t n = write(stop_pipe[1], &b, 1);
    (void)n;
}

static void usage(FILE* f) {
    fprintf(
        f,
        "usage: hapsim-server SCENE [options]\n"
        "\n"
        "Serve the scene file SCENE (JSON, docs/scenes.md): tool poses in, reaction forces\n"
        "out at 1 kHz, the deforming mesh, status and commands over LCM (docs/protocol.md).\n"
        "\n"
        "options:\n"
        "  --haptic-url URL  haptic bus: poses in, forces out (scene lcm.haptic_url)\n"
        "  --mesh-url URL    mesh bus: mesh, tool state, commands, acks, status\n"
        "                    (scene lcm.mesh_url; another bus than the haptic URL: a\n"
        "                    different group or port, options after '?' do not count)\n"
        "  --prefix P        channel prefix [A-Z0-9_]* (scene lcm.prefix)\n"
        "  --realtime        ask for SCHED_FIFO (priority 80) and mlockall for the rt thread;\n"
        "                    falls back to ordinary scheduling when refused and says so\n"
        "  --duration S      stop by itself after S seconds (at most 1e7)\n"
        "  --live            one status line on stderr, rewritten in place twice a second\n"
        "  --quiet           no start-up summary and no exit line\n"
        "  -h, --help        this text\n"
        "\n"
        "Before it serves, the server listens ~1.25 s on its buses: another server already\n"
        "serving the same prefix there (its topology, status or forces) stops this one.\n"
        "\n"
        "Exit status: 0 after SIGINT/SIGTERM/SIGHUP or --duration; 1 on a bad scene (the message\n"
        "names the file, line and key), a bad --prefix, a URL longer than 255 bytes,\n"
        "haptic and mesh URLs on the same bus, another server on the buses and prefix or a\n"
        "run-time failure; 2 on an unknown option, a missing or bad value, or no scene.\n");
}

int main(int argc, char** argv) {
    if (hapsim_version_asked(argc, argv, "hapsim-server")) return 0;
    hs_platform_setup(argv); // before any thread: it may re-execute the program
    // SIGINT/SIGTERM write one byte to a pipe the net loop polls (async-signal-safe), whichever
    // thread the kernel picks (libraries start threads before main, so masks cannot steer it).
    if (pipe(stop_pipe) != 0) {
        perror("hapsim-server: pipe");
        return 1;
    }
    for (int k = 0; k < 2; ++k) {
        fcntl(stop_pipe[k], F_SETFL, O_NONBLOCK);
        fcntl(stop_pipe[k], F_SETFD, FD_CLOEXEC);
    }
    struct sigaction sa;
    memset(&sa, 0, sizeof sa);
    sa.sa_handler = on_stop_signal;
    sa.sa_flags = SA_RESTART;
    sigemptyset(&sa.sa_mask);
    sigaction(SIGINT, &sa, NULL);
    sigaction(SIGTERM, &sa, NULL);
    sigaction(SIGHUP, &sa, NULL); // a closed terminal stops it the same way, with its exit line
    signal(SIGPIPE, SIG_IGN);

    hs_server_opts o;
    memset(&o, 0, sizeof o);
    o.stop_fd = stop_pipe[0];
    for (int i = 1; i < argc; ++i) {
        const char* a = argv[i];
        int has_val = i + 1 < argc;
        if (!strcmp(a, "-h") || !strcmp(a, "--help")) {
            usage(stdout);
            return 0;
        } else if (!strcmp(a, "--haptic-url") && has_val) {
            o.haptic_url = argv[++i];
        } else if (!strcmp(a, "--mesh-url") && has_val) {
            o.mesh_url = argv[++i];
        } else if (!strcmp(a, "--prefix") && has_val) {
            o.prefix = argv[++i];
        } else if (!strcmp(a, "--realtime")) {
            o.realtime = 1;
        } else if (!strcmp(a, "--duration") && has_val) {
            char* end = NULL;
            o.duration_s = strtod(argv[++i], &end);
            if (end == argv[i] || *end || !(o.duration_s > 0) || o.duration_s > 1e7) {
                fprintf(stderr, "hapsim-server: --duration '%s': seconds, > 0 and at most 1e7\n",
                        argv[i]);
                return 2;
            }
        } else if (!strcmp(a, "--live")) {
            o.live = 1;
        } else if (!strcmp(a, "--quiet")) {
            o.quiet = 1;
        } else if (a[0] == '-') {
            fprintf(stderr, "hapsim-server: unknown option or missing value: '%s' (see --help)\n",
                    a);
            return 2;
        } else if (!o.scene_path) {
            o.scene_path = a;
        } else {
            fprintf(stderr, "hapsim-server: one scene only (got '%s' and '%s')\n", o.scene_path, a);
            return 2;
        }
    }
    if (!o.scene_path) {
        usage(stderr);
        return 2;
    }
    hs_err err = {0};
    hs_server* s = NULL;
    if (hs_server_create(&o, &s, &err) != HS_OK) {
        fprintf(stderr, "hapsim-server: %s\n", err.msg);
        return 1;
    }
    hs_status st = hs_server_run(s, &err);
    hs_server_destroy(&s);
    if (st != HS_OK) {
        fprintf(stderr, "hapsim-server: %s\n", err.msg);
        return 1;
    }
    return 0;
}
