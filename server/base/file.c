// SPDX-License-Identifier: GPL-2.0-or-later
// Whole-file reading, path extensions and token parsing for the file readers.
#include "base_internal.h"
#include "open_regular.h"

#include <errno.h>
#include <limits.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

hs_status hs_read_file(const char* path, char** data, size_t* len, hs_err* err) {
    *data = NULL;
    *len = 0;
    FILE* f = NULL; // a FIFO or device is refused without blocking on it
    hs_status ost = hs_open_regular(path, &f, err);
    if (ost != HS_OK) return ost;
    size_t cap = (size_t)1 << 16, n = 0;
    char* buf = hs_alloc(cap);
    hs_status st = buf ? HS_OK : hs_err_set(err, HS_ERR_NOMEM, "%s: out of memory", path);
    while (st == HS_OK) {
        if (n == cap) {
            if (cap >= HS_MAX_FILE_BYTES) {
                st = hs_err_set(err, HS_ERR_IO, "%s: larger than %zu MiB", path,
                                HS_MAX_FILE_BYTES >> 20);
                break;
            }
            char* g = hs_realloc(buf, cap * 2);
            if (!g) {
                st = hs_err_set(err, HS_ERR_NOMEM, "%s: out of memory", path);
                break;
            }
            buf = g;
            cap *= 2;
        }
        size_t got = fread(buf + n, 1, cap - n, f);
        n += got;
        if (got == 0) {
            if (ferror(f))
                st = hs_err_set(err, HS_ERR_IO, "%s: read error: %s", path, strerror(errno));
            break;
        }
    }
    fclose(f);
    if (st != HS_OK) {
        hs_free(buf);
        return st;
    }
    *data = buf;
    *len = n;
    return HS_OK;
}

int hs_path_has_ext(const char* path, const char* ext) {
    size_t n = strlen(path), e = strlen(ext);
    if (n < e) return 0;
    for (size_t i = 0; i < e; ++i) {
        char c = path[n - e + i], x = ext[i];
        if (c >= 'A' && c <= 'Z') c = (char)(c - 'A' + 'a');
        if (x >= 'A' && x <= 'Z') x = (char)(x - 'A' + 'a');
        if (c != x) return 0;
    }
    return 1;
}

int hs_parse_ll(const char* s, size_t len, long long* v) {
    size_t i = 0;
    int neg = 0;
    if (len > 0 && (s[0] == '-' || s[0] == '+')) {
        neg = s[0] == '-';
        i = 1;
    }
    if (i == len) return 0;
    unsigned long long acc = 0;
    for (; i < len; ++i) {
        unsigned d = (unsigned)(unsigned char)s[i] - '0';
        if (d > 9 || acc > ((unsigned long long)LLONG_MAX - d) / 10) return 0;
        acc = acc * 10 + d;
    }
    *v = neg ? -(long long)acc : (long long)acc;
    return 1;
}

int hs_parse_number(const char* s, size_t len, double* v) {
    char buf[512];
    if (len == 0 || len >= sizeof buf) return 0;
    for (size_t i = 0; i < len; ++i)
        if (s[i] == 'x' || s[i] == 'X') return 0;
    memcpy(buf, s, len);
    buf[len] = '\0';
    char* e = NULL;
    double d = strtod(buf, &e);
    if (e != buf + len) return 0;
    *v = d;
    return 1;
}

const char* hs_text_excerpt(const char* s, size_t len, size_t max, char* buf) {
    size_t n = len < max ? len : max;
    for (size_t i = 0; i < n; ++i) {
        unsigned char c = (unsigned char)s[i];
        buf[i] = c >= 0x20 && c < 0x7f ? (char)c : '?';
    }
    strcpy(buf + n, len > max ? "..." : "");
    return buf;
}
