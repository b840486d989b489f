// SPDX-License-Identifier: MIT
// hapsim-view: watch a running hapsim-server and write a ParaView time series (.vtu + .pvd) and
// PNG snapshots of the deforming surface, with a live one-line status. docs/client.md.
#define _POSIX_C_SOURCE 200809L
#include "hapsim/version.h"
#include <errno.h>
#include <math.h>
#include <signal.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <poll.h>
#include <time.h>
#include <unistd.h>

#include <lcm/lcm.h>

#include "hapsim_channels.h"
#include "hapsim_tool_state_t.h"
#include "view.h"
#include "wire.h"

static volatile sig_atomic_t g_stop, g_snap;
static void on_signal(int sig) {
    if (sig == SIGUSR1)
        g_snap = 1;
    else
        g_stop = 1;
}

static void usage(FILE* f) {
    fprintf(f,
            "usage: hapsim-view [options]\n\n"
            "Watch a running hapsim-server's mesh bus and write what a person wants to look at:\n"
            "a ParaView time series (DIR/frame_NNNNNN.vtu + DIR/hapsim.pvd) and PNG snapshots\n"
            "(DIR/frame_NNNNNN.png) of the surface coloured by displacement magnitude.\n\n"
            "options:\n"
            "  --out DIR         output folder, created if missing (hapsim-view-out)\n"
            "  --rate HZ         outputs per second while the mesh changes (2); 0: only on\n"
            "                    demand (SIGUSR1) and one final frame at exit\n"
            "  --png             write PNG snapshots   (neither --png nor --vtk: both)\n"
            "  --vtk             write the VTK series\n"
            "  --duration S      stop after S seconds (0: until SIGINT/SIGTERM)\n"
            "  --view AZ,EL      camera azimuth about +z from +x and elevation, degrees (30,20)\n"
            "  --size WxH        PNG size in pixels, decimal integers 16 .. 8192 (640x480)\n"
            "  --dmax M|auto     displacement shown red, m; 0 is blue. auto (default): the next\n"
            "                    1-2-5 step above the largest displacement so far, >= 0.5 mm\n"
            "  --mesh-url URL    mesh bus (" HAPSIM_DEFAULT_MESH_URL "&recv_buf_size=...)\n"
            "  --prefix P        channel prefix (" HAPSIM_DEFAULT_PREFIX ")\n"
            "  --status          live status line on stderr (default when stderr is a terminal)\n"
            "  --quiet           no status line and no summary (wins over --status)\n"
            "  -h, --help        this text\n\n"
            "kill -USR1 <pid> writes a snapshot now. Exit status: 0 ok, 1 no mesh received\n"
            "before the end, 2 bad usage, 3 output could not be written.\n");
}

typedef struct viewer {
    const char* out;
    double rate, dmax;   // dmax 0: auto
    double auto_max;     // m, largest displacement seen (auto range)
    hs_view_tools tools; // live tools (tool_state within the last 0.5 s)
    hs_view_caption cap;
    int png, vtk, status, quiet;
    double az, el;
    int width, height;
    hs_camera cam;
    int have_cam;
    hs_image* img;
    float* disp;
    size_t disp_cap;
    int32_t n_written;
    char** files;
    double* times;
    int32_t cap_files;
    int64_t last_frame_written;
    FILE* index;
    int failed;
} viewer;

static int parse_pair(const char* s, char sep, double* a, double* b) {
    char* e;
    *a = strtod(s, &e);
    if (e == s || *e != sep) return -1;
    const char* t = e + 1;
    *b = strtod(t, &e);
    return e == t || *e || !isfinite(*a) || !isfinite(*b) ? -1 : 0;
}

// WxH in decimal digits only (strtod also read 0x10 as 16 and 1e2 as 100), 16 .. 8192 each.
static int parse_size(const char* s, int* w, int* h) {
    long v[2];
    for (int k = 0; k < 2; k++) {
        if (*s < '0' || *s > '9') return -1;
        for (v[k] = 0; *s >= '0' && *s <= '9'; s++)
            if ((v[k] = 10 * v[k] + (*s - '0')) > 8192) return -1;
        if (*s != (k ? '\0' : 'x')) return -1;
        s++;
    }
    if (v[0] < 16 || v[1] < 16) return -1;
    *w = (int)v[0];
    *h = (int)v[1];
    return 0;
}

static int write_frame(viewer* v, const hs_client_mesh* m) {
    hs_err err = {0};
    if ((size_t)m->n_vis > v->disp_cap) {
        hs_proto_free(v->disp);
        v->disp = hs_proto_alloc((size_t)m->n_vis * sizeof(float));
        v->disp_cap = v->disp ? (size_t)m->n_vis : 0;
        if (!v->disp) return -1;
    }
    hs_view_displacement(m, v->disp);
    float dmax_seen = 0;
    for (int32_t i = 0; i < m->n_vis; i++) dmax_seen = fmaxf(dmax_seen, v->disp[i]);
    if (!v->have_cam) { // fixed camera from the first rest shape: frames stay comparable
        hs_camera_fit(&v->cam, m->rest, m->n_vis, v->az, v->el, v->width, v->height);
        v->have_cam = 1;
        char p[4200];
        snprintf(p, sizeof p, "%s/camera.txt", v->out);
        FILE* f = fopen(p, "w");
        if (f) {
            fprintf(f, "# hapsim-view orthographic camera: pixel = (W/2 + scale*dot(p-c,right),"
                       " H/2 - scale*dot(p-c,up))\n");
            fprintf(f, "width %d\nheight %d\nazimuth %.9g\nelevation %.9g\nscale %.17g\n", v->width,
                    v->height, v->az, v->el, v->cam.scale);
            fprintf(f, "center %.17g %.17g %.17g\nright %.17g %.17g %.17g\nup %.17g %.17g %.17g\n",
                    v->cam.center[0], v->cam.center[1], v->cam.center[2], v->cam.right[0],
                    v->cam.right[1], v->cam.right[2], v->cam.up[0], v->cam.up[1], v->cam.up[2]);
            fclose(f);
        }
    }
    int32_t idx = v->n_written;
    char png_name[64] = "", vtu_name[64] = "", path[4200];
    if ((double)dmax_seen > v->auto_max) v->auto_max = dmax_seen;
    double range = v->dmax > 0 ? v->dmax : hs_nice_ceil(fmax(v->auto_max * 1.05, 0.5e-3));
    if (v->png) {
        snprintf(png_name, sizeof png_name, "frame_%06d.png", idx);
        hs_image_clear(v->img);
        hs_render_mesh(v->img, &v->cam, m->position, m->n_vis, m->triangles, m->n_tri, v->disp,
                       0.0f, (float)range);
        v->cap.sim_time = m->sim_time;
        v->cap.sim_step = m->sim_step;
        v->cap.topology_version = m->topology_version;
        v->cap.range_m = range;
        v->cap.max_disp_m = dmax_seen;
        hs_view_annotate(v->img, &v->cam, &v->tools, &v->cap);
        snprintf(path, sizeof path, "%s/%s", v->out, png_name);
        if (hs_png_write(path, v->img, &err) != HS_OK) {
            fprintf(stderr, "hapsim-view: %s\n", err.msg);
            return -1;
        }
    }
    if (v->vtk) {
        snprintf(vtu_name, sizeof vtu_name, "frame_%06d.vtu", idx);
        snprintf(path, sizeof path, "%s/%s", v->out, vtu_name);
        if (hs_vtu_write(path, m, v->disp, &v->tools, &err) != HS_OK) {
            fprintf(stderr, "hapsim-view: %s\n", err.msg);
            return -1;
        }
        if (idx >= v->cap_files) {
            int32_t nc = v->cap_files ? 2 * v->cap_files : 256;
            char** nf = hs_proto_calloc((size_t)nc, sizeof *nf);
            double* nt = hs_proto_calloc((size_t)nc, sizeof *nt);
            if (!nf || !nt) {
                hs_proto_free(nf);
                hs_proto_free(nt);
                return -1;
            }
            if (v->cap_files) {
                memcpy(nf, v->files, (size_t)v->cap_files * sizeof *nf);
                memcpy(nt, v->times, (size_t)v->cap_files * sizeof *nt);
            }
            hs_proto_free(v->files);
            hs_proto_free(v->times);
            v->files = nf;
            v->times = nt;
            v->cap_files = nc;
        }
        v->files[idx] = hs_proto_alloc(strlen(vtu_name) + 1);
        if (!v->files[idx]) return -1;
        strcpy(v->files[idx], vtu_name);
        // Distinct, increasing timesteps even if the server's sim_time repeats.
        double t = m->sim_time;
        if (idx > 0 && !(t > v->times[idx - 1])) t = v->times[idx - 1] + 1e-6;
        v->times[idx] = t;
        snprintf(path, sizeof path, "%s/hapsim.pvd", v->out);
        if (hs_pvd_write(path, idx + 1, (const char* const*)v->files, v->times, &err) != HS_OK) {
            fprintf(stderr, "hapsim-view: %s\n", err.msg);
            return -1;
        }
    }
    if (v->index) {
        fprintf(v->index, "%d,%s,%s,%.9g,%lld,%lld,%lld,%.9g\n", idx, png_name, vtu_name,
                m->sim_time, (long long)m->sim_step, (long long)m->topology_version,
                (long long)m->keyframe_id, (double)dmax_seen);
        fflush(v->index);
    }
    v->n_written++;
    v->last_frame_written = m->frame;
    return 0;
}

// Tool states through the protocol library's decoder (another length or a non-finite number is
// dropped), newest per device.
typedef struct tool_slot {
    hs_view_tool tool;
    int64_t arrival_us; // 0: none
} tool_slot;
static tool_slot g_tools[HS_CLIENT_MAX_DEVICES];

static void on_tool_state(const lcm_recv_buf_t* rbuf, const char* ch, void* user) {
    (void)ch;
    (void)user;
    hs_wire_tool_state t;
    if (hs_wire_tool_state_decode(rbuf->data, rbuf->data_size, &t) ||
        t.device_id >= HS_CLIENT_MAX_DEVICES)
        return;
    hs_view_tool* o = &g_tools[t.device_id].tool;
    o->device = t.device_id;
    o->kind = t.kind;
    o->radius = t.radius;
    o->contact = t.contact;
    o->cutting = t.cutting;
    memcpy(o->position, t.position, sizeof o->position);
    memcpy(o->force, t.force, sizeof o->force);
    memcpy(o->blade_a, t.blade_a, sizeof o->blade_a);
    memcpy(o->blade_b, t.blade_b, sizeof o->blade_b);
    g_tools[t.device_id].arrival_us = hs_client_now_us();
}

static void collect_tools(viewer* v, int64_t now) {
    v->tools.n = 0;
    for (int d = 0; d < HS_CLIENT_MAX_DEVICES; d++)
        if (g_tools[d].arrival_us && now - g_tools[d].arrival_us <= 500000)
            v->tools.tool[v->tools.n++] = g_tools[d].tool;
}

// "scenes/liver/liver.json" -> "liver".
static void scene_name(const char* path, char* out, size_t cap) {
    const char* b = strrchr(path, '/');
    b = b ? b + 1 : path;
    snprintf(out, cap, "%.63s", b);
    char* dot = strrchr(out, '.');
    if (dot && dot != out) *dot = '\0';
}

// Options not kept in the viewer.
typedef struct view_opts {
    double duration;
    const char *mesh_url, *prefix;
} view_opts;

// Reads the command line into v and o; returns -1 to go on, else the exit status.
static int parse_args(int argc, char** argv, viewer* v, view_opts* o) {
    int status = isatty(2);
    for (int i = 1; i < argc; i++) {
        const char* a = argv[i];
        const char* val = i + 1 < argc ? argv[i + 1] : NULL;
#define NEED_VAL                                                                                   \
    do {                                                                                           \
        if (!val) {                                                                                \
            fprintf(stderr, "hapsim-view: %s needs a value (see --help)\n", a);                    \
            return 2;                                                                              \
        }                                                                                          \
        i++;                                                                                       \
    } while (0)
        char* e = NULL;
        if (!strcmp(a, "-h") || !strcmp(a, "--help")) {
            usage(stdout);
            return 0;
        } else if (!strcmp(a, "--out")) {
            NEED_VAL;
            v->out = val;
        } else if (!strcmp(a, "--rate")) {
            NEED_VAL;
            v->rate = strtod(val, &e);
            if (e == val || *e || !(v->rate == 0 || (v->rate >= 0.001 && v->rate <= 1000))) {
                fprintf(stderr, "hapsim-view: --rate '%s': expected 0, or 0.001 .. 1000 Hz\n", val);
                return 2;
            }
        } else if (!strcmp(a, "--duration")) {
            NEED_VAL;
            o->duration = strtod(val, &e);
            if (e == val || *e || !(o->duration >= 0 && o->duration <= 1e9)) {
                fprintf(stderr, "hapsim-view: --duration '%s': expected 0 .. 1e9 seconds\n", val);
                return 2;
            }
        } else if (!strcmp(a, "--dmax")) {
            NEED_VAL;
            v->dmax = strcmp(val, "auto") ? strtod(val, &e) : 0;
            if (strcmp(val, "auto") && (e == val || *e || !(v->dmax > 0) || !isfinite(v->dmax))) {
                fprintf(stderr, "hapsim-view: --dmax '%s': expected metres > 0 or auto\n", val);
                return 2;
            }
        } else if (!strcmp(a, "--view")) {
            NEED_VAL;
            if (parse_pair(val, ',', &v->az, &v->el) || fabs(v->el) > 90) {
                fprintf(stderr, "hapsim-view: --view '%s': expected AZ,EL in degrees, |EL| <= 90\n",
                        val);
                return 2;
            }
        } else if (!strcmp(a, "--size")) {
            NEED_VAL;
            if (parse_size(val, &v->width, &v->height)) {
                fprintf(stderr, "hapsim-view: --size '%s': expected WxH, 16 .. 8192 pixels\n", val);
                return 2;
            }
        } else if (!strcmp(a, "--mesh-url")) {
            NEED_VAL;
            o->mesh_url = val;
        } else if (!strcmp(a, "--prefix")) {
            NEED_VAL;
            o->prefix = val;
        } else if (!strcmp(a, "--png")) {
            v->png = 1;
        } else if (!strcmp(a, "--vtk")) {
            v->vtk = 1;
        } else if (!strcmp(a, "--status")) {
            status = 1;
        } else if (!strcmp(a, "--quiet")) {
            v->quiet = 1;
        } else {
            fprintf(stderr, "hapsim-view: unknown option '%s' (see --help)\n", a);
            return 2;
        }
    }
    if (!v->png && !v->vtk) v->png = v->vtk = 1;
    v->status = status && !v->quiet; // in either order
    // An unusable --out is bad usage (exit 2), found before connecting or creating anything.
    // The length limit keeps "DIR/frame_NNNNNN.vtu.tmp" within the writers' 4200-byte paths.
    struct stat st_out;
    if (!v->out[0] || strlen(v->out) > 4000) {
        fprintf(stderr, "hapsim-view: --out '%.40s%s': expected a folder path of 1 .. 4000 bytes\n",
                v->out, strlen(v->out) > 40 ? "..." : "");
        return 2;
    }
    if (stat(v->out, &st_out) == 0 && !S_ISDIR(st_out.st_mode)) {
        fprintf(stderr, "hapsim-view: --out '%s': expected a folder, this is not one\n", v->out);
        return 2;
    }
    return -1;
}

// The live one-line status on stderr.
static void print_status(const viewer* v, hs_client* c, const hs_client_mesh* m, int64_t now,
                         int64_t* frames_at_status, int64_t* status_t) {
    hs_sync_stats s;
    hs_client_mesh_stats(c, &s);
    double dt = (double)(now - *status_t) * 1e-6;
    double fps = dt > 0 ? (double)(m->frame - *frames_at_status) / dt : 0;
    int64_t age = m->ready ? hs_client_age_us(m->utime) : -1;
    double lat_ms = age >= 0 ? (double)age * 1e-3 : NAN;
    int64_t lost = s.lost[0] + s.lost[1] + s.lost[2] + s.lost[3];
    fprintf(stderr,
            "\rhapsim-view: %5.1f fps  topology v%lld  keyframe %lld  latency %6.1f ms  "
            "lost %lld  bad %lld  written %d   ",
            fps, (long long)m->topology_version, (long long)m->keyframe_id, lat_ms, (long long)lost,
            (long long)s.malformed, v->n_written);
    fflush(stderr);
    *frames_at_status = m->frame;
    *status_t = now;
}

// Why no mesh came, and the summary; returns the exit status.
static int report_end(const viewer* v, hs_client* c, const hs_client_mesh* m, int rc) {
    if (rc == 0 && !m->ready) {
        hs_sync_stats s;
        hs_client_mesh_stats(c, &s);
        const long long keys = (long long)s.received[HS_SYNC_STATE];
        if (keys > 0 && s.received[HS_SYNC_TOPOLOGY] == 0)
            fprintf(stderr,
                    "hapsim-view: %lld keyframes but no topology received: a topology larger than "
                    "this socket's receive buffer is lost (see the server's note on message sizes; "
                    "raise net.core.rmem_max and the mesh URL's recv_buf_size, docs/protocol.md)\n",
                    keys);
        else if (keys > 0 && s.topologies == 0) // the sync refused what came (counted as bad)
            fprintf(stderr,
                    "hapsim-view: %lld keyframes but no topology accepted: %lld topology messages "
                    "came, none usable (malformed, or no memory for them)\n",
                    keys, (long long)s.received[HS_SYNC_TOPOLOGY]);
        else
            fprintf(stderr,
                    "hapsim-view: no mesh received (is hapsim-server running on this bus?)\n");
        rc = 1;
    }
    if (!v->quiet) {
        hs_sync_stats s;
        hs_client_mesh_stats(c, &s);
        printf("hapsim-view: %d frames written to %s; mesh messages %lld topology, %lld keyframes,"
               " %lld deltas; lost %lld, malformed %lld\n",
               v->n_written, v->out, (long long)s.received[0], (long long)s.received[1],
               (long long)s.received[2], (long long)(s.lost[0] + s.lost[1] + s.lost[2] + s.lost[3]),
               (long long)s.malformed);
    }
    return rc;
}

int main(int argc, char** argv) {
    if (hapsim_version_asked(argc, argv, "hapsim-view")) return 0;
    viewer v;
    memset(&v, 0, sizeof v);
    v.out = "hapsim-view-out";
    v.rate = 2;
    v.dmax = 0; // auto
    v.az = 30;
    v.el = 20;
    v.width = 640;
    v.height = 480;
    v.last_frame_written = -1;
    view_opts o = {0};
    int prc = parse_args(argc, argv, &v, &o);
    if (prc >= 0) return prc;
    double duration = o.duration;
    const char *mesh_url = o.mesh_url, *prefix = o.prefix;

    // The client checks --prefix and --mesh-url: before anything is created on disk.
    hs_client_config cfg;
    hs_client_config_default(&cfg);
    cfg.haptic_url = "";
    cfg.mesh_url = mesh_url;
    cfg.prefix = prefix;
    cfg.subscribe = HS_CLIENT_SUB_MESH | HS_CLIENT_SUB_STATUS;
    hs_client* c = NULL;
    hs_err err = {0};
    if (hs_client_create(&cfg, &c, &err) != HS_OK) {
        fprintf(stderr, "hapsim-view: %s\n", err.msg);
        return 2;
    }
    // Tool states are not taken by the client library: a mesh-bus subscriber of our own.
    lcm_t* ts_lcm = lcm_create(mesh_url ? mesh_url : HAPSIM_DEFAULT_MESH_URL);
    if (!ts_lcm) {
        fprintf(stderr, "hapsim-view: LCM cannot open '%s'\n",
                mesh_url ? mesh_url : HAPSIM_DEFAULT_MESH_URL);
        hs_client_destroy(&c);
        return 1;
    }
    char ts_ch[128];
    snprintf(ts_ch, sizeof ts_ch, "%.63s%s", prefix ? prefix : HAPSIM_DEFAULT_PREFIX,
             HAPSIM_CH_TOOL_STATE);
    lcm_subscribe(ts_lcm, ts_ch, on_tool_state, NULL);
    char path[4200];
    snprintf(path, sizeof path, "%s/frames.csv", v.out);
    if (mkdir(v.out, 0777) != 0 && errno != EEXIST) {
        fprintf(stderr, "hapsim-view: cannot create %s: %s\n", v.out, strerror(errno));
    } else if (v.png && hs_image_create(v.width, v.height, &v.img, &err) != HS_OK) {
        fprintf(stderr, "hapsim-view: %s\n", err.msg);
    } else if (!(v.index = fopen(path, "w"))) {
        fprintf(stderr, "hapsim-view: cannot create %s: %s\n", path, strerror(errno));
    }
    if (!v.index) {
        hs_image_destroy(&v.img);
        lcm_destroy(ts_lcm);
        hs_client_destroy(&c);
        return 3;
    }
    fprintf(v.index, "index,png,vtu,sim_time_s,sim_step,topology_version,keyframe_id,max_disp_m\n");
    struct sigaction sa;
    memset(&sa, 0, sizeof sa);
    sa.sa_handler = on_signal;
    sigaction(SIGINT, &sa, NULL);
    sigaction(SIGTERM, &sa, NULL);
    sigaction(SIGUSR1, &sa, NULL);

    int64_t t0 = hs_client_now_us(), next_out = t0, next_status = t0 + 500000;
    int64_t period = v.rate > 0 ? (int64_t)(1e6 / v.rate) : 0;
    int64_t frames_at_status = 0, status_t = t0;
    int rc = 0;
    while (!g_stop) {
        int64_t now = hs_client_now_us();
        if (duration > 0 && now - t0 >= (int64_t)(duration * 1e6)) break;
        if (hs_client_poll(c, 20, &err) < 0) {
            fprintf(stderr, "hapsim-view: %s\n", err.msg);
            rc = 1;
            break;
        }
        for (int k = 0; k < 64; k++) { // tool states waiting, without blocking
            struct pollfd q = {.fd = lcm_get_fileno(ts_lcm), .events = POLLIN};
            if (poll(&q, 1, 0) <= 0 || lcm_handle(ts_lcm) != 0) break;
        }
        const hs_client_mesh* m = hs_client_mesh_view(c);
        now = hs_client_now_us();
        collect_tools(&v, now);
        hs_client_status st;
        if (hs_client_status_latest(c, &st, NULL))
            scene_name(st.scene, v.cap.scene, sizeof v.cap.scene);
        if (m->ready && m->n_vis > 0) {
            int due = period > 0 && now >= next_out && m->frame != v.last_frame_written;
            if (due || g_snap) {
                g_snap = 0;
                if (write_frame(&v, m)) {
                    rc = 3;
                    break;
                }
                if (period > 0) next_out = (now - next_out > period ? now : next_out) + period;
            }
        }
        if (v.status && now >= next_status) {
            print_status(&v, c, m, now, &frames_at_status, &status_t);
            next_status = now + 500000;
        }
    }
    const hs_client_mesh* m = hs_client_mesh_view(c);
    if (rc == 0 && m->ready && m->n_vis > 0 && m->frame != v.last_frame_written &&
        write_frame(&v, m))
        rc = 3;
    if (v.status) fputc('\n', stderr);
    rc = report_end(&v, c, m, rc);
    fclose(v.index);
    for (int32_t i = 0; i < v.n_written && i < v.cap_files; i++) hs_proto_free(v.files[i]);
    hs_proto_free(v.files);
    hs_proto_free(v.times);
    hs_proto_free(v.disp);
    hs_image_destroy(&v.img);
    lcm_destroy(ts_lcm);
    hs_client_destroy(&c);
    return rc;
}
