// SPDX-License-Identifier: GPL-2.0-or-later
// hapsim-bench: shared helpers for the benchmark subcommands (one file per subcommand).
#ifndef HS_BENCH_H
#define HS_BENCH_H

#include <stddef.h>

typedef struct hs_bench_args {
    int quick;          ///< --quick: the small, fast subset
    const char* meshes; ///< --meshes DIR: directory with the shared meshes
} hs_bench_args;

/// Each subcommand prints CSV with a header to stdout and returns 0 on success.
int hs_bench_core(const hs_bench_args* a);
int hs_bench_accuracy(const hs_bench_args* a);
int hs_bench_stress(const hs_bench_args* a);
/// Locking-free options against CalculiX's converged solution, with their cost.
int hs_bench_lockfree(const hs_bench_args* a);
/// 1 kHz haptic loop with the condensed-compliance probe.
int hs_bench_haptic(const hs_bench_args* a);
/// The rt tick's contact solve with two tools in one problem (16 contact nodes each).
int hs_bench_tools(const hs_bench_args* a);
/// Cutting on the server's path: cut step, compliance valid again, tick jumps.
int hs_bench_cut(const hs_bench_args* a);
/// The server path (deformation + rt threads) on organ meshes against the static press reference.
int hs_bench_organs(const hs_bench_args* a);
/// hapsim-server round trip vs a bare LCM echo, in a private network namespace.
int hs_bench_protocol(const hs_bench_args* a);

/// Path of a mesh file: DIR/file (--meshes) when it can be read, else the copy bundled in
/// scenes/ (liver2, the skin patch), else DIR/file (whose load error then names it). Returns buf.
const char* hs_bench_mesh_path(const hs_bench_args* a, const char* file, char* buf, size_t size);

/// p-th percentile (0..100) of v[n] (sorts v in place).
double hs_bench_percentile(double* v, size_t n, double p);
struct timespec;
/// Advance t (CLOCK_MONOTONIC) by 1 ms and sleep until then: a 1 kHz pose feed.
void hs_bench_next_ms(struct timespec* t);
/// CPU time of the calling thread, ms (CLOCK_THREAD_CPUTIME_ID).
double hs_bench_thread_ms(void);
/// Peak resident set size of this process, MB.
double hs_bench_peak_rss_mb(void);

#endif
