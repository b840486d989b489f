// SPDX-License-Identifier: GPL-2.0-or-later
// Sparse Cholesky on CHOLMOD: analysis once, numeric refactorisation into a spare factor (the
// last good factor survives a non-SPD matrix), allocation-free solves, and low-rank
// update/downdate for cutting. The only file that includes cholmod.h.
//
// Memory: CHOLMOD allocates through SuiteSparse_config, which is pointed (once, process-wide)
// at hs_alloc/hs_calloc/hs_realloc/hs_free, so CHOLMOD's memory is in hs_byte_count and fault
// injection reaches it. METIS, when CHOLMOD tries it, uses its own malloc during analysis only.
#define _GNU_SOURCE // RTLD_DEFAULT
#include "sparse.h"

#include <cholmod.h>
#include <dlfcn.h>
#include <math.h>
#include <stdatomic.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/mman.h>

struct hs_cholesky {
    cholmod_common c;            // one context per object; objects are single-threaded
    cholmod_factor* L;           // current good factor
    cholmod_factor* spare;       // refactor target, swapped with L on success (same symbolic)
    cholmod_sparse a;            // header over the caller's hs_csc arrays (stype 1: upper used)
    int natural;                 // A is pre-ordered: natural ordering, lower triangle read in place
    cholmod_dense b;             // header over the caller's right-hand side
    cholmod_dense *x1, *y1, *e1; // solve workspaces, k = 1
    cholmod_dense *xk, *yk, *ek; // solve_many workspaces, last k
    double* work; // [8n] permuted right-hand sides and block scratch for simplicial solves
    int blocked;  // simplicial L still has the spare's supernodal layout (fast solve)
    int n, nnz;
    int* colp;          // [n+1] copy of the pattern's column starts (cheap same-pattern check)
    uint64_t rowi_hash; // hash of the pattern's row indices
    int broken;         // a downdate made L indefinite; solves refuse until a refactor succeeds
    // Update mode (simplicial LDL^T).
    int updatable;
    int* pinv;        // [n] inverse fill-reducing permutation: row of dof d in L is pinv[d]
    double* d0;       // [n] D of the last full factorisation (singularity test after downdates)
    int cap_cols;     // capacity of each C buffer in columns
    int cap_nnz;      // and in entries
    int *cp_p, *ci_p; // update columns: colp [cap_cols+1], rowi [cap_nnz]
    double* cx_p;
    int *cp_m, *ci_m; // downdate columns
    double* cx_m;
    // Aggregated element updates: the step's summed change over the union of its dofs.
    int aggregate; // 1 (default): one L-ordered LDL^T of the summed change; 0: per element
    int cap_d;     // order of the dense workspace
    int* dpos;     // [n] position of a dof in the union, -1 outside
    int* dlist;    // [cap_d] union dofs, then their rows in L
    double* dense; // [cap_d^2] summed change, then its LDL^T (lower triangle)
    struct hs_partial* part;      // partial refactorisation data (hs_cholesky_prepare_partial)
    hs_parallel par;              // its parallelism (hs_cholesky_set_partial_parallel)
    hs_cholesky_update_info last; // of the last update_elements / update_parts
};

// ---------------------------------------------------------------------------------------------
// CHOLMOD set-up: allocator hooks (once) and a quiet error handler.

static atomic_int g_alloc_state; // 0 untouched, 1 installing, 2 installed

// CHOLMOD's OpenMP loops say num_threads(4), which would start teams of threads on every call.
// The sparse layer starts no thread (parallelism comes from the caller through hs_parallel), so
// each thread that calls CHOLMOD sets its own max-active-levels to zero on entry: libgomp keeps
// that per thread, so it touches no other thread. BLAS threads are the program's choice
// (hs_platform_set_threads in server/base/platform.h).
static _Thread_local int tl_serial = 0; // this thread's OpenMP loops are teams of one

static void apply_thread_limit(void) {
    if (tl_serial) return;
    tl_serial = 1;
    void (*set_levels)(int);
    *(void**)&set_levels = dlsym(RTLD_DEFAULT, "omp_set_max_active_levels");
    if (set_levels) set_levels(0);
}

// CHOLMOD's supernodal numeric factorisation allocates and frees a dense scratch block (and
// its header) on every call. A few cached freed blocks, reused for requests of the same size,
// keep refactorisations free of allocator calls once warm. Lock-free: a block is owned by
// whoever swapped it out of its slot. hs_cholesky_destroy empties the cache.
#define HS_BLOCK_CACHE 4
static _Atomic(void*) g_block_cache[HS_BLOCK_CACHE];
static atomic_uint g_block_victim;

static void* cached_malloc(size_t n) {
    for (int i = 0; i < HS_BLOCK_CACHE; ++i) {
        void* p = atomic_exchange(&g_block_cache[i], NULL);
        if (!p) continue;
        if (hs_alloc_size(p) == n) return p;
        void* empty = NULL;
        if (!atomic_compare_exchange_strong(&g_block_cache[i], &empty, p)) hs_free(p);
    }
    return hs_alloc(n);
}

static void cached_free(void* p) {
    if (!p) return;
    for (int i = 0; i < HS_BLOCK_CACHE; ++i) {
        void* empty = NULL;
        if (atomic_compare_exchange_strong(&g_block_cache[i], &empty, p)) return;
    }
    unsigned v = atomic_fetch_add(&g_block_victim, 1) % HS_BLOCK_CACHE;
    hs_free(atomic_exchange(&g_block_cache[v], p));
}

static void flush_block_cache(void) {
    for (int i = 0; i < HS_BLOCK_CACHE; ++i) hs_free(atomic_exchange(&g_block_cache[i], NULL));
}

static void install_allocator(void) {
    int expected = 0;
    if (atomic_compare_exchange_strong(&g_alloc_state, &expected, 1)) {
        SuiteSparse_config.malloc_func = cached_malloc;
        SuiteSparse_config.calloc_func = hs_calloc;
        SuiteSparse_config.realloc_func = hs_realloc;
        SuiteSparse_config.free_func = cached_free;
        atomic_store(&g_alloc_state, 2);
        return;
    }
    // Another thread is installing: CHOLMOD must not allocate before the hooks are in place,
    // or hs_free would later receive a libc block.
    while (atomic_load(&g_alloc_state) != 2) {
    }
}

// CHOLMOD's handler has no user pointer; objects are single-threaded, so per-thread is exact.
static _Thread_local struct {
    int status;
    int line;
    const char* file;
    const char* msg; // CHOLMOD passes string literals
} tl_last;

static void on_cholmod_error(int status, const char* file, int line, const char* message) {
    tl_last.status = status;
    tl_last.file = file;
    tl_last.line = line;
    tl_last.msg = message;
}

static hs_status map_status(int s) {
    switch (s) {
    case CHOLMOD_OK:
        return HS_OK;
    case CHOLMOD_OUT_OF_MEMORY:
        return HS_ERR_NOMEM;
    case CHOLMOD_TOO_LARGE:
        return HS_ERR_UNSUPPORTED;
    case CHOLMOD_INVALID:
        return HS_ERR_INVALID;
    case CHOLMOD_NOT_POSDEF:
        return HS_ERR_NOT_POSDEF;
    default:
        // Remaining warnings (tiny diagonal) leave a usable factor; other errors are internal.
        return s > 0 ? HS_OK : HS_ERR_NUMERIC;
    }
}

// ---------------------------------------------------------------------------------------------

static void set_matrix_view(hs_cholesky* f, const hs_csc* m, const cholmod_factor* target) {
    cholmod_sparse* a = &f->a;
    memset(a, 0, sizeof *a);
    a->nrow = (size_t)m->n;
    a->ncol = (size_t)m->n;
    a->nzmax = (size_t)m->nnz;
    // CHOLMOD's API is not const-qualified; factorize only reads A.
    a->p = (void*)(uintptr_t)m->colp;
    a->i = (void*)(uintptr_t)m->rowi;
    a->x = (void*)(uintptr_t)m->val;
    // The full pattern is stored; CHOLMOD reads one triangle. With the natural ordering it
    // factorises A in place when given the lower triangle for a supernodal factor, or the
    // upper one for a simplicial factor; every other combination makes a permuted transpose
    // (an allocation) per factorisation.
    a->stype = f->natural && target && target->is_super ? -1 : 1;
    a->itype = CHOLMOD_INT;
    a->xtype = CHOLMOD_REAL;
    a->dtype = CHOLMOD_DOUBLE;
    a->sorted = 1;
    a->packed = 1;
}

// Diagonal of L (LL^T) or D (LDL^T): HS_ERR_NUMERIC if an entry is not finite (NaN/Inf in
// the matrix), else HS_ERR_NOT_POSDEF if one is not positive (a simplicial LDL^T takes
// negative pivots where LL^T stops), else HS_OK. O(n).
static hs_status factor_diag_status(const cholmod_factor* L) {
    const double* x = L->x;
    int neg = 0;
    if (L->is_super) {
        const int* super = L->super;
        const int* pi = L->pi;
        const int* px = L->px;
        for (size_t s = 0; s < L->nsuper; s++) {
            int k1 = super[s], k2 = super[s + 1];
            int nsrow = pi[s + 1] - pi[s];
            for (int j = 0; j < k2 - k1; j++) {
                double d = x[px[s] + (size_t)j * (size_t)nsrow + (size_t)j];
                if (!isfinite(d)) return HS_ERR_NUMERIC;
                neg |= !(d > 0.0);
            }
        }
    } else {
        const int* p = L->p;
        for (size_t j = 0; j < L->n; j++) {
            double d = x[p[j]];
            if (!isfinite(d)) return HS_ERR_NUMERIC;
            neg |= !(d > 0.0);
        }
    }
    return neg ? HS_ERR_NOT_POSDEF : HS_OK;
}

// FNV-1a over the row indices: a pattern with the same column counts but other rows would
// otherwise be factorised silently with the old analysis.
static uint64_t hash_rows(const hs_csc* a) {
    uint64_t h = 1469598103934665603ull;
    for (int p = 0; p < a->nnz; p++) h = (h ^ (uint32_t)a->rowi[p]) * 1099511628211ull;
    return h;
}

// Same pattern as at create? The row hash costs O(nnz), under 1 % of a refactor in 3D; a
// pointer comparison would not do, since a freed and rebuilt pattern may reuse the address.
static int pattern_matches(const hs_cholesky* f, const hs_csc* a) {
    return a && a->n == f->n && a->nnz == f->nnz &&
           memcmp(a->colp, f->colp, sizeof(int) * ((size_t)f->n + 1)) == 0 &&
           hash_rows(a) == f->rowi_hash;
}

static hs_status check_csc(const hs_csc* a, hs_err* err) {
    if (!a) return hs_err_set(err, HS_ERR_INVALID, "%s:%d: matrix is NULL", __FILE__, __LINE__);
    if (a->n < 0 || a->nnz < 0 || !a->colp || (a->nnz > 0 && (!a->rowi || !a->val)))
        return hs_err_set(err, HS_ERR_INVALID, "%s:%d: malformed hs_csc (n %d, nnz %d)", __FILE__,
                          __LINE__, a->n, a->nnz);
    if (a->colp[0] != 0 || a->colp[a->n] != a->nnz)
        return hs_err_set(err, HS_ERR_INVALID, "%s:%d: colp[0] = %d, colp[n] = %d, nnz = %d",
                          __FILE__, __LINE__, a->colp[0], a->colp[a->n], a->nnz);
    for (int j = 0; j < a->n; j++) {
        int has_diag = 0;
        for (int p = a->colp[j]; p < a->colp[j + 1]; p++) {
            int r = a->rowi[p];
            if (r < 0 || r >= a->n || (p > a->colp[j] && r <= a->rowi[p - 1]))
                return hs_err_set(err, HS_ERR_INVALID,
                                  "%s:%d: column %d: row index %d out of range or not ascending",
                                  __FILE__, __LINE__, j, r);
            has_diag |= r == j;
        }
        if (!has_diag)
            return hs_err_set(err, HS_ERR_INVALID, "%s:%d: column %d has no diagonal entry",
                              __FILE__, __LINE__, j);
    }
    return HS_OK;
}

static hs_status fail_from_cholmod(hs_cholesky* f, hs_err* err, const char* what) {
    hs_status st = map_status(f->c.status);
    if (st == HS_OK) st = HS_ERR_NUMERIC;
    return hs_err_set(err, st, "%s:%d: %s failed: CHOLMOD status %d (%s:%d: %s)", __FILE__,
                      __LINE__, what, f->c.status, tl_last.file ? tl_last.file : "?", tl_last.line,
                      tl_last.msg ? tl_last.msg : "no message");
}

// Transparent huge pages for a large block not yet touched: its first touch then takes one
// fault per 2 MB instead of per 4 KB (page faults were ~40 % of building a window's factor at
// 5,043 vertices). Advice only: without THP nothing changes.
static void advise_huge(void* p, size_t bytes) {
#ifdef MADV_HUGEPAGE
    const uintptr_t huge = (uintptr_t)2 << 20;
    uintptr_t b = ((uintptr_t)p + huge - 1) & ~(huge - 1), e = ((uintptr_t)p + bytes) & ~(huge - 1);
    if (bytes >= 4 * huge && e > b) (void)madvise((void*)b, e - b, MADV_HUGEPAGE);
#else
    (void)p;
    (void)bytes;
#endif
}

// The spare factor is made on first need: a partial-refactor factor may never refactor in full.
static int ensure_spare(hs_cholesky* f) {
    if (!f->spare) f->spare = cholmod_copy_factor(f->L, &f->c);
    return f->spare != NULL;
}

static hs_status create_factor(const hs_csc* a, int natural, hs_cholesky** out, hs_err* err) {
    if (!out) return hs_err_set(err, HS_ERR_INVALID, "%s:%d: out is NULL", __FILE__, __LINE__);
    *out = NULL;
    hs_status st = check_csc(a, err);
    if (st != HS_OK) return st;
    install_allocator();
    apply_thread_limit();

    hs_cholesky* f = hs_calloc(1, sizeof *f);
    if (!f) return hs_err_set(err, HS_ERR_NOMEM, "%s:%d: out of memory", __FILE__, __LINE__);
    cholmod_start(&f->c);
    f->c.print = 0;
    f->c.error_handler = on_cholmod_error;
    // The spare factor is thrown away on failure, so stop at the first bad pivot.
    f->c.quick_return_if_not_posdef = 1;
    f->natural = natural;
    if (natural) {
        f->c.nmethods = 1;
        f->c.method[0].ordering = CHOLMOD_NATURAL;
        f->c.postorder = 0; // a postorder would permute again (and copy A per factorisation)
    }
    f->n = a->n;
    f->nnz = a->nnz;
    tl_last.msg = NULL;

    f->colp = hs_alloc(sizeof(int) * ((size_t)a->n + 1));
    if (!f->colp) {
        st = hs_err_set(err, HS_ERR_NOMEM, "%s:%d: out of memory", __FILE__, __LINE__);
        goto fail;
    }
    memcpy(f->colp, a->colp, sizeof(int) * ((size_t)a->n + 1));
    f->rowi_hash = hash_rows(a);
    f->work = hs_alloc(sizeof(double) * (8 * (size_t)a->n + 1));
    if (!f->work) {
        st = hs_err_set(err, HS_ERR_NOMEM, "%s:%d: out of memory", __FILE__, __LINE__);
        goto fail;
    }
    set_matrix_view(f, a, NULL);

    f->L = cholmod_analyze(&f->a, &f->c);
    if (!f->L) {
        st = fail_from_cholmod(f, err, "symbolic analysis");
        goto fail;
    }
    set_matrix_view(f, a, f->L);
    cholmod_factorize(&f->a, f->L, &f->c);
    if (f->c.status == CHOLMOD_NOT_POSDEF) {
        st = hs_err_set(err, HS_ERR_NOT_POSDEF,
                        "%s:%d: matrix (n %d) is not positive definite (pivot %zu of the "
                        "permuted matrix)",
                        __FILE__, __LINE__, a->n, f->L->minor);
        goto fail;
    }
    if (map_status(f->c.status) != HS_OK) {
        st = fail_from_cholmod(f, err, "numeric factorisation");
        goto fail;
    }
    st = factor_diag_status(f->L);
    if (st == HS_ERR_NOT_POSDEF) {
        st = hs_err_set(err, HS_ERR_NOT_POSDEF,
                        "%s:%d: matrix (n %d) is not positive definite (a pivot <= 0)", __FILE__,
                        __LINE__, a->n);
        goto fail;
    }
    if (st != HS_OK) {
        st = hs_err_set(err, HS_ERR_NUMERIC,
                        "%s:%d: factor has a non-finite diagonal (NaN/Inf "
                        "in the matrix?)",
                        __FILE__, __LINE__);
        goto fail;
    }
    // Double buffering costs one more factor of memory but no copy per refactor.
    if (!ensure_spare(f)) {
        st = fail_from_cholmod(f, err, "copying the factor");
        goto fail;
    }
    f->b.nrow = (size_t)a->n;
    f->b.ncol = 1;
    f->b.nzmax = (size_t)a->n;
    f->b.d = (size_t)a->n;
    f->b.xtype = CHOLMOD_REAL;
    f->b.dtype = CHOLMOD_DOUBLE;
    f->aggregate = 1;
    *out = f;
    return HS_OK;

fail:
    hs_cholesky_destroy(&f);
    return st;
}

hs_status hs_cholesky_create(const hs_csc* a, hs_cholesky** out, hs_err* err) {
    return create_factor(a, 0, out, err);
}

hs_status hs_cholesky_create_natural(const hs_csc* a, hs_cholesky** out, hs_err* err) {
    return create_factor(a, 1, out, err);
}

hs_status hs_cholesky_fill_order(const hs_csc* a, int* perm, hs_err* err) {
    hs_status st = check_csc(a, err);
    if (st != HS_OK) return st;
    if (!perm) return hs_err_set(err, HS_ERR_INVALID, "%s:%d: perm is NULL", __FILE__, __LINE__);
    install_allocator();
    cholmod_common c;
    cholmod_start(&c);
    c.print = 0;
    c.error_handler = on_cholmod_error;
    cholmod_sparse v;
    memset(&v, 0, sizeof v);
    v.nrow = v.ncol = (size_t)a->n;
    v.nzmax = (size_t)a->nnz;
    v.p = (void*)(uintptr_t)a->colp;
    v.i = (void*)(uintptr_t)a->rowi;
    v.stype = 1;
    v.itype = CHOLMOD_INT;
    v.xtype = CHOLMOD_PATTERN;
    v.dtype = CHOLMOD_DOUBLE;
    v.sorted = 1;
    v.packed = 1;
    cholmod_factor* L = cholmod_analyze(&v, &c);
    if (!L) {
        int s = c.status;
        cholmod_finish(&c);
        return hs_err_set(err, s == CHOLMOD_OUT_OF_MEMORY ? HS_ERR_NOMEM : HS_ERR_INVALID,
                          "%s:%d: ordering failed: CHOLMOD status %d", __FILE__, __LINE__, s);
    }
    memcpy(perm, L->Perm, sizeof(int) * (size_t)a->n);
    cholmod_free_factor(&L, &c);
    cholmod_finish(&c);
    flush_block_cache();
    return HS_OK;
}

// Does the simplicial LDL^T factor L keep the column layout of the supernodal S it was
// converted from (change_factor with to_packed = 0)? Then L->x holds S's dense column-major
// blocks (upper parts unused) and the solve can run per supernode. O(n).
static int ldl_has_super_layout(const cholmod_factor* S, const cholmod_factor* L) {
    if (!S || !S->is_super || L->is_super || L->is_ll || L->n != S->n) return 0;
    const int *super = S->super, *pi = S->pi, *px = S->px, *lp = L->p, *lnz = L->nz;
    for (size_t s = 0; s < S->nsuper; s++) {
        int nsrow = pi[s + 1] - pi[s];
        for (int j = super[s]; j < super[s + 1]; j++) {
            int jj = j - super[s];
            if (lp[j] != px[s] + jj * nsrow + jj || lnz[j] != nsrow - jj) return 0;
        }
    }
    return 1;
}

// Pour a supernodal LL^T factor S into a simplicial LDL^T factor L of the same pattern (the
// layout change_factor produced from an S of the same analysis): D(j) = S(j,j)^2 and
// L(i,j) = S(i,j) / S(j,j). With fill = 0 only checks that the patterns agree. O(nnz(L)).
static int super_to_ldl(const cholmod_factor* S, cholmod_factor* L, int fill) {
    if (L->is_super || L->is_ll || L->n != S->n || L->xtype != CHOLMOD_REAL) return 0;
    const int *super = S->super, *pi = S->pi, *px = S->px, *ls = S->s;
    const int *lp = L->p, *li = L->i, *lnz = L->nz;
    const double* sx = S->x;
    double* lx = L->x;
    for (size_t s = 0; s < S->nsuper; s++) {
        int k1 = super[s], nsrow = pi[s + 1] - pi[s];
        const int* rows = ls + pi[s];
        for (int j = k1; j < super[s + 1]; j++) {
            int jj = j - k1, len = nsrow - jj, p = lp[j];
            const double* col = sx + px[s] + (size_t)jj * (size_t)nsrow + (size_t)jj;
            if (!fill) {
                if (lnz[j] != len) return 0;
                for (int q = 0; q < len; q++)
                    if (li[p + q] != rows[jj + q]) return 0;
                continue;
            }
            double d = col[0], dinv = 1.0 / d;
            lx[p] = d * d;
            for (int q = 1; q < len; q++) lx[p + q] = col[q] * dinv;
        }
    }
    return 1;
}

// Update mode: remember D after a full factorisation. A downdate that leaves a part of the
// structure without support (a fragment cut free of every fixed node) makes A singular, which
// in floating point shows as a pivot collapsing to round-off rather than turning negative.
static void save_pivots(hs_cholesky* f) {
    const int* lp = f->L->p;
    const double* lx = f->L->x;
    for (int j = 0; j < f->n; j++) f->d0[j] = lx[lp[j]];
}

// 0 if a pivot of the LDL^T factor is not positive or fell below 1e-10 of its value at the last
// full factorisation (no physical stiffness change in one cut is that large). O(n).
static int pivots_ok(const hs_cholesky* f) {
    const int* lp = f->L->p;
    const double* lx = f->L->x;
    for (int j = 0; j < f->n; j++) {
        double d = lx[lp[j]];
        if (!(d > 1e-10 * f->d0[j] && d < INFINITY)) return 0;
    }
    return 1;
}

static void invalidate_partial(hs_cholesky* f);

hs_status hs_cholesky_refactor(hs_cholesky* f, const hs_csc* a) {
    if (!f || !pattern_matches(f, a)) return HS_ERR_INVALID;
    if (!ensure_spare(f)) return HS_ERR_NOMEM;
    apply_thread_limit();
    set_matrix_view(f, a, f->spare);
    cholmod_factorize(&f->a, f->spare, &f->c);
    hs_status st = map_status(f->c.status);
    if (st != HS_OK) return st;
    st = factor_diag_status(f->spare);
    if (st != HS_OK) return st;
    if (f->updatable && f->spare->is_super) {
        // Update mode keeps the spare supernodal: CHOLMOD's simplicial refactor is 5-10x
        // slower on 3D meshes than a supernodal one plus this O(nnz(L)) copy.
        // A kept layout (blocked) implies the rows still match: checked when it was set up.
        if (f->blocked || super_to_ldl(f->spare, f->L, 0)) {
            super_to_ldl(f->spare, f->L, 1);
        } else {
            // L's pattern grew in a general update: rebuild it (allocates; L kept on failure).
            cholmod_factor* t = cholmod_copy_factor(f->spare, &f->c);
            if (!t || !cholmod_change_factor(CHOLMOD_REAL, 0, 0, 0, 0, t, &f->c)) {
                cholmod_free_factor(&t, &f->c);
                return HS_ERR_NOMEM;
            }
            cholmod_free_factor(&f->L, &f->c);
            f->L = t;
        }
    } else {
        cholmod_factor* t = f->L;
        f->L = f->spare;
        f->spare = t;
    }
    f->broken = 0;
    invalidate_partial(f); // its update matrices belong to the old numbers
    f->blocked = f->updatable && ldl_has_super_layout(f->spare, f->L);
    if (f->updatable) save_pivots(f);
    return HS_OK;
}

// Simplicial LL^T or LDL^T solve of one column. cholmod_solve2's simplicial path shrinks its Y
// workspace header to the block it last used and so reallocates on every call; this loop is
// the same arithmetic without that. Columns may be unpacked (nz) and in any order (next).
static void simplicial_solve(const cholmod_factor* L, double* y, const double* b, double* x) {
    const int n = (int)L->n;
    const int *perm = L->Perm, *lp = L->p, *li = L->i, *lnz = L->nz;
    const double* lx = L->x;
    const int ll = L->is_ll;
    for (int k = 0; k < n; k++) y[k] = b[perm[k]];
    for (int j = 0; j < n; j++) { // L y = P b
        int p = lp[j], e = p + lnz[j];
        double yj = ll ? y[j] / lx[p] : y[j];
        y[j] = yj;
        for (p++; p < e; p++) y[li[p]] -= lx[p] * yj;
    }
    if (!ll)
        for (int j = 0; j < n; j++) y[j] /= lx[lp[j]]; // D
    for (int j = n - 1; j >= 0; j--) {                 // L^T z = y
        int p = lp[j], e = p + lnz[j];
        double s = y[j];
        for (int q = p + 1; q < e; q++) s -= lx[q] * y[li[q]];
        y[j] = ll ? s / lx[p] : s;
    }
    for (int k = 0; k < n; k++) x[perm[k]] = y[k];
}

// t[q] += sum_jj B[q, jj] y[jj] for q in [r0, r1), B column-major with leading dimension ld.
// Four columns per pass: one load/store of t per four multiply-adds.
static void gemv_n(int r0, int r1, int nc, const double* b, size_t ld, const double* y, double* t) {
    int jj = 0;
    for (; jj + 4 <= nc; jj += 4) {
        const double *c0 = b + jj * ld, *c1 = c0 + ld, *c2 = c1 + ld, *c3 = c2 + ld;
        double y0 = y[jj], y1 = y[jj + 1], y2 = y[jj + 2], y3 = y[jj + 3];
        for (int q = r0; q < r1; q++) t[q] += c0[q] * y0 + c1[q] * y1 + c2[q] * y2 + c3[q] * y3;
    }
    for (; jj < nc; jj++) {
        const double* c0 = b + jj * ld;
        for (int q = r0; q < r1; q++) t[q] += c0[q] * y[jj];
    }
}

// y[jj] -= sum_q B[q, jj] t[q] for q in [r0, r1): four independent sums per pass.
static void gemv_t(int r0, int r1, int nc, const double* b, size_t ld, const double* t, double* y) {
    int jj = 0;
    for (; jj + 4 <= nc; jj += 4) {
        const double *c0 = b + jj * ld, *c1 = c0 + ld, *c2 = c1 + ld, *c3 = c2 + ld;
        double a0 = 0, a1 = 0, a2 = 0, a3 = 0;
        for (int q = r0; q < r1; q++) {
            double tq = t[q];
            a0 += c0[q] * tq;
            a1 += c1[q] * tq;
            a2 += c2[q] * tq;
            a3 += c3[q] * tq;
        }
        y[jj] -= a0;
        y[jj + 1] -= a1;
        y[jj + 2] -= a2;
        y[jj + 3] -= a3;
    }
    for (; jj < nc; jj++) {
        const double* c0 = b + jj * ld;
        double a0 = 0;
        for (int q = r0; q < r1; q++) a0 += c0[q] * t[q];
        y[jj] -= a0;
    }
}

// LDL^T solve of one column over the supernodes of S, values from L (unit lower, D on the
// diagonal). The rectangular part of each supernode is a dense matrix-vector product on
// contiguous memory, its rows gathered/scattered once. y[n] and t[n] are scratch.
static void blocked_ldl_solve(const cholmod_factor* S, const cholmod_factor* L, double* y,
                              double* t, const double* b, double* x) {
    const int n = (int)L->n;
    const int *perm = L->Perm, *super = S->super, *pi = S->pi, *px = S->px, *ls = S->s;
    const double* lx = L->x;
    const int ns = (int)S->nsuper;
    for (int k = 0; k < n; k++) y[k] = b[perm[k]];
    for (int s = 0; s < ns; s++) { // L y = P b
        const int k1 = super[s], nscol = super[s + 1] - k1, nsrow = pi[s + 1] - pi[s];
        const int* rows = ls + pi[s];
        const double* blk = lx + px[s];
        double* yb = y + k1;
        for (int jj = 0; jj < nscol; jj++) {
            const double* col = blk + (size_t)jj * (size_t)nsrow;
            for (int q = jj + 1; q < nscol; q++) yb[q] -= col[q] * yb[jj];
        }
        for (int q = nscol; q < nsrow; q++) t[q] = 0.0;
        gemv_n(nscol, nsrow, nscol, blk, (size_t)nsrow, yb, t);
        for (int q = nscol; q < nsrow; q++) y[rows[q]] -= t[q];
    }
    for (int s = 0; s < ns; s++) { // D
        const int k1 = super[s], nsrow = pi[s + 1] - pi[s];
        const double* blk = lx + px[s];
        for (int jj = 0; jj < super[s + 1] - k1; jj++)
            y[k1 + jj] /= blk[(size_t)jj * (size_t)nsrow + (size_t)jj];
    }
    for (int s = ns - 1; s >= 0; s--) { // L^T z = y
        const int k1 = super[s], nscol = super[s + 1] - k1, nsrow = pi[s + 1] - pi[s];
        const int* rows = ls + pi[s];
        const double* blk = lx + px[s];
        double* yb = y + k1;
        for (int q = nscol; q < nsrow; q++) t[q] = y[rows[q]];
        gemv_t(nscol, nsrow, nscol, blk, (size_t)nsrow, t, yb);
        for (int jj = nscol - 1; jj >= 0; jj--) {
            const double* col = blk + (size_t)jj * (size_t)nsrow;
            double acc = yb[jj];
            for (int q = jj + 1; q < nscol; q++) acc -= col[q] * yb[q];
            yb[jj] = acc;
        }
    }
    for (int k = 0; k < n; k++) x[perm[k]] = y[k];
}

// Four right-hand sides at once (b and x columns n apart), interleaved in y[4n] and t[4n]:
// each entry of L is loaded once for four multiply-adds, so the pass over L, which is memory
// bound, is shared by the four solves.
static void blocked_ldl_solve4(const cholmod_factor* S, const cholmod_factor* L, double* y,
                               double* t, const double* b, double* x) {
    enum { W = 4 };
    const int n = (int)L->n;
    const int *perm = L->Perm, *super = S->super, *pi = S->pi, *px = S->px, *ls = S->s;
    const double* lx = L->x;
    const int ns = (int)S->nsuper;
    for (int k = 0; k < n; k++)
        for (int r = 0; r < W; r++) y[k * W + r] = b[(size_t)r * (size_t)n + (size_t)perm[k]];
    for (int s = 0; s < ns; s++) { // L y = P b
        const int k1 = super[s], nscol = super[s + 1] - k1, nsrow = pi[s + 1] - pi[s];
        const int* rows = ls + pi[s];
        const double* blk = lx + px[s];
        double* yb = y + (size_t)k1 * W;
        for (int q = nscol * W; q < nsrow * W; q++) t[q] = 0.0;
        for (int jj = 0; jj < nscol; jj++) {
            const double* col = blk + (size_t)jj * (size_t)nsrow;
            const double* yj = yb + jj * W;
            for (int q = jj + 1; q < nscol; q++)
                for (int r = 0; r < W; r++) yb[q * W + r] -= col[q] * yj[r];
            for (int q = nscol; q < nsrow; q++)
                for (int r = 0; r < W; r++) t[q * W + r] += col[q] * yj[r];
        }
        for (int q = nscol; q < nsrow; q++)
            for (int r = 0; r < W; r++) y[rows[q] * W + r] -= t[q * W + r];
    }
    for (int s = 0; s < ns; s++) { // D
        const int k1 = super[s], nsrow = pi[s + 1] - pi[s];
        const double* blk = lx + px[s];
        for (int jj = 0; jj < super[s + 1] - k1; jj++) {
            double dinv = 1.0 / blk[(size_t)jj * (size_t)nsrow + (size_t)jj];
            for (int r = 0; r < W; r++) y[(k1 + jj) * W + r] *= dinv;
        }
    }
    for (int s = ns - 1; s >= 0; s--) { // L^T z = y
        const int k1 = super[s], nscol = super[s + 1] - k1, nsrow = pi[s + 1] - pi[s];
        const int* rows = ls + pi[s];
        const double* blk = lx + px[s];
        double* yb = y + (size_t)k1 * W;
        for (int q = nscol; q < nsrow; q++)
            for (int r = 0; r < W; r++) t[q * W + r] = y[rows[q] * W + r];
        for (int jj = nscol - 1; jj >= 0; jj--) {
            const double* col = blk + (size_t)jj * (size_t)nsrow;
            double acc[W];
            for (int r = 0; r < W; r++) acc[r] = yb[jj * W + r];
            for (int q = jj + 1; q < nscol; q++)
                for (int r = 0; r < W; r++) acc[r] -= col[q] * yb[q * W + r];
            for (int q = nscol; q < nsrow; q++)
                for (int r = 0; r < W; r++) acc[r] -= col[q] * t[q * W + r];
            for (int r = 0; r < W; r++) yb[jj * W + r] = acc[r];
        }
    }
    for (int k = 0; k < n; k++)
        for (int r = 0; r < W; r++) x[(size_t)r * (size_t)n + (size_t)perm[k]] = y[k * W + r];
}

static hs_status solve_into(hs_cholesky* f, int k, const double* b, double* x, cholmod_dense** X,
                            cholmod_dense** Y, cholmod_dense** E) {
    if (!f || k < 0 || (f->n > 0 && k > 0 && (!b || !x))) return HS_ERR_INVALID;
    if (f->broken) return HS_ERR_NOT_POSDEF;
    if (f->n == 0 || k == 0) return HS_OK;
    size_t n = (size_t)f->n;
    if (!f->L->is_super) {
        int c = 0;
        if (f->blocked)
            for (; c + 4 <= k; c += 4)
                blocked_ldl_solve4(f->spare, f->L, f->work, f->work + 4 * n, b + c * n, x + c * n);
        for (; c < k; c++) {
            if (f->blocked)
                blocked_ldl_solve(f->spare, f->L, f->work, f->work + n, b + c * n, x + c * n);
            else
                simplicial_solve(f->L, f->work, b + c * n, x + c * n);
        }
        return HS_OK;
    }
    f->b.ncol = (size_t)k;
    f->b.nzmax = n * (size_t)k;
    f->b.x = (void*)(uintptr_t)b; // read only by cholmod_solve2
    int ok = cholmod_solve2(CHOLMOD_A, f->L, &f->b, NULL, X, NULL, Y, E, &f->c);
    f->b.x = NULL;
    if (!ok) return map_status(f->c.status) != HS_OK ? map_status(f->c.status) : HS_ERR_NUMERIC;
    // X is CHOLMOD's; copying out lets x alias b and keeps X reusable.
    memcpy(x, (*X)->x, sizeof(double) * n * (size_t)k);
    return HS_OK;
}

hs_status hs_cholesky_solve(hs_cholesky* f, const double* b, double* x) {
    if (!f) return HS_ERR_INVALID;
    return solve_into(f, 1, b, x, &f->x1, &f->y1, &f->e1);
}

hs_status hs_cholesky_solve_many(hs_cholesky* f, int k, const double* b, double* x) {
    if (!f) return HS_ERR_INVALID;
    return solve_into(f, k, b, x, &f->xk, &f->yk, &f->ek);
}

static int cmp_int_asc(const void* pa, const void* pb) {
    int a = *(const int*)pa, b = *(const int*)pb;
    return (a > b) - (a < b);
}

static int cmp_i64_asc(const void* pa, const void* pb) {
    int64_t a = *(const int64_t*)pa, b = *(const int64_t*)pb;
    return (a > b) - (a < b);
}

void dtrsm_(const char* side, const char* uplo, const char* transa, const char* diag, const int* m,
            const int* n, const double* alpha, const double* a, const int* lda, double* b,
            const int* ldb);

// hs_cholesky_inverse_diag3: every path of the elimination tree ends in the root separator,
// whose columns form a dense trailing triangle of L; a sparse solve per block walked it again
// for every block (75 % of a 25k-tet organ's compliance set-up). Blocks are solved DIAG_GROUP
// at a time (their paths mostly coincide near the root), the tail with one dense triangular
// solve per group (BLAS 3).
#define DIAG_GROUP     16   // blocks solved together (3 right-hand sides each)
#define DIAG_DENSE_MIN 32   // a shorter dense tail is left to the sparse solves
#define DIAG_DENSE_MAX 3072 // columns at most in the dense tail (72 MB)
#define DIAG_DENSITY   0.9  // a tail column counts as dense with this share of its rows stored

// y[li[p]][.] -= lx[p] v for a column's nz entries below its diagonal (rows of 3 DIAG_GROUP
// doubles; v is the column's own row, which no target row is): the whole inner loop, so AVX2
// where the processor has it (as fem.c's element passes).
#define DIAG_COLUMN_BODY                                                                           \
    for (int p = 0; p < nz; ++p) {                                                                 \
        double* restrict yr = y + (size_t)(3 * DIAG_GROUP) * (size_t)li[p];                        \
        const double l = lx[p];                                                                    \
        for (int r = 0; r < 3 * DIAG_GROUP; ++r) yr[r] -= l * v[r];                                \
    }
static void diag_column_base(double* y, const int* li, const double* lx, int nz,
                             const double* restrict v) {
    DIAG_COLUMN_BODY
}
__attribute__((target("avx2"))) static void
diag_column_avx2(double* y, const int* li, const double* lx, int nz, const double* restrict v) {
    DIAG_COLUMN_BODY
}

// What every worker of hs_cholesky_inverse_diag3 reads, and each one's own scratch.
typedef struct diag_job {
    const int *Lp, *Li, *Lnz, *pinv, *parent, *dofs;
    const double *Lx, *tl;
    const int64_t* order;
    int n, n0, T, nb, ldl, n_groups, n_parts;
    void (*column)(double*, const int*, const double*, int, const double*);
    double* out;
    struct diag_ws {
        int *mark, *list;
        double *y, *ty;
    } ws[HS_PARALLEL_MAX];
} diag_job;

// Groups of blocks from g_begin to g_end with workspace w (zeroed: y and ty are left zero).
static void diag_groups(const diag_job* J, struct diag_ws* w, int g_begin, int g_end) {
    enum { G = DIAG_GROUP, R = 3 * DIAG_GROUP };
    const int *Lp = J->Lp, *Li = J->Li, *Lnz = J->Lnz, *dofs = J->dofs;
    const double* Lx = J->Lx;
    const int n0 = J->n0, T = J->T, nb = J->nb, ldl = J->ldl;
    double *y = w->y, *ty = w->ty;
    int *mark = w->mark, *list = w->list;
    for (int gi = g_begin; gi < g_end; ++gi) {
        const int g0 = gi * G, stamp = gi + 1;
        const int ng = nb - g0 < G ? nb - g0 : G;
        int m = 0;
        for (int j = 0; j < ng; ++j) {
            const int b = (int)(J->order[g0 + j] & 0xffffffff);
            for (int a = 0; a < 3; ++a) {
                const int q = dofs[3 * b + a] >= 0 ? J->pinv[dofs[3 * b + a]] : -1;
                if (q < 0) continue;
                y[(size_t)R * (size_t)q + (size_t)(3 * j + a)] = 1.0;
                for (int k = q; k >= 0 && k < n0 && mark[k] != stamp; k = J->parent[k]) {
                    mark[k] = stamp;
                    list[m++] = k;
                }
            }
        }
        qsort(list, (size_t)m, sizeof(int), cmp_int_asc); // ancestors come later
        for (int t = 0; t < m; ++t) {
            const int k = list[t];
            const double d = ldl ? 1.0 : Lx[Lp[k]]; // the diagonal comes first in a column
            double* yk = y + (size_t)R * (size_t)k;
            int any = 0;
            for (int r = 0; r < R; ++r) {
                yk[r] /= d;
                any |= yk[r] != 0;
            }
            if (!any) continue;
            J->column(y, Li + Lp[k] + 1, Lx + Lp[k] + 1, Lnz[k] - 1, yk);
        }
        double acc[G][6];
        memset(acc, 0, sizeof acc);
        for (int t = 0; t < m; ++t) {
            double* yk = y + (size_t)R * (size_t)list[t];
            const double wd = ldl ? 1.0 / Lx[Lp[list[t]]] : 1.0;
            for (int j = 0; j < ng; ++j) {
                const double* v = yk + 3 * j;
                acc[j][0] += wd * v[0] * v[0];
                acc[j][1] += wd * v[0] * v[1];
                acc[j][2] += wd * v[0] * v[2];
                acc[j][3] += wd * v[1] * v[1];
                acc[j][4] += wd * v[1] * v[2];
                acc[j][5] += wd * v[2] * v[2];
            }
            memset(yk, 0, R * sizeof(double));
        }
        if (T > 0) {
            // The tail: its right-hand sides (unit loads there, the sparse part's updates), one
            // dense triangular solve for the group.
            for (int r = 0; r < 3 * ng; ++r)
                for (int i = 0; i < T; ++i) {
                    double* yi = y + (size_t)R * (size_t)(n0 + i) + r;
                    ty[(size_t)T * (size_t)r + (size_t)i] = *yi;
                    *yi = 0;
                }
            const int nr = 3 * ng;
            const double one = 1.0;
            dtrsm_("L", "L", "N", ldl ? "U" : "N", &T, &nr, &one, J->tl, &T, ty, &T);
            for (int j = 0; j < ng; ++j) {
                const double* r0 = ty + (size_t)T * (size_t)(3 * j);
                const double *r1 = r0 + T, *r2 = r1 + T;
                for (int i = 0; i < T; ++i) {
                    const double wd = ldl ? 1.0 / Lx[Lp[n0 + i]] : 1.0;
                    acc[j][0] += wd * r0[i] * r0[i];
                    acc[j][1] += wd * r0[i] * r1[i];
                    acc[j][2] += wd * r0[i] * r2[i];
                    acc[j][3] += wd * r1[i] * r1[i];
                    acc[j][4] += wd * r1[i] * r2[i];
                    acc[j][5] += wd * r2[i] * r2[i];
                }
            }
        }
        for (int j = 0; j < ng; ++j) {
            double* o = J->out + 9 * (size_t)(J->order[g0 + j] & 0xffffffff);
            o[0] = acc[j][0];
            o[1] = o[3] = acc[j][1];
            o[2] = o[6] = acc[j][2];
            o[4] = acc[j][3];
            o[5] = o[7] = acc[j][4];
            o[8] = acc[j][5];
        }
    }
}

// One contiguous share of the groups (neighbouring groups share most of their paths).
static void diag_part(int part, void* ctx) {
    diag_job* J = ctx;
    const int per = (J->n_groups + J->n_parts - 1) / J->n_parts;
    const int b = part * per, e = b + per < J->n_groups ? b + per : J->n_groups;
    if (b < e) diag_groups(J, &J->ws[part], b, e);
}

hs_status hs_cholesky_inverse_diag3(hs_cholesky* f, int nb, const int* dofs, double* out) {
    return hs_cholesky_inverse_diag3_par(f, nb, dofs, out, NULL);
}

hs_status hs_cholesky_inverse_diag3_par(hs_cholesky* f, int nb, const int* dofs, double* out,
                                        const hs_parallel* par) {
    if (!f || !f->L || f->broken || nb < 0 || (nb > 0 && (!dofs || !out))) return HS_ERR_INVALID;
    if (f->L->xtype == CHOLMOD_PATTERN) return HS_ERR_INVALID;
    if (par && (!par->run || par->width < 1 || par->width > HS_PARALLEL_MAX)) return HS_ERR_INVALID;
    install_allocator();
    apply_thread_limit();
    const int n = f->n;
    for (int k = 0; k < 3 * nb; ++k)
        if (dofs[k] < -1 || dofs[k] >= n) return HS_ERR_INVALID;
    // A simplicial factor's columns give the elimination tree and the sparse solves: use L
    // itself when it is one (LDL' in update mode: unit L, D on the diagonal), else a simplicial
    // LL' copy of the supernodal one.
    cholmod_factor* copy = NULL;
    cholmod_factor* S = f->L;
    if (S->is_super) {
        copy = cholmod_copy_factor(f->L, &f->c);
        if (!copy) return HS_ERR_NOMEM;
        if (!cholmod_change_factor(CHOLMOD_REAL, 1, 0, 1, 1, copy, &f->c)) {
            cholmod_free_factor(&copy, &f->c);
            return HS_ERR_NOMEM;
        }
        S = copy;
    }
    enum { G = DIAG_GROUP, R = 3 * DIAG_GROUP };
    diag_job J;
    memset(&J, 0, sizeof J);
    J.ldl = !S->is_ll; // then y = L^-1 e with unit L, and A^-1 = L^-T D^-1 L^-1
    J.Lp = S->p;
    J.Li = S->i;
    J.Lnz = S->nz;
    J.Lx = S->x;
    J.n = n;
    J.nb = nb;
    J.dofs = dofs;
    J.out = out;
    J.column = __builtin_cpu_supports("avx2") ? diag_column_avx2 : diag_column_base;
    J.n_groups = (nb + G - 1) / G;
    J.n_parts = par && J.n_groups > 1 ? (par->width < J.n_groups ? par->width : J.n_groups) : 1;
    const int* perm = S->Perm;
    int* pinv = hs_alloc((size_t)n * sizeof(int));
    int* parent = hs_alloc((size_t)n * sizeof(int));
    int64_t* order = hs_alloc((size_t)nb * sizeof(int64_t) + sizeof(int64_t));
    double* tl = NULL; // [T * T] the dense tail of L, column-major (LDL^T: unit diagonal)
    hs_status st = HS_OK;
    if (!pinv || !parent || !order) {
        st = HS_ERR_NOMEM;
        goto done;
    }
    // The dense tail: columns n0 .. n-1, each holding at least DIAG_DENSITY of its rows.
    int n0 = n;
    while (n0 > 0 && n - n0 < DIAG_DENSE_MAX && J.Lnz[n0 - 1] >= DIAG_DENSITY * (n - n0 + 1)) --n0;
    const int T = n - n0 >= DIAG_DENSE_MIN ? n - n0 : 0;
    if (T == 0) n0 = n;
    J.n0 = n0;
    J.T = T;
    for (int w = 0; w < J.n_parts; ++w) {
        struct diag_ws* ws = &J.ws[w];
        ws->mark = hs_calloc((size_t)n, sizeof(int));
        ws->list = hs_alloc((size_t)n * sizeof(int));
        ws->y = hs_calloc((size_t)R * (size_t)n, sizeof(double));         // [n][R]: a group's loads
        ws->ty = T > 0 ? hs_calloc((size_t)T * R, sizeof(double)) : NULL; // the tail's
        if (!ws->mark || !ws->list || !ws->y || (T > 0 && !ws->ty)) {
            st = HS_ERR_NOMEM;
            goto done;
        }
    }
    if (T > 0) {
        tl = hs_calloc((size_t)T * (size_t)T, sizeof(double));
        if (!tl) {
            st = HS_ERR_NOMEM;
            goto done;
        }
        for (int k = n0; k < n; ++k)
            for (int p = J.Lp[k]; p < J.Lp[k] + J.Lnz[k]; ++p)
                tl[(size_t)(J.Li[p] - n0) + (size_t)T * (size_t)(k - n0)] = J.Lx[p];
        if (J.ldl)
            for (int k = 0; k < T; ++k) tl[(size_t)k * (size_t)(T + 1)] = 1.0;
    }
    J.tl = tl;
    for (int k = 0; k < n; ++k) {
        pinv[perm ? perm[k] : k] = k;
        int par_k = -1; // the first sub-diagonal row: the elimination-tree parent
        for (int p = J.Lp[k] + 1; p < J.Lp[k] + J.Lnz[k]; ++p)
            if (J.Li[p] > k && (par_k < 0 || J.Li[p] < par_k)) par_k = J.Li[p];
        parent[k] = par_k;
    }
    J.pinv = pinv;
    J.parent = parent;
    // Blocks by the position of their first dof in L: neighbours in that order mostly share
    // their paths up the tree, so G of them are solved together, R right-hand sides per row of
    // L (contiguous: the inner loop vectorises, and each entry of L is loaded once per group).
    for (int b = 0; b < nb; ++b) {
        int key = n;
        for (int a = 0; a < 3; ++a)
            if (dofs[3 * b + a] >= 0 && pinv[dofs[3 * b + a]] < key) key = pinv[dofs[3 * b + a]];
        order[b] = ((int64_t)key << 32) | (int64_t)b;
    }
    qsort(order, (size_t)nb, sizeof *order, cmp_i64_asc);
    J.order = order;
    if (J.n_parts > 1) {
        if (par->begin) par->begin(par->user);
        par->run(J.n_parts, diag_part, &J, par->user);
        if (par->end) par->end(par->user);
    } else
        diag_part(0, &J);
done:
    for (int w = 0; w < HS_PARALLEL_MAX; ++w) {
        hs_free(J.ws[w].mark);
        hs_free(J.ws[w].list);
        hs_free(J.ws[w].y);
        hs_free(J.ws[w].ty);
    }
    hs_free(tl);
    hs_free(order);
    hs_free(pinv);
    hs_free(parent);
    cholmod_free_factor(&copy, &f->c);
    return st;
}

int64_t hs_cholesky_factor_nnz(const hs_cholesky* f) {
    if (!f || !f->L) return 0;
    const cholmod_factor* L = f->L;
    if (L->is_super) return (int64_t)L->xsize;
    if (L->xtype == CHOLMOD_PATTERN || !L->nz) return 0; // symbolic after a failed update
    const int* nz = L->nz;
    int64_t s = 0;
    for (size_t j = 0; j < L->n; j++) s += nz[j];
    return s;
}

int hs_cholesky_size(const hs_cholesky* f) {
    return f ? f->n : 0;
}

int hs_cholesky_is_supernodal(const hs_cholesky* f) {
    return f && f->L && f->L->is_super;
}

static void free_partial(struct hs_partial** pp);

void hs_cholesky_destroy(hs_cholesky** pf) {
    if (!pf || !*pf) return;
    hs_cholesky* f = *pf;
    cholmod_free_factor(&f->L, &f->c);
    cholmod_free_factor(&f->spare, &f->c);
    cholmod_free_dense(&f->x1, &f->c);
    cholmod_free_dense(&f->y1, &f->c);
    cholmod_free_dense(&f->e1, &f->c);
    cholmod_free_dense(&f->xk, &f->c);
    cholmod_free_dense(&f->yk, &f->c);
    cholmod_free_dense(&f->ek, &f->c);
    cholmod_finish(&f->c);
    hs_free(f->colp);
    hs_free(f->work);
    hs_free(f->pinv);
    hs_free(f->d0);
    hs_free(f->cp_p);
    hs_free(f->ci_p);
    hs_free(f->cx_p);
    hs_free(f->cp_m);
    hs_free(f->ci_m);
    hs_free(f->cx_m);
    hs_free(f->dpos);
    hs_free(f->dlist);
    hs_free(f->dense);
    free_partial(&f->part);
    hs_free(f);
    *pf = NULL;
    flush_block_cache();
}

// ---------------------------------------------------------------------------------------------
// Low-rank updates.

static int grow(void** p, size_t bytes) {
    void* q = hs_realloc(*p, bytes);
    if (!q) return 0;
    *p = q;
    return 1;
}

static hs_status reserve_columns(hs_cholesky* f, int64_t cols, int64_t nnz) {
    if (cols > INT32_MAX / 2 || nnz > INT32_MAX / 2) return HS_ERR_UNSUPPORTED;
    if (cols <= f->cap_cols && nnz <= f->cap_nnz) return HS_OK;
    int nc = (int)(cols > f->cap_cols ? cols : f->cap_cols);
    int nz = (int)(nnz > f->cap_nnz ? nnz : f->cap_nnz);
    size_t ib = sizeof(int) * ((size_t)nc + 1);
    if (!grow((void**)&f->cp_p, ib) || !grow((void**)&f->cp_m, ib) ||
        !grow((void**)&f->ci_p, sizeof(int) * (size_t)nz) ||
        !grow((void**)&f->ci_m, sizeof(int) * (size_t)nz) ||
        !grow((void**)&f->cx_p, sizeof(double) * (size_t)nz) ||
        !grow((void**)&f->cx_m, sizeof(double) * (size_t)nz))
        return HS_ERR_NOMEM; // whatever grew stays, capacities unchanged: consistent
    f->cap_cols = nc;
    f->cap_nnz = nz;
    return HS_OK;
}

// Largest union of dofs aggregated into one dense change; a larger step goes element by element
// (its update would cost more than a refactor on any mesh where such a step occurs).
#define HS_AGG_MAX_D 768

// Order of the dense workspace a step of max_elems elements can need.
static int agg_order(const hs_cholesky* f, int max_elems) {
    int64_t d = 12 * (int64_t)max_elems;
    if (d > HS_AGG_MAX_D) d = HS_AGG_MAX_D;
    if (d > f->n) d = f->n;
    return (int)d;
}

static hs_status reserve_dense(hs_cholesky* f, int max_elems) {
    if (!f->dpos) {
        f->dpos = hs_alloc(sizeof(int) * ((size_t)f->n + 1));
        if (!f->dpos) return HS_ERR_NOMEM;
        for (int i = 0; i < f->n; i++) f->dpos[i] = -1;
    }
    int d = agg_order(f, max_elems);
    if (d <= f->cap_d) return HS_OK;
    int* l = hs_realloc(f->dlist, sizeof(int) * (size_t)d);
    if (!l) return HS_ERR_NOMEM;
    f->dlist = l;
    double* m = hs_realloc(f->dense, sizeof(double) * (size_t)d * (size_t)d);
    if (!m) return HS_ERR_NOMEM;
    f->dense = m;
    f->cap_d = d;
    return HS_OK;
}

hs_status hs_cholesky_prepare_updates(hs_cholesky* f, int max_elems) {
    if (!f || max_elems < 0) return HS_ERR_INVALID;
    if (!ensure_spare(f)) return HS_ERR_NOMEM;
    if (!f->updatable) {
        // Unpacked LDL^T: packing would drop the numerically zero entries of the supernodes,
        // and an element update then refills them (reallocating columns). Unpacked keeps the
        // full symbolic pattern, so updates never allocate and refactors refill it in place.
        // A supernodal spare stays supernodal for fast refactors (see hs_cholesky_refactor).
        if (f->L->is_super && !f->spare->is_super) {
            // A failed earlier prepare and a refactor swapped a converted factor into the
            // spare: give the spare the supernodal structure back.
            cholmod_factor* t = cholmod_copy_factor(f->L, &f->c);
            if (!t) return HS_ERR_NOMEM;
            cholmod_free_factor(&f->spare, &f->c);
            f->spare = t;
        }
        int both = !f->L->is_super;
        if (!cholmod_change_factor(CHOLMOD_REAL, 0, 0, 0, 0, f->L, &f->c) ||
            (both && !cholmod_change_factor(CHOLMOD_REAL, 0, 0, 0, 0, f->spare, &f->c)))
            return map_status(f->c.status) != HS_OK ? map_status(f->c.status) : HS_ERR_NUMERIC;
        if (!f->pinv) f->pinv = hs_alloc(sizeof(int) * ((size_t)f->n + 1));
        if (!f->d0) f->d0 = hs_alloc(sizeof(double) * ((size_t)f->n + 1));
        if (!f->pinv || !f->d0) return HS_ERR_NOMEM;
        const int* perm = f->L->Perm;
        for (int k = 0; k < f->n; k++) f->pinv[perm[k]] = k;
        // updown's workspace (Flag, Head, Iwork, W of maxrank*n) sized now, not on the first
        // cut; the default maxrank is 8.
        size_t n = (size_t)f->n;
        if (!cholmod_allocate_work(n, 2 * n, 8 * n, &f->c)) return map_status(f->c.status);
        f->updatable = 1;
        f->blocked = f->spare->is_super && super_to_ldl(f->spare, f->L, 0) &&
                     ldl_has_super_layout(f->spare, f->L);
        save_pivots(f);
    }
    hs_status st = reserve_dense(f, max_elems);
    if (st != HS_OK) return st;
    int64_t d = agg_order(f, max_elems);
    int64_t nnz = 144 * (int64_t)max_elems;
    if (d * (d + 1) / 2 > nnz) nnz = d * (d + 1) / 2;
    return reserve_columns(f, 12 * (int64_t)max_elems, nnz);
}

// In-place shell sort of rows (and their values) of one column.
static void sort_column(int* r, double* v, int len) {
    for (int gap = len / 2; gap > 0; gap = gap == 2 ? 1 : (int)(gap / 2.2)) {
        for (int i = gap; i < len; i++) {
            int ri = r[i];
            double vi = v[i];
            int j = i;
            for (; j >= gap && r[j - gap] > ri; j -= gap) {
                r[j] = r[j - gap];
                v[j] = v[j - gap];
            }
            r[j] = ri;
            v[j] = vi;
        }
    }
}

static void set_c_view(cholmod_sparse* c, int n, int ncol, int* cp, int* ci, double* cx) {
    memset(c, 0, sizeof *c);
    c->nrow = (size_t)n;
    c->ncol = (size_t)ncol;
    c->nzmax = (size_t)(cp[ncol] > 0 ? cp[ncol] : 1);
    c->p = cp;
    c->i = ci;
    c->x = cx;
    c->stype = 0;
    c->itype = CHOLMOD_INT;
    c->xtype = CHOLMOD_REAL;
    c->dtype = CHOLMOD_DOUBLE;
    c->sorted = 1;
    c->packed = 1;
}

// Apply update (sign 1) or downdate (0) with C already permuted and sorted.
static hs_status apply_updown(hs_cholesky* f, int update, int ncol, int* cp, int* ci, double* cx) {
    if (ncol == 0) return HS_OK;
    apply_thread_limit();
    cholmod_sparse c;
    set_c_view(&c, f->n, ncol, cp, ci, cx);
    if (!cholmod_updown(update, &c, f->L, &f->c)) {
        // Out of memory leaves L as a symbolic factor per CHOLMOD: unusable until refactor.
        f->broken = 1;
        f->blocked = 0;
        return map_status(f->c.status) != HS_OK ? map_status(f->c.status) : HS_ERR_NUMERIC;
    }
    // Fill outside the pattern moves columns and ends the supernodal layout.
    f->blocked = f->blocked && ldl_has_super_layout(f->spare, f->L);
    // A downdate can lose definiteness; an update can overflow (finite values that are huge).
    if (!pivots_ok(f)) {
        f->broken = 1;
        return update ? HS_ERR_NUMERIC : HS_ERR_NOT_POSDEF;
    }
    return HS_OK;
}

hs_status hs_cholesky_updown(hs_cholesky* f, int update, int n_cols, const int* colp,
                             const int* rowi, const double* val) {
    if (!f || n_cols < 0 || (n_cols > 0 && (!colp || !rowi || !val)) ||
        (n_cols > 0 && colp[0] != 0))
        return HS_ERR_INVALID;
    if (n_cols == 0) return HS_OK;
    for (int j = 0; j < n_cols; j++)
        if (colp[j + 1] < colp[j]) return HS_ERR_INVALID;
    hs_status st = hs_cholesky_prepare_updates(f, 0);
    if (st != HS_OK) return st;
    st = reserve_columns(f, n_cols, colp[n_cols]);
    if (st != HS_OK) return st;
    for (int j = 0; j <= n_cols; j++) f->cp_p[j] = colp[j];
    for (int j = 0; j < n_cols; j++) {
        for (int p = colp[j]; p < colp[j + 1]; p++) {
            if (rowi[p] < 0 || rowi[p] >= f->n) return HS_ERR_INVALID;
            if (!isfinite(val[p])) return HS_ERR_NUMERIC; // before L is touched
            f->ci_p[p] = f->pinv[rowi[p]];
            f->cx_p[p] = val[p];
        }
        sort_column(f->ci_p + colp[j], f->cx_p + colp[j], colp[j + 1] - colp[j]);
        for (int p = colp[j] + 1; p < colp[j + 1]; p++)
            if (f->ci_p[p] == f->ci_p[p - 1]) return HS_ERR_INVALID;
    }
    return apply_updown(f, update != 0, n_cols, f->cp_p, f->ci_p, f->cx_p);
}

// Cyclic Jacobi eigen-decomposition of a symmetric m x m (row-major, destroyed): eigenvalues in
// w[m], eigenvectors in the columns of v (row-major m x m). m <= 12, so this is microseconds.
static void sym_eig(int m, double* a, double* v, double* w) {
    double frob2 = 0.0;
    for (int i = 0; i < m * m; i++) frob2 += a[i] * a[i];
    for (int i = 0; i < m; i++)
        for (int j = 0; j < m; j++) v[i * m + j] = i == j;
    for (int sweep = 0; sweep < 60; sweep++) {
        double off = 0.0;
        for (int p = 0; p < m; p++)
            for (int q = p + 1; q < m; q++) off += 2.0 * a[p * m + q] * a[p * m + q];
        if (off <= 1e-32 * frob2) break;
        for (int p = 0; p < m; p++) {
            for (int q = p + 1; q < m; q++) {
                double apq = a[p * m + q];
                if (apq == 0.0) continue;
                double theta = (a[q * m + q] - a[p * m + p]) / (2.0 * apq);
                double t = fabs(theta) > 1e150 ? 0.5 / theta
                                               : (theta >= 0 ? 1.0 : -1.0) /
                                                     (fabs(theta) + sqrt(theta * theta + 1));
                double c = 1.0 / sqrt(t * t + 1.0), s = t * c;
                for (int k = 0; k < m; k++) {
                    if (k == p || k == q) continue;
                    double akp = a[k * m + p], akq = a[k * m + q];
                    a[k * m + p] = a[p * m + k] = c * akp - s * akq;
                    a[k * m + q] = a[q * m + k] = s * akp + c * akq;
                }
                a[p * m + p] -= t * apq;
                a[q * m + q] += t * apq;
                a[p * m + q] = a[q * m + p] = 0.0;
                for (int k = 0; k < m; k++) {
                    double vkp = v[k * m + p], vkq = v[k * m + q];
                    v[k * m + p] = c * vkp - s * vkq;
                    v[k * m + q] = s * vkp + c * vkq;
                }
            }
        }
    }
    for (int i = 0; i < m; i++) w[i] = a[i * m + i];
}

// Element by element: each dK_e (negated from first_minus on) split by its own
// eigen-decomposition (rank <= 12 each).
static hs_status update_per_element(hs_cholesky* f, int n_elem, const double* dk, const int* dofs,
                                    int first_minus) {
    hs_status st;
    int np = 0, nm = 0; // columns so far
    f->cp_p[0] = f->cp_m[0] = 0;
    for (int e = 0; e < n_elem; e++) {
        const int* d = dofs + 12 * e;
        const double* k = dk + 144 * e;
        int loc[12], m = 0;
        for (int i = 0; i < 12; i++)
            if (d[i] >= 0) loc[m++] = i;
        if (m == 0) continue;
        // Order the free local dofs by their row in L so every column comes out sorted.
        for (int i = 1; i < m; i++) {
            int li = loc[i], j = i;
            for (; j > 0 && f->pinv[d[loc[j - 1]]] > f->pinv[d[li]]; j--) loc[j] = loc[j - 1];
            loc[j] = li;
        }
        double a[144], v[144], w[12];
        double amax = 0.0;
        for (int i = 0; i < m; i++)
            for (int j = 0; j < m; j++) {
                // Symmetrise against round-off in the caller's dK.
                double x = 0.5 * (k[loc[i] * 12 + loc[j]] + k[loc[j] * 12 + loc[i]]);
                if (e >= first_minus) x = -x;
                if (!isfinite(x)) return HS_ERR_NUMERIC;
                a[i * m + j] = x;
            }
        sym_eig(m, a, v, w);
        for (int i = 0; i < m; i++) amax = fmax(amax, fabs(w[i]));
        // Eigenvalues at round-off level (rigid modes of an element) carry no stiffness.
        double tol = 1e-12 * amax;
        for (int i = 0; i < m; i++) {
            if (fabs(w[i]) <= tol) continue;
            int plus = w[i] > 0;
            int* cp = plus ? f->cp_p : f->cp_m;
            int* ci = plus ? f->ci_p : f->ci_m;
            double* cx = plus ? f->cx_p : f->cx_m;
            int* nc = plus ? &np : &nm;
            double s = sqrt(fabs(w[i]));
            int q = cp[*nc];
            for (int r = 0; r < m; r++) {
                ci[q] = f->pinv[d[loc[r]]];
                cx[q] = s * v[r * m + i];
                q++;
            }
            cp[++*nc] = q;
        }
    }
    f->last.rank = np + nm;
    // Updates first: every intermediate matrix then dominates the final one.
    st = apply_updown(f, 1, np, f->cp_p, f->ci_p, f->cx_p);
    if (st != HS_OK) return st;
    return apply_updown(f, 0, nm, f->cp_m, f->ci_m, f->cx_m);
}

// Sort the union's dofs by their row in L (insertion sort: d is a few hundred at most).
static void sort_by_row(const int* pinv, int* dl, int d) {
    for (int i = 1; i < d; i++) {
        int v = dl[i], r = pinv[v], j = i;
        for (; j > 0 && pinv[dl[j - 1]] > r; j--) dl[j] = dl[j - 1];
        dl[j] = v;
    }
}

// The whole step at once. Sum the blocks e0 <= e < e1 (negated from first_minus on) into S over
// the union D of their free dofs, ordered as
// the rows of L, and factor S = G Q G^T (G unit lower, Q diagonal) without pivoting, in L's
// elimination order. S's graph is a union of element cliques, a subgraph of A's, so the fill of
// this elimination lies inside L's pattern: column j of G has its rows in those of column j of
// L, and the update adds no fill (an eigen-split would give columns dense over D, which fill L
// and slow every later update). Rank <= d instead of up to 12 per element. Pivots are not
// chosen, so an indefinite S can break down: a negligible pivot with a non-negligible column,
// or large growth, returns 0 (the caller then splits S or goes element by element). A
// semidefinite S cannot: its growth is bounded by its diagonal. Columns are appended to the
// update (Q_j > 0) and downdate (Q_j < 0) lists at *np, *nm; -1 on NaN/Inf.
static int aggregate_columns(hs_cholesky* f, int e0, int e1, int first_minus, const double* dk,
                             const int* dofs, int* np_io, int* nm_io) {
    int* pos = f->dpos;
    int* dl = f->dlist;
    int d = 0;
    for (int e = e0; e < e1; e++)
        for (int i = 0; i < 12; i++) {
            int q = dofs[12 * e + i];
            if (q < 0 || pos[q] >= 0) continue;
            if (d == f->cap_d) {
                for (int k = 0; k < d; k++) pos[dl[k]] = -1;
                f->last.union_dofs = -1;
                return 0;
            }
            pos[q] = d;
            dl[d++] = q;
        }
    f->last.union_dofs = d;
    sort_by_row(f->pinv, dl, d);
    for (int k = 0; k < d; k++) pos[dl[k]] = k;
    double* S = f->dense;
    for (int i = 0; i < d; i++)
        memset(S + (size_t)i * (size_t)d, 0, sizeof(double) * (size_t)(i + 1));
    // Lower triangle, row-major: S[i*d + j], j <= i.
    for (int e = e0; e < e1; e++) {
        const int* q = dofs + 12 * e;
        const double* k = dk + 144 * e;
        const double sg = e >= first_minus ? -1.0 : 1.0;
        for (int a = 0; a < 12; a++) {
            if (q[a] < 0) continue;
            int pa = pos[q[a]];
            for (int b = 0; b < 12; b++) {
                if (q[b] < 0) continue;
                int pb = pos[q[b]];
                if (pb > pa) continue;
                // Both halves of the element's symmetric block land on the one stored entry;
                // a diagonal entry once.
                S[(size_t)pa * (size_t)d + (size_t)pb] +=
                    sg * (pa == pb ? k[a * 12 + b] : 0.5 * (k[a * 12 + b] + k[b * 12 + a]));
            }
        }
    }
    for (int k = 0; k < d; k++) pos[dl[k]] = -1;
    double smax = 0.0;
    for (int i = 0; i < d; i++)
        for (int j = 0; j <= i; j++) {
            double x = S[(size_t)i * (size_t)d + (size_t)j];
            if (!isfinite(x)) return -1;
            smax = fmax(smax, fabs(x));
        }
    if (smax == 0.0) return 1;
    // Right-looking LDL^T; structural zeros stay exact zeros, so rows outside L's pattern of
    // the column never appear.
    const double tiny = 1e-12 * smax, drop = 1e-10 * smax, growth_max = 1e3 * smax;
    for (int j = 0; j < d; j++) {
        double* rj = S + (size_t)j * (size_t)d;
        double p = rj[j];
        if (fabs(p) <= tiny) {
            // A zero pivot: only a column of round-off may be dropped.
            for (int i = j + 1; i < d; i++)
                if (fabs(S[(size_t)i * (size_t)d + (size_t)j]) > drop) return 0;
            rj[j] = 0.0;
            for (int i = j + 1; i < d; i++) S[(size_t)i * (size_t)d + (size_t)j] = 0.0;
            continue;
        }
        double pinv = 1.0 / p;
        for (int i = j + 1; i < d; i++) {
            double* ri = S + (size_t)i * (size_t)d;
            double sij = ri[j];
            if (sij == 0.0) continue;
            double g = sij * pinv;
            for (int k = j + 1; k <= i; k++) {
                double skj = S[(size_t)k * (size_t)d + (size_t)j];
                if (skj != 0.0) ri[k] -= g * skj;
            }
        }
        for (int i = j + 1; i < d; i++) {
            double* sij = S + (size_t)i * (size_t)d + (size_t)j;
            *sij *= pinv;
            if (fabs(p) * *sij * *sij > growth_max) return 0;
        }
    }
    // Columns sqrt|Q_j| G_j, updates and downdates apart; rows as in L, ascending.
    int np = *np_io, nm = *nm_io;
    for (int j = 0; j < d; j++) {
        double p = S[(size_t)j * (size_t)d + (size_t)j];
        if (p == 0.0) continue;
        int plus = p > 0;
        int* cp = plus ? f->cp_p : f->cp_m;
        int* ci = plus ? f->ci_p : f->ci_m;
        double* cx = plus ? f->cx_p : f->cx_m;
        int* nc = plus ? &np : &nm;
        double s = sqrt(fabs(p));
        int q = cp[*nc];
        ci[q] = f->pinv[dl[j]];
        cx[q++] = s;
        for (int i = j + 1; i < d; i++) {
            double g = S[(size_t)i * (size_t)d + (size_t)j];
            if (g == 0.0) continue;
            ci[q] = f->pinv[dl[i]];
            cx[q++] = s * g;
        }
        cp[++*nc] = q;
    }
    *np_io = np;
    *nm_io = nm;
    return 1;
}

// Blocks [0, first_minus) add, [first_minus, n_elem) subtract. Signed aggregate first; if its
// factorisation breaks down and both parts are semidefinite, each part alone (rank <= 2d);
// else element by element.
static hs_status update_blocks(hs_cholesky* f, int n_elem, const double* dk, const int* dofs,
                               int first_minus, int parts_semidefinite) {
    if (!f || n_elem < 0 || (n_elem > 0 && (!dk || !dofs))) return HS_ERR_INVALID;
    if (n_elem == 0) return HS_OK;
    for (int e = 0; e < n_elem; e++) {
        const int* d = dofs + 12 * e;
        for (int i = 0; i < 12; i++) {
            if (d[i] < -1 || d[i] >= f->n) return HS_ERR_INVALID;
            for (int j = 0; j < i; j++)
                if (d[i] >= 0 && d[i] == d[j]) return HS_ERR_INVALID;
        }
    }
    hs_status st = hs_cholesky_prepare_updates(f, n_elem);
    if (st != HS_OK) return st;
    f->last.union_dofs = -1;
    if (f->aggregate) {
        int np = 0, nm = 0;
        f->cp_p[0] = f->cp_m[0] = 0;
        f->last.method = HS_UPDATE_AGGREGATED;
        int ok = aggregate_columns(f, 0, n_elem, first_minus, dk, dofs, &np, &nm);
        if (!ok && parts_semidefinite) {
            int d = f->last.union_dofs;
            np = nm = 0;
            f->last.method = HS_UPDATE_PARTS;
            ok = aggregate_columns(f, 0, first_minus, first_minus, dk, dofs, &np, &nm);
            if (ok > 0)
                ok = aggregate_columns(f, first_minus, n_elem, first_minus, dk, dofs, &np, &nm);
            f->last.union_dofs = d; // of the whole step, not of its last part
        }
        if (ok < 0) return HS_ERR_NUMERIC;
        if (ok) {
            f->last.rank = np + nm;
            st = apply_updown(f, 1, np, f->cp_p, f->ci_p, f->cx_p);
            if (st != HS_OK) return st;
            return apply_updown(f, 0, nm, f->cp_m, f->ci_m, f->cx_m);
        }
    }
    f->last.method = HS_UPDATE_PER_ELEMENT;
    return update_per_element(f, n_elem, dk, dofs, first_minus);
}

hs_status hs_cholesky_update_elements(hs_cholesky* f, int n_elem, const double* dk,
                                      const int* dofs) {
    return update_blocks(f, n_elem, dk, dofs, n_elem, 0);
}

hs_status hs_cholesky_update_parts(hs_cholesky* f, int n_plus, int n_minus, const double* k,
                                   const int* dofs) {
    if (n_plus < 0 || n_minus < 0 || n_plus > INT32_MAX - n_minus) return HS_ERR_INVALID;
    return update_blocks(f, n_plus + n_minus, k, dofs, n_plus, 1);
}

void hs_cholesky_set_aggregate(hs_cholesky* f, int on) {
    if (f) f->aggregate = on != 0;
}

void hs_cholesky_last_update(const hs_cholesky* f, hs_cholesky_update_info* info) {
    if (!info) return;
    if (f) {
        *info = f->last;
    } else {
        memset(info, 0, sizeof *info);
        info->union_dofs = -1;
    }
}

// ---------------------------------------------------------------------------------------------
// Partial refactorisation: multifrontal over CHOLMOD's supernodes, keeping every supernode's
// update (contribution) matrix, so a change of A confined to a few columns recomputes only
// their supernodes and those supernodes' ancestors; the others' blocks of L and their update
// matrices stay as they are. The result is written into L's own supernodal blocks, so CHOLMOD
// solves with it unchanged.

// BLAS / LAPACK (the ones CHOLMOD itself links).
void dpotrf_(const char* uplo, const int* n, double* a, const int* lda, int* info);
void dtrsm_(const char* side, const char* uplo, const char* transa, const char* diag, const int* m,
            const int* n, const double* alpha, const double* a, const int* lda, double* b,
            const int* ldb);
void dsyrk_(const char* uplo, const char* trans, const int* n, const int* k, const double* alpha,
            const double* a, const int* lda, const double* beta, double* c, const int* ldc);
void dgemm_(const char* ta, const char* tb, const int* m, const int* n, const int* k,
            const double* alpha, const double* a, const int* lda, const double* b, const int* ldb,
            const double* beta, double* c, const int* ldc);

struct hs_partial {
    int ns;              // supernodes
    int* parent;         // [ns] parent supernode, -1 for a root
    int* child_start;    // [ns+1] children of s: child[child_start[s] .. child_start[s+1])
    int* child;          // [ns]
    int* col_super;      // [n] supernode of each column of L
    int* ent_start;      // [ns+1] A's entries assembled into supernode s
    int* ent_val;        // [nnz_upper] index into A's values
    int* ent_off;        // [nnz_upper] offset in L->x
    int* diag_val;       // [n] index of A(j,j) (L's order) in A's values
    int* rel_start;      // [ns+1] rows of s's update matrix, as local rows of its parent's block
    int* rel;            //
    int* run_end;        // [as rel] end of the run of consecutive rows in rel holding each
    size_t* u_start;     // [ns+1] offsets of the update matrices (m x m, column-major)
    double* u;           //
    double* flops;       // [ns] cost of each supernode
    double total_flops;  //
    unsigned char* mark; // [ns]
    int valid;           // the update matrices are those of the numbers in L
    double last_share;   // flops of the last call / total
    const int* colp;     // arrays of the matrix last checked in full (see refactor_partial)
    const int* rowi;
};

static void free_partial(struct hs_partial** pp) {
    struct hs_partial* p = *pp;
    if (!p) return;
    hs_free(p->parent);
    hs_free(p->child_start);
    hs_free(p->child);
    hs_free(p->col_super);
    hs_free(p->ent_start);
    hs_free(p->ent_val);
    hs_free(p->ent_off);
    hs_free(p->diag_val);
    hs_free(p->rel_start);
    hs_free(p->rel);
    hs_free(p->run_end);
    hs_free(p->u_start);
    hs_free(p->u);
    hs_free(p->flops);
    hs_free(p->mark);
    hs_free(p);
    *pp = NULL;
}

// Cost of recomputing a supernode of nc columns and m rows below them: potrf, trsm, syrk.
static double supernode_flops(int nc, int m) {
    return (double)nc * nc * nc / 3.0 + (double)m * nc * nc + (double)m * m * nc;
}

// build_partial's arrays sized by n and ns.
static hs_status partial_alloc(struct hs_partial* p, int n, int ns) {
    p->ns = ns;
    p->parent = hs_alloc(sizeof(int) * ((size_t)ns + 1));
    p->child_start = hs_calloc((size_t)ns + 2, sizeof(int));
    p->child = hs_alloc(sizeof(int) * ((size_t)ns + 1));
    p->col_super = hs_alloc(sizeof(int) * ((size_t)n + 1));
    p->ent_start = hs_calloc((size_t)ns + 2, sizeof(int));
    p->diag_val = hs_alloc(sizeof(int) * ((size_t)n + 1));
    p->rel_start = hs_calloc((size_t)ns + 2, sizeof(int));
    p->u_start = hs_calloc((size_t)ns + 2, sizeof(size_t));
    p->flops = hs_alloc(sizeof(double) * ((size_t)ns + 1));
    p->mark = hs_calloc((size_t)ns + 1, 1);
    if (!p->parent || !p->child_start || !p->child || !p->col_super || !p->ent_start ||
        !p->diag_val || !p->rel_start || !p->u_start || !p->flops || !p->mark)
        return HS_ERR_NOMEM;
    return HS_OK;
}

// Tree, sizes and the row lists' order (ascending, columns first: relied on below); then the
// update matrices' storage.
static hs_status partial_tree(const cholmod_factor* L, struct hs_partial* p) {
    const int ns = p->ns;
    const int *super = L->super, *pi = L->pi, *ls = L->s;
    for (int s = 0; s < ns; s++) {
        int nc = super[s + 1] - super[s], nr = pi[s + 1] - pi[s], m = nr - nc;
        if (m < 0) return HS_ERR_UNSUPPORTED;
        for (int k = 0; k < nr; k++)
            if ((k < nc && ls[pi[s] + k] != super[s] + k) ||
                (k > 0 && ls[pi[s] + k] <= ls[pi[s] + k - 1]))
                return HS_ERR_UNSUPPORTED;
        p->parent[s] = m > 0 ? p->col_super[ls[pi[s] + nc]] : -1;
        if (m > 0 && p->parent[s] <= s) return HS_ERR_UNSUPPORTED;
        if (m > 0) p->child_start[p->parent[s] + 1]++;
        p->rel_start[s + 1] = p->rel_start[s] + m;
        p->u_start[s + 1] = p->u_start[s] + (size_t)m * (size_t)m;
        p->flops[s] = supernode_flops(nc, m);
        p->total_flops += p->flops[s];
    }
    for (int s = 0; s < ns; s++) p->child_start[s + 1] += p->child_start[s];
    p->rel = hs_alloc(sizeof(int) * ((size_t)p->rel_start[ns] + 1));
    p->run_end = hs_alloc(sizeof(int) * ((size_t)p->rel_start[ns] + 1));
    p->u = hs_alloc(sizeof(double) * (p->u_start[ns] + 1));
    if (!p->rel || !p->run_end || !p->u) return HS_ERR_NOMEM;
    advise_huge(p->u, sizeof(double) * (p->u_start[ns] + 1));
    return HS_OK;
}

// Children lists, and each child's update rows as local rows of its parent (rel, run_end).
// fill and pos: [n] scratch.
static hs_status partial_children(const cholmod_factor* L, struct hs_partial* p, int* fill,
                                  int* pos) {
    const int n = (int)L->n, ns = p->ns;
    const int *super = L->super, *pi = L->pi, *ls = L->s;
    for (int s = 0; s < ns; s++) fill[s] = p->child_start[s]; // next free child slot
    for (int s = 0; s < ns; s++)
        if (p->parent[s] >= 0) p->child[fill[p->parent[s]]++] = s;
    // A child's rows below its columns lie in its parent's row list (elimination-tree
    // property); checked, since the extend-add writes through these positions unchecked.
    for (int k = 0; k < n; k++) pos[k] = -1;
    int bad = 0;
    for (int s = 0; s < ns && !bad; s++) {
        for (int k = pi[s]; k < pi[s + 1]; k++) pos[ls[k]] = k - pi[s];
        for (int q = p->child_start[s]; q < p->child_start[s + 1]; q++) {
            int c = p->child[q], cnc = super[c + 1] - super[c];
            int* r = p->rel + p->rel_start[c];
            for (int k = pi[c] + cnc; k < pi[c + 1]; k++) {
                int lr = pos[ls[k]];
                bad |= lr < 0 || lr >= pi[s + 1] - pi[s] || ls[pi[s] + lr] != ls[k];
                *r++ = lr;
            }
        }
    }
    if (bad) return HS_ERR_UNSUPPORTED;
    for (int c = 0; c < ns; c++) {
        const int *r = p->rel + p->rel_start[c], mc = p->rel_start[c + 1] - p->rel_start[c];
        int* e = p->run_end + p->rel_start[c];
        for (int k = mc - 1; k >= 0; k--)
            e[k] = k + 1 < mc && r[k + 1] == r[k] + 1 ? e[k + 1] : k + 1;
    }
    return HS_OK;
}

// Where each of A's entries goes in supernode s: ent_val / ent_off from cnt[s] on. cstart and
// clist list A's upper entries by their lower column (L's order); colof: each entry's column;
// pos: [n] scratch. HS_ERR_UNSUPPORTED when an entry is not in L's pattern.
static hs_status partial_place(const cholmod_factor* L, const hs_csc* a, struct hs_partial* p,
                               const int* pinv, const int* cstart, const int* clist,
                               const int* colof, int* cnt, int* pos) {
    const int *super = L->super, *pi = L->pi, *px = L->px, *ls = L->s;
    int bad = 0;
    for (int s = 0; s < p->ns && !bad; s++) {
        int nr = pi[s + 1] - pi[s];
        for (int k = pi[s]; k < pi[s + 1]; k++) pos[ls[k]] = k - pi[s];
        for (int c = super[s]; c < super[s + 1]; c++)
            for (int t = cstart[c]; t < cstart[c + 1]; t++) {
                int q = clist[t];
                int r = pinv[a->rowi[q]] > pinv[colof[q]] ? pinv[a->rowi[q]] : pinv[colof[q]];
                int lr = pos[r];
                if (lr < 0 || lr >= nr || ls[pi[s] + lr] != r) bad = 1; // not in L's pattern
                int e = cnt[s]++;
                p->ent_val[e] = q;
                p->ent_off[e] = px[s] + (c - super[s]) * nr + lr;
            }
    }
    return bad ? HS_ERR_UNSUPPORTED : HS_OK;
}

// A's upper entries (original numbering), each to the supernode of its lower column.
// cnt and pos: [n] scratch.
static hs_status partial_entries(const cholmod_factor* L, const hs_csc* a, struct hs_partial* p,
                                 const int* pinv, int* cnt, int* pos) {
    const int n = (int)L->n, ns = p->ns;
    memset(cnt, 0, sizeof(int) * ((size_t)n + 1));
    int nz = 0;
    for (int j = 0; j < n; j++)
        for (int q = a->colp[j]; q < a->colp[j + 1]; q++) {
            int i = a->rowi[q];
            if (i > j) continue;
            int c = pinv[i] < pinv[j] ? pinv[i] : pinv[j];
            cnt[p->col_super[c]]++;
            nz++;
            if (i == j) p->diag_val[pinv[j]] = q;
        }
    p->ent_val = hs_alloc(sizeof(int) * ((size_t)nz + 1));
    p->ent_off = hs_alloc(sizeof(int) * ((size_t)nz + 1));
    if (!p->ent_val || !p->ent_off) return HS_ERR_NOMEM;
    for (int s = 0; s < ns; s++) p->ent_start[s + 1] = p->ent_start[s] + cnt[s];
    for (int s = 0; s < ns; s++) cnt[s] = p->ent_start[s];
    // Local rows of every supernode at once would need n x ns; go supernode by supernode over
    // a column-to-entries list instead.
    int* cstart = hs_calloc((size_t)n + 2, sizeof(int));
    int* clist = hs_alloc(sizeof(int) * ((size_t)nz + 1));
    int* colof = hs_alloc(sizeof(int) * ((size_t)a->nnz + 1)); // column of each entry
    hs_status st = HS_ERR_NOMEM;
    if (cstart && clist && colof) {
        for (int j = 0; j < n; j++)
            for (int q = a->colp[j]; q < a->colp[j + 1]; q++)
                if (a->rowi[q] <= j) {
                    int c = pinv[a->rowi[q]] < pinv[j] ? pinv[a->rowi[q]] : pinv[j];
                    cstart[c + 2]++;
                }
        for (int c = 0; c < n; c++) cstart[c + 2] += cstart[c + 1];
        for (int j = 0; j < n; j++)
            for (int q = a->colp[j]; q < a->colp[j + 1]; q++)
                if (a->rowi[q] <= j) {
                    int c = pinv[a->rowi[q]] < pinv[j] ? pinv[a->rowi[q]] : pinv[j];
                    clist[cstart[c + 1]++] = q;
                }
        for (int j = 0; j < n; j++)
            for (int q = a->colp[j]; q < a->colp[j + 1]; q++) colof[q] = j;
        st = partial_place(L, a, p, pinv, cstart, clist, colof, cnt, pos);
    }
    hs_free(cstart);
    hs_free(clist);
    hs_free(colof);
    return st;
}

// Build the maps of a supernodal factor L for a matrix with a's pattern (both halves stored).
static hs_status build_partial(const cholmod_factor* L, const hs_csc* a, struct hs_partial** out) {
    const int n = (int)L->n, ns = (int)L->nsuper;
    const int *super = L->super, *perm = L->Perm;
    struct hs_partial* p = hs_calloc(1, sizeof *p);
    int* pinv = hs_alloc(sizeof(int) * ((size_t)n + 1));
    int* pos = hs_alloc(sizeof(int) * ((size_t)n + 1));
    int* cnt = hs_calloc((size_t)n + 1, sizeof(int));
    hs_status st = HS_ERR_NOMEM;
    if (p && pinv && pos && cnt) st = partial_alloc(p, n, ns);
    if (st == HS_OK) {
        for (int k = 0; k < n; k++) pinv[perm ? perm[k] : k] = k;
        for (int s = 0; s < ns; s++)
            for (int j = super[s]; j < super[s + 1]; j++) p->col_super[j] = s;
        st = partial_tree(L, p);
    }
    if (st == HS_OK) st = partial_children(L, p, cnt, pos);
    if (st == HS_OK) st = partial_entries(L, a, p, pinv, cnt, pos);
    hs_free(pinv);
    hs_free(pos);
    hs_free(cnt);
    if (st != HS_OK) {
        free_partial(&p);
        return st;
    }
    *out = p;
    return HS_OK;
}

// ---------------------------------------------------------------------------------------------
// Parallelism for the partial refactor's large supernodes (hs_cholesky_set_partial_parallel).
// A piece of work is cut into chunks that write disjoint parts of the output, run through the
// caller's hs_parallel; the cut depends on the sizes alone, never on the runner.

// Supernodes below this many flops (about 0.1 ms) stay on one thread: the split kernels would
// be too small to pay for the hand-over.
#define HS_PAR_MIN_FLOPS 3e6
#define HS_PAR_CHUNKS    8  // chunks per kernel: enough to even out unequal ones,
#define HS_PAR_WIDTH     48 // but no narrower than this (BLAS slows down on thin blocks)

// Rows or columns per chunk when m are shared out: a multiple of 4.
static int chunk_width(int m) {
    int w = (m + HS_PAR_CHUNKS - 1) / HS_PAR_CHUNKS;
    if (w < HS_PAR_WIDTH) w = HS_PAR_WIDTH;
    return (w + 3) & ~3;
}

void hs_sparse_thread_init(void* arg) {
    (void)arg;
    enum { W = 64 };
    static const double one = 1.0, zero = 0.0;
    double a[W * W] = {0}, c[W * W] = {0};
    const int w = W;
    dgemm_("N", "T", &w, &w, &w, &one, a, &w, a, &w, &zero, c, &w);
}

// fn(c, arg) for every chunk c < n, through d when given, else in order here.
static void chunks_run(const hs_parallel* d, hs_task_fn* fn, void* arg, int n) {
    if (!d) {
        for (int c = 0; c < n; c++) fn(c, arg);
        return;
    }
    d->run(n, fn, arg, d->user);
}

// B (m x k, rows of a lower block) := B L^-T, in chunks of rows.
typedef struct trsm_job {
    int m, k, ld, rows;
    const double* l;
    double* b;
} trsm_job;

static void trsm_chunk(int c, void* arg) {
    const trsm_job* j = arg;
    int r0 = c * j->rows, mm = j->m - r0 < j->rows ? j->m - r0 : j->rows;
    const double one = 1.0;
    if (mm > 0) dtrsm_("R", "L", "T", "N", &mm, &j->k, &one, j->l, &j->ld, j->b + r0, &j->ld);
}

static void trsm_run(const hs_parallel* d, int m, int k, const double* l, double* b, int ld) {
    trsm_job t = {m, k, ld, chunk_width(m), l, b};
    chunks_run(d, trsm_chunk, &t, (m + t.rows - 1) / t.rows);
}

// Lower triangle of C (m x m) := beta C - A A^T (A m x k), in blocks of columns: each a
// triangle on the diagonal and the rectangle under it, the first ones the largest.
typedef struct syrk_job {
    int m, k, lda, ldc, cols;
    double beta;
    const double* a;
    double* c;
} syrk_job;

static void syrk_chunk(int ch, void* arg) {
    const syrk_job* j = arg;
    int c0 = ch * j->cols, w = j->m - c0 < j->cols ? j->m - c0 : j->cols, below = j->m - c0 - w;
    const double minus = -1.0;
    if (w <= 0) return;
    double* cc = j->c + (size_t)c0 * (size_t)j->ldc + (size_t)c0;
    dsyrk_("L", "N", &w, &j->k, &minus, j->a + c0, &j->lda, &j->beta, cc, &j->ldc);
    if (below > 0)
        dgemm_("N", "T", &below, &w, &j->k, &minus, j->a + c0 + w, &j->lda, j->a + c0, &j->lda,
               &j->beta, cc + w, &j->ldc);
}

static void syrk_run(const hs_parallel* d, int m, int k, const double* a, int lda, double beta,
                     double* c, int ldc) {
    syrk_job y = {m, k, lda, ldc, chunk_width(m), beta, a, c};
    chunks_run(d, syrk_chunk, &y, (m + y.cols - 1) / y.cols);
}

// Cholesky of the n x n lower block a: recursive halves, the off-diagonal solve and the
// trailing update shared between the threads. LAPACK's info convention.
static int potrf_par(const hs_parallel* d, int n, double* a, int lda) {
    int info = 0;
    if (n < 192) {
        dpotrf_("L", &n, a, &lda, &info);
        return info;
    }
    int h = (n / 2 + 3) & ~3;
    info = potrf_par(d, h, a, lda);
    if (info) return info;
    double* a22 = a + (size_t)h * (size_t)lda + (size_t)h;
    trsm_run(d, n - h, h, a, a + h, lda);
    syrk_run(d, n - h, h, a + h, lda, 1.0, a22, lda);
    info = potrf_par(d, n - h, a22, lda);
    return info ? info + h : 0;
}

// d[i] += v[i], unrolled so that -O2 pairs the adds (its vectoriser leaves epilogue loops be).
static inline void add_run(double* restrict d, const double* restrict v, int len) {
    int i = 0;
    for (; i + 4 <= len; i += 4) {
        d[i] += v[i];
        d[i + 1] += v[i + 1];
        d[i + 2] += v[i + 2];
        d[i + 3] += v[i + 3];
    }
    for (; i < len; i++) d[i] += v[i];
}

// dst[rel[k]] += src[k] for k in [k0, k1): whole runs of consecutive rows at a time (rows come
// in node triples, and separators map in long runs).
static void extend_add_col(double* dst, const double* src, const int* rel, const int* run_end,
                           int k0, int k1) {
    for (int k = k0; k < k1; k = run_end[k]) add_run(dst + rel[k], src + k, run_end[k] - k);
}

// Supernode s's block assembled (phase 0: zeroed, A's entries and the children's update
// matrices in its columns) or the rest of the children's update matrices added into s's own
// (phase 1). Chunks are ranges of destination columns of about equal area, so no two chunks
// write the same entry.
typedef struct extadd_job {
    const struct hs_partial* p;
    int s, nc, nr, m, phase, n_chunks;
    double *x, *blk, *us;
    const double* aval;
} extadd_job;

// First destination column of chunk c: column j holds rows j..rows-1 of a width-column block.
static int extadd_bound(int c, int n_chunks, int width, int rows) {
    if (c <= 0) return 0;
    if (c >= n_chunks) return width;
    double total = (double)width * rows - 0.5 * (double)width * (width - 1);
    double area = total * c / n_chunks, b = rows + 0.5;
    int j = (int)(b - sqrt(b * b - 2.0 * area));
    return j < 0 ? 0 : j > width ? width : j;
}

static void extadd_chunk(int ch, void* arg) {
    const extadd_job* j = arg;
    const struct hs_partial* p = j->p;
    int width = j->phase ? j->m : j->nc, rows = j->phase ? j->m : j->nr;
    int lo = extadd_bound(ch, j->n_chunks, width, rows);
    int hi = extadd_bound(ch + 1, j->n_chunks, width, rows);
    int shift = j->phase ? j->nc : 0; // destination column of child column k: rel[k] - shift
    if (lo >= hi) return;
    if (j->phase == 0) {
        memset(j->blk + (size_t)lo * (size_t)j->nr, 0,
               sizeof(double) * (size_t)(hi - lo) * (size_t)j->nr);
        // A's entries of s come column by column: find those of columns [lo, hi).
        int e0 = p->ent_start[j->s], e1 = p->ent_start[j->s + 1];
        ptrdiff_t first = j->blk - j->x + (ptrdiff_t)lo * j->nr;
        ptrdiff_t last = j->blk - j->x + (ptrdiff_t)hi * j->nr;
        int a = e0, b = e1;
        while (a < b) {
            int mid = a + (b - a) / 2;
            if (p->ent_off[mid] < first)
                a = mid + 1;
            else
                b = mid;
        }
        for (int e = a; e < e1 && p->ent_off[e] < last; e++)
            j->x[p->ent_off[e]] += j->aval[p->ent_val[e]];
    }
    for (int q = p->child_start[j->s]; q < p->child_start[j->s + 1]; q++) {
        int c = p->child[q];
        int mc = p->rel_start[c + 1] - p->rel_start[c];
        const int* rel = p->rel + p->rel_start[c];
        const int* run = p->run_end + p->rel_start[c];
        const double* uc = p->u + p->u_start[c];
        int k = 0;
        while (k < mc && rel[k] - shift < lo) k++;
        for (; k < mc && rel[k] - shift < hi; k++) {
            double* dst = j->phase ? j->us + (size_t)(rel[k] - shift) * (size_t)j->m - shift
                                   : j->blk + (size_t)rel[k] * (size_t)j->nr;
            extend_add_col(dst, uc + (size_t)k * (size_t)mc, rel, run, k, mc);
        }
    }
}

// Recompute supernode s of L (its block in x) and its update matrix from A's values and the
// children's kept update matrices, on two threads when d is given. 0 if a pivot is not positive
// and finite, or collapsed below 1e-12 of A's diagonal (a singular matrix shows as round-off
// rather than a negative pivot).
static int factor_supernode(const cholmod_factor* L, struct hs_partial* p, const double* aval,
                            int s, const hs_parallel* d) {
    const int *super = L->super, *pi = L->pi, *px = L->px;
    double* x = L->x;
    const int nc = super[s + 1] - super[s], nr = pi[s + 1] - pi[s], m = nr - nc;
    double* blk = x + px[s];
    double* us = p->u + p->u_start[s];
    // Children's update matrices, the columns landing in s's own columns first; the rest go
    // after the syrk, which then writes the update matrix outright instead of adding to a
    // zeroed one.
    extadd_job ej = {p, s, nc, nr, m, 0, d ? HS_PAR_CHUNKS : 1, x, blk, us, aval};
    chunks_run(d, extadd_chunk, &ej, ej.n_chunks);
    int info = 0;
    if (d)
        info = potrf_par(d, nc, blk, nr);
    else
        dpotrf_("L", &nc, blk, &nr, &info);
    if (info != 0) return 0;
    for (int j = 0; j < nc; j++) {
        double dj = blk[(size_t)j * (size_t)nr + (size_t)j];
        double ajj = aval[p->diag_val[super[s] + j]];
        if (!(dj > 0.0 && dj < INFINITY) || !(dj * dj > 1e-12 * ajj)) return 0;
    }
    if (m == 0) return 1;
    if (d) {
        trsm_run(d, m, nc, blk, blk + nc, nr);
        syrk_run(d, m, nc, blk + nc, nr, 0.0, us, m);
    } else {
        const double one = 1.0, minus = -1.0, zero = 0.0;
        dtrsm_("R", "L", "T", "N", &m, &nc, &one, blk, &nr, blk + nc, &nr);
        dsyrk_("L", "N", &m, &nc, &minus, blk + nc, &nr, &zero, us, &m);
    }
    ej.phase = 1;
    chunks_run(d, extadd_chunk, &ej, ej.n_chunks);
    return 1;
}

hs_status hs_cholesky_prepare_partial(hs_cholesky* f, const hs_csc* a) {
    if (!f || !pattern_matches(f, a)) return HS_ERR_INVALID;
    if (f->updatable || !f->L->is_super) return HS_ERR_UNSUPPORTED;
    if (!f->pinv) {
        f->pinv = hs_alloc(sizeof(int) * ((size_t)f->n + 1));
        if (!f->pinv) return HS_ERR_NOMEM;
        for (int k = 0; k < f->n; k++) f->pinv[f->L->Perm ? ((const int*)f->L->Perm)[k] : k] = k;
    }
    if (!f->part) {
        hs_status st = build_partial(f->L, a, &f->part);
        if (st != HS_OK) return st;
    }
    return hs_cholesky_refactor_partial(f, a, -1, NULL);
}

hs_status hs_cholesky_refactor_partial(hs_cholesky* f, const hs_csc* a, int n_dofs,
                                       const int* dofs) {
    if (!f || !a || (n_dofs > 0 && !dofs)) return HS_ERR_INVALID;
    struct hs_partial* p = f->part;
    if (!p || f->updatable || !f->L->is_super) return HS_ERR_UNSUPPORTED;
    // The full pattern check costs O(nnz), a large part of a small partial refactor: done when
    // the matrix's arrays are not those checked last.
    if (a->n != f->n || a->nnz != f->nnz || a->colp != p->colp || a->rowi != p->rowi) {
        if (!pattern_matches(f, a)) return HS_ERR_INVALID;
        p->colp = a->colp;
        p->rowi = a->rowi;
    }
    apply_thread_limit();
    int all = n_dofs < 0 || !p->valid;
    if (!all) {
        for (int k = 0; k < n_dofs; k++)
            if (dofs[k] < 0 || dofs[k] >= f->n) return HS_ERR_INVALID;
        for (int k = 0; k < n_dofs; k++)
            for (int s = p->col_super[f->pinv[dofs[k]]]; s >= 0 && !p->mark[s]; s = p->parent[s])
                p->mark[s] = 1;
    }
    const double* aval = a->val;
    double done = 0;
    int ok = 1;
    const hs_parallel* d = f->par.width >= 2 ? &f->par : NULL;
    int awake = 0;
    for (int s = 0; s < p->ns; s++) {
        if (!all && !p->mark[s]) continue;
        p->mark[s] = 0;
        if (!ok) continue; // clear the remaining marks only
        int big = d && p->flops[s] >= HS_PAR_MIN_FLOPS;
        if (big && !awake) {
            // Supernodes come in postorder: the large ones last, so wake late.
            if (d->begin) d->begin(d->user);
            awake = 1;
        }
        ok = factor_supernode(f->L, p, aval, s, big ? d : NULL);
        done += p->flops[s];
    }
    if (awake && d->end) d->end(d->user);
    p->last_share = p->total_flops > 0 ? done / p->total_flops : 0;
    if (!ok) {
        // L is partly recomputed: unusable until a full refactor (as after a failed downdate).
        p->valid = 0;
        f->broken = 1;
        return HS_ERR_NOT_POSDEF;
    }
    p->valid = 1;
    f->broken = 0;
    return HS_OK;
}

hs_status hs_cholesky_set_partial_parallel(hs_cholesky* f, const hs_parallel* par) {
    if (!f || (par && par->width >= 2 && !par->run)) return HS_ERR_INVALID;
    f->par = par && par->width >= 2 ? *par : (hs_parallel){0};
    return HS_OK;
}

static void invalidate_partial(hs_cholesky* f) {
    if (f->part) f->part->valid = 0;
}

int64_t hs_cholesky_partial_bytes(const hs_cholesky* f) {
    if (!f || !f->L || !f->L->is_super) return -1;
    const cholmod_factor* L = f->L;
    const int *super = L->super, *pi = L->pi;
    int64_t b = 0;
    for (size_t s = 0; s < L->nsuper; s++) {
        int64_t m = (pi[s + 1] - pi[s]) - (super[s + 1] - super[s]);
        b += 8 * m * m + 8 * m + 64; // update matrix, rows in the parent and their runs, arrays
    }
    return b + 4 * (int64_t)f->nnz + 12 * (int64_t)f->n; // A's entries (upper half), columns
}

double hs_cholesky_partial_share(const hs_cholesky* f) {
    return f && f->part ? f->part->last_share : 0;
}
