// SPDX-License-Identifier: GPL-2.0-or-later
// libFuzzer target: scene files (hs_scene_parse). Any input either parses or fails with an
// HS_ERR_PARSE message naming the file; nothing leaks.
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include "scene.h"

int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size);

int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
    int64_t before = hs_byte_count();
    char* text = malloc(size + 1);
    if (!text) return 0;
    memcpy(text, data, size);
    text[size] = '\0';
    hs_scene s;
    hs_err err = {0};
    hs_status st = hs_scene_parse(text, "/fuzz/scene.json", 0, &s, &err);
    if (st != HS_OK && (st != HS_ERR_PARSE || !strstr(err.msg, "/fuzz/scene.json"))) abort();
    if (st == HS_OK &&
        (s.n_fixed < 1 || s.n_fixed > HS_SCENE_MAX_FIXED || s.n_tools > HS_SCENE_MAX_TOOLS ||
         !memchr(s.mesh_path, 0, sizeof s.mesh_path)))
        abort();
    free(text);
    if (hs_byte_count() != before) abort();
    return 0;
}
