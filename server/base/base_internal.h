// SPDX-License-Identifier: GPL-2.0-or-later
// Helpers the server's modules share but the public API does not offer: whole-file reading for
// the file readers (mesh, surface) and path extensions.
#ifndef HAPSIM_BASE_INTERNAL_H
#define HAPSIM_BASE_INTERNAL_H

#include "hapsim/base.h"

/// Largest file hs_read_file reads.
#define HS_MAX_FILE_BYTES ((size_t)512 << 20)

/// Whole file into an accounted buffer (free with hs_free), at most HS_MAX_FILE_BYTES; errors
/// name the path (cannot open, read error, too large, no memory).
hs_status hs_read_file(const char* path, char** data /* OUT */, size_t* len /* OUT */, hs_err* err);

/// 1 when path ends in ext (".msh"), ignoring ASCII case.
int hs_path_has_ext(const char* path, const char* ext);

#endif
