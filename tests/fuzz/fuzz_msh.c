// SPDX-License-Identifier: GPL-2.0-or-later
// libFuzzer target: the Gmsh MSH 2.2 / 4.1 reader.
#include "fuzz_mesh_common.h"

int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
    int64_t before = hs_byte_count();
    hs_mesh* m = NULL;
    hs_err err = {0};
    hs_status st = hs_mesh_parse("fuzz.msh", "msh", (const char*)data, size, &m, &err);
    hs_fuzz_mesh_verify(st, m, &err, "fuzz.msh", before);
    return 0;
}
