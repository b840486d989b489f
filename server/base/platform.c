// SPDX-License-Identifier: GPL-2.0-or-later
// Platform set-up for the programs: BLAS kernels and threads. Looked up at run time: the BLAS
// behind libblas.so.3 is chosen by the system (Debian alternatives), only OpenBLAS has these
// entry points, and libgomp comes with CHOLMOD.
#define _GNU_SOURCE // RTLD_DEFAULT
#include "platform.h"

#include <dlfcn.h>
#include <errno.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

hs_status hs_platform_set_threads(int n) {
    if (n < 1) return HS_ERR_INVALID;
    void (*set_blas)(int);
    *(void**)&set_blas = dlsym(RTLD_DEFAULT, "openblas_set_num_threads");
    void (*set_levels)(int);
    *(void**)&set_levels = dlsym(RTLD_DEFAULT, "omp_set_max_active_levels");
    if (set_blas) set_blas(n);
    // CHOLMOD's loops say num_threads(4), which overrides omp_set_num_threads; zero active
    // levels makes every parallel region a team of one (libgomp keeps it per thread).
    if (set_levels) set_levels(n == 1 ? 0 : 1);
    return set_blas || set_levels ? HS_OK : HS_ERR_UNSUPPORTED;
}

const char* hs_platform_blas_core(void) {
    const char* (*core)(void);
    *(void**)&core = dlsym(RTLD_DEFAULT, "openblas_get_corename");
    const char* name = core ? core() : NULL;
    return name ? name : "not OpenBLAS";
}

// OpenBLAS's kernel sets that predate AVX2 (its fallback for an unknown model is one of them);
// on an AVX2 processor any of them means the detection failed.
static int predates_avx2(const char* core) {
    static const char* const generic[] = {
        "Katmai",      "Coppermine", "Northwood", "Prescott",     "Banias",
        "Atom",        "Core2",      "Penryn",    "Dunnington",   "Nehalem",
        "Sandybridge", "Athlon",     "Opteron",   "Opteron_SSE3", "Barcelona",
        "Nano",        "Bobcat",     "Bulldozer", "Piledriver",   "Steamroller"};
    for (size_t i = 0; i < sizeof generic / sizeof generic[0]; ++i)
        if (!strcmp(core, generic[i])) return 1;
    return 0;
}

hs_status hs_platform_blas_select(char** argv) {
    if (!argv || !argv[0] || getenv("OPENBLAS_CORETYPE")) return HS_OK;
    for (char** a = argv + 1; *a; ++a) // a program asked for its usage computes nothing
        if (!strcmp(*a, "-h") || !strcmp(*a, "--help")) return HS_OK;
    const char* core = hs_platform_blas_core();
    __builtin_cpu_init();
    if (!predates_avx2(core) || !__builtin_cpu_supports("avx2") || !__builtin_cpu_supports("fma"))
        return HS_OK;
    fprintf(stderr,
            "%s: OpenBLAS runs its %s kernels, older than this AVX2 processor; restarting with "
            "OPENBLAS_CORETYPE=Haswell (set OPENBLAS_CORETYPE to choose otherwise)\n",
            argv[0], core);
    fflush(NULL);
    if (setenv("OPENBLAS_CORETYPE", "Haswell", 1) != 0) return HS_ERR_UNSUPPORTED;
    execv("/proc/self/exe", argv);
    unsetenv("OPENBLAS_CORETYPE"); // the exec failed: run on as loaded, and say so
    fprintf(stderr, "%s: could not restart (%s); running on the %s kernels\n", argv[0],
            strerror(errno), core);
    return HS_ERR_UNSUPPORTED;
}

hs_status hs_platform_setup(char** argv) {
    hs_status st = hs_platform_blas_select(argv);
    hs_status threads = hs_platform_set_threads(1);
    return st != HS_OK ? st : threads;
}
