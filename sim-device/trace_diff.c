// SPDX-License-Identifier: MIT
// hapsim-trace-diff: compare a hapsim-stylus trace against a reference trace (golden traces).
// The applied force of the run, interpolated at the reference's sample times, must stay within
// abs + rel * (reference peak) everywhere, and the run must cover the reference's duration.
#include "hapsim/version.h"
#include <errno.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "stylus.h"

static void usage(FILE* f) {
    fprintf(f, "usage: hapsim-trace-diff REF.csv RUN.csv [--abs N] [--rel R] [--skip S]\n"
               "Compares the applied force of a hapsim-stylus trace with a reference trace at\n"
               "the reference's times. Passes (exit 0) when |F_run - F_ref| <= abs + rel * peak\n"
               "|F_ref| at every sample after --skip seconds and the run spans the reference\n"
               "from --skip to its end (within 10 ms at each end); else exit 1 (2: bad\n"
               "arguments or unreadable traces).\n"
               "  --abs N   absolute tolerance, N (default 0.01)\n"
               "  --rel R   tolerance relative to the reference's peak force (default 0.02)\n"
               "  --skip S  ignore the first S seconds (default 0)\n");
}

static int number(const char* s, double* v) {
    char* end = NULL;
    errno = 0;
    double x = strtod(s, &end);
    if (end == s || *end || errno || !isfinite(x) || x < 0) return 0;
    *v = x;
    return 1;
}

int main(int argc, char** argv) {
    if (hapsim_version_asked(argc, argv, "hapsim-trace-diff")) return 0;
    const char* path[2] = {NULL, NULL};
    int n_paths = 0;
    hs_trace_tol tol = {.abs_n = 0.01, .rel = 0.02, .skip_s = 0};
    for (int i = 1; i < argc; ++i) {
        double* dst = !strcmp(argv[i], "--abs")    ? &tol.abs_n
                      : !strcmp(argv[i], "--rel")  ? &tol.rel
                      : !strcmp(argv[i], "--skip") ? &tol.skip_s
                                                   : NULL;
        if (!strcmp(argv[i], "--help") || !strcmp(argv[i], "-h")) {
            usage(stdout);
            return 0;
        }
        if (dst) {
            if (i + 1 >= argc || !number(argv[i + 1], dst)) {
                fprintf(stderr, "hapsim-trace-diff: %s needs a number >= 0\n", argv[i]);
                return 2;
            }
            ++i;
        } else if (argv[i][0] == '-' || n_paths == 2) {
            usage(stderr);
            return 2;
        } else {
            path[n_paths++] = argv[i];
        }
    }
    if (n_paths != 2) {
        usage(stderr);
        return 2;
    }
    hs_stylus_trace *ref = NULL, *run = NULL;
    hs_err err = {0};
    if (hs_stylus_trace_read_csv(path[0], &ref, &err) ||
        hs_stylus_trace_read_csv(path[1], &run, &err)) {
        fprintf(stderr, "hapsim-trace-diff: %s\n", err.msg);
        hs_stylus_trace_destroy(&ref);
        return 2;
    }
    hs_trace_diff d;
    int pass = hs_stylus_trace_compare(ref, run, &tol, &d);
    printf("hapsim-trace-diff: %s: %lld samples, %lld outside; max |dF| %.4f N at t = %.3f s "
           "(allowed %.4f N = %.4f + %.3f x peak %.4f N); rms %.4f N; covers %.3f s of %.3f s\n",
           pass ? "PASS" : "FAIL", (long long)d.samples, (long long)d.failed, d.max_err_n,
           d.max_err_t_s, d.allowed_n, tol.abs_n, tol.rel, d.ref_peak_n, d.rms_err_n, d.coverage_s,
           hs_stylus_trace_row(ref, hs_stylus_trace_rows(ref) - 1)->t_s -
               hs_stylus_trace_row(ref, 0)->t_s);
    hs_stylus_trace_destroy(&ref);
    hs_stylus_trace_destroy(&run);
    return pass ? 0 : 1;
}
