// SPDX-License-Identifier: GPL-2.0-or-later
// Surface readers: STL (ASCII, binary), OBJ, PLY (ASCII, binary either endian), OFF, legacy VTK
// POLYDATA (ASCII, binary), and MSH/VTU triangles (through the mesh module's reader). Each parses a
// byte buffer that need not be NUL-terminated, never reads past it, checks declared counts against
// the bytes left before allocating, and fails with "<file>:<line>: <problem>" (binary: "<file>:
// byte N: ...").
#include "base_internal.h"
#include "surface_internal.h"

#include <errno.h>
#include <limits.h>
#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#define HS_SURFACE_MAX_COUNT (0x7fffffff / 16)

typedef struct rd {
    const char* name;
    const char* p;
    const char* end;
    int line;
    hs_err* err;
    hs_status status;
    // growing output
    int n_verts, cap_verts;
    double* x;
    int n_tris, cap_tris;
    int* tris;
} rd;

static int rd_fail(rd* r, int line, const char* fmt, ...) __attribute__((format(printf, 3, 4)));
static int rd_fail(rd* r, int line, const char* fmt, ...) {
    char problem[400];
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(problem, sizeof problem, fmt, ap);
    va_end(ap);
    r->status = HS_ERR_PARSE;
    if (line > 0)
        hs_err_set(r->err, HS_ERR_PARSE, "%s:%d: %s", r->name, line, problem);
    else
        hs_err_set(r->err, HS_ERR_PARSE, "%s: %s", r->name, problem);
    return 0;
}

static int rd_nomem(rd* r) {
    r->status = HS_ERR_NOMEM;
    hs_err_set(r->err, HS_ERR_NOMEM, "%s: out of memory", r->name);
    return 0;
}

static int add_vert(rd* r, const double v[3], int line) {
    for (int d = 0; d < 3; ++d)
        if (!isfinite(v[d]) || fabs(v[d]) > 1e30)
            return rd_fail(r, line, "vertex %d: coordinate %d is %g (not a finite number)",
                           r->n_verts + 1, d, v[d]);
    if (r->n_verts >= HS_SURFACE_MAX_COUNT) return rd_fail(r, line, "too many vertices");
    if (r->n_verts == r->cap_verts) {
        int cap = r->cap_verts ? 2 * r->cap_verts : 256;
        if (cap > HS_SURFACE_MAX_COUNT) cap = HS_SURFACE_MAX_COUNT;
        double* g = hs_realloc(r->x, (size_t)cap * 3 * sizeof(double));
        if (!g) return rd_nomem(r);
        r->x = g;
        r->cap_verts = cap;
    }
    memcpy(r->x + 3 * r->n_verts++, v, 3 * sizeof(double));
    return 1;
}

static int add_tri(rd* r, int a, int b, int c, int line) {
    if (r->n_tris >= HS_SURFACE_MAX_COUNT) return rd_fail(r, line, "too many triangles");
    if (r->n_tris == r->cap_tris) {
        int cap = r->cap_tris ? 2 * r->cap_tris : 256;
        if (cap > HS_SURFACE_MAX_COUNT) cap = HS_SURFACE_MAX_COUNT;
        int* g = hs_realloc(r->tris, (size_t)cap * 3 * sizeof(int));
        if (!g) return rd_nomem(r);
        r->tris = g;
        r->cap_tris = cap;
    }
    int* t = r->tris + 3 * r->n_tris++;
    t[0] = a;
    t[1] = b;
    t[2] = c;
    return 1;
}

// ---------------------------------------------------------------------------------------------
// Tokens on lines.

static int is_blank(char c) {
    return c == ' ' || c == '\t' || c == '\r' || c == '\f' || c == '\v';
}

typedef struct tk {
    const char* s;
    size_t len;
} tk;

// Next token on the current line; 0 at its end (the newline is not consumed).
static int tok_line(rd* r, tk* t) {
    while (r->p < r->end && is_blank(*r->p)) ++r->p;
    if (r->p >= r->end || *r->p == '\n') return 0;
    t->s = r->p;
    while (r->p < r->end && !is_blank(*r->p) && *r->p != '\n') ++r->p;
    t->len = (size_t)(r->p - t->s);
    return 1;
}

static void next_line(rd* r) {
    const char* nl = memchr(r->p, '\n', (size_t)(r->end - r->p));
    r->p = nl ? nl + 1 : r->end;
    ++r->line;
}

// Next token, crossing lines; 0 at the end of the data.
static int tok_any(rd* r, tk* t) {
    for (;;) {
        if (tok_line(r, t)) return 1;
        if (r->p >= r->end) return 0;
        next_line(r);
    }
}

static int tok_eq(const tk* t, const char* s) {
    size_t n = strlen(s);
    if (t->len != n) return 0;
    for (size_t i = 0; i < n; ++i) {
        char a = t->s[i];
        if (a >= 'A' && a <= 'Z') a = (char)(a - 'A' + 'a');
        if (a != s[i]) return 0;
    }
    return 1;
}

static const char* tok_show(const tk* t, char buf[40]) {
    return hs_text_excerpt(t->s, t->len, 24, buf);
}

// A decimal number (NaN and inf are read so the caller can name them; hexadecimal refused).
static int tok_double(const tk* t, double* v) {
    return hs_parse_number(t->s, t->len, v);
}

static int tok_ll(const tk* t, long long* v) {
    return hs_parse_ll(t->s, t->len, v);
}

static int need_double(rd* r, int any, const char* what, double* v) {
    tk t;
    char b[40];
    int line = r->line;
    if (!(any ? tok_any(r, &t) : tok_line(r, &t))) return rd_fail(r, line, "missing %s", what);
    if (!tok_double(&t, v))
        return rd_fail(r, r->line, "bad %s '%s' (expected a number)", what, tok_show(&t, b));
    return 1;
}

static int need_int(rd* r, int any, long long lo, long long hi, const char* what, long long* v) {
    tk t;
    char b[40];
    int line = r->line;
    if (!(any ? tok_any(r, &t) : tok_line(r, &t))) return rd_fail(r, line, "missing %s", what);
    if (!tok_ll(&t, v))
        return rd_fail(r, r->line, "bad %s '%s' (expected an integer)", what, tok_show(&t, b));
    if (*v < lo || *v > hi)
        return rd_fail(r, r->line, "%s %lld out of range [%lld, %lld]", what, *v, lo, hi);
    return 1;
}

static int check_count(rd* r, long long n, size_t min_bytes, const char* what) {
    size_t left = (size_t)(r->end - r->p);
    if (n < 0 || (unsigned long long)n > left / min_bytes + 1 || n > HS_SURFACE_MAX_COUNT)
        return rd_fail(r, r->line, "%s count %lld does not fit in the %zu bytes that follow", what,
                       n, left);
    return 1;
}

// A polygon's vertices (file indices already made 0-based and checked) as a fan.
static int add_polygon(rd* r, const int* v, int k, int line) {
    if (k < 3) return rd_fail(r, line, "a face needs at least 3 vertices, this one has %d", k);
    for (int i = 1; i + 1 < k; ++i)
        if (!add_tri(r, v[0], v[i], v[i + 1], line)) return 0;
    return 1;
}

// ---------------------------------------------------------------------------------------------
// STL

static uint32_t le32(const unsigned char* p) {
    return (uint32_t)p[0] | (uint32_t)p[1] << 8 | (uint32_t)p[2] << 16 | (uint32_t)p[3] << 24;
}

static float lef32(const unsigned char* p) {
    uint32_t u = le32(p);
    float f;
    memcpy(&f, &u, sizeof f);
    return f;
}

static int stl_binary(rd* r) {
    size_t len = (size_t)(r->end - r->p);
    const unsigned char* d = (const unsigned char*)r->p;
    uint32_t n = le32(d + 80);
    if ((size_t)n > (len - 84) / 50)
        return rd_fail(r, 0,
                       "binary STL header says %u triangles (%llu bytes) but the file has %zu "
                       "bytes",
                       n, 84ull + 50ull * n, len);
    if (n == 0) return rd_fail(r, 0, "binary STL with no triangles");
    if (len != 84 + 50 * (size_t)n)
        return rd_fail(r, 0, "binary STL of %u triangles should be %zu bytes, the file has %zu", n,
                       84 + 50 * (size_t)n, len);
    for (uint32_t i = 0; i < n; ++i) {
        const unsigned char* f = d + 84 + 50 * (size_t)i;
        for (int c = 0; c < 3; ++c) {
            double v[3];
            for (int k = 0; k < 3; ++k) v[k] = lef32(f + 12 + 12 * c + 4 * k);
            if (!isfinite(v[0]) || !isfinite(v[1]) || !isfinite(v[2]))
                return rd_fail(r, 0, "byte %zu: triangle %u, corner %d is not finite (%g, %g, %g)",
                               84 + 50 * (size_t)i + 12 + 12 * (size_t)c, i + 1, c + 1, v[0], v[1],
                               v[2]);
            if (!add_vert(r, v, 0)) return 0;
        }
        if (!add_tri(r, r->n_verts - 3, r->n_verts - 2, r->n_verts - 1, 0)) return 0;
    }
    return 1;
}

static int stl_ascii(rd* r) {
    tk t;
    char b[40];
    int in_facet = 0, corners = 0, facet_line = 0;
    next_line(r); // "solid name"
    while (tok_any(r, &t)) {
        int line = r->line;
        if (tok_eq(&t, "facet")) {
            if (in_facet) return rd_fail(r, line, "'facet' inside a facet (missing 'endfacet')");
            in_facet = 1;
            corners = 0;
            facet_line = line;
            next_line(r); // the normal is recomputed from the corners
        } else if (tok_eq(&t, "vertex")) {
            if (!in_facet) return rd_fail(r, line, "'vertex' outside a facet");
            double v[3];
            if (!need_double(r, 0, "x", v) || !need_double(r, 0, "y", v + 1) ||
                !need_double(r, 0, "z", v + 2))
                return 0;
            if (++corners > 3)
                return rd_fail(r, line, "facet of line %d has more than 3 vertices", facet_line);
            if (!add_vert(r, v, line)) return 0;
        } else if (tok_eq(&t, "endfacet")) {
            if (!in_facet) return rd_fail(r, line, "'endfacet' without 'facet'");
            if (corners != 3)
                return rd_fail(r, line, "facet of line %d has %d vertices, not 3", facet_line,
                               corners);
            if (!add_tri(r, r->n_verts - 3, r->n_verts - 2, r->n_verts - 1, facet_line)) return 0;
            in_facet = 0;
        } else if (tok_eq(&t, "outer") || tok_eq(&t, "endloop")) {
            next_line(r);
        } else if (tok_eq(&t, "endsolid")) {
            next_line(r);
            // Several solids may follow each other.
            if (tok_any(r, &t)) {
                if (!tok_eq(&t, "solid"))
                    return rd_fail(r, r->line, "unexpected '%s' after endsolid", tok_show(&t, b));
                next_line(r);
            }
        } else {
            return rd_fail(r, line, "unexpected '%s' in an ASCII STL", tok_show(&t, b));
        }
    }
    if (in_facet) return rd_fail(r, facet_line, "file ends inside the facet of this line");
    if (r->n_tris == 0) return rd_fail(r, r->line, "ASCII STL with no facets");
    return 1;
}

static int parse_stl(rd* r) {
    size_t len = (size_t)(r->end - r->p);
    if (len == 0) return rd_fail(r, 0, "empty file");
    // "solid" starts ASCII files, but some binary exporters write it in the 80-byte header too:
    // the size formula decides.
    if (len >= 84) {
        uint32_t n = le32((const unsigned char*)r->p + 80);
        if (84 + 50 * (size_t)n == len) return stl_binary(r);
    }
    if (len >= 5 && strncmp(r->p, "solid", 5) == 0) return stl_ascii(r);
    if (len < 84) return rd_fail(r, 0, "not an STL file (%zu bytes, no 'solid' header)", len);
    return stl_binary(r);
}

// ---------------------------------------------------------------------------------------------
// OBJ: v x y z [w], f a[/t][/n] b c ... (1-based, negative = relative), other records skipped.

static int parse_obj(rd* r) {
    tk t;
    char b[40];
    int poly[64];
    if (r->p >= r->end) return rd_fail(r, 0, "empty file");
    for (; r->p < r->end; next_line(r)) {
        int line = r->line;
        if (!tok_line(r, &t) || t.s[0] == '#') continue;
        if (tok_eq(&t, "v")) {
            double v[3];
            if (!need_double(r, 0, "x", v) || !need_double(r, 0, "y", v + 1) ||
                !need_double(r, 0, "z", v + 2) || !add_vert(r, v, line))
                return 0;
        } else if (tok_eq(&t, "f")) {
            int k = 0;
            while (tok_line(r, &t)) {
                tk idx = t;
                const char* slash = memchr(t.s, '/', t.len);
                if (slash) idx.len = (size_t)(slash - t.s);
                long long i;
                if (!tok_ll(&idx, &i) || i == 0)
                    return rd_fail(r, line, "bad face index '%s'", tok_show(&t, b));
                long long j = i > 0 ? i - 1 : r->n_verts + i;
                if (j < 0 || j >= r->n_verts)
                    return rd_fail(r, line, "face index %lld: only %d vertices so far", i,
                                   r->n_verts);
                if (k == 64) return rd_fail(r, line, "face with more than 64 vertices");
                poly[k++] = (int)j;
            }
            if (!add_polygon(r, poly, k, line)) return 0;
        } else if (t.len > 0 && (t.s[0] < 0x20 || (unsigned char)t.s[0] >= 0x7f)) {
            return rd_fail(r, line, "binary data in an OBJ file");
        }
        // vt, vn, g, o, s, usemtl, mtllib, l, p: not surface geometry, skipped
    }
    if (r->n_tris == 0) return rd_fail(r, r->line, "no faces ('f' lines)");
    return 1;
}

// ---------------------------------------------------------------------------------------------
// OFF: "OFF", then "nv nf ne", nv vertices, nf faces "k i0 .. ik-1 [colour]". '#' comments.

static int off_next(rd* r, tk* t) {
    for (;;) {
        if (!tok_any(r, t)) return 0;
        if (t->s[0] != '#') return 1;
        next_line(r);
    }
}

static int parse_off(rd* r) {
    tk t;
    char b[40];
    if (!off_next(r, &t)) return rd_fail(r, 0, "empty file");
    if (!tok_eq(&t, "off"))
        return rd_fail(r, r->line, "not an OFF file (expected 'OFF', found '%s')", tok_show(&t, b));
    long long nv, nf, ne;
    if (!off_next(r, &t)) return rd_fail(r, r->line, "missing vertex count");
    if (!tok_ll(&t, &nv) || nv < 0)
        return rd_fail(r, r->line, "bad vertex count '%s'", tok_show(&t, b));
    if (!need_int(r, 1, 0, LLONG_MAX, "face count", &nf) ||
        !need_int(r, 1, 0, LLONG_MAX, "edge count", &ne) || !check_count(r, nv, 6, "vertex") ||
        !check_count(r, nf, 8, "face"))
        return 0;
    for (long long i = 0; i < nv; ++i) {
        double v[3];
        if (!need_double(r, 1, "x", v) || !need_double(r, 1, "y", v + 1) ||
            !need_double(r, 1, "z", v + 2) || !add_vert(r, v, r->line))
            return 0;
        next_line(r); // colours or normals after the coordinates
    }
    int poly[64];
    for (long long f = 0; f < nf; ++f) {
        long long k, v;
        if (!need_int(r, 1, 0, 64, "face vertex count", &k)) return 0;
        int line = r->line;
        for (long long c = 0; c < k; ++c) {
            if (!need_int(r, 0, 0, nv - 1, "vertex index", &v)) return 0;
            poly[c] = (int)v;
        }
        if (!add_polygon(r, poly, (int)k, line)) return 0;
        next_line(r); // optional colour
    }
    if (nf == 0) return rd_fail(r, r->line, "no faces");
    return 1;
}

// ---------------------------------------------------------------------------------------------
// PLY: header, then elements in order. Reads vertex x, y, z and face vertex_indices (or
// vertex_index); every other property and element is read past.

enum { PLY_MAX_PROPS = 32, PLY_MAX_ELEMS = 16 };

typedef struct ply_prop {
    int type;       // scalar type (1..8 below), the list's item type when is_list
    int count_type; // list: type of the count
    int is_list;
    int role; // 0 other, 1 x, 2 y, 3 z, 4 face indices
} ply_prop;

typedef struct ply_elem {
    int kind; // 0 other, 1 vertex, 2 face
    long long n;
    int n_props;
    ply_prop props[PLY_MAX_PROPS];
} ply_elem;

// char uchar short ushort int uint float double (and int8 .. float64 aliases).
static int ply_type(const tk* t) {
    static const char* const names[] = {"char",  "uchar",  "short",   "ushort", "int",   "uint",
                                        "float", "double", "int8",    "uint8",  "int16", "uint16",
                                        "int32", "uint32", "float32", "float64"};
    for (int i = 0; i < 16; ++i)
        if (tok_eq(t, names[i])) return i % 8 + 1;
    return 0;
}

// Bytes of each scalar type; 9 and 10 (int64, uint64) occur in VTK only.
static const int k_ply_size[11] = {0, 1, 1, 2, 2, 4, 4, 4, 8, 8, 8};

static double ply_bin_value(const unsigned char* p, int type, int big) {
    unsigned char b[8];
    int n = k_ply_size[type];
    for (int i = 0; i < n; ++i) b[i] = big ? p[n - 1 - i] : p[i];
    switch (type) {
    case 1:
        return (double)(int8_t)b[0];
    case 2:
        return (double)b[0];
    case 3: {
        int16_t v;
        memcpy(&v, b, 2);
        return v;
    }
    case 4: {
        uint16_t v;
        memcpy(&v, b, 2);
        return v;
    }
    case 5: {
        int32_t v;
        memcpy(&v, b, 4);
        return v;
    }
    case 6: {
        uint32_t v;
        memcpy(&v, b, 4);
        return v;
    }
    case 7: {
        float v;
        memcpy(&v, b, 4);
        return v;
    }
    case 9: {
        int64_t v;
        memcpy(&v, b, 8);
        return (double)v;
    }
    case 10: {
        uint64_t v;
        memcpy(&v, b, 8);
        return (double)v;
    }
    default: {
        double v;
        memcpy(&v, b, 8);
        return v;
    }
    }
}

// One property value of element e, item i: ASCII token or binary bytes.
static int ply_value(rd* r, int binary, int big, int type, double* v, const char* what) {
    if (!binary) return need_double(r, 1, what, v);
    size_t n = (size_t)k_ply_size[type];
    if ((size_t)(r->end - r->p) < n)
        return rd_fail(r, 0, "byte %zu: file ends in the binary data (%s)", (size_t)(r->end - r->p),
                       what);
    *v = ply_bin_value((const unsigned char*)r->p, type, big);
    r->p += n;
    return 1;
}

static int parse_ply(rd* r) {
    tk t;
    char b[40];
    if (r->p >= r->end) return rd_fail(r, 0, "empty file");
    if (!tok_line(r, &t) || !tok_eq(&t, "ply")) return rd_fail(r, 1, "not a PLY file (no 'ply')");
    next_line(r);
    int binary = 0, big = 0, have_format = 0, n_elems = 0;
    ply_elem el[PLY_MAX_ELEMS];
    for (;;) {
        if (r->p >= r->end) return rd_fail(r, r->line, "header has no end_header");
        int line = r->line;
        if (!tok_line(r, &t)) {
            next_line(r);
            continue;
        }
        if (tok_eq(&t, "end_header")) {
            next_line(r);
            break;
        }
        if (tok_eq(&t, "format")) {
            if (!tok_line(r, &t)) return rd_fail(r, line, "format needs a type");
            if (tok_eq(&t, "ascii")) {
                binary = 0;
            } else if (tok_eq(&t, "binary_little_endian")) {
                binary = 1;
            } else if (tok_eq(&t, "binary_big_endian")) {
                binary = 1;
                big = 1;
            } else {
                return rd_fail(r, line, "unknown PLY format '%s'", tok_show(&t, b));
            }
            have_format = 1;
        } else if (tok_eq(&t, "element")) {
            if (n_elems == PLY_MAX_ELEMS) return rd_fail(r, line, "more than 16 elements");
            ply_elem* e = &el[n_elems++];
            memset(e, 0, sizeof *e);
            if (!tok_line(r, &t)) return rd_fail(r, line, "element needs a name");
            e->kind = tok_eq(&t, "vertex") ? 1 : tok_eq(&t, "face") ? 2 : 0;
            if (!need_int(r, 0, 0, HS_SURFACE_MAX_COUNT, "element count", &e->n)) return 0;
        } else if (tok_eq(&t, "property")) {
            if (!n_elems) return rd_fail(r, line, "property before any element");
            ply_elem* e = &el[n_elems - 1];
            if (e->n_props == PLY_MAX_PROPS)
                return rd_fail(r, line, "more than %d properties", PLY_MAX_PROPS);
            ply_prop* p = &e->props[e->n_props++];
            memset(p, 0, sizeof *p);
            if (!tok_line(r, &t)) return rd_fail(r, line, "property needs a type");
            if (tok_eq(&t, "list")) {
                p->is_list = 1;
                tk ct, it;
                if (!tok_line(r, &ct) || !tok_line(r, &it) || !(p->count_type = ply_type(&ct)) ||
                    !(p->type = ply_type(&it)))
                    return rd_fail(r, line, "bad list property types");
                if (p->count_type >= 7) return rd_fail(r, line, "list count of a float type");
            } else if (!(p->type = ply_type(&t))) {
                return rd_fail(r, line, "unknown property type '%s'", tok_show(&t, b));
            }
            if (!tok_line(r, &t)) return rd_fail(r, line, "property needs a name");
            if (e->kind == 1 && !p->is_list)
                p->role = tok_eq(&t, "x") ? 1 : tok_eq(&t, "y") ? 2 : tok_eq(&t, "z") ? 3 : 0;
            if (e->kind == 2 && p->is_list &&
                (tok_eq(&t, "vertex_indices") || tok_eq(&t, "vertex_index")))
                p->role = 4;
        } else if (!tok_eq(&t, "comment") && !tok_eq(&t, "obj_info")) {
            return rd_fail(r, line, "unexpected '%s' in the PLY header", tok_show(&t, b));
        }
        next_line(r);
    }
    if (!have_format) return rd_fail(r, r->line, "PLY header without a format line");
    int have_xyz = 0, have_faces = 0;
    for (int i = 0; i < n_elems; ++i) {
        int roles = 0;
        for (int k = 0; k < el[i].n_props; ++k) roles |= 1 << el[i].props[k].role;
        if (el[i].kind == 1) have_xyz = (roles & 14) == 14;
        if (el[i].kind == 2) have_faces = (roles & 16) != 0;
    }
    if (!have_xyz) return rd_fail(r, r->line, "PLY has no vertex element with x, y and z");
    if (!have_faces) return rd_fail(r, r->line, "PLY has no face element with vertex_indices");
    long long nv_total = 0;
    int poly[64];
    for (int i = 0; i < n_elems; ++i) {
        ply_elem* e = &el[i];
        if (!check_count(r, e->n, binary ? 1 : 2, "element")) return 0;
        if (e->kind == 1) nv_total = e->n;
        for (long long j = 0; j < e->n; ++j) {
            double xyz[3] = {0, 0, 0};
            int k_poly = 0, line = r->line;
            for (int k = 0; k < e->n_props; ++k) {
                ply_prop* p = &e->props[k];
                double v;
                if (!p->is_list) {
                    if (!ply_value(r, binary, big, p->type, &v, "property value")) return 0;
                    if (p->role >= 1 && p->role <= 3) xyz[p->role - 1] = v;
                    continue;
                }
                if (!ply_value(r, binary, big, p->count_type, &v, "list count")) return 0;
                if (!(v >= 0 && v <= 64))
                    return rd_fail(r, binary ? 0 : r->line, "list of %g items (at most 64)", v);
                int cnt = (int)v;
                for (int c = 0; c < cnt; ++c) {
                    if (!ply_value(r, binary, big, p->type, &v, "list item")) return 0;
                    if (p->role == 4) {
                        if (!(v >= 0 && v < (double)nv_total && v == floor(v)))
                            return rd_fail(r, binary ? 0 : r->line,
                                           "face %lld: vertex index %g not in [0, %lld)", j + 1, v,
                                           nv_total);
                        poly[k_poly++] = (int)v;
                    }
                }
            }
            if (!binary) next_line(r);
            if (e->kind == 1 && !add_vert(r, xyz, binary ? 0 : line)) return 0;
            if (e->kind == 2 && !add_polygon(r, poly, k_poly, binary ? 0 : line)) return 0;
        }
    }
    if (r->n_tris == 0) return rd_fail(r, r->line, "no faces");
    return 1;
}

// ---------------------------------------------------------------------------------------------
// Legacy VTK POLYDATA, ASCII or BINARY (big-endian values after each section's header line):
// POINTS, then POLYGONS (fanned) and TRIANGLE_STRIPS, in the classic "n size" layout or the 5.1
// OFFSETS/CONNECTIVITY one. VERTICES and LINES are read past, FIELD and METADATA skipped, point
// and cell data end the reading. An UNSTRUCTURED_GRID goes to the mesh reader (its boundary).

typedef struct vtk_rd {
    rd* r;
    int binary;
    const char* start; // for byte offsets in binary messages
    long long n_pts;
} vtk_rd;

// VTK data type names as the scalar types above (0: unknown).
static int vtk_type(const tk* t) {
    static const char* const names[] = {
        "char",          "unsigned_char", "short",         "unsigned_short", "int",
        "unsigned_int",  "float",         "double",        "long",           "unsigned_long",
        "vtkidtype",     "vtktypeint64",  "vtktypeuint64", "vtktypeint32",   "vtktypeuint32",
        "vtktypeint8",   "vtktypeuint8",  "vtktypeint16",  "vtktypeuint16",  "vtktypefloat32",
        "vtktypefloat64"};
    static const int types[] = {1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 9, 9, 10, 5, 6, 1, 2, 3, 4, 7, 8};
    for (size_t i = 0; i < sizeof types / sizeof types[0]; ++i)
        if (tok_eq(t, names[i])) return types[i];
    return 0;
}

// One value: an ASCII token (crossing lines) or big-endian bytes.
static int vtk_value(vtk_rd* v, int type, const char* what, double* out) {
    rd* r = v->r;
    if (!v->binary) return need_double(r, 1, what, out);
    size_t n = (size_t)k_ply_size[type];
    if ((size_t)(r->end - r->p) < n)
        return rd_fail(r, 0, "byte %zu: file ends in the binary %s data", (size_t)(r->p - v->start),
                       what);
    *out = ply_bin_value((const unsigned char*)r->p, type, 1);
    r->p += n;
    return 1;
}

// An integer value in [lo, hi].
static int vtk_index(vtk_rd* v, int type, long long lo, long long hi, const char* what,
                     long long* out) {
    rd* r = v->r;
    if (!v->binary) return need_int(r, 1, lo, hi, what, out);
    size_t at = (size_t)(r->p - v->start);
    double d;
    if (!vtk_value(v, type, what, &d)) return 0;
    if (!(d >= (double)lo && d <= (double)hi && d == floor(d)))
        return rd_fail(r, 0, "byte %zu: %s %g out of range [%lld, %lld]", at, what, d, lo, hi);
    *out = (long long)d;
    return 1;
}

// "DATATYPE" at the end of a header line, then the line's end: the values start after it.
static int vtk_header_type(vtk_rd* v, int hl, const char* what, int* type) {
    rd* r = v->r;
    tk t;
    char b[40];
    if (!tok_line(r, &t)) return rd_fail(r, hl, "%s needs a data type", what);
    if (!(*type = vtk_type(&t)))
        return rd_fail(r, hl, "%s: unknown data type '%s'", what, tok_show(&t, b));
    if (tok_line(r, &t))
        return rd_fail(r, hl, "unexpected '%s' after the %s header", tok_show(&t, b), what);
    next_line(r);
    return 1;
}

// Adds one cell of k points read from the stream: a polygon as a fan, a strip as its triangles
// (every second one turned to keep the strip's orientation); other kinds are read past.
static int vtk_cell(vtk_rd* v, int kind, int type, long long k, long long cell, int hl) {
    rd* r = v->r;
    const char* name = kind == 1 ? "polygon" : "triangle strip";
    if (kind && k < 3 && v->binary)
        return rd_fail(r, 0, "byte %zu: %s %lld has %lld points (a face needs 3)",
                       (size_t)(r->p - v->start), name, cell + 1, k);
    if (kind && k < 3)
        return rd_fail(r, r->line, "%s %lld has %lld points (a face needs 3)", name, cell + 1, k);
    long long first = -1, prev2 = -1, prev = -1, i;
    for (long long j = 0; j < k; ++j) {
        if (!vtk_index(v, type, 0, v->n_pts - 1, "point index", &i)) return 0;
        if (kind && j >= 2) {
            long long a = kind == 1 ? first : prev2, b = prev;
            if (kind == 2 && j % 2) a = prev, b = prev2;
            if (!add_tri(r, (int)a, (int)b, (int)i, v->binary ? 0 : hl)) return 0;
        }
        if (j == 0) first = i;
        prev2 = prev;
        prev = i;
    }
    return 1;
}

// A cell section after its keyword: "n size" (classic) or "n_offsets n_connectivity" (5.1).
static int vtk_cells(vtk_rd* v, int kind, int v5, int hl, const char* what) {
    rd* r = v->r;
    long long n, size;
    if (v->n_pts < 0) return rd_fail(r, hl, "%s before POINTS", what);
    if (!need_int(r, 0, 0, LLONG_MAX, v5 ? "offset count" : "cell count", &n) ||
        !need_int(r, 0, 0, LLONG_MAX, v5 ? "connectivity size" : "cell list size", &size))
        return 0;
    next_line(r);
    size_t min = v->binary ? 4 : 2;
    if (!check_count(r, n, min, "cell") || !check_count(r, size, min, "cell list entry")) return 0;
    if (!v5) {
        int type = 5; // classic binary cells are 32-bit
        long long used = 0, k;
        for (long long c = 0; c < n; ++c) {
            int line = r->line;
            if (!vtk_index(v, type, 0, size - used - 1, "cell point count", &k) ||
                !vtk_cell(v, kind, type, k, c, line))
                return 0;
            used += 1 + k;
        }
        if (used != size)
            return rd_fail(r, hl, "%s size is %lld but the cells use %lld", what, size, used);
        return 1;
    }
    if (n == 0) return size == 0 ? 1 : rd_fail(r, hl, "%s: no offsets for %lld points", what, size);
    long long* off = hs_alloc((size_t)n * sizeof(long long));
    if (!off) return rd_nomem(r);
    int ok = 1, type;
    tk t;
    for (int part = 0; part < 2 && ok; ++part) {
        const char* key = part ? "CONNECTIVITY" : "OFFSETS";
        if (!tok_any(r, &t) || !tok_eq(&t, part ? "connectivity" : "offsets")) {
            ok = rd_fail(r, r->line, "%s: expected %s", what, key);
            break;
        }
        if (!(ok = vtk_header_type(v, r->line, key, &type))) break;
        if (part == 0) {
            for (long long i = 0; i < n && ok; ++i)
                ok = vtk_index(v, type, i ? off[i - 1] : 0, i ? size : 0, "offset", &off[i]);
            if (ok && off[n - 1] != size)
                ok = rd_fail(r, hl, "%s: last offset %lld differs from the connectivity size %lld",
                             what, off[n - 1], size);
            continue;
        }
        for (long long c = 0; c + 1 < n && ok; ++c)
            ok = vtk_cell(v, kind, type, off[c + 1] - off[c], c, r->line);
    }
    hs_free(off);
    return ok;
}

// FIELD name n, then per array "name components tuples type" and its values (skipped).
static int vtk_field(vtk_rd* v, int hl) {
    rd* r = v->r;
    tk t;
    long long n_arrays, comps, tuples;
    double d;
    if (!tok_line(r, &t)) return rd_fail(r, hl, "FIELD needs a name");
    if (!need_int(r, 0, 0, LLONG_MAX, "field array count", &n_arrays)) return 0;
    next_line(r);
    if (!check_count(r, n_arrays, 8, "field array")) return 0;
    for (long long a = 0; a < n_arrays; ++a) {
        if (!tok_any(r, &t)) return rd_fail(r, r->line, "file ends in FIELD array %lld", a + 1);
        int al = r->line, type;
        if (!need_int(r, 0, 0, LLONG_MAX, "field components", &comps) ||
            !need_int(r, 0, 0, LLONG_MAX, "field tuples", &tuples) ||
            !vtk_header_type(v, al, "field array", &type))
            return 0;
        if (comps > 0 && tuples > (long long)(r->end - r->p) / comps + 1)
            return rd_fail(r, al, "field array of %lld x %lld values does not fit", comps, tuples);
        for (long long i = 0; i < comps * tuples; ++i)
            if (!vtk_value(v, type, "field", &d)) return 0;
    }
    return 1;
}

// 1: POLYDATA read; 2: an UNSTRUCTURED_GRID for the mesh reader; 0: failed.
static int parse_vtk(rd* r) {
    tk t;
    char b[40];
    vtk_rd v = {.r = r, .start = r->p, .n_pts = -1};
    if (r->p >= r->end) return rd_fail(r, 0, "empty file");
    static const char* const head[4] = {"#", "vtk", "datafile", "version"};
    for (int i = 0; i < 4; ++i)
        if (!tok_line(r, &t) || !tok_eq(&t, head[i]))
            return rd_fail(r, 1, "not a legacy VTK file (expected '# vtk DataFile Version')");
    double version;
    if (!need_double(r, 0, "VTK version", &version)) return 0;
    int v5 = version >= 5.0;
    next_line(r);
    if (r->p >= r->end) return rd_fail(r, r->line, "missing title line");
    next_line(r); // title
    if (!tok_any(r, &t)) return rd_fail(r, r->line, "missing ASCII/BINARY line");
    if (tok_eq(&t, "binary"))
        v.binary = 1;
    else if (!tok_eq(&t, "ascii"))
        return rd_fail(r, r->line, "expected ASCII or BINARY, found '%s'", tok_show(&t, b));
    next_line(r);
    if (!tok_any(r, &t) || !tok_eq(&t, "dataset"))
        return rd_fail(r, r->line, "expected DATASET POLYDATA");
    if (!tok_line(r, &t)) return rd_fail(r, r->line, "DATASET needs a type");
    if (tok_eq(&t, "unstructured_grid"))
        return v.binary ? rd_fail(r, r->line,
                                  "binary UNSTRUCTURED_GRID not supported (save it as ASCII, or as "
                                  "POLYDATA)")
                        : 2;
    if (!tok_eq(&t, "polydata"))
        return rd_fail(
            r, r->line,
            "DATASET %s is not a surface (POLYDATA, or an UNSTRUCTURED_GRID of tetrahedra)",
            tok_show(&t, b));
    next_line(r);
    int have_polys = 0, have_strips = 0;
    while (tok_any(r, &t)) {
        int hl = r->line;
        if (tok_eq(&t, "points")) {
            long long n;
            int type;
            if (v.n_pts >= 0) return rd_fail(r, hl, "second POINTS section");
            if (!need_int(r, 0, 0, HS_SURFACE_MAX_COUNT, "point count", &n) ||
                !vtk_header_type(&v, hl, "POINTS", &type) ||
                !check_count(r, n, v.binary ? (size_t)k_ply_size[type] * 3 : 6, "point"))
                return 0;
            for (long long i = 0; i < n; ++i) {
                double x[3];
                for (int d = 0; d < 3; ++d)
                    if (!vtk_value(&v, type, "point coordinate", x + d)) return 0;
                if (!add_vert(r, x, v.binary ? 0 : r->line)) return 0;
            }
            v.n_pts = n;
        } else if (tok_eq(&t, "polygons") || tok_eq(&t, "triangle_strips")) {
            int strips = t.s[0] == 't' || t.s[0] == 'T';
            int* seen = strips ? &have_strips : &have_polys;
            const char* what = strips ? "TRIANGLE_STRIPS" : "POLYGONS";
            if (*seen) return rd_fail(r, hl, "second %s section", what);
            if (!vtk_cells(&v, strips ? 2 : 1, v5, hl, what)) return 0;
            *seen = 1;
        } else if (tok_eq(&t, "vertices") || tok_eq(&t, "lines")) {
            if (!vtk_cells(&v, 0, v5, hl, tok_eq(&t, "lines") ? "LINES" : "VERTICES")) return 0;
        } else if (tok_eq(&t, "metadata")) {
            // VTK 9 writes METADATA blocks (text) that end at an empty line.
            next_line(r);
            while (r->p < r->end) {
                tk first;
                int has = tok_line(r, &first);
                next_line(r);
                if (!has) break;
            }
        } else if (tok_eq(&t, "field")) {
            if (!vtk_field(&v, hl)) return 0;
        } else if (tok_eq(&t, "point_data") || tok_eq(&t, "cell_data")) {
            break; // attributes are not read
        } else {
            return v.binary
                       ? rd_fail(r, 0,
                                 "byte %zu: unexpected '%s' (a binary section longer than its "
                                 "header says?)",
                                 (size_t)(t.s - v.start), tok_show(&t, b))
                       : rd_fail(r, hl, "unexpected '%s' in a VTK POLYDATA file", tok_show(&t, b));
        }
    }
    if (v.n_pts < 0) return rd_fail(r, r->line, "missing POINTS section");
    if (r->n_tris == 0)
        return rd_fail(r, r->line, "no POLYGONS or TRIANGLE_STRIPS (a VTK surface needs faces)");
    return 1;
}

// ---------------------------------------------------------------------------------------------

typedef struct vkey {
    double x[3];
    int i;
} vkey;

static int cmp_vkey(const void* pa, const void* pb) {
    const vkey* a = pa;
    const vkey* b = pb;
    for (int d = 0; d < 3; ++d)
        if (a->x[d] != b->x[d]) return a->x[d] < b->x[d] ? -1 : 1;
    return (a->i > b->i) - (a->i < b->i);
}

// Merges vertices with exactly equal coordinates (STL repeats every corner), keeping the first
// of each in file order. Returns how many were merged, -1 on no memory.
int hs_surface_weld(hs_surface* s) {
    int n = s->n_verts;
    if (n == 0) return 0;
    vkey* k = hs_alloc((size_t)n * sizeof(vkey));
    int* first = hs_alloc((size_t)n * sizeof(int));
    if (!k || !first) {
        hs_free(k);
        hs_free(first);
        return -1;
    }
    for (int i = 0; i < n; ++i) {
        memcpy(k[i].x, s->x + 3 * i, sizeof k[i].x);
        k[i].i = i;
    }
    qsort(k, (size_t)n, sizeof(vkey), cmp_vkey);
    for (int i = 0; i < n;) {
        int j = i;
        while (j < n && memcmp(k[i].x, k[j].x, sizeof k[i].x) == 0) ++j;
        for (int q = i; q < j; ++q) first[k[q].i] = k[i].i; // k[i] has the lowest index
        i = j;
    }
    int* newidx = (int*)k; // n ints fit in n vkeys
    int m = 0;
    for (int i = 0; i < n; ++i)
        if (first[i] == i) {
            newidx[i] = m;
            memmove(s->x + 3 * m, s->x + 3 * i, 3 * sizeof(double));
            ++m;
        }
    for (int i = 0; i < n; ++i)
        if (first[i] != i) newidx[i] = newidx[first[i]];
    for (int t = 0; t < 3 * s->n_tris; ++t) s->tris[t] = newidx[s->tris[t]];
    s->n_verts = m;
    hs_free(k);
    hs_free(first);
    return n - m;
}

static hs_status finish(rd* r, int ok, hs_surface** out) {
    if (!ok) {
        hs_free(r->x);
        hs_free(r->tris);
        return r->status ? r->status : HS_ERR_PARSE;
    }
    hs_surface* s = hs_calloc(1, sizeof *s);
    if (!s) {
        hs_free(r->x);
        hs_free(r->tris);
        return hs_err_set(r->err, HS_ERR_NOMEM, "%s: out of memory", r->name);
    }
    s->n_verts = r->n_verts;
    s->x = r->x;
    s->n_tris = r->n_tris;
    s->tris = r->tris;
    int merged = hs_surface_weld(s);
    if (merged < 0) {
        hs_surface_destroy(&s);
        return hs_err_set(r->err, HS_ERR_NOMEM, "%s: out of memory", r->name);
    }
    s->merged_on_read = merged;
    *out = s;
    return HS_OK;
}

hs_status hs_surface_parse(const char* name, const char* format, const char* data, size_t len,
                           hs_surface** out, hs_err* err) {
    if (!out) return hs_err_set(err, HS_ERR_INVALID, "out is NULL");
    *out = NULL;
    if (!format || (!data && len)) return hs_err_set(err, HS_ERR_INVALID, "format or data is NULL");
    rd r = {0};
    r.name = name ? name : "(memory)";
    r.p = data ? data : "";
    r.end = r.p + (data ? len : 0);
    r.line = 1;
    r.err = err;
    if (strcmp(format, "msh") == 0 || strcmp(format, "vtu") == 0)
        return hs_surface_parse_mesh(r.name, format, data, len, out, err);
    int ok;
    if (strcmp(format, "stl") == 0)
        ok = parse_stl(&r);
    else if (strcmp(format, "obj") == 0)
        ok = parse_obj(&r);
    else if (strcmp(format, "ply") == 0)
        ok = parse_ply(&r);
    else if (strcmp(format, "off") == 0)
        ok = parse_off(&r);
    else if (strcmp(format, "vtk") == 0) {
        ok = parse_vtk(&r);
        if (ok == 2) { // an unstructured grid: the mesh reader, then its triangles or boundary
            hs_free(r.x);
            hs_free(r.tris);
            hs_mesh* m = NULL;
            hs_status st = hs_mesh_parse(r.name, "vtk", data, len, &m, err);
            if (st < 0) return st;
            st = hs_surface_from_mesh(m, out, err);
            hs_mesh_destroy(&m);
            return st;
        }
    } else
        return hs_err_set(err, HS_ERR_INVALID, "unknown surface format '%.20s'", format);
    return finish(&r, ok, out);
}

hs_status hs_surface_load(const char* path, hs_surface** out, hs_err* err) {
    if (!out) return hs_err_set(err, HS_ERR_INVALID, "out is NULL");
    *out = NULL;
    if (!path) return hs_err_set(err, HS_ERR_INVALID, "path is NULL");
    static const char* const fmts[] = {"stl", "obj", "ply", "off", "msh", "vtu", "vtk"};
    for (int i = 0; i < 7; ++i) {
        char ext[8];
        snprintf(ext, sizeof ext, ".%s", fmts[i]);
        if (!hs_path_has_ext(path, ext)) continue;
        char* data;
        size_t len;
        hs_status st = hs_read_file(path, &data, &len, err);
        if (st != HS_OK) return st;
        st = hs_surface_parse(path, fmts[i], data, len, out, err);
        hs_free(data);
        return st;
    }
    if (hs_path_has_ext(path, ".node") || hs_path_has_ext(path, ".ele")) {
        hs_mesh* m = NULL;
        hs_status st = hs_mesh_load(path, &m, err);
        if (st < 0) return st;
        st = hs_surface_from_mesh(m, out, err);
        hs_mesh_destroy(&m);
        return st;
    }
    return hs_err_set(err, HS_ERR_UNSUPPORTED,
                      "%s: unknown surface extension (.stl, .obj, .ply, .off, .msh, .vtu, .vtk; "
                      "volume meshes .node/.ele)",
                      path);
}
