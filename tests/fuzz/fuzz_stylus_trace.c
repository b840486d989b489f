// SPDX-License-Identifier: GPL-2.0-or-later
// libFuzzer target: the force-trace reader behind hapsim-trace-diff (golden traces). Each input
// is written to one temporary file and read back; an accepted trace is compared with itself and
// with its first half. A refused one must name the file with a line ("PATH:LINE: problem") or
// say it has no rows, and return no trace.
#define _POSIX_C_SOURCE 200809L // mkstemp
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "stylus.h"

int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size);

static char g_path[64];

static void remove_file(void) {
    unlink(g_path);
}

int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
    if (!g_path[0]) {
        snprintf(g_path, sizeof g_path, "/tmp/hs_fuzz_trace_XXXXXX");
        int fd = mkstemp(g_path);
        if (fd < 0) abort();
        close(fd);
        atexit(remove_file);
    }
    FILE* f = fopen(g_path, "wb");
    if (!f) abort();
    if (size && fwrite(data, 1, size, f) != size) abort();
    fclose(f);
    hs_stylus_trace* t = NULL;
    hs_err err = {0};
    hs_status st = hs_stylus_trace_read_csv(g_path, &t, &err);
    if (st != HS_OK) {
        size_t n = strlen(g_path);
        if (t || strncmp(err.msg, g_path, n) != 0 || err.msg[n] != ':') abort();
        return 0;
    }
    int64_t rows = hs_stylus_trace_rows(t);
    if (rows < 1) abort();
    for (int64_t k = 1; k < rows; k++)
        if (hs_stylus_trace_row(t, k)->t_s < hs_stylus_trace_row(t, k - 1)->t_s) abort();
    hs_trace_tol tol = {0.01, 0.05, 0};
    hs_trace_diff d;
    int pass = hs_stylus_trace_compare(t, t, &tol, &d);
    if ((pass != 0 && pass != 1) || d.samples > rows || d.failed > d.samples) abort();
    hs_stylus_trace* half = NULL;
    if (hs_stylus_trace_create(rows / 2 + 1, &half, NULL) != HS_OK) abort();
    for (int64_t k = 0; k <= rows / 2; k++) hs_stylus_trace_add(half, hs_stylus_trace_row(t, k));
    hs_stylus_trace_compare(t, half, &tol, &d);
    if (d.samples > rows || d.failed > d.samples) abort();
    hs_stylus_trace_compare(half, t, &tol, &d);
    if (d.samples > rows / 2 + 1 || d.failed > d.samples) abort();
    hs_stylus_trace_destroy(&half);
    hs_stylus_trace_destroy(&t);
    return 0;
}
