// SPDX-License-Identifier: GPL-2.0-or-later
// Shared oracle of the mesh fuzzers: any input either fails with a message naming the file,
// or gives a mesh that passes hs_mesh_check; nothing leaks either way.
#ifndef HS_FUZZ_MESH_COMMON_H
#define HS_FUZZ_MESH_COMMON_H

#include "mesh.h"

#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size);

static inline void hs_fuzz_mesh_verify(hs_status st, hs_mesh* m, const hs_err* err,
                                       const char* name, int64_t bytes_before) {
    if (st < 0) {
        if (m != NULL) {
            fprintf(stderr, "error %d but a mesh was returned\n", st);
            abort();
        }
        if (strncmp(err->msg, name, strlen(name)) != 0) {
            fprintf(stderr, "error message does not name the file: %s\n", err->msg);
            abort();
        }
    } else {
        hs_err check = {0};
        if (!m || hs_mesh_check(m, &check) != HS_OK) {
            fprintf(stderr, "loaded mesh fails hs_mesh_check: %s\n", check.msg);
            abort();
        }
        hs_mesh_destroy(&m);
    }
    if (hs_byte_count() != bytes_before) {
        fprintf(stderr, "leak: %lld bytes\n", (long long)(hs_byte_count() - bytes_before));
        abort();
    }
}

#endif
