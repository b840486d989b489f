// SPDX-License-Identifier: GPL-2.0-or-later
// libFuzzer target: hs_mesh_create / hs_mesh_finalize on arbitrary small meshes. Nodes sit on
// a coarse grid so inverted, degenerate, duplicate, overlapping and non-manifold tets are
// common. Byte 0: node count; then 3 bytes per node; then 4 bytes per tet.
#include "fuzz_mesh_common.h"

int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
    if (size < 1) return 0;
    int64_t before = hs_byte_count();
    int n_nodes = 1 + data[0] % 24;
    if (size < 1 + 3 * (size_t)n_nodes) return 0;
    double x[3 * 24];
    for (int i = 0; i < 3 * n_nodes; ++i) {
        uint8_t b = data[1 + i];
        x[i] = (double)(b % 7) - 3.0 + (b & 0x80 ? 0.5 : 0.0);
    }
    const uint8_t* t = data + 1 + 3 * n_nodes;
    int n_tets = (int)((size - 1 - 3 * (size_t)n_nodes) / 4);
    if (n_tets > 256) n_tets = 256;
    int tets[4 * 256];
    for (int k = 0; k < 4 * n_tets; ++k) tets[k] = t[k] % (n_nodes + 1); // n_nodes: out of range
    hs_mesh* m = NULL;
    hs_err err = {0};
    hs_status st = hs_mesh_create(n_nodes, x, n_tets, tets, &m, &err);
    if (st >= 0 && (!m || hs_mesh_finalize(m, &err) != HS_OK)) abort(); // nothing left to repair
    hs_fuzz_mesh_verify(st, m, &err, "", before);
    return 0;
}
