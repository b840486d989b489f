// SPDX-License-Identifier: GPL-2.0-or-later
// Tiny test macros (after Box2D's test/test_macros.h). A failed check prints and returns 1.
#ifndef HS_TEST_MACROS_H
#define HS_TEST_MACROS_H

#include <math.h>
#include <stdio.h>
#include <string.h>

#define ENSURE(C)                                                                                  \
    do {                                                                                           \
        if (!(C)) {                                                                                \
            printf("  condition false: %s (%s:%d)\n", #C, __FILE__, __LINE__);                     \
            return 1;                                                                              \
        }                                                                                          \
    } while (0)

#define ENSURE_SMALL(C, tol)                                                                       \
    do {                                                                                           \
        double ensure_v_ = (double)(C);                                                            \
        if (!(fabs(ensure_v_) <= (tol))) {                                                         \
            printf("  not small: %s = %g > %g (%s:%d)\n", #C, ensure_v_, (double)(tol), __FILE__,  \
                   __LINE__);                                                                      \
            return 1;                                                                              \
        }                                                                                          \
    } while (0)

#define ENSURE_NEAR(A, B, tol) ENSURE_SMALL((double)(A) - (double)(B), tol)

typedef struct hs_test_case {
    const char* name;
    int (*fn)(void);
} hs_test_case;

// Runs the cases whose name contains argv[1] (all if absent). Prints "N passed, N failed".
static inline int hs_test_main(int argc, char** argv, const hs_test_case* cases, int n) {
    const char* filter = argc > 1 ? argv[1] : NULL;
    int passed = 0, failed = 0;
    for (int i = 0; i < n; ++i) {
        if (filter && !strstr(cases[i].name, filter)) continue;
        printf("[ RUN  ] %s\n", cases[i].name);
        fflush(stdout);
        int rc = cases[i].fn();
        printf("[ %s ] %s\n", rc == 0 ? " OK " : "FAIL", cases[i].name);
        fflush(stdout);
        if (rc == 0)
            ++passed;
        else
            ++failed;
    }
    printf("%d passed, %d failed\n", passed, failed);
    return failed == 0 && passed > 0 ? 0 : 1;
}

#define HS_TEST_MAIN(...)                                                                          \
    int main(int argc, char** argv) {                                                              \
        static const hs_test_case cases[] = {__VA_ARGS__};                                         \
        return hs_test_main(argc, argv, cases, (int)(sizeof cases / sizeof cases[0]));             \
    }
#define HS_CASE(fn)                                                                                \
    { #fn, fn }

#endif
