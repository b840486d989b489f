// SPDX-License-Identifier: GPL-2.0-or-later
// libFuzzer target: the TetGen reader. The input is the .node text, a NUL byte, then the .ele
// text (no NUL: the .ele file is empty).
#include "fuzz_mesh_common.h"

int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
    int64_t before = hs_byte_count();
    const char* text = (const char*)data;
    const char* nul = size ? memchr(text, '\0', size) : NULL;
    size_t node_len = nul ? (size_t)(nul - text) : size;
    const char* ele = nul ? nul + 1 : text + size;
    size_t ele_len = size - node_len - (nul ? 1 : 0);
    hs_mesh* m = NULL;
    hs_err err = {0};
    hs_status st = hs_mesh_parse_tetgen("fuzz", text, node_len, ele, ele_len, &m, &err);
    hs_fuzz_mesh_verify(st, m, &err, "fuzz.", before);
    return 0;
}
