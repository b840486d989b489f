// SPDX-License-Identifier: GPL-2.0-or-later
// hapsim-bench: benchmarks that print CSV. Targets live in docs/benchmarks.md, not in tests.
#define _POSIX_C_SOURCE 200809L
#include "hapsim/version.h"
#include "bench.h"
#include "platform.h"

#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/resource.h>
#include <time.h>
#include <unistd.h>

const char* hs_bench_mesh_path(const hs_bench_args* a, const char* file, char* buf, size_t size) {
    static const char* const bundled[] = {HS_SCENES_DIR "/liver", HS_SCENES_DIR "/skin"};
    for (size_t k = 0; k < sizeof bundled / sizeof bundled[0]; ++k) {
        snprintf(buf, size, "%s/%s", bundled[k], file);
        if (access(buf, R_OK) == 0) break;
    }
    char own[1024];
    snprintf(own, sizeof own, "%s/%s", a->meshes, file);
    if (access(own, R_OK) == 0 || access(buf, R_OK) != 0) snprintf(buf, size, "%s", own);
    return buf;
}

void hs_bench_next_ms(struct timespec* t) {
    t->tv_nsec += 1000000L;
    if (t->tv_nsec >= 1000000000L) t->tv_nsec -= 1000000000L, t->tv_sec++;
    clock_nanosleep(CLOCK_MONOTONIC, TIMER_ABSTIME, t, NULL);
}

double hs_bench_thread_ms(void) {
    struct timespec ts;
    clock_gettime(CLOCK_THREAD_CPUTIME_ID, &ts);
    return (double)ts.tv_sec * 1e3 + (double)ts.tv_nsec * 1e-6;
}

double hs_bench_peak_rss_mb(void) {
    struct rusage ru;
    getrusage(RUSAGE_SELF, &ru);
    return (double)ru.ru_maxrss / 1024.0;
}

static int cmp_double(const void* a, const void* b) {
    double x = *(const double*)a, y = *(const double*)b;
    return (x > y) - (x < y);
}

double hs_bench_percentile(double* v, size_t n, double p) {
    if (n == 0) return 0;
    qsort(v, n, sizeof *v, cmp_double);
    double pos = p / 100.0 * (double)(n - 1);
    size_t i = (size_t)pos;
    if (i + 1 >= n) return v[n - 1];
    double f = pos - (double)i;
    return v[i] * (1 - f) + v[i + 1] * f;
}

typedef struct bench_cmd {
    const char* name;
    int (*fn)(const hs_bench_args*);
    const char* what;
} bench_cmd;

static int bench_blas(const hs_bench_args* a) {
    (void)a;
    printf("blas_core\n%s\n", hs_platform_blas_core());
    return 0;
}

static const bench_cmd cmds[] = {
    {"blas", bench_blas, "the BLAS kernels in use (hs_platform_blas_select may have chosen them)"},
    {"core", hs_bench_core, "FEM step cost per model and mesh"},
    {"accuracy", hs_bench_accuracy, "run time against error per model, solver, dt"},
    {"lockfree", hs_bench_lockfree, "locking-free options vs CalculiX's converged solution"},
    {"stress", hs_bench_stress, "numerical stress cases: NaN, energy, inversion"},
    {"haptic", hs_bench_haptic, "1 kHz loop with the compliance probe vs a bare loop"},
    {"organs", hs_bench_organs, "server path on organ meshes: force at depth vs the static press"},
#ifdef HS_BENCH_HAVE_CUT
    {"cut", hs_bench_cut, "the server's cutting path: cut step and compliance valid again"},
#endif
#ifdef HS_BENCH_HAVE_PROTOCOL
    {"protocol", hs_bench_protocol, "pose -> force round trip via hapsim-server vs bare LCM"},
#endif
};

static void usage(FILE* f) {
    fprintf(f, "usage: hapsim-bench [--quick] [--meshes DIR] <command>|all\n\ncommands:\n");
    for (size_t i = 0; i < sizeof cmds / sizeof cmds[0]; ++i)
        fprintf(f, "  %-10s %s\n", cmds[i].name, cmds[i].what);
    fprintf(f, "\nOptions may come before or after the command.\n"
               "Each prints CSV with a header on stdout; progress goes to stderr.\n"
               "Run on an otherwise idle machine; compare ratios measured in one run.\n"
               "--meshes DIR holds the organ meshes (default: the shared meshes beside the\n"
               "source tree); a mesh not there is taken from scenes/ when bundled (liver2,\n"
               "the skin patch), and a case whose mesh is missing fails with its path.\n"
               "Exit status: 0 done, 1 a case failed, 2 bad usage.\n");
}

int main(int argc, char** argv) {
    if (hapsim_version_asked(argc, argv, "hapsim-bench")) return 0;
    hs_platform_setup(argv); // before any thread: it may re-execute the program
    hs_bench_args a = {0, HS_SHARED_MESHES};
    const char* cmd = NULL; // options may come before or after it
    for (int i = 1; i < argc; ++i) {
        if (!strcmp(argv[i], "-h") || !strcmp(argv[i], "--help")) {
            usage(stdout);
            return 0;
        }
        if (!strcmp(argv[i], "--quick")) {
            a.quick = 1;
        } else if (!strcmp(argv[i], "--meshes")) {
            if (i + 1 >= argc) {
                fprintf(stderr, "hapsim-bench: missing value for --meshes\n");
                return 2;
            }
            a.meshes = argv[++i];
        } else if (argv[i][0] == '-') {
            fprintf(stderr, "hapsim-bench: unknown option '%s'\n", argv[i]);
            return 2;
        } else if (cmd) {
            fprintf(stderr, "hapsim-bench: one command only (got '%s' and '%s')\n", cmd, argv[i]);
            return 2;
        } else {
            cmd = argv[i];
        }
    }
    if (!cmd) {
        usage(stderr);
        return 2;
    }
    int all = !strcmp(cmd, "all"), found = 0, rc = 0;
    if (strcmp(cmd, "blas"))
        fprintf(stderr, "hapsim-bench: BLAS kernels %s\n", hs_platform_blas_core());
    for (size_t i = 0; i < sizeof cmds / sizeof cmds[0]; ++i) {
        if (!all && strcmp(cmd, cmds[i].name)) continue;
        if (all && cmds[i].fn == bench_blas) continue;
        found = 1;
        if (all) printf("# %s\n", cmds[i].name);
        fflush(stdout);
        if (cmds[i].fn(&a) != 0) rc = 1;
    }
    if (!found) {
        fprintf(stderr, "hapsim-bench: unknown command '%s'\n", cmd);
        usage(stderr);
        return 2;
    }
    return rc;
}
