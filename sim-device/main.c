// SPDX-License-Identifier: MIT
// hapsim-stylus: a simulated 3-DoF haptic stylus that plays a probe script against a running
// hapsim-server over LCM (or, with --offline-stiffness, against a built-in elastic half-space in
// deterministic virtual time), and writes a trace CSV with a summary.
//
// DESIGN: two threads.
//   device loop (1 kHz): clock_nanosleep on absolute CLOCK_MONOTONIC deadlines, real elapsed dt;
//     takes the newest force model from the mailbox, evaluates the script target, steps the
//     device (render, clamps, dynamics), appends a trace row to memory allocated before the run,
//     publishes the tool pose. No allocation, no lock of ours, no printing.
//   receive: the only caller of lcm_handle(), after poll() on lcm_get_fileno() (never
//     lcm_handle_timeout: it aborts on fds >= 1024). Checks each tool_force and puts it into the
//     mailbox (triple buffer, latest wins).
//   main: options, set-up, a one-line status per second (--status), summary and trace at the end.
// SIGINT/SIGTERM end the run gracefully: the trace and summary are still written.
#define _POSIX_C_SOURCE 200809L

#include "hapsim/version.h"
#include <errno.h>
#include <getopt.h>
#include <inttypes.h>
#include <math.h>
#include <poll.h>
#include <pthread.h>
#include <sched.h>
#include <signal.h>
#include <stdatomic.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>
#include <unistd.h>

#include <fcntl.h>
#include <sys/mman.h>

#include <lcm/lcm.h>

#include "hapsim_channels.h"
#include "hapsim_tool_force_t.h"
#include "hapsim_tool_pose_t.h"
#include "stylus.h"
#include "wire.h"

#define MAX_TRACE_S 600.0 // rows beyond 10 minutes are counted, not kept

static atomic_int g_stop;

static void on_signal(int sig) {
    (void)sig;
    atomic_store(&g_stop, 1);
}

static int64_t wall_us(void) {
    struct timespec ts;
    clock_gettime(CLOCK_REALTIME, &ts);
    return (int64_t)ts.tv_sec * 1000000 + ts.tv_nsec / 1000;
}

// The device clock, CLOCK_MONOTONIC ns.
static int64_t now_ns(void) {
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (int64_t)ts.tv_sec * 1000000000 + ts.tv_nsec;
}

typedef struct options {
    const char* script;
    const char* haptic_url;
    const char* status_url;
    const char* prefix;
    const char* trace;
    int device_id;
    int tool_id;
    double duration_s;
    double rate_hz;
    int has_origin;
    double origin[3];
    int status;
    int duration_auto; // no --duration: the script's end (+ 0.5 s)
    int realtime;
    int quiet;
    double offline_k;
    int has_plane;
    double plane[6];
    int offline_delay;
    int offline_period;
    double offline_radius;
    double offline_timeout;
} options;

typedef struct app {
    options opt;
    hs_stylus_def def;
    hs_script* script;
    hs_stylus_trace* trace;
    lcm_t* lcm;
    lcm_t* status_lcm; // mesh bus, for SERVER_STATUS (--status-url), or NULL
    char status_channel[HAPSIM_CHANNEL_MAX];
    char pose_channel[HAPSIM_CHANNEL_MAX];
    char force_channel[HAPSIM_CHANNEL_MAX];
    hs_stylus_mailbox mailbox;
    int64_t session;
    hs_stylus_rx_state rx; // receive thread only
    // Counters shared with main (relaxed: statistics only).
    atomic_llong rx_forces, rx_rejected, rx_other_device, rx_other_session;
    atomic_llong ticks, overruns, late_max_us;
    atomic_llong force_mn, period_p99_us, latency_us;
    atomic_int loop_done;
    atomic_int rx_failed;
    atomic_int rt_granted; // bit 0: SCHED_FIFO, bit 1: mlockall
    // From the server's status (--status-url): rt loop rate (mHz), rt period p99 (us), the
    // slowest step's p99 (us), status messages seen, malformed ones dropped.
    atomic_llong srv_rate_mhz, srv_p99_us, srv_step_p99_us, srv_status_count, srv_status_bad;
} app;

static void usage(FILE* f) {
    fprintf(f,
            "usage: hapsim-stylus --script FILE [options]\n"
            "A simulated 3-DoF haptic stylus: plays a probe script (docs/stylus.md) at 1 kHz,\n"
            "publishes tool poses, renders the server's force model, writes a trace CSV.\n"
            "\n"
            "  --script FILE           probe script (required)\n"
            "  --haptic-url URL        LCM URL of the haptic bus (default %s)\n"
            "  --prefix P              channel prefix (default %s)\n"
            "  --device-id N           device id in the server's scene (default 0)\n"
            "  --tool-id N             tool id held by the device (default 0)\n"
            "  --trace FILE            trace CSV (default hapsim-stylus-trace.csv)\n"
            "  --duration S            run length, s (default: script length + 0.5 s)\n"
            "  --origin X,Y,Z          workspace centre in scene coordinates, m (default: the\n"
            "                          script's origin, else its start)\n"
            "  --rate HZ               device loop rate (default 1000)\n"
            "  --mass KG               handle mass (default 0.05)\n"
            "  --hand-stiffness N/M    virtual hand spring (default 400)\n"
            "  --hand-damping NS/M     virtual hand damper (default 8)\n"
            "  --max-force N           motor force limit (default 3.3)\n"
            "  --max-rate N/S          motor force rate limit (default 2000)\n"
            "  --workspace X,Y,Z       workspace box, m (default 0.16,0.12,0.07)\n"
            "  --timeout-ms MS         force is zero at this model age (default 100, <= 60000)\n"
            "  --ramp-ms MS            ramp-down length within the timeout (default 20)\n"
            "  --realtime              SCHED_FIFO (priority 70) and mlockall for the device loop\n"
            "                          when permitted (else ordinary scheduling, said at the end)\n"
            "  --status                print a one-line status every second\n"
            "  --status-url URL        also show the server's loop rate, jitter and step time\n"
            "                          from its SERVER_STATUS on this bus (the mesh bus, e.g.\n"
            "                          %s)\n"
            "  --quiet                 no summary on stdout\n"
            "Offline (no network, virtual time, deterministic):\n"
            "  --offline-stiffness K   replace the server by an elastic half-space, N/m\n"
            "  --offline-plane P,N     its plane: px,py,pz,nx,ny,nz (default: the script's\n"
            "                          `surface`)\n"
            "  --offline-delay N       ticks between a pose and its force (default 1)\n"
            "  --offline-period N      the half-space answers every N poses (default 1)\n"
            "  --offline-radius M      validity radius of its models, m (default 0.002)\n"
            "  --help                  this text\n",
            HAPSIM_DEFAULT_HAPTIC_URL, HAPSIM_DEFAULT_PREFIX, HAPSIM_DEFAULT_MESH_URL);
}

static int parse_double(const char* s, double* v) {
    char* end = NULL;
    errno = 0;
    double x = strtod(s, &end);
    if (end == s || *end || errno == ERANGE || !isfinite(x)) return 0;
    *v = x;
    return 1;
}

// n comma-separated numbers; an empty field ("1,,2") is an error, not skipped.
static int parse_list(const char* s, double* v, int n) {
    char buf[256];
    if (strlen(s) >= sizeof buf) return 0;
    memcpy(buf, s, strlen(s) + 1);
    char* p = buf;
    for (int i = 0; i < n; ++i) {
        char* comma = strchr(p, ',');
        if ((comma != NULL) != (i < n - 1)) return 0; // too few or too many fields
        if (comma) *comma = '\0';
        if (!parse_double(p, &v[i])) return 0;
        p = comma + 1;
    }
    return 1;
}

// Scales v (finite) to unit length; 0 when it is zero. Divided by its largest component
// first: the plain sum of squares overflows for 1e200 and underflows to 0 for 1e-200.
static int unit_vector(double v[3]) {
    double big = fmax(fabs(v[0]), fmax(fabs(v[1]), fabs(v[2])));
    if (!(big > 0)) return 0;
    for (int i = 0; i < 3; ++i) v[i] /= big;
    double l = sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2]);
    for (int i = 0; i < 3; ++i) v[i] /= l;
    return 1;
}

// The channel prefix the server accepts: [A-Z0-9_]*.
static int prefix_ok(const char* p) {
    for (; *p; ++p)
        if (!((*p >= 'A' && *p <= 'Z') || (*p >= '0' && *p <= '9') || *p == '_')) return 0;
    return 1;
}

static int parse_int(const char* s, int lo, int hi, int* v) {
    double x;
    if (!parse_double(s, &x) || x != floor(x) || x < lo || x > hi) return 0;
    *v = (int)x;
    return 1;
}

// getopt_long codes of the long options.
enum {
    O_SCRIPT = 256,
    O_URL,
    O_PREFIX,
    O_DEVICE,
    O_TOOL,
    O_TRACE,
    O_DURATION,
    O_ORIGIN,
    O_RATE,
    O_MASS,
    O_HK,
    O_HB,
    O_FMAX,
    O_RMAX,
    O_WS,
    O_TIMEOUT,
    O_RAMP,
    O_STATUS,
    O_REALTIME,
    O_STATUS_URL,
    O_QUIET,
    O_OK,
    O_PLANE,
    O_DELAY,
    O_PERIOD,
    O_RADIUS,
    O_HELP
};

static const struct option longopts[] = {
    {"script", required_argument, 0, O_SCRIPT},
    {"haptic-url", required_argument, 0, O_URL},
    {"prefix", required_argument, 0, O_PREFIX},
    {"device-id", required_argument, 0, O_DEVICE},
    {"tool-id", required_argument, 0, O_TOOL},
    {"trace", required_argument, 0, O_TRACE},
    {"duration", required_argument, 0, O_DURATION},
    {"origin", required_argument, 0, O_ORIGIN},
    {"rate", required_argument, 0, O_RATE},
    {"mass", required_argument, 0, O_MASS},
    {"hand-stiffness", required_argument, 0, O_HK},
    {"hand-damping", required_argument, 0, O_HB},
    {"max-force", required_argument, 0, O_FMAX},
    {"max-rate", required_argument, 0, O_RMAX},
    {"workspace", required_argument, 0, O_WS},
    {"timeout-ms", required_argument, 0, O_TIMEOUT},
    {"ramp-ms", required_argument, 0, O_RAMP},
    {"status", no_argument, 0, O_STATUS},
    {"realtime", no_argument, 0, O_REALTIME},
    {"status-url", required_argument, 0, O_STATUS_URL},
    {"quiet", no_argument, 0, O_QUIET},
    {"offline-stiffness", required_argument, 0, O_OK},
    {"offline-plane", required_argument, 0, O_PLANE},
    {"offline-delay", required_argument, 0, O_DELAY},
    {"offline-period", required_argument, 0, O_PERIOD},
    {"offline-radius", required_argument, 0, O_RADIUS},
    {"help", no_argument, 0, O_HELP},
    {0, 0, 0, 0},
};

// Applies one option that takes its value (or sets a flag); 1: done, 0: a bad value, -1: a
// bad value already reported. offline_only and live_only name a flag one mode would ignore.
static int set_option(int c, const char* a, options* o, hs_stylus_def* def,
                      const char** offline_only, const char** live_only) {
    double ms;
    int ok = 1;
    switch (c) {
    case O_SCRIPT:
        o->script = a;
        break;
    case O_URL:
        o->haptic_url = a;
        *live_only = "--haptic-url";
        break;
    case O_PREFIX:
        o->prefix = a;
        ok = prefix_ok(a);
        break;
    case O_DEVICE:
        ok = parse_int(a, 0, 1 << 20, &o->device_id);
        break;
    case O_TOOL:
        ok = parse_int(a, 0, 1 << 20, &o->tool_id);
        break;
    case O_TRACE:
        o->trace = a;
        break;
    case O_DURATION:
        // At most 1e7 s, as the server: beyond, ticks would overflow the tick count.
        ok = parse_double(a, &o->duration_s) && o->duration_s > 0 && o->duration_s <= 1e7;
        break;
    case O_ORIGIN:
        ok = o->has_origin = parse_list(a, o->origin, 3);
        break;
    case O_RATE:
        ok = parse_double(a, &o->rate_hz) && o->rate_hz >= 10 && o->rate_hz <= 10000;
        break;
    case O_MASS:
        ok = parse_double(a, &def->mass_kg);
        break;
    case O_HK:
        ok = parse_double(a, &def->hand_stiffness_n_m);
        break;
    case O_HB:
        ok = parse_double(a, &def->hand_damping_n_s_m);
        break;
    case O_FMAX:
        ok = parse_double(a, &def->max_force_n);
        break;
    case O_RMAX:
        ok = parse_double(a, &def->max_rate_n_s);
        break;
    case O_WS:
        ok = parse_list(a, def->workspace_m, 3);
        break;
    case O_TIMEOUT: // bounded: beyond ~9.2e12 ms the ramp's ns overflowed and was skipped
        ok = parse_double(a, &ms) && ms > 0 && ms <= 1e3 * HS_STYLUS_MAX_TIMEOUT_S;
        def->timeout_s = ms * 1e-3;
        break;
    case O_RAMP:
        ok = parse_double(a, &ms) && ms > 0 && ms <= 1e3 * HS_STYLUS_MAX_TIMEOUT_S;
        def->ramp_s = ms * 1e-3;
        break;
    case O_STATUS:
        o->status = 1;
        break;
    case O_REALTIME:
        o->realtime = 1;
        *live_only = "--realtime";
        break;
    case O_STATUS_URL:
        o->status_url = a;
        o->status = 1;
        *live_only = "--status-url";
        break;
    case O_QUIET:
        o->quiet = 1;
        break;
    case O_OK:
        ok = parse_double(a, &o->offline_k) && o->offline_k > 0;
        break;
    case O_PLANE:
        ok = o->has_plane = parse_list(a, o->plane, 6);
        if (ok && !unit_vector(o->plane + 3)) {
            fprintf(stderr,
                    "hapsim-stylus: bad value '%s' for --offline-plane: the normal "
                    "(NX,NY,NZ) must not be zero\n",
                    a);
            return -1;
        }
        *offline_only = "--offline-plane";
        break;
    case O_DELAY:
        ok = parse_int(a, 1, 63, &o->offline_delay);
        *offline_only = "--offline-delay";
        break;
    case O_PERIOD:
        ok = parse_int(a, 1, 1000, &o->offline_period);
        *offline_only = "--offline-period";
        break;
    case O_RADIUS:
        ok = parse_double(a, &o->offline_radius) && o->offline_radius >= 0;
        *offline_only = "--offline-radius";
        break;
    }
    return ok;
}

// Returns 0 to run, 1 to exit with success (--help), 2 on a bad option (message printed).
static int parse_options(int argc, char** argv, options* o, hs_stylus_def* def) {
    memset(o, 0, sizeof *o);
    o->haptic_url = HAPSIM_DEFAULT_HAPTIC_URL;
    o->prefix = HAPSIM_DEFAULT_PREFIX;
    o->trace = "hapsim-stylus-trace.csv";
    o->rate_hz = 1000;
    o->offline_delay = 1;
    o->offline_period = 1;
    o->offline_radius = 0.002;
    o->offline_timeout = 0.05;
    int c, idx = -1;
    const char *offline_only = NULL, *live_only = NULL; // a flag the chosen mode would ignore
    opterr = 0;
    while ((c = getopt_long(argc, argv, "h", longopts, &idx)) != -1) {
        const char* a = optarg;
        if (c == 'h' || c == O_HELP) {
            usage(stdout);
            return 1;
        }
        if (c < O_SCRIPT || c > O_RADIUS) {
            // getopt_long sets optopt to the short option it did not know, else 0
            if (optopt > 0 && optopt < 256 && optopt != 'h')
                fprintf(stderr, "hapsim-stylus: unknown option -%c\n", optopt);
            else
                fprintf(stderr, "hapsim-stylus: unknown option or missing value: %s\n",
                        argv[optind - 1]);
            usage(stderr);
            return 2;
        }
        int ok = set_option(c, a, o, def, &offline_only, &live_only);
        if (ok < 0) return 2;
        if (!ok) {
            fprintf(stderr, "hapsim-stylus: bad value '%s' for --%s\n", a,
                    idx >= 0 ? longopts[idx].name : "?");
            return 2;
        }
        idx = -1;
    }
    if (optind < argc) {
        fprintf(stderr, "hapsim-stylus: unexpected argument '%s'\n", argv[optind]);
        return 2;
    }
    if (!o->script) {
        fprintf(stderr, "hapsim-stylus: --script FILE is required (see --help)\n");
        return 2;
    }
    const char* bad_url = hapsim_url_problem(o->haptic_url) ? o->haptic_url : o->status_url;
    const char* why = hapsim_url_problem(bad_url);
    if (why) {
        fprintf(stderr, "hapsim-stylus: LCM URL '%s' %s\n", bad_url, why);
        return 2;
    }
    if (o->offline_k > 0 ? live_only != NULL : offline_only != NULL) {
        fprintf(stderr, "hapsim-stylus: %s has no effect %s\n",
                o->offline_k > 0 ? live_only : offline_only,
                o->offline_k > 0 ? "in an offline run (--offline-stiffness)"
                                 : "without --offline-stiffness");
        return 2;
    }
    return 0;
}

// ---------------------------------------------------------------------------------------------
// Receive thread.

// Raw subscription: lcm-gen's subscriber printed an error per undecodable message and dropped
// it uncounted; here it is one more rejected message.
static void on_force(const lcm_recv_buf_t* rbuf, const char* channel, void* user) {
    (void)channel;
    app* a = user;
    hs_stylus_model m;
    hs_stylus_rx r =
        hs_stylus_rx_bytes(&a->rx, rbuf->data, rbuf->data_size, now_ns(), wall_us(), &m);
    if (r == HS_RX_OK) {
        hs_stylus_mailbox_put(&a->mailbox, &m);
        atomic_fetch_add_explicit(&a->rx_forces, 1, memory_order_relaxed);
        atomic_store_explicit(&a->latency_us, m.latency_us, memory_order_relaxed);
    } else if (r == HS_RX_OTHER_DEVICE) {
        atomic_fetch_add_explicit(&a->rx_other_device, 1, memory_order_relaxed);
    } else if (r == HS_RX_OTHER_SESSION) {
        atomic_fetch_add_explicit(&a->rx_other_session, 1, memory_order_relaxed);
    } else {
        atomic_fetch_add_explicit(&a->rx_rejected, 1, memory_order_relaxed);
    }
}

// The server's own view, for the status line only. Decoded with every length checked (lcm-gen's
// decoder leaves a string without its NUL, read past by strcmp); a malformed one is counted.
static void on_status(const lcm_recv_buf_t* rbuf, const char* channel, void* user) {
    (void)channel;
    app* a = user;
    hs_stylus_srv_status s;
    if (hs_stylus_status_decode(rbuf->data, rbuf->data_size, &s) != 0) {
        atomic_fetch_add(&a->srv_status_bad, 1);
        return;
    }
    if (s.has_rt) {
        atomic_store(&a->srv_rate_mhz, llround(1e3 * s.rt_rate_hz));
        atomic_store(&a->srv_p99_us, llround(s.rt_p99_us));
    }
    atomic_store(&a->srv_step_p99_us, llround(s.step_p99_us));
    atomic_fetch_add(&a->srv_status_count, 1);
}

static void* rx_main(void* arg) {
    app* a = arg;
    struct pollfd pfd[2] = {
        {.fd = lcm_get_fileno(a->lcm), .events = POLLIN},
        {.fd = a->status_lcm ? lcm_get_fileno(a->status_lcm) : -1, .events = POLLIN}};
    while (!atomic_load(&g_stop) && !atomic_load(&a->loop_done)) {
        int r = poll(pfd, a->status_lcm ? 2 : 1, 50);
        if (r < 0 && errno != EINTR) break;
        if (r <= 0) continue;
        if ((pfd[0].revents & POLLIN) && lcm_handle(a->lcm) != 0) break;
        if (a->status_lcm && (pfd[1].revents & POLLIN) && lcm_handle(a->status_lcm) != 0) break;
    }
    // Without forces the device ramps to zero on its own; say why at the end.
    if (!atomic_load(&g_stop) && !atomic_load(&a->loop_done)) atomic_store(&a->rx_failed, 1);
    return NULL;
}

// ---------------------------------------------------------------------------------------------
// Device loop.

static void ts_add_ns(struct timespec* t, int64_t ns) {
    int64_t v = (int64_t)t->tv_nsec + ns;
    t->tv_sec += v / 1000000000;
    t->tv_nsec = v % 1000000000;
}

static int64_t ts_ns(const struct timespec* t) {
    return (int64_t)t->tv_sec * 1000000000 + t->tv_nsec;
}

static void* loop_main(void* arg) {
    app* a = arg;
    const int64_t period_ns = (int64_t)llround(1e9 / a->opt.rate_hz);
    hs_script_runner run;
    hs_script_runner_init(&run, a->script);
    double felt[3] = {0, 0, 0};
    hs_stylus_device dev;
    hs_stylus_device_init(&dev, &a->def, a->script->start_m);
    hapsim_tool_pose_t pose;
    uint8_t pbuf[128]; // one encoded pose (100 bytes)
    memset(&pose, 0, sizeof pose);
    pose.session = a->session;
    pose.device_id = a->opt.device_id;
    pose.tool_id = a->opt.tool_id;
    pose.orientation[0] = 1;
    // Period error histogram for the status line (1 us bins, window of one second).
    enum { BINS = 2000 };
    static uint32_t hist[BINS + 1];
    int64_t in_window = 0;
    if (a->opt.realtime) {
        struct sched_param sp = {.sched_priority = 70};
        int got = pthread_setschedparam(pthread_self(), SCHED_FIFO, &sp) == 0 ? 1 : 0;
        if (mlockall(MCL_CURRENT | MCL_FUTURE) == 0) got |= 2;
        atomic_store(&a->rt_granted, got);
    }
    struct timespec next;
    clock_gettime(CLOCK_MONOTONIC, &next);
    const int64_t start_ns = ts_ns(&next);
    int64_t last_ns = start_ns - period_ns;
    while (!atomic_load_explicit(&g_stop, memory_order_relaxed)) {
        // Take the model before reading the clock: the receive thread stamps its arrival, so a
        // model taken after `now` could be younger than `now` (negative age, read as "none").
        hs_stylus_model m;
        int got_model = hs_stylus_mailbox_take(&a->mailbox, &m);
        int64_t now = now_ns();
        double t = (double)(now - start_ns) * 1e-9;
        // Without --duration: 0.5 s after the script, whose end moves when a touch finds the
        // surface early.
        if (t >= (a->opt.duration_auto ? hs_script_runner_end(&run) + 0.5 : a->opt.duration_s))
            break;
        double dt = (double)(now - last_ns) * 1e-9;
        int64_t err_us = llabs(now - last_ns - period_ns) / 1000;
        hist[err_us < BINS ? err_us : BINS]++;
        last_ns = now;

        if (got_model) hs_stylus_device_set_model(&dev, &m);
        double target[3], tvel[3];
        uint32_t buttons;
        uint32_t events;
        int seg = hs_script_runner_eval(&run, t, felt, target, tvel, &buttons, &events);
        hs_stylus_tick tick;
        hs_stylus_device_step(&dev, target, tvel, now, dt, &tick);
        memcpy(felt, tick.f_applied, sizeof felt);
        tick.t_s = t;
        tick.segment = seg;
        if (events & HS_TOUCH_FOUND) tick.flags |= HS_TICK_TOUCH_FOUND;
        if (events & HS_TOUCH_MISSED) tick.flags |= HS_TICK_TOUCH_MISSED;
        hs_stylus_trace_add(a->trace, &tick);

        pose.utime = wall_us();
        pose.seq++;
        for (int i = 0; i < 3; ++i) pose.position[i] = dev.pos_m[i];
        pose.buttons = (int32_t)buttons;
        if (seg >= 0 && seg < a->script->n_segments)
            memcpy(pose.orientation, a->script->seg[seg].quat_wxyz, sizeof pose.orientation);
        // Encoded on the stack: lcm-gen's _publish mallocs a buffer per message.
        int len = hapsim_tool_pose_t_encoded_size(&pose);
        if (len <= (int)sizeof pbuf && hapsim_tool_pose_t_encode(pbuf, 0, len, &pose) == len)
            lcm_publish(a->lcm, a->pose_channel, pbuf, (unsigned)len);

        const double* f = tick.f_applied;
        atomic_store_explicit(&a->force_mn,
                              llround(1e3 * sqrt(f[0] * f[0] + f[1] * f[1] + f[2] * f[2])),
                              memory_order_relaxed);
        atomic_fetch_add_explicit(&a->ticks, 1, memory_order_relaxed);
        if (++in_window >= (int64_t)a->opt.rate_hz) {
            int64_t need = (in_window * 99 + 99) / 100, acc = 0, p99 = BINS;
            for (int i = 0; i <= BINS; ++i) {
                acc += hist[i];
                if (acc >= need) {
                    p99 = i + 1;
                    break;
                }
            }
            atomic_store_explicit(&a->period_p99_us, p99, memory_order_relaxed);
            memset(hist, 0, sizeof hist);
            in_window = 0;
        }

        // Absolute deadlines; after a long stall skip ahead rather than burst to catch up.
        ts_add_ns(&next, period_ns);
        int64_t after = now_ns();
        int64_t late = after - ts_ns(&next);
        if (late > 0) {
            atomic_fetch_add_explicit(&a->overruns, 1, memory_order_relaxed);
            if (late / 1000 > atomic_load_explicit(&a->late_max_us, memory_order_relaxed))
                atomic_store_explicit(&a->late_max_us, late / 1000, memory_order_relaxed);
            if (late > 5 * period_ns) {
                clock_gettime(CLOCK_MONOTONIC, &next);
                ts_add_ns(&next, period_ns);
            }
        }
        while (clock_nanosleep(CLOCK_MONOTONIC, TIMER_ABSTIME, &next, NULL) == EINTR &&
               !atomic_load_explicit(&g_stop, memory_order_relaxed)) {
        }
    }
    atomic_store(&a->loop_done, 1);
    return NULL;
}

// ---------------------------------------------------------------------------------------------

static int finish(app* a, const char* mode) {
    hs_stylus_summary sum;
    hs_stylus_trace_summary(a->trace, a->script, &sum);
    hs_err err = {0};
    int rc = 0;
    if (hs_stylus_trace_write_csv(a->trace, &sum, a->opt.trace, &err)) {
        fprintf(stderr, "hapsim-stylus: %s\n", err.msg);
        rc = 1;
    }
    if (!a->opt.quiet) {
        printf("hapsim-stylus: %s run of %s\n", mode, a->script->name);
        hs_stylus_summary_print(stdout, &sum, rc ? NULL : a->opt.trace);
    }
    return rc;
}

static int run_offline(app* a) {
    hs_offline_def off;
    memset(&off, 0, sizeof off);
    off.dt_s = 1.0 / a->opt.rate_hz;
    off.period_ticks = a->opt.offline_period;
    off.delay_ticks = a->opt.offline_delay;
    off.duration_s = a->opt.duration_auto ? 0 : a->opt.duration_s; // 0: follows the touches
    off.surface.stiffness_n_m = a->opt.offline_k;
    off.surface.radius_m = a->opt.offline_radius;
    off.surface.timeout_s = a->opt.offline_timeout;
    off.stop = &g_stop; // SIGINT / SIGTERM: the trace so far is still written
    if (a->opt.has_plane) {
        const double* p = a->opt.plane; // its normal made unit by parse_options
        for (int i = 0; i < 3; ++i) {
            off.surface.point_m[i] = p[i];
            off.surface.normal[i] = p[3 + i];
        }
    } else if (a->script->has_surface) {
        memcpy(off.surface.point_m, a->script->surface_point_m, sizeof off.surface.point_m);
        memcpy(off.surface.normal, a->script->surface_normal, sizeof off.surface.normal);
    } else {
        fprintf(stderr, "hapsim-stylus: %s has no `surface` line: give --offline-plane\n",
                a->script->name);
        return 2;
    }
    hs_err err = {0};
    if (hs_stylus_run_offline(a->script, &a->def, &off, a->trace, NULL, &err)) {
        fprintf(stderr, "hapsim-stylus: %s\n", err.msg);
        return 1;
    }
    return finish(a, "offline");
}

static void print_status(app* a, double t, double rate_hz) {
    // No force received yet (or its latency unknown): "none", not a perfect 0 us.
    char lat[32] = " none";
    long long l = (long long)atomic_load(&a->latency_us);
    if (atomic_load(&a->rx_forces) > 0 && l >= 0) snprintf(lat, sizeof lat, "%5lld us", l);
    fprintf(stderr,
            "\rhapsim-stylus: t %6.1f s  %6.0f Hz  |F| %5.2f N  period err p99 %4lld us  "
            "overruns %lld  forces rx %lld (bad %lld)  latency %s",
            t, rate_hz, 1e-3 * (double)atomic_load(&a->force_mn),
            (long long)atomic_load(&a->period_p99_us), (long long)atomic_load(&a->overruns),
            (long long)atomic_load(&a->rx_forces), (long long)atomic_load(&a->rx_rejected), lat);
    if (a->status_lcm && atomic_load(&a->srv_status_count) > 0)
        fprintf(stderr, "  | server rt %6.1f Hz, period p99 %4lld us, sim step p99 %6lld us",
                1e-3 * (double)atomic_load(&a->srv_rate_mhz),
                (long long)atomic_load(&a->srv_p99_us),
                (long long)atomic_load(&a->srv_step_p99_us));
    else if (a->status_lcm)
        fprintf(stderr, "  | no server status yet");
    if (a->status_lcm && atomic_load(&a->srv_status_bad) > 0)
        fprintf(stderr, " (%lld malformed)", (long long)atomic_load(&a->srv_status_bad));
    fprintf(stderr, "   ");
    fflush(stderr);
}

static int run_live(app* a) {
    if (hapsim_channel_name(a->pose_channel, sizeof a->pose_channel, a->opt.prefix,
                            HAPSIM_CH_TOOL_POSE) ||
        hapsim_channel_name(a->force_channel, sizeof a->force_channel, a->opt.prefix,
                            HAPSIM_CH_TOOL_FORCE)) {
        fprintf(stderr, "hapsim-stylus: --prefix '%s' is too long\n", a->opt.prefix);
        return 2;
    }
    a->lcm = lcm_create(a->opt.haptic_url);
    if (!a->lcm) {
        fprintf(stderr,
                "hapsim-stylus: cannot open LCM URL '%s' (for udpm on one host: a "
                "multicast route on lo, see docs/stylus.md)\n",
                a->opt.haptic_url);
        return 1;
    }
    lcm_subscription_t* sub = lcm_subscribe(a->lcm, a->force_channel, on_force, a);
    lcm_subscription_t* status_sub = NULL;
    if (a->opt.status_url) {
        a->status_lcm = lcm_create(a->opt.status_url);
        if (!a->status_lcm || hapsim_channel_name(a->status_channel, sizeof a->status_channel,
                                                  a->opt.prefix, HAPSIM_CH_SERVER_STATUS)) {
            fprintf(stderr, "hapsim-stylus: cannot open --status-url '%s'\n", a->opt.status_url);
            if (a->status_lcm) lcm_destroy(a->status_lcm);
            lcm_unsubscribe(a->lcm, sub);
            lcm_destroy(a->lcm);
            return 1;
        }
        status_sub = lcm_subscribe(a->status_lcm, a->status_channel, on_status, a);
    }
    // A session id per start, so the server can tell a restarted stylus from a replayed one.
    uint64_t r = (uint64_t)now_ns() ^ ((uint64_t)getpid() << 32) ^ (uint64_t)wall_us();
    r ^= r >> 33;
    r *= 0xff51afd7ed558ccdull;
    r ^= r >> 33;
    a->session = (int64_t)(r & 0x7fffffffffffffffull);
    if (a->session == 0) a->session = 1;
    hs_stylus_mailbox_init(&a->mailbox);
    hs_stylus_rx_init(&a->rx, a->opt.device_id);
    a->rx.session = a->session; // forces answering another session's poses are not ours
    if (!a->opt.quiet)
        printf("hapsim-stylus: device %d (tool %d), session %" PRId64 ", %s on %s -> %s, %s %.1f "
               "s at %.0f Hz\n",
               a->opt.device_id, a->opt.tool_id, a->session, a->opt.haptic_url, a->pose_channel,
               a->force_channel, a->script->name, a->opt.duration_s, a->opt.rate_hz);
    fflush(stdout);

    pthread_t rx, loop;
    int rc = 0;
    if (pthread_create(&rx, NULL, rx_main, a) != 0) {
        fprintf(stderr, "hapsim-stylus: cannot start the receive thread\n");
        rc = 1;
    } else {
        if (pthread_create(&loop, NULL, loop_main, a) != 0) {
            fprintf(stderr, "hapsim-stylus: cannot start the device loop\n");
            atomic_store(&a->loop_done, 1);
            rc = 1;
        } else {
            int64_t t0 = now_ns(), next_status = t0 + 1000000000, last_ticks = 0, last_ns = t0;
            while (!atomic_load(&a->loop_done)) {
                struct timespec nap = {0, 50000000};
                nanosleep(&nap, NULL);
                int64_t now = now_ns();
                if (a->opt.status && now >= next_status) {
                    int64_t ticks = atomic_load(&a->ticks);
                    print_status(a, (double)(now - t0) * 1e-9,
                                 (double)(ticks - last_ticks) / ((double)(now - last_ns) * 1e-9));
                    last_ticks = ticks;
                    last_ns = now;
                    next_status += 1000000000;
                }
            }
            pthread_join(loop, NULL);
            if (a->opt.status) fprintf(stderr, "\n");
        }
        pthread_join(rx, NULL);
    }
    lcm_unsubscribe(a->lcm, sub);
    lcm_destroy(a->lcm);
    a->lcm = NULL;
    if (a->status_lcm) {
        lcm_unsubscribe(a->status_lcm, status_sub);
        lcm_destroy(a->status_lcm);
        a->status_lcm = NULL;
    }
    if (atomic_load(&a->rx_failed))
        fprintf(stderr, "hapsim-stylus: the LCM receive loop failed; no forces after that\n");
    if (rc) return rc;
    if (!a->opt.quiet) {
        printf("hapsim-stylus: %lld forces received, %lld rejected, %lld for other devices, "
               "%lld for earlier sessions; %lld overruns (worst %lld us late)%s\n",
               (long long)atomic_load(&a->rx_forces), (long long)atomic_load(&a->rx_rejected),
               (long long)atomic_load(&a->rx_other_device),
               (long long)atomic_load(&a->rx_other_session), (long long)atomic_load(&a->overruns),
               (long long)atomic_load(&a->late_max_us),
               atomic_load(&g_stop) ? "; stopped by signal" : "");
        if (a->opt.realtime)
            printf("hapsim-stylus: --realtime: SCHED_FIFO %s, mlockall %s\n",
                   (atomic_load(&a->rt_granted) & 1) ? "granted" : "refused",
                   (atomic_load(&a->rt_granted) & 2) ? "granted" : "refused");
    }
    return finish(a, "live");
}

int main(int argc, char** argv) {
    if (hapsim_version_asked(argc, argv, "hapsim-stylus")) return 0;
    static app a; // large (mailbox): not on the stack
    hs_stylus_def def = hs_stylus_default_def();
    int pr = parse_options(argc, argv, &a.opt, &def);
    if (pr) return pr == 1 ? 0 : 2;
    // The trace is written at the end: a path that cannot take it (a folder, "", a missing or
    // read-only folder, a file as folder) is a bad command line now, not a lost run. A file
    // created only for this check is removed again.
    int fd = open(a.opt.trace, O_WRONLY | O_CREAT | O_EXCL | O_NONBLOCK, 0666);
    int created = fd >= 0;
    if (fd < 0 && errno == EEXIST) fd = open(a.opt.trace, O_WRONLY | O_NONBLOCK);
    if (fd < 0) {
        fprintf(stderr, "hapsim-stylus: --trace '%s': cannot write the trace there: %s\n",
                a.opt.trace, strerror(errno));
        return 2;
    }
    close(fd);
    if (created) unlink(a.opt.trace);
    hs_err err = {0};
    if (hs_script_create(&a.script, &err) || hs_script_parse_file(a.script, a.opt.script, &err)) {
        fprintf(stderr, "hapsim-stylus: %s\n", err.msg);
        hs_script_destroy(&a.script);
        return 1;
    }
    // Workspace centre: --origin, else the script's origin, else where the script starts.
    const double* origin = a.opt.has_origin       ? a.opt.origin
                           : a.script->has_origin ? a.script->origin_m
                                                  : a.script->start_m;
    memcpy(def.origin_m, origin, sizeof def.origin_m);
    def.tick_s = 1.0 / a.opt.rate_hz; // the integrator's stability limit depends on it
    if (hs_stylus_def_check(&def, &err)) {
        fprintf(stderr, "hapsim-stylus: %s\n", err.msg);
        hs_script_destroy(&a.script);
        return 2;
    }
    a.def = def;
    // A target outside the workspace is legal (the handle stops at the box) but rarely meant.
    for (int i = -1; i < a.script->n_segments; ++i) {
        const double* q = i < 0 ? a.script->start_m : a.script->seg[i].to_m;
        int out = 0;
        for (int k = 0; k < 3; ++k)
            out |= fabs(q[k] - def.origin_m[k]) > 0.5 * def.workspace_m[k] + 1e-9;
        if (out) {
            int line = i < 0 ? a.script->start_line : a.script->seg[i].line;
            char where[64] = " the default start:"; // no start line: no line to name
            if (line > 0) snprintf(where, sizeof where, "%d:", line);
            fprintf(stderr,
                    "hapsim-stylus: warning: %s:%s target (%.4f, %.4f, %.4f) m is outside the "
                    "workspace box (%.3f x %.3f x %.3f m around %.4f, %.4f, %.4f)\n",
                    a.script->name, where, q[0], q[1], q[2], def.workspace_m[0], def.workspace_m[1],
                    def.workspace_m[2], def.origin_m[0], def.origin_m[1], def.origin_m[2]);
            break;
        }
    }
    if (a.opt.duration_s <= 0) {
        a.opt.duration_s = a.script->duration_s + 0.5; // the longest it can take
        a.opt.duration_auto = 1;
    }
    double kept = a.opt.duration_s < MAX_TRACE_S ? a.opt.duration_s : MAX_TRACE_S;
    int64_t rows = (int64_t)ceil(kept * a.opt.rate_hz) + (int64_t)a.opt.rate_hz + 16;
    if (hs_stylus_trace_create(rows, &a.trace, &err)) {
        fprintf(stderr, "hapsim-stylus: %s\n", err.msg);
        hs_script_destroy(&a.script);
        return 1;
    }
    struct sigaction sa;
    memset(&sa, 0, sizeof sa);
    sa.sa_handler = on_signal;
    sigemptyset(&sa.sa_mask);
    sigaction(SIGINT, &sa, NULL);
    sigaction(SIGTERM, &sa, NULL);

    int rc = a.opt.offline_k > 0 ? run_offline(&a) : run_live(&a);
    hs_stylus_trace_destroy(&a.trace);
    hs_script_destroy(&a.script);
    return rc;
}
