// SPDX-License-Identifier: GPL-2.0-or-later
// Base: allocation accounting, fault injection, status text, error formatting.
#include "base.h"
#include "test_macros.h"

static int AllocAccounting(void) {
    int64_t before = hs_byte_count();
    double* a = hs_alloc(100 * sizeof(double));
    ENSURE(a != NULL);
    ENSURE(((uintptr_t)a & 15u) == 0);
    ENSURE(hs_byte_count() == before + 100 * (int64_t)sizeof(double));
    a = hs_realloc(a, 10 * sizeof(double));
    ENSURE(a != NULL);
    ENSURE(hs_byte_count() == before + 10 * (int64_t)sizeof(double));
    int* z = hs_calloc(7, sizeof(int));
    ENSURE(z && z[0] == 0 && z[6] == 0);
    ENSURE(hs_calloc(SIZE_MAX / 2, 4) == NULL); // overflow refused, nothing counted
    hs_free(a);
    hs_free(z);
    hs_free(NULL);
    ENSURE(hs_byte_count() == before);
    return 0;
}

static int FaultInjection(void) {
    hs_alloc_fail_after(2);
    void* a = hs_alloc(8);
    void* b = hs_alloc(8);
    void* c = hs_alloc(8);
    ENSURE(a != NULL && b == NULL && c != NULL);
    hs_free(a);
    hs_free(c);
    return 0;
}

static int StatusText(void) {
    ENSURE(strcmp(hs_status_str(HS_OK), "ok") == 0);
    ENSURE(strstr(hs_status_str(HS_ERR_PARSE), "malformed") != NULL);
    ENSURE(strcmp(hs_status_str((hs_status)-99), "unknown status") == 0);
    hs_err e;
    ENSURE(hs_err_set(&e, HS_ERR_IO, "%s:%d: bad", "f.msh", 12) == HS_ERR_IO);
    ENSURE(e.code == HS_ERR_IO && strcmp(e.msg, "f.msh:12: bad") == 0);
    ENSURE(hs_err_set(NULL, HS_ERR_IO, "x") == HS_ERR_IO);
    return 0;
}

HS_TEST_MAIN(HS_CASE(AllocAccounting), HS_CASE(FaultInjection), HS_CASE(StatusText))
