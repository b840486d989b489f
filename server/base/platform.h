// SPDX-License-Identifier: GPL-2.0-or-later
// Process-wide platform set-up for the programs (hapsim-server, hapsim-solve, hapsim-bench, the
// timing tools): the BLAS kernel choice, which may re-execute the program, and the BLAS
// thread count. Libraries never call these: a program calls hs_platform_setup first thing in
// main, before any thread starts.
#ifndef HS_PLATFORM_H
#define HS_PLATFORM_H

#include "base.h"

/// The program's start: hs_platform_blas_select(argv), then hs_platform_set_threads(1) (the
/// BLAS's own threads spin-wait on every core, competing with the haptic thread; parallelism
/// comes from the server's own threads instead).
/// @param argv main's argv (NULL-terminated) | Thread: main, alone | Allocates: no
hs_status hs_platform_setup(char** argv);

/// Threads the BLAS uses, process-wide (OpenBLAS's openblas_set_num_threads), and CHOLMOD's
/// OpenMP loops on the calling thread (one thread when n == 1; the sparse layer keeps them at
/// one on every thread that factorises). HS_ERR_INVALID for n < 1; HS_ERR_UNSUPPORTED when
/// neither control exists in the loaded libraries.
hs_status hs_platform_set_threads(int n);

/// The BLAS kernel family in use, as OpenBLAS names it ("Haswell", "SkylakeX", "Prescott", ...),
/// or "not OpenBLAS" when the BLAS behind libblas.so.3 has no such query. Static text.
const char* hs_platform_blas_core(void);

/// OpenBLAS chooses its kernels when it loads, from the processor's model number. On a model it
/// does not know it falls back to its generic SSE3 kernels ("Prescott"): CHOLMOD's
/// factorisation and the cut step then take about 1.5x the time they take on its AVX2 kernels
/// (docs/benchmarks.md). If the kernels in use predate AVX2, OPENBLAS_CORETYPE is unset and the
/// processor has AVX2 and FMA, this re-executes the running program (/proc/self/exe, same argv
/// and environment) with OPENBLAS_CORETYPE=Haswell, after one line on stderr; it returns only
/// when nothing was to be done (HS_OK) or the exec failed (HS_ERR_UNSUPPORTED, the program runs
/// on). A set OPENBLAS_CORETYPE is the user's choice and is kept, which also stops a second
/// exec; so does -h or --help among the arguments.
/// @param argv main's argv (NULL-terminated) | Thread: main, alone | Allocates: no
hs_status hs_platform_blas_select(char** argv);

#endif
