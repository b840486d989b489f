// SPDX-License-Identifier: GPL-2.0-or-later
// libFuzzer target: the VTK XML unstructured-grid (.vtu, ASCII) reader.
#include "fuzz_mesh_common.h"

int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
    int64_t before = hs_byte_count();
    hs_mesh* m = NULL;
    hs_err err = {0};
    hs_status st = hs_mesh_parse("fuzz.vtu", "vtu", (const char*)data, size, &m, &err);
    hs_fuzz_mesh_verify(st, m, &err, "fuzz.vtu", before);
    return 0;
}
