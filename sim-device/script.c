// SPDX-License-Identifier: MIT
// Probe scripts: a line-based keyframe format parsed into timed straight-line segments, and the
// target trajectory target(t). Loops are expanded by re-reading their body (no allocation), so
// the segment array is the whole, flat timeline.
#include "stylus.h"

#include "hapsim_proto.h"

#include <ctype.h>
#include <errno.h>
#include <math.h>
#include <stdarg.h>
#include <stdlib.h>
#include <string.h>

#define BUTTON_PRIMARY 1u // tool_pose BUTTON_PRIMARY: blade engaged
#define MAX_TOKENS     12
#define TOUCH_ACCEL    0.1  // m/s^2: a touch reaches its search speed within a few ms
#define TOUCH_ONSET_N  1e-4 // N: a force above this marks where the contact began
#define TOUCH_FORCE_N  0.02 // N: default force that ends a touch

hs_status hs_script_create(hs_script** out, hs_err* err) {
    *out = NULL;
    hs_script* s = hs_proto_calloc(1, sizeof *s);
    if (!s) return hs_err_set(err, HS_ERR_NOMEM, "script: out of memory");
    *out = s;
    return HS_OK;
}

void hs_script_destroy(hs_script** s) {
    if (!s || !*s) return;
    hs_proto_free(*s);
    *s = NULL;
}

// Parser state carried across lines (and loop iterations).
typedef struct parser {
    hs_script* s;
    const char* name;
    int line;
    double scale;     // metres per script length unit (1 or 0.001)
    int profile;      // hs_profile for the next moves
    double accel;     // m/s^2 (trapezoid)
    double cur[3];    // target at the end of the timeline so far, m
    double t;         // end time of the timeline so far, s
    int pressed;      // a press is active
    double normal[3]; // its outward unit normal
    double depth;     // total pressed depth, m
    int moved;        // any segment emitted (start/origin may no longer change)
    double quat[4];   // tool orientation (w, x, y, z) from the last `cut` with a blade axis
} parser;

static hs_status perr(parser* p, hs_err* err, const char* fmt, ...)
    __attribute__((format(printf, 3, 4)));
static hs_status perr(parser* p, hs_err* err, const char* fmt, ...) {
    char what[400];
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(what, sizeof what, fmt, ap);
    va_end(ap);
    return hs_err_set(err, HS_ERR_PARSE, "%s:%d: %s", p->name, p->line, what);
}

static int parse_num(const char* tok, double* v) {
    char* end = NULL;
    errno = 0;
    double x = strtod(tok, &end);
    if (end == tok || *end != '\0' || errno == ERANGE || !isfinite(x)) return 0;
    *v = x;
    return 1;
}

// Duration of a straight move of length len at peak speed v with the parser's profile.
static double move_duration(int profile, double len, double v, double a) {
    if (len <= 0) return 0;
    if (profile == HS_PROFILE_MINJERK) return 1.875 * len / v; // peak of 30u^2(1-u)^2 is 1.875
    if (len >= v * v / a) return len / v + v / a;
    return 2.0 * sqrt(len / a); // triangular: never reaches v
}

// Fraction s in [0, 1] of the path and ds/dt (1/s) at time tau into a move.
static void profile_eval(const hs_script_segment* g, double tau, double* s, double* ds) {
    double T = g->dur_s;
    if (T <= 0 || tau >= T) {
        *s = 1;
        *ds = 0;
        return;
    }
    if (tau <= 0) {
        *s = 0;
        *ds = 0;
        return;
    }
    double d[3] = {g->to_m[0] - g->from_m[0], g->to_m[1] - g->from_m[1], g->to_m[2] - g->from_m[2]};
    double len = sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2]);
    if (g->profile == HS_PROFILE_MINJERK) {
        double u = tau / T, u2 = u * u, u3 = u2 * u;
        *s = u3 * (10 - 15 * u + 6 * u2);
        *ds = 30 * u2 * (1 - u) * (1 - u) / T;
        return;
    }
    double a = g->accel_m_s2, v = g->speed_m_s;
    double ta = v / a;
    if (len < v * v / a) { // triangular
        ta = T / 2;
        v = a * ta;
    }
    double x, vel;
    if (tau < ta) {
        x = 0.5 * a * tau * tau;
        vel = a * tau;
    } else if (tau > T - ta) {
        double r = T - tau;
        x = len - 0.5 * a * r * r;
        vel = a * r;
    } else {
        x = 0.5 * a * ta * ta + v * (tau - ta);
        vel = v;
    }
    *s = x / len;
    *ds = vel / len;
}

static hs_status emit(parser* p, hs_err* err, int kind, int cmd, const double to[3], double speed,
                      double hold_s, uint32_t buttons) {
    hs_script* s = p->s;
    double len = 0;
    for (int i = 0; i < 3; ++i) len += (to[i] - p->cur[i]) * (to[i] - p->cur[i]);
    len = sqrt(len);
    double dur = kind == HS_SEG_HOLD ? hold_s : move_duration(p->profile, len, speed, p->accel);
    p->moved = 1;
    if (dur <= 0) { // a zero-length move or hold: nothing to add
        for (int i = 0; i < 3; ++i) p->cur[i] = to[i];
        return HS_OK;
    }
    // A crawl (speed 1e-300) or a hold of years: a typo, refused before it plays forever.
    if (!(p->t + dur <= HS_SCRIPT_MAX_DURATION_S))
        return perr(p, err, "the script would last beyond %g s (a speed too low, a hold too long?)",
                    HS_SCRIPT_MAX_DURATION_S);
    if (s->n_segments >= HS_SCRIPT_MAX_SEGMENTS) {
        char lim[32];
        snprintf(lim, sizeof lim, "%d", HS_SCRIPT_MAX_SEGMENTS);
        return perr(p, err, "too many segments after loop expansion (limit %s)", lim);
    }
    hs_script_segment* g = &s->seg[s->n_segments++];
    memset(g, 0, sizeof *g);
    g->kind = kind;
    g->cmd = cmd;
    g->line = p->line;
    g->profile = p->profile;
    g->t0_s = p->t;
    g->dur_s = dur;
    g->speed_m_s = speed;
    g->accel_m_s2 = p->accel;
    g->buttons = buttons;
    memcpy(g->quat_wxyz, p->quat, sizeof g->quat_wxyz);
    for (int i = 0; i < 3; ++i) {
        g->from_m[i] = p->cur[i];
        g->to_m[i] = to[i];
        p->cur[i] = to[i];
    }
    p->t += dur;
    s->duration_s = p->t;
    return HS_OK;
}

// Reads n numbers from tok[1..n] scaled per kind ('L' length, 'V' speed, 'A' accel, 'N' plain,
// 'T' time), with the command's usage in the error.
static hs_status read_args(parser* p, hs_err* err, char** tok, int ntok, const char* kinds,
                           const char* usage, double* v) {
    int n = (int)strlen(kinds);
    if (ntok - 1 != n) {
        char msg[200];
        snprintf(msg, sizeof msg, "%s: expected %d number%s (%s), got %d", tok[0], n,
                 n == 1 ? "" : "s", usage, ntok - 1);
        return perr(p, err, "%s", msg);
    }
    for (int i = 0; i < n; ++i) {
        if (!parse_num(tok[i + 1], &v[i])) {
            char msg[200];
            snprintf(msg, sizeof msg, "%s: '%.60s' is not a finite number (%s)", tok[0], tok[i + 1],
                     usage);
            return perr(p, err, "%s", msg);
        }
        if (kinds[i] == 'L' || kinds[i] == 'V' || kinds[i] == 'A') v[i] *= p->scale;
        if (kinds[i] == 'L' && !(fabs(v[i]) <= HS_SCRIPT_MAX_LENGTH_M)) {
            char msg[200];
            snprintf(msg, sizeof msg, "%s: '%.60s' is beyond +-%g m (%s)", tok[0], tok[i + 1],
                     HS_SCRIPT_MAX_LENGTH_M, usage);
            return perr(p, err, "%s", msg);
        }
    }
    return HS_OK;
}

// The shortest rotation taking +z to the unit vector a, as a unit quaternion (w, x, y, z).
static void axis_quat(const double a[3], double q[4]) {
    double w = 1 + a[2]; // 1 + z . a
    if (w < 1e-9) {      // a = -z: half a turn about x
        q[0] = 0, q[1] = 1, q[2] = 0, q[3] = 0;
        return;
    }
    // q = (1 + z.a, z x a) normalised; z x a = (-a_y, a_x, 0)
    double n = sqrt(w * w + a[0] * a[0] + a[1] * a[1]);
    q[0] = w / n;
    q[1] = -a[1] / n;
    q[2] = a[0] / n;
    q[3] = 0;
}

static hs_status need_positive(parser* p, hs_err* err, const char* cmd, const char* what,
                               double v) {
    if (v > 0) return HS_OK;
    char msg[160];
    snprintf(msg, sizeof msg, "%s: %s must be > 0", cmd, what);
    return perr(p, err, "%s", msg);
}

static hs_status unit_normal(parser* p, hs_err* err, const char* cmd, const double* in,
                             double out[3]) {
    // Divided by the largest component first: the plain sum of squares overflows for 1e200
    // (a zero normal came out) and underflows to 0 for 1e-200.
    double big = fmax(fabs(in[0]), fmax(fabs(in[1]), fabs(in[2])));
    if (!(big > 0)) {
        char msg[160];
        snprintf(msg, sizeof msg, "%s: the normal (nx ny nz) must not be zero", cmd);
        return perr(p, err, "%s", msg);
    }
    double u[3] = {in[0] / big, in[1] / big, in[2] / big};
    double l = sqrt(u[0] * u[0] + u[1] * u[1] + u[2] * u[2]);
    for (int i = 0; i < 3; ++i) out[i] = u[i] / l;
    return HS_OK;
}

// Each argument is bounded, but press depths add up (a press in a loop, then a release): the
// resulting target is bounded too, else a loop of presses drives it kilometres away.
static hs_status bounded_target(parser* p, hs_err* err, const char* cmd, const double to[3]) {
    for (int i = 0; i < 3; ++i)
        if (!(fabs(to[i]) <= HS_SCRIPT_MAX_LENGTH_M))
            return perr(p, err, "%s: the target (pressed %g m deep in all) is beyond +-%g m", cmd,
                        p->depth, HS_SCRIPT_MAX_LENGTH_M);
    return HS_OK;
}

typedef struct loop_frame {
    const char* body; // text just after the loop line
    int line;         // line number of the loop command
    long remaining;   // iterations still to run after the current one
} loop_frame;

// One command's words: tok[0] is the lower-cased command name.
typedef struct line_words {
    char* tok[MAX_TOKENS + 1];
    int ntok;
} line_words;

// Splits a line (comment already cut) into words; an empty comma field is an error.
static hs_status split_words(parser* p, hs_err* err, char* buf, line_words* w) {
    // An empty comma field ("0,,0", a comma first or last) was merged away, shifting every
    // later number into the wrong place: an error.
    for (const char* q = strchr(buf, ','); q; q = strchr(q + 1, ',')) {
        const char* b = q;
        while (b > buf && (b[-1] == ' ' || b[-1] == '\t' || b[-1] == '\r')) b--;
        const char* a = q + 1;
        while (*a == ' ' || *a == '\t' || *a == '\r') a++;
        if (b == buf || *a == '\0' || *a == ',') return perr(p, err, "empty field between commas");
    }
    w->ntok = 0;
    for (char* q = strtok(buf, " \t\r,"); q; q = strtok(NULL, " \t\r,")) {
        if (w->ntok == MAX_TOKENS) return perr(p, err, "too many words on the line");
        w->tok[w->ntok++] = q;
    }
    if (w->ntok > 0)
        for (char* q = w->tok[0]; *q; ++q) *q = (char)tolower((unsigned char)*q);
    return HS_OK;
}

static hs_status cmd_start_origin(parser* p, hs_err* err, char** tok, int ntok) {
    hs_script* s = p->s;
    const char* cmd = tok[0];
    double v[8];
    hs_status st;
    if ((st = read_args(p, err, tok, ntok, "LLL", "x y z", v))) return st;
    int is_start = !strcmp(cmd, "start");
    if (!is_start) {
        s->has_origin = 1;
        memcpy(s->origin_m, v, sizeof s->origin_m);
    }
    // The start (default: the origin) is where the timeline begins: fixed once moving.
    if (!p->moved && (is_start || !s->has_start)) {
        memcpy(s->start_m, v, sizeof s->start_m);
        memcpy(p->cur, v, sizeof p->cur);
        s->start_line = p->line;
        s->has_start |= is_start;
    } else if (is_start) {
        return perr(p, err, "start: must come before the first motion command");
    }
    return HS_OK;
}

static hs_status cmd_profile(parser* p, hs_err* err, char** tok, int ntok) {
    double v0;
    hs_status st;
    if (ntok == 2 && !strcmp(tok[1], "minjerk")) {
        p->profile = HS_PROFILE_MINJERK;
    } else if (ntok == 3 && !strcmp(tok[1], "trapezoid")) {
        if (!parse_num(tok[2], &v0))
            return perr(p, err, "profile trapezoid: '%.60s' is not a finite number", tok[2]);
        if ((st = need_positive(p, err, "profile trapezoid", "accel", v0))) return st;
        p->profile = HS_PROFILE_TRAPEZOID;
        p->accel = v0 * p->scale;
    } else {
        return perr(p, err,
                    "profile: expected 'profile minjerk' or "
                    "'profile trapezoid ACCEL'");
    }
    return HS_OK;
}

// cut x y z speed ax ay az: the tool turns so that its z axis (the blade of a scalpel whose
// blade lies along tool z) points along a, then moves.
static hs_status cmd_cut_axis(parser* p, hs_err* err, char** tok, int ntok) {
    const char* cmd = tok[0];
    double v[8];
    hs_status st;
    if ((st = read_args(p, err, tok, ntok, "LLLVNNN", "x y z speed [ax ay az]", v))) return st;
    if ((st = need_positive(p, err, cmd, "speed", v[3]))) return st;
    if (p->pressed) return perr(p, err, "%s: a press is active (use drag, or release first)", cmd);
    double a[3] = {0, 0, 1}; // set by unit_normal (init: -O3 cannot see that)
    if ((st = unit_normal(p, err, cmd, v + 4, a))) return st;
    axis_quat(a, p->quat);
    return emit(p, err, HS_SEG_MOVE, HS_CMD_CUT, v, v[3], 0, BUTTON_PRIMARY);
}

static hs_status cmd_move(parser* p, hs_err* err, char** tok, int ntok) {
    const char* cmd = tok[0];
    double v[8];
    hs_status st;
    if ((st = read_args(p, err, tok, ntok, "LLLV",
                        !strcmp(cmd, "cut") ? "x y z speed [ax ay az]" : "x y z speed", v)))
        return st;
    if ((st = need_positive(p, err, cmd, "speed", v[3]))) return st;
    if (p->pressed) return perr(p, err, "%s: a press is active (use drag, or release first)", cmd);
    int is_cut = !strcmp(cmd, "cut");
    return emit(p, err, HS_SEG_MOVE, is_cut ? HS_CMD_CUT : HS_CMD_MOVE_TO, v, v[3], 0,
                is_cut ? BUTTON_PRIMARY : 0);
}

static hs_status cmd_press(parser* p, hs_err* err, char** tok, int ntok) {
    const char* cmd = tok[0];
    double v[8];
    hs_status st;
    if ((st = read_args(p, err, tok, ntok, "NNNLV", "nx ny nz depth speed", v))) return st;
    double n[3];
    if ((st = unit_normal(p, err, cmd, v, n))) return st;
    if ((st = need_positive(p, err, cmd, "depth", v[3]))) return st;
    if ((st = need_positive(p, err, cmd, "speed", v[4]))) return st;
    if (p->pressed && n[0] * p->normal[0] + n[1] * p->normal[1] + n[2] * p->normal[2] < 1 - 1e-9)
        return perr(p, err,
                    "press: a press along another normal is active "
                    "(release first)");
    double to[3];
    for (int i = 0; i < 3; ++i) to[i] = p->cur[i] - n[i] * v[3];
    memcpy(p->normal, n, sizeof n);
    p->depth += v[3];
    p->pressed = 1;
    if ((st = bounded_target(p, err, cmd, to))) return st;
    return emit(p, err, HS_SEG_MOVE, HS_CMD_PRESS, to, v[4], 0, 0);
}

static hs_status cmd_drag(parser* p, hs_err* err, char** tok, int ntok) {
    const char* cmd = tok[0];
    double v[8];
    hs_status st;
    if ((st = read_args(p, err, tok, ntok, "LLLV", "x y z speed", v))) return st;
    if ((st = need_positive(p, err, cmd, "speed", v[3]))) return st;
    if (!p->pressed) return perr(p, err, "drag: no press is active (press first)");
    double to[3];
    for (int i = 0; i < 3; ++i) to[i] = v[i] - p->normal[i] * p->depth;
    if ((st = bounded_target(p, err, cmd, to))) return st;
    return emit(p, err, HS_SEG_MOVE, HS_CMD_DRAG, to, v[3], 0, 0);
}

// release speed [lift]: back out by the pressed depth, plus lift clear of the surface (so
// Coulomb friction cannot hold the handle in light contact).
static hs_status cmd_release(parser* p, hs_err* err, char** tok, int ntok) {
    const char* cmd = tok[0];
    double v[8];
    hs_status st;
    double lift = 0;
    if (ntok == 3) {
        if (!parse_num(tok[2], &lift) || lift < 0)
            return perr(p, err, "release: lift '%.60s' must be a number >= 0", tok[2]);
        lift *= p->scale;
        if (lift > HS_SCRIPT_MAX_LENGTH_M)
            return perr(p, err, "release: lift '%.60s' is beyond %g m", tok[2],
                        HS_SCRIPT_MAX_LENGTH_M);
        ntok = 2;
    }
    if ((st = read_args(p, err, tok, ntok, "V", "speed [lift]", v))) return st;
    if ((st = need_positive(p, err, cmd, "speed", v[0]))) return st;
    if (!p->pressed) return perr(p, err, "release: no press is active");
    double to[3];
    for (int i = 0; i < 3; ++i) to[i] = p->cur[i] + p->normal[i] * (p->depth + lift);
    if ((st = bounded_target(p, err, cmd, to))) return st;
    p->pressed = 0;
    p->depth = 0;
    return emit(p, err, HS_SEG_MOVE, HS_CMD_RELEASE, to, v[0], 0, 0);
}

// touch nx ny nz max_depth speed [force]: search along -n for the surface.
static hs_status cmd_touch(parser* p, hs_err* err, char** tok, int ntok) {
    hs_script* s = p->s;
    const char* cmd = tok[0];
    double v[8];
    hs_status st;
    int n_args = ntok - 1;
    if (n_args != 5 && n_args != 6)
        return perr(p, err,
                    "touch: expected 5 or 6 numbers (nx ny nz max_depth speed "
                    "[force_n]), got %d",
                    n_args);
    char* t6[7];
    for (int i = 0; i < 6; ++i) t6[i] = tok[i];
    if ((st = read_args(p, err, t6, 6, "NNNLV", "nx ny nz max_depth speed", v))) return st;
    double force = TOUCH_FORCE_N;
    if (n_args == 6 && !parse_num(tok[6], &force))
        return perr(p, err, "touch: '%.60s' is not a finite number (force_n)", tok[6]);
    double n[3];
    if ((st = unit_normal(p, err, cmd, v, n))) return st;
    if ((st = need_positive(p, err, cmd, "max_depth", v[3]))) return st;
    if ((st = need_positive(p, err, cmd, "speed", v[4]))) return st;
    if ((st = need_positive(p, err, cmd, "force_n", force))) return st;
    if (p->pressed) return perr(p, err, "touch: a press is active (release first)");
    double from[3], to[3], ref[3];
    for (int i = 0; i < 3; ++i) {
        from[i] = p->cur[i];
        to[i] = p->cur[i] - n[i] * v[3];
        ref[i] = from[i];
    }
    for (int i = 0; i < 3; ++i) // start and max_depth in bounds still reach 2000 m
        if (!(fabs(to[i]) <= HS_SCRIPT_MAX_LENGTH_M))
            return perr(p, err, "touch: the search ends beyond +-%g m (max_depth %g m)",
                        HS_SCRIPT_MAX_LENGTH_M, v[3]);
    if (s->has_surface) {
        // The expected contact: where the search line crosses the surface plane.
        const double* m = s->surface_normal;
        const double* q = s->surface_point_m;
        double mn = m[0] * n[0] + m[1] * n[1] + m[2] * n[2];
        double h = m[0] * (from[0] - q[0]) + m[1] * (from[1] - q[1]) + m[2] * (from[2] - q[2]);
        double at = mn > 1e-6 ? h / mn : -1;
        if (!(at >= 0 && at <= v[3]))
            return perr(p, err,
                        "touch: the search does not cross the `surface` plane "
                        "within max_depth (start above it, search toward it)");
        for (int i = 0; i < 3; ++i) ref[i] = from[i] - n[i] * at;
    }
    int keep_profile = p->profile;
    double keep_accel = p->accel;
    p->profile = HS_PROFILE_TRAPEZOID;
    p->accel = TOUCH_ACCEL;
    int before = s->n_segments;
    st = emit(p, err, HS_SEG_MOVE, HS_CMD_TOUCH, to, v[4], 0, 0);
    p->profile = keep_profile;
    p->accel = keep_accel;
    if (st) return st;
    if (s->n_segments > before) {
        s->seg[s->n_segments - 1].touch_force_n = force;
        memcpy(s->seg[s->n_segments - 1].touch_ref_m, ref, sizeof ref);
    }
    // What follows is written as if the surface were where the script expects it; the runner
    // shifts it to where the surface is found.
    memcpy(p->cur, ref, sizeof ref);
    return HS_OK;
}

// One command other than loop and end (which move the read position).
static hs_status run_command(parser* p, hs_err* err, char** tok, int ntok) {
    hs_script* s = p->s;
    const char* cmd = tok[0];
    double v[8];
    hs_status st;
    if (!strcmp(cmd, "units")) {
        if (ntok != 2 || (strcmp(tok[1], "m") && strcmp(tok[1], "mm")))
            return perr(p, err, "units: expected 'units m' or 'units mm'");
        p->scale = strcmp(tok[1], "mm") ? 1.0 : 1e-3;
        return HS_OK;
    }
    if (!strcmp(cmd, "start") || !strcmp(cmd, "origin")) return cmd_start_origin(p, err, tok, ntok);
    if (!strcmp(cmd, "surface")) {
        if ((st = read_args(p, err, tok, ntok, "LLLNNN", "px py pz nx ny nz", v))) return st;
        if ((st = unit_normal(p, err, cmd, v + 3, s->surface_normal))) return st;
        memcpy(s->surface_point_m, v, sizeof s->surface_point_m);
        s->has_surface = 1;
        return HS_OK;
    }
    if (!strcmp(cmd, "profile")) return cmd_profile(p, err, tok, ntok);
    if (!strcmp(cmd, "cut") && ntok == 8) return cmd_cut_axis(p, err, tok, ntok);
    if (!strcmp(cmd, "move_to") || !strcmp(cmd, "cut")) return cmd_move(p, err, tok, ntok);
    if (!strcmp(cmd, "press")) return cmd_press(p, err, tok, ntok);
    if (!strcmp(cmd, "drag")) return cmd_drag(p, err, tok, ntok);
    if (!strcmp(cmd, "release")) return cmd_release(p, err, tok, ntok);
    if (!strcmp(cmd, "touch")) return cmd_touch(p, err, tok, ntok);
    if (!strcmp(cmd, "hold")) {
        if ((st = read_args(p, err, tok, ntok, "T", "seconds", v))) return st;
        if (v[0] < 0) return perr(p, err, "hold: seconds must be >= 0");
        return emit(p, err, HS_SEG_HOLD, HS_CMD_HOLD, p->cur, 0, v[0], 0);
    }
    return perr(p, err,
                "unknown command '%.60s' (expected units, start, origin, surface, "
                "profile, move_to, touch, press, drag, release, hold, loop, end, cut)",
                cmd);
}

static hs_status parse_text(parser* p, const char* text, hs_err* err) {
    loop_frame stack[HS_SCRIPT_MAX_LOOP_DEPTH];
    int depth = 0;
    // Lines read again by loops: bounds loops of empty bodies. Lines read once are not counted
    // (the 1 MiB file bounds them): 10^6 blank lines were called "loops repeat".
    long repeated = 0;
    const char* c = text;
    const char* unread = text; // the first line never read yet; a loop jumps back before it
    p->line = 0;
    char buf[HS_SCRIPT_MAX_LINE];
    while (*c) {
        const char* eol = strchr(c, '\n');
        size_t len = eol ? (size_t)(eol - c) : strlen(c);
        const char* next = eol ? eol + 1 : c + len;
        p->line++;
        if (c >= unread)
            unread = next;
        else if (++repeated > HS_SCRIPT_MAX_EXECUTED)
            return perr(p, err, "loops repeat more than %d lines in all", HS_SCRIPT_MAX_EXECUTED);
        if (len >= sizeof buf) return perr(p, err, "line longer than %s bytes", "511");
        memcpy(buf, c, len);
        buf[len] = '\0';
        c = next;
        char* hash = strchr(buf, '#');
        if (hash) *hash = '\0';
        line_words w;
        hs_status st = split_words(p, err, buf, &w);
        if (st) return st;
        if (w.ntok == 0) continue;
        const char* cmd = w.tok[0];
        if (!strcmp(cmd, "loop")) {
            double n;
            if (w.ntok != 2 || !parse_num(w.tok[1], &n) || n != floor(n) || n < 1 || n > 1e6)
                return perr(p, err, "loop: expected a whole count 1..1000000");
            if (depth == HS_SCRIPT_MAX_LOOP_DEPTH)
                return perr(p, err, "loop: nested deeper than %s", "8");
            stack[depth].body = c;
            stack[depth].line = p->line;
            stack[depth].remaining = (long)n - 1;
            depth++;
        } else if (!strcmp(cmd, "end")) {
            if (w.ntok != 1) return perr(p, err, "end: takes no arguments");
            if (depth == 0) return perr(p, err, "end: no open loop");
            loop_frame* f = &stack[depth - 1];
            if (f->remaining > 0) {
                f->remaining--;
                c = f->body;
                p->line = f->line;
            } else {
                depth--;
            }
        } else if ((st = run_command(p, err, w.tok, w.ntok))) {
            return st;
        }
    }
    if (depth > 0) {
        p->line = stack[depth - 1].line;
        return perr(p, err, "loop: no matching 'end' before the end of the file");
    }
    return HS_OK;
}

hs_status hs_script_parse_string(hs_script* s, const char* text, const char* name, hs_err* err) {
    if (!s || !text) return hs_err_set(err, HS_ERR_INVALID, "script: no script or no text");
    memset(s, 0, offsetof(hs_script, seg));
    snprintf(s->name, sizeof s->name, "%s", name ? name : "<script>");
    parser p;
    memset(&p, 0, sizeof p);
    p.s = s;
    p.name = s->name;
    p.scale = 1.0;
    p.quat[0] = 1; // identity orientation until a `cut` gives a blade axis
    p.profile = HS_PROFILE_MINJERK;
    p.accel = 1.0;
    hs_status st = parse_text(&p, text, err);
    if (st) {
        char keep[256];
        memcpy(keep, s->name, sizeof keep);
        memset(s, 0, offsetof(hs_script, seg));
        memcpy(s->name, keep, sizeof keep);
        return st;
    }
    return HS_OK;
}

hs_status hs_script_parse_file(hs_script* s, const char* path, hs_err* err) {
    FILE* f = fopen(path, "rb");
    if (!f) return hs_err_set(err, HS_ERR_IO, "%s: cannot open: %s", path, strerror(errno));
    // Read to the end rather than trusting the size: /proc files say 0 and a pipe has none.
    const size_t max = 1 << 20;
    char* text = hs_proto_alloc(max + 2);
    if (!text) {
        fclose(f);
        return hs_err_set(err, HS_ERR_NOMEM, "%s: out of memory", path);
    }
    size_t got = fread(text, 1, max + 1, f);
    int bad = ferror(f);
    fclose(f);
    if (bad || got > max) {
        hs_proto_free(text);
        return hs_err_set(err, HS_ERR_IO, "%s: not a readable script (or larger than 1 MiB)", path);
    }
    text[got] = '\0';
    hs_status st = HS_OK;
    if (strlen(text) != got)
        st = hs_err_set(err, HS_ERR_PARSE, "%s: contains a NUL byte (not a text file)", path);
    else
        st = hs_script_parse_string(s, text, path, err);
    hs_proto_free(text);
    return st;
}

int hs_script_eval(const hs_script* s, double t_s, double pos_m[3], double vel_m_s[3],
                   uint32_t* buttons, int* hint) {
    if (vel_m_s) vel_m_s[0] = vel_m_s[1] = vel_m_s[2] = 0;
    if (buttons) *buttons = 0;
    if (s->n_segments == 0) {
        memcpy(pos_m, s->start_m, 3 * sizeof(double));
        return -1;
    }
    if (!(t_s > 0)) t_s = 0; // also maps NaN to the start
    int i = hint && *hint >= 0 && *hint < s->n_segments ? *hint : 0;
    if (s->seg[i].t0_s > t_s) i = 0;
    while (i + 1 < s->n_segments && s->seg[i + 1].t0_s <= t_s) ++i;
    if (hint) *hint = i;
    const hs_script_segment* g = &s->seg[i];
    double sfrac, ds;
    if (g->kind == HS_SEG_HOLD) {
        sfrac = 1;
        ds = 0;
    } else {
        profile_eval(g, t_s - g->t0_s, &sfrac, &ds);
    }
    for (int k = 0; k < 3; ++k) {
        double d = g->to_m[k] - g->from_m[k];
        pos_m[k] = g->from_m[k] + sfrac * d;
        if (vel_m_s) vel_m_s[k] = ds * d;
    }
    if (buttons && t_s < g->t0_s + g->dur_s) *buttons = g->buttons;
    return i;
}

void hs_script_runner_init(hs_script_runner* r, const hs_script* s) {
    memset(r, 0, sizeof *r);
    r->s = s;
    r->touch_seg = -1;
    r->has_onset = 0;
}

double hs_script_runner_end(const hs_script_runner* r) {
    return r->s->duration_s + r->t_off_s;
}

int hs_script_runner_eval(hs_script_runner* r, double t_s, const double force_n[3], double pos_m[3],
                          double vel_m_s[3], uint32_t* buttons, uint32_t* events) {
    const hs_script* s = r->s;
    uint32_t ev = 0;
    double t = t_s - r->t_off_s;
    int seg = hs_script_eval(s, t, pos_m, vel_m_s, buttons, &r->hint);
    // A touch searched earlier ended without a force: continue from where it stopped. (The
    // last segment of a script stays the current one after its end: check the time too.)
    if (r->touch_seg >= 0 &&
        (seg != r->touch_seg || t >= s->seg[r->touch_seg].t0_s + s->seg[r->touch_seg].dur_s)) {
        const hs_script_segment* g = &s->seg[r->touch_seg];
        for (int i = 0; i < 3; ++i) r->off_m[i] += g->to_m[i] - g->touch_ref_m[i];
        r->touch_seg = -1;
        r->missed++;
        ev |= HS_TOUCH_MISSED;
    }
    if (seg >= 0 && s->seg[seg].cmd == HS_CMD_TOUCH && t < s->seg[seg].t0_s + s->seg[seg].dur_s) {
        const hs_script_segment* g = &s->seg[seg];
        double d[3] = {g->from_m[0] - g->to_m[0], g->from_m[1] - g->to_m[1],
                       g->from_m[2] - g->to_m[2]};
        double len = sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2]);
        double fn = force_n ? (force_n[0] * d[0] + force_n[1] * d[1] + force_n[2] * d[2]) / len : 0;
        if (r->touch_seg != seg) r->has_onset = 0;
        r->touch_seg = seg;
        // Remember where the force began, forget it if it fades (a brush, not the surface).
        if (fn > TOUCH_ONSET_N && !r->has_onset) {
            r->has_onset = 1;
            memcpy(r->onset_m, pos_m, sizeof r->onset_m);
        } else if (fn <= TOUCH_ONSET_N) {
            r->has_onset = 0;
        }
        if (fn >= g->touch_force_n) {
            // Found: what follows starts where the contact began (so a release comes back to
            // zero force), and the rest of the search is skipped.
            const double* at = r->has_onset ? r->onset_m : pos_m;
            for (int i = 0; i < 3; ++i) r->off_m[i] += at[i] - g->touch_ref_m[i];
            r->t_off_s = t_s - (g->t0_s + g->dur_s);
            r->touch_seg = -1;
            r->found++;
            ev |= HS_TOUCH_FOUND;
            seg = hs_script_eval(s, g->t0_s + g->dur_s, pos_m, vel_m_s, buttons, &r->hint);
        }
    }
    // Past the end of a touch that ends the script (found or missed), hs_script_eval stays at
    // its full search depth: hold at its reference point instead, which the offset moves to
    // where the contact began or where the search stopped (it went max_depth further).
    const double t_now = t_s - r->t_off_s;
    if (seg >= 0 && s->seg[seg].cmd == HS_CMD_TOUCH && r->touch_seg < 0 &&
        t_now >= s->seg[seg].t0_s + s->seg[seg].dur_s) {
        memcpy(pos_m, s->seg[seg].touch_ref_m, 3 * sizeof(double));
        if (vel_m_s) vel_m_s[0] = vel_m_s[1] = vel_m_s[2] = 0;
    }
    for (int i = 0; i < 3; ++i) pos_m[i] += r->off_m[i];
    if (events) *events = ev;
    return seg;
}
