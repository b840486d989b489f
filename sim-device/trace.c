// SPDX-License-Identifier: MIT
// The run trace: one row per device tick kept in memory allocated before the run (the device
// loop only copies a struct), the summary numbers, and the CSV written after the run.
#include "stylus.h"

#include "hapsim_proto.h"

#include <errno.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>

struct hs_stylus_trace {
    int64_t capacity;
    int64_t rows;
    int64_t dropped;
    hs_stylus_tick* row; // [capacity]
};

const char hs_stylus_trace_header[] =
    "t_s,target_x,target_y,target_z,handle_x,handle_y,handle_z,f_recv_x,f_recv_y,f_recv_z,"
    "f_app_x,f_app_y,f_app_z,model_age_ms,latency_us,segment,flags";

hs_status hs_stylus_trace_create(int64_t capacity, hs_stylus_trace** out, hs_err* err) {
    *out = NULL;
    if (capacity < 1 || capacity > ((int64_t)1 << 31))
        return hs_err_set(err, HS_ERR_INVALID, "trace: capacity %lld out of range",
                          (long long)capacity);
    hs_stylus_trace* t = hs_proto_calloc(1, sizeof *t);
    if (!t) return hs_err_set(err, HS_ERR_NOMEM, "trace: out of memory");
    t->row = hs_proto_alloc((size_t)capacity * sizeof *t->row);
    if (!t->row) {
        hs_proto_free(t);
        return hs_err_set(err, HS_ERR_NOMEM, "trace: out of memory for %lld rows",
                          (long long)capacity);
    }
    t->capacity = capacity;
    *out = t;
    return HS_OK;
}

void hs_stylus_trace_destroy(hs_stylus_trace** t) {
    if (!t || !*t) return;
    hs_proto_free((*t)->row);
    hs_proto_free(*t);
    *t = NULL;
}

void hs_stylus_trace_add(hs_stylus_trace* t, const hs_stylus_tick* tick) {
    if (t->rows < t->capacity)
        t->row[t->rows++] = *tick;
    else
        t->dropped++;
}

int64_t hs_stylus_trace_rows(const hs_stylus_trace* t) {
    return t->rows;
}

const hs_stylus_tick* hs_stylus_trace_row(const hs_stylus_trace* t, int64_t i) {
    return i >= 0 && i < t->rows ? &t->row[i] : NULL;
}

static int cmp_double(const void* a, const void* b) {
    double x = *(const double*)a, y = *(const double*)b;
    return (x > y) - (x < y);
}

void hs_stylus_trace_summary(const hs_stylus_trace* t, const hs_script* script,
                             hs_stylus_summary* out) {
    memset(out, 0, sizeof *out);
    out->rows = t->rows;
    out->dropped = t->dropped;
    out->steady_segment = -1;
    out->latency_p50_us = out->latency_p99_us = -1;
    out->model_age_max_s = -1; // none until a row has a model
    // The longest hold: in a press-and-hold script this is where the force settles. Its rows
    // are found by segment index (run time and script time differ after a touch).
    if (script) {
        double best = 0;
        for (int i = 0; i < script->n_segments; ++i) {
            const hs_script_segment* g = &script->seg[i];
            if (g->kind == HS_SEG_HOLD && g->dur_s > best) {
                best = g->dur_s;
                out->steady_segment = i;
            }
        }
    }
    int64_t hold_rows = 0, hold_seen = 0;
    for (int64_t k = 0; k < t->rows; ++k) hold_rows += t->row[k].segment == out->steady_segment;
    int64_t n_steady = 0, n_lat = 0;
    for (int64_t k = 0; k < t->rows; ++k) {
        const hs_stylus_tick* r = &t->row[k];
        double fn = sqrt(r->f_applied[0] * r->f_applied[0] + r->f_applied[1] * r->f_applied[1] +
                         r->f_applied[2] * r->f_applied[2]);
        if (fn > out->peak_force_n) out->peak_force_n = fn;
        if (k > 0) {
            const double* p = t->row[k - 1].f_applied;
            double d[3] = {r->f_applied[0] - p[0], r->f_applied[1] - p[1], r->f_applied[2] - p[2]};
            double dn = sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2]);
            if (dn > out->max_force_step_n) out->max_force_step_n = dn;
        }
        out->energy_j += r->work_j;
        if (r->work_j > 0)
            out->energy_in_j += r->work_j;
        else
            out->energy_out_j += r->work_j;
        if (r->segment == out->steady_segment && 2 * hold_seen++ >= hold_rows) {
            for (int i = 0; i < 3; ++i) out->steady_force_n[i] += r->f_applied[i];
            n_steady++;
        }
        if (r->latency_us >= 0) n_lat++;
        if (r->model_age_s > out->model_age_max_s) out->model_age_max_s = r->model_age_s;
        if (r->flags & HS_TICK_MAGNITUDE) out->clamp_magnitude++;
        if (r->flags & HS_TICK_RATE) out->clamp_rate++;
        if (r->flags & HS_TICK_TIMEOUT) out->timeouts++;
        if (r->flags & HS_TICK_WORKSPACE) out->workspace_hits++;
        if (r->flags & HS_TICK_TOUCH_FOUND) out->touches_found++;
        if (r->flags & HS_TICK_TOUCH_MISSED) out->touches_missed++;
        out->duration_s = r->t_s;
    }
    if (n_steady > 0) {
        for (int i = 0; i < 3; ++i) out->steady_force_n[i] /= (double)n_steady;
        const double* s = out->steady_force_n;
        out->steady_force_norm_n = sqrt(s[0] * s[0] + s[1] * s[1] + s[2] * s[2]);
    } else {
        out->steady_segment = -1;
    }
    // Percentiles need a sorted copy: after the run, so an allocation is fine here.
    double* lat = n_lat > 0 ? hs_proto_alloc((size_t)n_lat * sizeof *lat) : NULL;
    if (lat) {
        int64_t j = 0;
        for (int64_t k = 0; k < t->rows; ++k)
            if (t->row[k].latency_us >= 0) lat[j++] = t->row[k].latency_us;
        qsort(lat, (size_t)n_lat, sizeof *lat, cmp_double);
        out->latency_p50_us = lat[(int64_t)floor(0.50 * (double)(n_lat - 1))];
        out->latency_p99_us = lat[(int64_t)floor(0.99 * (double)(n_lat - 1))];
        hs_proto_free(lat);
    }
}

static void summary_lines(FILE* f, const hs_stylus_summary* s, const char* prefix) {
    fprintf(f, "%srows=%lld\n", prefix, (long long)s->rows);
    fprintf(f, "%sdropped_rows=%lld\n", prefix, (long long)s->dropped);
    fprintf(f, "%sduration_s=%.6f\n", prefix, s->duration_s);
    fprintf(f, "%speak_force_n=%.9g\n", prefix, s->peak_force_n);
    fprintf(f, "%ssteady_segment=%d\n", prefix, s->steady_segment);
    fprintf(f, "%ssteady_force_n=%.9g,%.9g,%.9g\n", prefix, s->steady_force_n[0],
            s->steady_force_n[1], s->steady_force_n[2]);
    fprintf(f, "%ssteady_force_norm_n=%.9g\n", prefix, s->steady_force_norm_n);
    fprintf(f, "%smax_force_step_n=%.9g\n", prefix, s->max_force_step_n);
    fprintf(f, "%senergy_j=%.9g\n", prefix, s->energy_j);
    fprintf(f, "%senergy_in_j=%.9g\n", prefix, s->energy_in_j);
    fprintf(f, "%senergy_out_j=%.9g\n", prefix, s->energy_out_j);
    fprintf(f, "%slatency_p50_us=%.1f\n", prefix, s->latency_p50_us);
    fprintf(f, "%slatency_p99_us=%.1f\n", prefix, s->latency_p99_us);
    fprintf(f, "%smodel_age_max_ms=%.3f\n", prefix,
            s->model_age_max_s < 0 ? -1.0 : s->model_age_max_s * 1e3);
    fprintf(f, "%sclamp_magnitude_ticks=%lld\n", prefix, (long long)s->clamp_magnitude);
    fprintf(f, "%sclamp_rate_ticks=%lld\n", prefix, (long long)s->clamp_rate);
    fprintf(f, "%stimeout_ticks=%lld\n", prefix, (long long)s->timeouts);
    fprintf(f, "%sworkspace_ticks=%lld\n", prefix, (long long)s->workspace_hits);
    fprintf(f, "%stouches_found=%lld\n", prefix, (long long)s->touches_found);
    fprintf(f, "%stouches_missed=%lld\n", prefix, (long long)s->touches_missed);
}

hs_status hs_stylus_trace_write_csv(const hs_stylus_trace* t, const hs_stylus_summary* sum,
                                    const char* path, hs_err* err) {
    FILE* f = fopen(path, "w");
    if (!f) return hs_err_set(err, HS_ERR_IO, "%s: cannot write: %s", path, strerror(errno));
    fprintf(f, "%s\n", hs_stylus_trace_header);
    for (int64_t k = 0; k < t->rows; ++k) {
        const hs_stylus_tick* r = &t->row[k];
        fprintf(f,
                "%.6f,%.9g,%.9g,%.9g,%.9g,%.9g,%.9g,%.9g,%.9g,%.9g,%.9g,%.9g,%.9g,%.4f,%.1f,%d,"
                "%u\n",
                r->t_s, r->target_m[0], r->target_m[1], r->target_m[2], r->handle_m[0],
                r->handle_m[1], r->handle_m[2], r->f_received[0], r->f_received[1],
                r->f_received[2], r->f_applied[0], r->f_applied[1], r->f_applied[2],
                r->model_age_s < 0 ? -1.0 : r->model_age_s * 1e3, r->latency_us, r->segment,
                (unsigned)r->flags);
    }
    summary_lines(f, sum, "# ");
    int bad = ferror(f);
    if (fclose(f) != 0 || bad)
        return hs_err_set(err, HS_ERR_IO, "%s: write failed: %s", path, strerror(errno));
    return HS_OK;
}

void hs_stylus_summary_print(FILE* f, const hs_stylus_summary* s, const char* trace_path) {
    fprintf(f,
            "hapsim-stylus: %lld ticks over %.2f s; peak force %.3f N, steady %.3f N "
            "(hold #%d), max step %.4f N/tick\n",
            (long long)s->rows, s->duration_s, s->peak_force_n, s->steady_force_norm_n,
            s->steady_segment, s->max_force_step_n);
    // Nothing measured (no model received) is "none", not a perfect 0.
    char lat[64] = "none", age[32] = "none";
    if (s->latency_p50_us >= 0)
        snprintf(lat, sizeof lat, "p50 %.0f us p99 %.0f us", s->latency_p50_us, s->latency_p99_us);
    if (s->model_age_max_s >= 0) snprintf(age, sizeof age, "%.1f ms", s->model_age_max_s * 1e3);
    fprintf(f,
            "hapsim-stylus: energy into the handle %.3g J (in %.3g, out %.3g); latency %s; max "
            "model age %s\n",
            s->energy_j, s->energy_in_j, s->energy_out_j, lat, age);
    fprintf(f,
            "hapsim-stylus: clamps: magnitude %lld, rate %lld ticks; timeout %lld, workspace "
            "%lld ticks%s\n",
            (long long)s->clamp_magnitude, (long long)s->clamp_rate, (long long)s->timeouts,
            (long long)s->workspace_hits, s->dropped ? "; rows dropped (trace full)" : "");
    if (s->touches_found || s->touches_missed)
        fprintf(f, "hapsim-stylus: touch: surface found %lld time(s), missed %lld time(s)%s\n",
                (long long)s->touches_found, (long long)s->touches_missed,
                s->touches_missed ? " (WARNING: a touch ran its whole depth without contact)" : "");
    if (trace_path) fprintf(f, "hapsim-stylus: trace: %s\n", trace_path);
}

// One line into buf, its '\n' kept: 1, or 0 at the end of the file, -1 when it does not fit,
// -2 when it holds a NUL byte (strings would end there and hide what follows: found in
// review); the rest of a refused line is skipped, so the line count stays right.
static int next_line(FILE* f, char* buf, int cap) {
    int n = 0, ch, r = 1;
    while ((ch = getc(f)) != EOF && ch != '\n') {
        if (ch == '\0')
            r = -2;
        else if (n + 2 >= cap) // keep room for the '\n' and the NUL
            r = r == 1 ? -1 : r;
        else
            buf[n++] = (char)ch;
    }
    if (ch == EOF && n == 0 && r == 1) return 0;
    if (ch == '\n') buf[n++] = '\n';
    buf[n] = '\0';
    return r;
}

// 1 when line is exactly text, then an end of line ("\n", "\r\n", or none at the end of the
// file); "\rgarbage" is not an end.
static int line_is(const char* line, const char* text) {
    size_t n = strlen(text);
    if (strncmp(line, text, n) != 0) return 0;
    line += n;
    if (*line == '\r') line++;
    return *line == '\0' || (line[0] == '\n' && line[1] == '\0');
}

hs_status hs_stylus_trace_read_csv(const char* path, hs_stylus_trace** out, hs_err* err) {
    *out = NULL;
    FILE* f = fopen(path, "r");
    if (!f) return hs_err_set(err, HS_ERR_IO, "%s: cannot open: %s", path, strerror(errno));
    char line[1024];
    int64_t rows = 0;
    // First pass: check the header and count the rows, so the trace is allocated once. The
    // header is the whole line (extra columns are another format), and only the trailing summary
    // may be comments: a '#' line before data rows would cut the trace short unnoticed.
    if (next_line(f, line, sizeof line) != 1 || !line_is(line, hs_stylus_trace_header)) {
        fclose(f);
        return hs_err_set(err, HS_ERR_PARSE, "%s:1: not a hapsim-stylus trace (header differs)",
                          path);
    }
    int64_t n = 1, comment = 0; // line number of the first '#' line
    for (int r; (r = next_line(f, line, sizeof line)) != 0;) {
        n++;
        if (r < 0) {
            fclose(f);
            if (r == -2)
                return hs_err_set(err, HS_ERR_PARSE, "%s:%lld: a NUL byte in the line", path,
                                  (long long)n);
            return hs_err_set(err, HS_ERR_PARSE, "%s:%lld: line longer than %d bytes", path,
                              (long long)n, (int)sizeof line - 2);
        }
        if (line[0] == '#') {
            if (!comment) comment = n;
        } else if (comment) {
            fclose(f);
            return hs_err_set(err, HS_ERR_PARSE,
                              "%s:%lld: a '#' line before the row at line %lld (only the trailing "
                              "summary may be comments)",
                              path, (long long)comment, (long long)n);
        } else {
            rows++;
        }
    }
    if (rows == 0) {
        fclose(f);
        return hs_err_set(err, HS_ERR_PARSE, "%s: no rows", path);
    }
    hs_stylus_trace* t = NULL;
    hs_status st = hs_stylus_trace_create(rows, &t, err);
    if (st) {
        fclose(f);
        return st;
    }
    rewind(f);
    if (next_line(f, line, sizeof line) != 1) rows = 0;
    for (int64_t k = 0; k < rows; ++k) {
        if (next_line(f, line, sizeof line) <= 0) break;
        double v[17];
        char* at = line;
        int ok = 1;
        for (int i = 0; i < 17 && ok; ++i) {
            char* end = NULL;
            v[i] = strtod(at, &end);
            ok = end != at && isfinite(v[i]) && (i == 16 ? line_is(end, "") : *end == ',');
            at = end + 1;
        }
        const char* bad = ok ? NULL : "expected 17 finite numbers";
        // segment and flags are integers (a cast of 1e300 would be undefined); time runs forward
        if (!bad && (v[15] != floor(v[15]) || v[15] < -1 || v[15] > INT32_MAX ||
                     v[16] != floor(v[16]) || v[16] < 0 || v[16] > UINT32_MAX))
            bad = "segment and flags must be whole numbers (segment >= -1, flags >= 0)";
        if (!bad && t->rows > 0 && v[0] < t->row[t->rows - 1].t_s) bad = "t_s goes backwards";
        if (bad) {
            hs_stylus_trace_destroy(&t);
            fclose(f);
            return hs_err_set(err, HS_ERR_PARSE, "%s:%lld: %s", path, (long long)(k + 2), bad);
        }
        hs_stylus_tick r;
        memset(&r, 0, sizeof r);
        r.t_s = v[0];
        for (int i = 0; i < 3; ++i) {
            r.target_m[i] = v[1 + i];
            r.handle_m[i] = v[4 + i];
            r.f_received[i] = v[7 + i];
            r.f_applied[i] = v[10 + i];
        }
        r.model_age_s = v[13] < 0 ? -1 : v[13] * 1e-3;
        r.latency_us = v[14];
        r.segment = (int)v[15];
        r.flags = (uint32_t)v[16];
        if (t->rows > 0) {
            const double* p = t->row[t->rows - 1].handle_m;
            r.work_j = r.f_applied[0] * (r.handle_m[0] - p[0]) +
                       r.f_applied[1] * (r.handle_m[1] - p[1]) +
                       r.f_applied[2] * (r.handle_m[2] - p[2]);
        }
        hs_stylus_trace_add(t, &r);
    }
    fclose(f);
    *out = t;
    return HS_OK;
}

static double fnorm(const double f[3]) {
    return sqrt(f[0] * f[0] + f[1] * f[1] + f[2] * f[2]);
}

int hs_stylus_trace_compare(const hs_stylus_trace* ref, const hs_stylus_trace* run,
                            const hs_trace_tol* tol, hs_trace_diff* out) {
    memset(out, 0, sizeof *out);
    if (ref->rows == 0 || run->rows == 0) return 0;
    for (int64_t k = 0; k < ref->rows; ++k) {
        double n = fnorm(ref->row[k].f_applied);
        if (n > out->ref_peak_n) out->ref_peak_n = n;
    }
    out->allowed_n = tol->abs_n + tol->rel * out->ref_peak_n;
    double t_end_run = run->row[run->rows - 1].t_s, t_end_ref = ref->row[ref->rows - 1].t_s;
    double t0_run = run->row[0].t_s, t0_ref = ref->row[0].t_s;
    out->coverage_s =
        (t_end_run < t_end_ref ? t_end_run : t_end_ref) - (t0_run > t0_ref ? t0_run : t0_ref);
    if (out->coverage_s < 0) out->coverage_s = 0;
    double sum2 = 0;
    int64_t j = 0;
    for (int64_t k = 0; k < ref->rows; ++k) {
        const hs_stylus_tick* r = &ref->row[k];
        // 1 us of slack: times printed with 6 decimals compare equal to the exact ones.
        if (r->t_s < tol->skip_s || r->t_s > t_end_run + 1e-6 || r->t_s < run->row[0].t_s - 1e-6)
            continue;
        while (j + 1 < run->rows && run->row[j + 1].t_s < r->t_s) ++j;
        const hs_stylus_tick* a = &run->row[j];
        const hs_stylus_tick* b = j + 1 < run->rows ? &run->row[j + 1] : a;
        double w = b->t_s > a->t_s ? (r->t_s - a->t_s) / (b->t_s - a->t_s) : 0;
        if (w < 0) w = 0;
        if (w > 1) w = 1;
        double d[3];
        for (int i = 0; i < 3; ++i)
            d[i] = a->f_applied[i] + w * (b->f_applied[i] - a->f_applied[i]) - r->f_applied[i];
        double e = fnorm(d);
        if (e > out->max_err_n) {
            out->max_err_n = e;
            out->max_err_t_s = r->t_s;
        }
        if (e > out->allowed_n) out->failed++;
        sum2 += e * e;
        out->samples++;
    }
    out->rms_err_n = out->samples ? sqrt(sum2 / (double)out->samples) : 0;
    // The run must span the compared part of the reference at both ends, within 10 ms (a live
    // run's ticks fall where its clock puts them): a run missing the reference's start skipped
    // those samples and passed.
    double t_first = t0_ref > tol->skip_s ? t0_ref : tol->skip_s;
    int covered = t_end_run >= t_end_ref - 0.010 && t0_run <= t_first + 0.010;
    return out->samples > 0 && out->failed == 0 && covered;
}
