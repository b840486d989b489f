// SPDX-License-Identifier: GPL-2.0-or-later
// libFuzzer target: the surface readers (STL ASCII/binary, OBJ, PLY, OFF, legacy VTK POLYDATA
// ASCII/binary, MSH and VTU triangles) and the surface check/repair. The first byte picks the
// format (low 3 bits) and whether to repair (bit 3); the
// rest is the file. Oracle: an error names the file; a surface has its indices in range; a
// clean that succeeds leaves a closed, consistently oriented surface; nothing leaks.
#include "surface.h"

#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size);

static const char* const k_fmt[8] = {"stl", "obj", "ply", "off", "msh", "vtu", "vtk", "vtk"};

int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
    if (size < 1) return 0;
    const char* fmt = k_fmt[data[0] & 7];
    int repair = (data[0] >> 3) & 1;
    int64_t before = hs_byte_count();
    hs_surface* s = NULL;
    hs_err err = {0};
    hs_status st = hs_surface_parse("fuzz.surf", fmt, (const char*)data + 1, size - 1, &s, &err);
    if (st < 0) {
        if (s || strncmp(err.msg, "fuzz.surf", 9) != 0) {
            fprintf(stderr, "error without the file name, or a surface returned: %s\n", err.msg);
            abort();
        }
    } else {
        for (int i = 0; i < 3 * s->n_tris; ++i)
            if (s->tris[i] < 0 || s->tris[i] >= s->n_verts) {
                fprintf(stderr, "triangle index %d out of [0, %d)\n", s->tris[i], s->n_verts);
                abort();
            }
        hs_surface_clean_def cd = hs_surface_clean_default_def();
        cd.repair = repair;
        hs_surface_report r;
        st = hs_surface_clean(s, "fuzz.surf", &cd, &r, &err);
        if (st >= 0 && (r.boundary_edges || r.nonmanifold_edges || !(r.volume > 0))) {
            fprintf(stderr, "clean passed an open or empty surface\n");
            abort();
        }
        if (st < 0 && strncmp(err.msg, "fuzz.surf", 9) != 0) {
            fprintf(stderr, "clean error without the name: %s\n", err.msg);
            abort();
        }
        hs_surface_destroy(&s);
    }
    if (hs_byte_count() != before) {
        fprintf(stderr, "leak: %lld bytes\n", (long long)(hs_byte_count() - before));
        abort();
    }
    return 0;
}
