// SPDX-License-Identifier: MIT
// Example driver: move a probe around a horizontal circle at 1 kHz for a few seconds, send each
// pose to hapsim-server and print the force of the local model ten times a second.
//   hapsim-example-driver [SECONDS] [CX CY CZ RADIUS]     (defaults 3 s, a 1 cm circle above
//   the liver's top at (-0.060, 0.068, -0.015) m)
// Build against an installed hapsim: find_package(hapsim) + target_link_libraries(x hapsim::client)
// or `cc driver.c $(pkg-config --cflags --libs hapsim-client)`.
#define _POSIX_C_SOURCE 200809L
#include <hapsim/client.h>
#include <math.h>
#include <stdbool.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

static const char usage[] = "usage: hapsim-example-driver [SECONDS] [CX CY CZ RADIUS]\n"
                            "  a circle of probe poses at 1 kHz (defaults 3 s; a 1 cm circle at\n"
                            "  (-0.060, 0.068, -0.015) m, above the bundled liver)\n";

// A whole, finite number, or false (atof would read "--help" as 0 and run for 0 s).
static bool parse_number(const char* s, double* out) {
    char* end = NULL;
    double v = strtod(s, &end);
    if (end == s || *end != '\0' || !isfinite(v)) return false;
    *out = v;
    return true;
}

int main(int argc, char** argv) {
    double seconds = 3.0;
    double cx = -0.060, cy = 0.068, cz = -0.015, r = 0.010;
    double* args[] = {&seconds, &cx, &cy, &cz, &r};
    if (argc > 1 && (!strcmp(argv[1], "-h") || !strcmp(argv[1], "--help"))) {
        fputs(usage, stdout);
        return 0;
    }
    if (argc != 1 && argc != 2 && argc != 6) {
        fprintf(stderr, "driver: expected 0, 1 or 5 arguments, got %d\n%s", argc - 1, usage);
        return 2;
    }
    for (int i = 1; i < argc; i++)
        if (!parse_number(argv[i], args[i - 1])) {
            fprintf(stderr, "driver: argument %d '%s' is not a finite number\n%s", i, argv[i],
                    usage);
            return 2;
        }
    if (seconds < 0) {
        fprintf(stderr, "driver: SECONDS must be >= 0, got %g\n", seconds);
        return 2;
    }
    hs_client_config cfg;
    hs_client_config_default(&cfg);
    cfg.mesh_url = ""; // a driver needs only the haptic bus
    cfg.subscribe = HS_CLIENT_SUB_FORCE;
    hs_client* c = NULL;
    hs_err err = {0};
    if (hs_client_create(&cfg, &c, &err) != HS_OK) {
        fprintf(stderr, "driver: %s\n", err.msg);
        return 1;
    }
    struct timespec next;
    clock_gettime(CLOCK_MONOTONIC, &next);
    int64_t t0 = hs_client_now_us();
    for (long tick = 0;; tick++) {
        int64_t now = hs_client_now_us();
        double t = (double)(now - t0) * 1e-6;
        if (t >= seconds) break;
        hs_client_poll(c, 0, NULL); // take whatever forces arrived, never wait
        hs_client_pose pose = {.device_id = 0, .tool_id = 0, .orientation = {1, 0, 0, 0}};
        pose.position[0] = cx + r * cos(2 * 3.14159265358979 * 0.5 * t);
        pose.position[1] = cy;
        pose.position[2] = cz + r * sin(2 * 3.14159265358979 * 0.5 * t);
        if (hs_client_send_pose(c, &pose, &err) != HS_OK) {
            fprintf(stderr, "driver: %s\n", err.msg);
            break;
        }
        double f[3];
        int32_t state = hs_client_force(c, 0, pose.position, now, f);
        if (tick % 100 == 0)
            printf(
                "t %.2f s  p (%.4f %.4f %.4f) m  F (%.3f %.3f %.3f) N  state %d  latency %lld us\n",
                t, pose.position[0], pose.position[1], pose.position[2], f[0], f[1], f[2],
                (int)state, (long long)hs_client_force_latency_us(c, 0));
        next.tv_nsec += 1000000; // 1 kHz on absolute deadlines
        if (next.tv_nsec >= 1000000000) {
            next.tv_nsec -= 1000000000;
            next.tv_sec++;
        }
        clock_nanosleep(CLOCK_MONOTONIC, TIMER_ABSTIME, &next, NULL);
    }
    hs_client_stats s;
    hs_client_stats_get(c, &s);
    printf("driver: %lld poses sent, %lld forces received\n", (long long)s.poses_sent,
           (long long)s.forces);
    hs_client_destroy(&c);
    return 0;
}
