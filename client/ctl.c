// SPDX-License-Identifier: MIT
// hapsim-ctl: send commands to a running hapsim-server and show its status. docs/client.md.
#define _POSIX_C_SOURCE 200809L
#include "hapsim/version.h"
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "hapsim/client.h"
#include "hapsim_channels.h"
#include "hapsim_command_ack_t.h"
#include "hapsim_command_rules.h"
#include "hapsim_command_t.h"

// 2 for bad usage, as every hapsim program.
enum { EXIT_OK = 0, EXIT_NO_SERVER = 1, EXIT_USAGE = 2, EXIT_REJECTED = 3 };

static void usage(FILE* f) {
    fprintf(f, "usage: hapsim-ctl [options] COMMAND [ARGS]\n\n"
               "Send a command to a running hapsim-server and wait for its acknowledgement\n"
               "(retried with the same request id until it arrives), or show its status.\n\n"
               "commands:\n"
               "  status               wait for one server status message and print it\n"
               "  reset                rest shape, cuts undone\n"
               "  pause | resume       freeze / continue the deformation (forces ramp to zero)\n"
               "  load-scene PATH      load a scene file (path on the server host)\n"
               "  set NAME VALUE       change a run-time parameter (VALUE: a decimal number)\n"
               "  set --list           the parameters, their ranges and whether a change\n"
               "                       rebuilds the simulation (at rest; refused after a cut)\n"
               "  estop                latch every force to zero\n"
               "  estop-release        clear the e-stop latch\n"
               "  request-topology     publish the mesh topology and a keyframe now\n\n"
               "options:\n"
               "  --mesh-url URL       mesh bus (" HAPSIM_DEFAULT_MESH_URL ")\n"
               "  --prefix P           channel prefix (" HAPSIM_DEFAULT_PREFIX ")\n"
               "  --timeout MS         give up after MS milliseconds (3000)\n"
               "  --retry MS           re-send an unanswered command every MS milliseconds (250)\n"
               "  -q, --quiet          print nothing on success\n"
               "  -h, --help           this text (anywhere on the line)\n\n"
               "exit status: 0 ok, 1 no server / timeout, 2 bad usage (also a --mesh-url LCM\n"
               "cannot open), 3 command rejected\n");
}

static void print_status(const hs_client_status* s, int64_t age_us) {
    printf("server   %s, up %.1f s, scene %s\n", hs_client_state_name(s->state),
           (double)s->uptime_us * 1e-6, s->scene[0] ? s->scene : "(none)");
    printf("topology version %lld   (status %.0f ms old, seq %lld)\n",
           (long long)s->topology_version, (double)age_us * 1e-3, (long long)s->seq);
    if (s->n_loops)
        printf("%-10s %9s %9s %9s %9s %10s\n", "loop", "rate Hz", "p50 us", "p99 us", "max us",
               "overruns");
    for (int i = 0; i < s->n_loops && i < HS_CLIENT_STATUS_LOOPS; i++)
        printf("%-10s %9.1f %9.1f %9.1f %9.1f %10lld\n", s->loops[i].name, s->loops[i].rate_hz,
               s->loops[i].p50_us, s->loops[i].p99_us, s->loops[i].max_us,
               (long long)s->loops[i].overruns);
    if (s->n_steps) printf("%-10s %9s %9s %9s\n", "step", "p50 us", "p99 us", "max us");
    for (int i = 0; i < s->n_steps && i < HS_CLIENT_STATUS_STEPS; i++)
        printf("%-10s %9.1f %9.1f %9.1f\n", s->steps[i].name, s->steps[i].p50_us,
               s->steps[i].p99_us, s->steps[i].max_us);
    for (int i = 0; i < s->n_devices && i < HS_CLIENT_STATUS_DEVICES; i++)
        printf("device %d  %s  pose age %.1f ms  poses %lld (lost %lld)  latency p50 %.0f us "
               "p99 %.0f us  force %.3f N\n",
               s->devices[i].id, s->devices[i].live ? "live" : "idle", s->devices[i].pose_age_ms,
               (long long)s->devices[i].poses_received, (long long)s->devices[i].poses_lost,
               s->devices[i].latency_p50_us, s->devices[i].latency_p99_us,
               s->devices[i].force_norm);
    for (int i = 0; i < s->n_rejects && i < HS_CLIENT_STATUS_REJECTS; i++)
        printf("rejected %s/%s: %lld\n", s->rejects[i].channel, s->rejects[i].reason,
               (long long)s->rejects[i].count);
    if (s->warnings[0]) printf("warnings:\n%s\n", s->warnings);
}

// The options before the command.
typedef struct ctl_opts {
    const char *mesh_url, *prefix;
    int timeout_ms, retry_ms, quiet;
} ctl_opts;

// Reads the options into o and *first to the command's index; -1 to go on, else the exit status.
static int parse_options(int argc, char** argv, ctl_opts* o, int* first) {
    int i = 1;
    // Asking for help is never a usage error, also after the command ("status --help").
    for (int j = 1; j < argc; j++)
        if (!strcmp(argv[j], "-h") || !strcmp(argv[j], "--help")) {
            usage(stdout);
            return EXIT_OK;
        }
    for (; i < argc && argv[i][0] == '-'; i++) {
        const char* a = argv[i];
        if (!strcmp(a, "-q") || !strcmp(a, "--quiet")) {
            o->quiet = 1;
            continue;
        }
        if (i + 1 >= argc) {
            fprintf(stderr, "hapsim-ctl: unknown option or missing value: '%s' (see --help)\n", a);
            return EXIT_USAGE;
        }
        const char* val = argv[++i];
        char* e;
        if (!strcmp(a, "--mesh-url"))
            o->mesh_url = val;
        else if (!strcmp(a, "--prefix"))
            o->prefix = val;
        else if (!strcmp(a, "--timeout") || !strcmp(a, "--retry")) {
            long v = strtol(val, &e, 10);
            if (e == val || *e || v < 1 || v > 3600000) {
                fprintf(stderr, "hapsim-ctl: %s '%s': expected 1 .. 3600000 ms\n", a, val);
                return EXIT_USAGE;
            }
            if (a[2] == 't')
                o->timeout_ms = (int)v;
            else
                o->retry_ms = (int)v;
        } else {
            fprintf(stderr, "hapsim-ctl: unknown option '%s' (see --help)\n", a);
            return EXIT_USAGE;
        }
    }
    if (i >= argc) {
        usage(stderr);
        return EXIT_USAGE;
    }
    *first = i;
    return -1;
}

// The commands; kind 0 is status (read, not sent).
static const struct ctl_command {
    const char* name;
    int kind, nargs;
} commands[] = {{"status", 0, 0},
                {"reset", HAPSIM_COMMAND_T_KIND_RESET, 0},
                {"pause", HAPSIM_COMMAND_T_KIND_PAUSE, 0},
                {"resume", HAPSIM_COMMAND_T_KIND_RESUME, 0},
                {"load-scene", HAPSIM_COMMAND_T_KIND_LOAD_SCENE, 1},
                {"set", HAPSIM_COMMAND_T_KIND_SET_PARAM, 2},
                {"estop", HAPSIM_COMMAND_T_KIND_ESTOP, 0},
                {"estop-release", HAPSIM_COMMAND_T_KIND_ESTOP_RELEASE, 0},
                {"request-topology", HAPSIM_COMMAND_T_KIND_REQUEST_TOPOLOGY, 0}};

// set --list: the parameter table.
static void print_params(void) {
    int n;
    const hapsim_param_info* t = hapsim_params(&n);
    printf("%-24s %-22s %-5s %-10s %s\n", "parameter", "accepted", "unit", "on set", "meaning");
    for (int j = 0; j < n; j++) {
        char range[64];
        snprintf(range, sizeof range, "%s%g .. %g", t[j].min_open ? "> " : "", t[j].min, t[j].max);
        printf("%-24s %-22s %-5s %-10s %s\n", t[j].name, range, t[j].unit,
               t[j].rebuilds ? "rebuild" : "at once", t[j].what);
    }
}

// Waits for one status message and prints it; returns the exit status.
static int show_status(hs_client* c, int timeout_ms) {
    hs_err err = {0};
    int64_t deadline = hs_client_now_us() + (int64_t)timeout_ms * 1000;
    hs_client_status s;
    int64_t age = 0;
    while (!hs_client_status_latest(c, NULL, NULL) && hs_client_now_us() < deadline)
        if (hs_client_poll(c, 50, &err) < 0) break;
    if (hs_client_status_latest(c, &s, &age)) {
        print_status(&s, age);
        return EXIT_OK;
    }
    fprintf(stderr,
            "hapsim-ctl: no server status within %d ms (is hapsim-server "
            "running on this mesh bus and prefix?)\n",
            timeout_ms);
    return EXIT_NO_SERVER;
}

// Sends one command and reports its acknowledgement; returns the exit status.
static int send_command(hs_client* c, const struct ctl_command* k, const char** keys,
                        const char** values, const ctl_opts* o) {
    const char* cmd = k->name;
    hs_err err = {0};
    hs_client_ack ack;
    hs_status st = hs_client_command(c, k->kind, k->nargs, keys, values, o->timeout_ms, o->retry_ms,
                                     &ack, &err);
    if (st == HS_ERR_INVALID) {
        fprintf(stderr, "hapsim-ctl: %s\n", err.msg);
        return EXIT_USAGE;
    }
    if (st != HS_OK) {
        // The library's reason: no ack at all, or a PENDING one and then nothing.
        if (ack.status == HAPSIM_COMMAND_ACK_T_STATUS_PENDING && ack.message[0])
            fprintf(stderr, "hapsim-ctl: %s: %s (the server said: %s)\n", cmd, err.msg,
                    ack.message);
        else
            fprintf(stderr, "hapsim-ctl: %s: %s (%d attempts)\n", cmd, err.msg, ack.attempts);
        return EXIT_NO_SERVER;
    }
    if (ack.status != HAPSIM_COMMAND_ACK_T_STATUS_OK) {
        fprintf(stderr, "hapsim-ctl: %s %s: %s\n", cmd,
                ack.status == HAPSIM_COMMAND_ACK_T_STATUS_INVALID ? "rejected as invalid"
                                                                  : "failed",
                ack.message[0] ? ack.message : "(no detail)");
        return EXIT_REJECTED;
    }
    if (!o->quiet)
        printf("%s: ok (request %lld, %d attempt%s, %.1f ms)%s%s\n", cmd, (long long)ack.request_id,
               ack.attempts, ack.attempts == 1 ? "" : "s", (double)ack.rtt_us * 1e-3,
               ack.message[0] ? ": " : "", ack.message);
    return EXIT_OK;
}

int main(int argc, char** argv) {
    if (hapsim_version_asked(argc, argv, "hapsim-ctl")) return 0;
    ctl_opts o = {.timeout_ms = 3000, .retry_ms = 250};
    int i = 1;
    int prc = parse_options(argc, argv, &o, &i);
    if (prc >= 0) return prc;
    const char* cmd = argv[i++];
    int nrest = argc - i;
    const struct ctl_command* k = NULL;
    for (int j = 0; j < (int)(sizeof commands / sizeof commands[0]); j++)
        if (!strcmp(cmd, commands[j].name)) k = &commands[j];
    if (!k) {
        fprintf(stderr, "hapsim-ctl: unknown command '%s' (see --help)\n", cmd);
        return EXIT_USAGE;
    }
    if (k->kind == HAPSIM_COMMAND_T_KIND_SET_PARAM && nrest == 1 && !strcmp(argv[i], "--list")) {
        print_params();
        return EXIT_OK;
    }
    if (nrest != k->nargs) {
        fprintf(stderr, "hapsim-ctl: %s takes %d argument%s, got %d (see --help)\n", cmd, k->nargs,
                k->nargs == 1 ? "" : "s", nrest);
        return EXIT_USAGE;
    }
    const char* keys[2];
    const char* values[2];
    if (k->kind == HAPSIM_COMMAND_T_KIND_LOAD_SCENE) {
        keys[0] = "path";
        values[0] = argv[i];
    } else if (k->kind == HAPSIM_COMMAND_T_KIND_SET_PARAM) {
        char* e;
        double d = strtod(argv[i + 1], &e);
        if (e == argv[i + 1] || *e || !isfinite(d)) {
            fprintf(stderr, "hapsim-ctl: set: value '%s' is not a finite decimal number\n",
                    argv[i + 1]);
            return EXIT_USAGE;
        }
        keys[0] = "name";
        values[0] = argv[i];
        keys[1] = "value";
        values[1] = argv[i + 1];
    }

    hs_client_config cfg;
    hs_client_config_default(&cfg);
    cfg.haptic_url = "";
    cfg.mesh_url = o.mesh_url;
    cfg.prefix = o.prefix;
    cfg.sender = "hapsim-ctl";
    cfg.subscribe = k->kind ? HS_CLIENT_SUB_COMMANDS : HS_CLIENT_SUB_STATUS;
    hs_client* c = NULL;
    hs_err err = {0};
    if (hs_client_create(&cfg, &c, &err) != HS_OK) {
        // Nothing was sent yet: a prefix or a URL that LCM cannot open is a bad value, not a
        // missing server (the message names the URL).
        fprintf(stderr, "hapsim-ctl: %s\n", err.msg);
        return EXIT_USAGE;
    }
    int rc = k->kind == 0 ? show_status(c, o.timeout_ms) : send_command(c, k, keys, values, &o);
    hs_client_destroy(&c);
    return rc;
}
