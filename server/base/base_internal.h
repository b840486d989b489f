// SPDX-License-Identifier: GPL-2.0-or-later
// Helpers the server's modules share but the public API does not offer: whole-file reading,
// path extensions and token parsing for the file readers (mesh, surface).
#ifndef HAPSIM_BASE_INTERNAL_H
#define HAPSIM_BASE_INTERNAL_H

#include "base.h"

/// Largest file hs_read_file reads.
#define HS_MAX_FILE_BYTES ((size_t)512 << 20)

/// Whole file into an accounted buffer (free with hs_free), at most HS_MAX_FILE_BYTES; errors
/// name the path (cannot open, read error, too large, no memory).
hs_status hs_read_file(const char* path, char** data /* OUT */, size_t* len /* OUT */, hs_err* err);

/// 1 when path ends in ext (".msh"), ignoring ASCII case.
int hs_path_has_ext(const char* path, const char* ext);

/// Strict decimal integer of s[0..len) with an optional sign; 0 if malformed or beyond long long.
int hs_parse_ll(const char* s, size_t len, long long* v /* OUT */);

/// Decimal number of s[0..len), NaN and infinities included (callers name them); 0 if
/// malformed, hexadecimal (strtod would take "0x1p0") or longer than 511 characters.
int hs_parse_number(const char* s, size_t len, double* v /* OUT */);

/// Printable excerpt of s[0..len) for messages: at most max characters, others as '?', "..."
/// when cut. buf holds max + 4 bytes. Returns buf.
const char* hs_text_excerpt(const char* s, size_t len, size_t max, char* buf);

#endif
