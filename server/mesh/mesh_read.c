// SPDX-License-Identifier: GPL-2.0-or-later
// Mesh readers: Gmsh MSH 2.2 / 4.1 ASCII, TetGen .node/.ele, legacy VTK ASCII unstructured
// grids. All parse from a memory buffer that need not be NUL-terminated, never read past its
// end, and check every declared count against the bytes left before allocating, so memory
// stays proportional to the input. Errors read "<file>:<line>: <problem>".
#include "base_internal.h"
#include "mesh_internal.h"

#include <errno.h>
#include <limits.h>
#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

typedef struct lexer {
    const char* name; // for messages
    const char* p;    // next unread byte
    const char* end;
    int line;          // 1-based line of p
    int hash_comments; // TetGen: '#' starts a comment that runs to the end of the line
    hs_status status;  // first error (err may be NULL)
    hs_err* err;
} lexer;

typedef struct tok {
    const char* s;
    size_t len;
    int line;
} tok;

static void lx_init(lexer* lx, const char* name, const char* data, size_t len, hs_err* err) {
    memset(lx, 0, sizeof *lx);
    lx->name = name ? name : "(memory)";
    lx->p = data ? data : "";
    lx->end = lx->p + (data ? len : 0);
    lx->line = 1;
    lx->err = err;
}

static int lx_fail(lexer* lx, int line, hs_status code, const char* fmt, ...)
    __attribute__((format(printf, 4, 5)));

// Records the error and returns 0 so callers can `return lx_fail(...)`.
static int lx_fail(lexer* lx, int line, hs_status code, const char* fmt, ...) {
    char problem[400];
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(problem, sizeof problem, fmt, ap);
    va_end(ap);
    lx->status = code;
    hs_err_set(lx->err, code, "%s:%d: %s", lx->name, line, problem);
    return 0;
}

// Printable excerpt of a token for messages.
static const char* tok_text(const tok* t, char buf[48]) {
    return hs_text_excerpt(t->s, t->len, 32, buf);
}

static int is_blank(char c) {
    return c == ' ' || c == '\t' || c == '\r' || c == '\f' || c == '\v';
}

static void skip_blanks(lexer* lx) {
    while (lx->p < lx->end) {
        char c = *lx->p;
        if (is_blank(c))
            ++lx->p;
        else if (c == '#' && lx->hash_comments)
            while (lx->p < lx->end && *lx->p != '\n') ++lx->p;
        else
            break;
    }
}

// Next token on the current line; 0 at the end of the line or file (newline not consumed).
static int tok_line(lexer* lx, tok* t) {
    skip_blanks(lx);
    if (lx->p >= lx->end || *lx->p == '\n') return 0;
    t->s = lx->p;
    t->line = lx->line;
    while (lx->p < lx->end && !is_blank(*lx->p) && *lx->p != '\n' &&
           !(*lx->p == '#' && lx->hash_comments))
        ++lx->p;
    t->len = (size_t)(lx->p - t->s);
    return 1;
}

// Next token anywhere, crossing newlines; 0 at the end of the file.
static int tok_any(lexer* lx, tok* t) {
    for (;;) {
        if (tok_line(lx, t)) return 1;
        if (lx->p >= lx->end) return 0;
        ++lx->p;
        ++lx->line;
    }
}

static void skip_line(lexer* lx) {
    const char* nl = memchr(lx->p, '\n', (size_t)(lx->end - lx->p));
    if (nl) {
        lx->p = nl + 1;
        ++lx->line;
    } else {
        lx->p = lx->end;
    }
}

// The rest of the line must be blank; consumes the newline.
static int end_line(lexer* lx, const char* what) {
    tok t;
    char b[48];
    if (tok_line(lx, &t))
        return lx_fail(lx, t.line, HS_ERR_PARSE, "unexpected '%s' after %s", tok_text(&t, b), what);
    skip_line(lx);
    return 1;
}

// Moves to the next line that has a token; 0 at the end of the file.
static int next_record(lexer* lx) {
    for (;;) {
        skip_blanks(lx);
        if (lx->p >= lx->end) return 0;
        if (*lx->p != '\n') return 1;
        ++lx->p;
        ++lx->line;
    }
}

static int tok_is(const tok* t, const char* s) {
    size_t n = strlen(s);
    return t->len == n && memcmp(t->s, s, n) == 0;
}

static int tok_is_nocase(const tok* t, const char* s) {
    size_t n = strlen(s);
    if (t->len != n) return 0;
    for (size_t i = 0; i < n; ++i) {
        char a = t->s[i], b = s[i];
        if (a >= 'a' && a <= 'z') a = (char)(a - 'a' + 'A');
        if (b >= 'a' && b <= 'z') b = (char)(b - 'a' + 'A');
        if (a != b) return 0;
    }
    return 1;
}

static int parse_ll(const tok* t, long long* v) {
    return hs_parse_ll(t->s, t->len, v);
}

// Finite decimal number; 0 if malformed, too long, infinite or NaN.
static int parse_double(const tok* t, double* v) {
    double d;
    if (!hs_parse_number(t->s, t->len, &d) || !isfinite(d)) return 0;
    *v = d;
    return 1;
}

// Reads an integer in [lo, hi]: on the current line, or anywhere if `any`.
static int rd_int(lexer* lx, int any, long long lo, long long hi, const char* what, long long* v) {
    tok t;
    char b[48];
    if (!(any ? tok_any(lx, &t) : tok_line(lx, &t)))
        return lx_fail(lx, lx->line, HS_ERR_PARSE, "missing %s", what);
    if (!parse_ll(&t, v))
        return lx_fail(lx, t.line, HS_ERR_PARSE, "bad %s '%s' (expected an integer)", what,
                       tok_text(&t, b));
    if (*v < lo || *v > hi)
        return lx_fail(lx, t.line, HS_ERR_PARSE, "%s %lld out of range [%lld, %lld]", what, *v, lo,
                       hi);
    return 1;
}

static int rd_double(lexer* lx, int any, const char* what, double* v) {
    tok t;
    char b[48];
    if (!(any ? tok_any(lx, &t) : tok_line(lx, &t)))
        return lx_fail(lx, lx->line, HS_ERR_PARSE, "missing %s", what);
    if (!parse_double(&t, v))
        return lx_fail(lx, t.line, HS_ERR_PARSE, "bad %s '%s' (expected a finite number)", what,
                       tok_text(&t, b));
    return 1;
}

// A node coordinate: finite, and within the mesh's limit (hs_mesh_finalize would refuse it
// later, but only by node index and without the line).
static int rd_coord(lexer* lx, int any, const char* what, double* v) {
    if (!rd_double(lx, any, what, v)) return 0;
    if (fabs(*v) > 1e30)
        return lx_fail(lx, lx->line, HS_ERR_PARSE, "%s %g is beyond 1e30 m", what, *v);
    return 1;
}

// A declared count must fit in the bytes left (each item takes at least min_bytes) and in the
// mesh limits; checked before anything is allocated for it.
static int check_count(lexer* lx, long long n, size_t min_bytes, int line, const char* what) {
    size_t left = (size_t)(lx->end - lx->p);
    if (n < 0 || (unsigned long long)n > left / min_bytes + 1 || n > HS_MESH_MAX_COUNT)
        return lx_fail(lx, line, HS_ERR_PARSE,
                       "%s count %lld does not fit in the %zu bytes that follow", what, n, left);
    return 1;
}

// Start of record i of n inside a section: fails on end of file or an early '$' line.
static int record(lexer* lx, long long i, long long n, const char* what) {
    if (!next_record(lx))
        return lx_fail(lx, lx->line, HS_ERR_PARSE, "file ends after %lld of %lld %s", i, n, what);
    if (*lx->p == '$')
        return lx_fail(lx, lx->line, HS_ERR_PARSE, "section ends after %lld of %lld %s", i, n,
                       what);
    return 1;
}

// ---------------------------------------------------------------------------------------------
// What every reader fills: nodes with their file ids (mapped to 0-based indices) and tets.

typedef struct id_pair {
    long long id;
    int idx;
} id_pair;

typedef struct grp_entry {
    int dim, tag, node;
} grp_entry;

typedef struct phys_name {
    int dim, tag;
    char name[HS_MESH_REGION_NAME_MAX];
} phys_name;

typedef struct ent_phys {
    int dim, ent, phys;
} ent_phys;

typedef struct builder {
    int n_nodes;
    double* x;     // [3 n_nodes]
    long long* id; // [n_nodes] file id of each node
    int* line;     // [n_nodes] line each node was read on
    id_pair* map;  // [n_nodes] sorted by id
    int n_tets;
    int* tets;      // [4 capacity]
    int* tline;     // [capacity] line of each tet (0 for VTK cells)
    long long* tid; // [capacity] file id of each tet (VTK: cell index)
    int by_index;   // VTK: nodes and cells are named by 0-based index, no line each
    int skipped;
    // Gmsh physical groups: one entry per (group, element node); names; 4.1 entity -> group
    int n_grp, cap_grp;
    grp_entry* grp;
    int n_names, cap_names;
    phys_name* names;
    int n_ents, cap_ents;
    ent_phys* ents;
    // triangles (type 2), when collect_tris
    int collect_tris;
    int n_tris, cap_tris;
    int* tris;
} builder;

static void builder_free(builder* b) {
    hs_free(b->x);
    hs_free(b->id);
    hs_free(b->line);
    hs_free(b->map);
    hs_free(b->tets);
    hs_free(b->tline);
    hs_free(b->tid);
    hs_free(b->grp);
    hs_free(b->names);
    hs_free(b->ents);
    hs_free(b->tris);
    memset(b, 0, sizeof *b);
}

// Grows an array of `size`-byte items to hold one more; 0 on no memory.
static int grow(void** p, int* cap, int n, size_t size) {
    if (n < *cap) return 1;
    if (*cap > HS_MESH_MAX_COUNT / 2) return 0;
    int c = *cap ? 2 * *cap : 64;
    void* g = hs_realloc(*p, (size_t)c * size);
    if (!g) return 0;
    *p = g;
    *cap = c;
    return 1;
}

// Dimension of Gmsh element type 1-31 (0 points, 1 lines, 2 surfaces, 3 volumes).
static int gmsh_type_dim(long long type) {
    static const signed char d[32] = {-1, 1, 2, 2, 3, 3, 3, 3, 1, 2, 2, 3, 3, 3, 3, 0,
                                      2,  3, 3, 3, 2, 2, 2, 2, 2, 2, 1, 1, 1, 3, 3, 3};
    return type >= 1 && type <= 31 ? d[type] : -1;
}

static int nomem(lexer* lx) {
    lx->status = HS_ERR_NOMEM;
    hs_err_set(lx->err, HS_ERR_NOMEM, "%s: out of memory", lx->name);
    return 0;
}

// Records that element nodes nodes[0..k) belong to physical group (dim, tag).
static int add_group_nodes(lexer* lx, builder* b, int dim, long long tag, const int* nodes, int k) {
    if (tag == 0 || dim < 0) return 1;
    if (tag < INT_MIN || tag > INT_MAX)
        return lx_fail(lx, lx->line, HS_ERR_PARSE, "physical tag %lld out of range", tag);
    for (int i = 0; i < k; ++i) {
        if (!grow((void**)&b->grp, &b->cap_grp, b->n_grp, sizeof(grp_entry))) return nomem(lx);
        b->grp[b->n_grp++] = (grp_entry){dim, (int)tag, nodes[i]};
    }
    return 1;
}

// The physical groups of a 4.1 element block's entity, then its element nodes.
static int add_entity_nodes(lexer* lx, builder* b, int dim, long long ent, const int* nodes,
                            int k) {
    for (int i = 0; i < b->n_ents; ++i)
        if (b->ents[i].dim == dim && b->ents[i].ent == ent &&
            !add_group_nodes(lx, b, dim, b->ents[i].phys, nodes, k))
            return 0;
    return 1;
}

static int add_triangle(lexer* lx, builder* b, const int* nodes) {
    if (!b->collect_tris) return 1;
    if (!grow((void**)&b->tris, &b->cap_tris, 3 * b->n_tris + 2, sizeof(int))) return nomem(lx);
    memcpy(b->tris + 3 * b->n_tris++, nodes, 3 * sizeof(int));
    return 1;
}

static int alloc_nodes(lexer* lx, builder* b, long long n) {
    b->x = hs_alloc(((size_t)n * 3 + 1) * sizeof(double));
    b->id = hs_alloc(((size_t)n + 1) * sizeof(long long));
    b->line = hs_alloc(((size_t)n + 1) * sizeof(int));
    if (!b->x || !b->id || !b->line) return nomem(lx);
    b->n_nodes = (int)n;
    return 1;
}

static int alloc_tets(lexer* lx, builder* b, long long capacity) {
    b->tets = hs_alloc(((size_t)capacity * 4 + 1) * sizeof(int));
    b->tline = hs_alloc(((size_t)capacity + 1) * sizeof(int));
    b->tid = hs_alloc(((size_t)capacity + 1) * sizeof(long long));
    return b->tets && b->tline && b->tid ? 1 : nomem(lx);
}

static int cmp_id_pair(const void* pa, const void* pb) {
    const id_pair* a = pa;
    const id_pair* b = pb;
    if (a->id != b->id) return a->id < b->id ? -1 : 1;
    return (a->idx > b->idx) - (a->idx < b->idx);
}

// Sorts the node ids for lookup and rejects repeated ids.
static int build_map(lexer* lx, builder* b) {
    b->map = hs_alloc(((size_t)b->n_nodes + 1) * sizeof(id_pair));
    if (!b->map) return nomem(lx);
    for (int i = 0; i < b->n_nodes; ++i) b->map[i] = (id_pair){b->id[i], i};
    qsort(b->map, (size_t)b->n_nodes, sizeof(id_pair), cmp_id_pair);
    for (int i = 1; i < b->n_nodes; ++i)
        if (b->map[i].id == b->map[i - 1].id)
            return lx_fail(lx, b->line[b->map[i].idx], HS_ERR_PARSE,
                           "node id %lld repeated (first on line %d)", b->map[i].id,
                           b->line[b->map[i - 1].idx]);
    return 1;
}

// Reads a node id on the current line and stores its index as tet corner c.
// Reads node id c of an element of k nodes and returns its index in *idx (or fails).
static int rd_elem_node(lexer* lx, builder* b, long long lo, int c, int k, long long elem, int* idx,
                        int* line) {
    tok t;
    char buf[48];
    long long id;
    if (!tok_line(lx, &t))
        return lx_fail(lx, lx->line, HS_ERR_PARSE, "element %lld has only %d of %d nodes", elem, c,
                       k);
    if (!parse_ll(&t, &id) || id < lo)
        return lx_fail(lx, t.line, HS_ERR_PARSE, "element %lld: bad node id '%s'", elem,
                       tok_text(&t, buf));
    int lo_i = 0, hi_i = b->n_nodes;
    while (lo_i < hi_i) {
        int mid = lo_i + (hi_i - lo_i) / 2;
        if (b->map[mid].id < id)
            lo_i = mid + 1;
        else
            hi_i = mid;
    }
    if (lo_i == b->n_nodes || b->map[lo_i].id != id)
        return lx_fail(lx, t.line, HS_ERR_PARSE, "element %lld references unknown node %lld", elem,
                       id);
    *idx = b->map[lo_i].idx;
    *line = t.line;
    return 1;
}

static int rd_tet_node(lexer* lx, builder* b, long long lo, int c, long long elem) {
    int idx, line;
    if (!rd_elem_node(lx, b, lo, c, 4, elem, &idx, &line)) return 0;
    b->tets[4 * b->n_tets + c] = idx;
    if (c == 0) {
        b->tline[b->n_tets] = line;
        b->tid[b->n_tets] = elem;
    }
    return 1;
}

// Nodes of Gmsh element type `type` (1-31, the types Gmsh writes), or 0 when not known.
static int gmsh_type_nodes(long long type) {
    static const unsigned char k[32] = {0,  2,  3,  4,  4, 8, 6,  5,  3,  6, 9,
                                        10, 27, 18, 14, 1, 8, 20, 15, 13, 9, 10,
                                        12, 15, 15, 21, 4, 5, 6,  20, 35, 56};
    return type >= 1 && type <= 31 ? k[type] : 0;
}

// The node ids of a skipped (not linear tet) element: a known type must name exactly its
// nodes, each one known, as a tet's must; an unknown type's line is skipped unread.
// *k_out: how many nodes went to nodes[] (0 for an unknown type).
static int skip_element_nodes(lexer* lx, builder* b, long long type, long long elem, int nodes[56],
                              int* k_out) {
    const int k = gmsh_type_nodes(type);
    *k_out = 0;
    if (!k) {
        skip_line(lx);
        return 1;
    }
    for (int c = 0; c < k; ++c) {
        int line;
        if (!rd_elem_node(lx, b, 1, c, k, elem, &nodes[c], &line)) return 0;
    }
    *k_out = k;
    return end_line(lx, "an element");
}

static int build_regions(lexer* lx, builder* b, hs_mesh* m);

static hs_status builder_finish(lexer* lx, builder* b, hs_mesh** out) {
    if (b->n_tets == 0) {
        lx_fail(lx, lx->line, HS_ERR_PARSE, "no linear tetrahedra (%d other elements skipped)",
                b->skipped);
        builder_free(b);
        return lx->status;
    }
    double* x = b->x;
    int* tets = b->tets;
    b->x = NULL;
    b->tets = NULL;
    hs_mesh_fault f;
    hs_status st = hs_mesh_adopt(b->n_nodes, x, b->n_tets, tets, b->skipped, out, &f, lx->err);
    if (st < 0 && st != HS_ERR_NOMEM && lx->err) {
        char msg[sizeof lx->err->msg];
        memcpy(msg, lx->err->msg, sizeof msg);
        if (f.n_sharing) {
            // A face error in the file's own terms: lines, element and node ids.
            char e0[64], e1[64], face[80];
            long long nid[3];
            for (int k = 0; k < 3; ++k) nid[k] = b->by_index ? f.node[k] : b->id[f.node[k]];
            snprintf(face, sizeof face, "nodes %lld %lld %lld", nid[0], nid[1], nid[2]);
            if (b->by_index) {
                snprintf(e0, sizeof e0, "%s: cell %lld", lx->name, b->tid[f.tet[0]]);
                snprintf(e1, sizeof e1, "cell %lld", b->tid[f.tet[1]]);
            } else {
                snprintf(e0, sizeof e0, "%s:%d: element %lld", lx->name, b->tline[f.tet[0]],
                         b->tid[f.tet[0]]);
                snprintf(e1, sizeof e1, "element %lld (line %d)", b->tid[f.tet[1]],
                         b->tline[f.tet[1]]);
            }
            if (f.n_sharing == 2)
                snprintf(lx->err->msg, sizeof lx->err->msg,
                         "%.200s and %s overlap: both lie on the same side of their shared face "
                         "(%s)",
                         e0, e1, face);
            else
                snprintf(lx->err->msg, sizeof lx->err->msg,
                         "%.200s, %s and %d more share one face (%s): not a volume mesh", e0, e1,
                         f.n_sharing - 2, face);
        } else {
            snprintf(lx->err->msg, sizeof lx->err->msg, "%s: %.400s", lx->name, msg);
        }
    }
    if (st >= 0) { // repaired elements by their ids in the file
        hs_mesh_report* r = &(*out)->report;
        long long* lists[3] = {r->first_reoriented, r->first_degenerate, r->first_duplicate};
        for (int k = 0; k < 3; ++k)
            for (int j = 0; j < HS_MESH_REPORT_FIRST; ++j)
                if (lists[k][j] >= 0 && lists[k][j] < b->n_tets) lists[k][j] = b->tid[lists[k][j]];
    }
    if (st >= 0 && !build_regions(lx, b, *out)) {
        hs_mesh_destroy(out);
        st = HS_ERR_NOMEM;
    }
    builder_free(b);
    return st;
}

// ---------------------------------------------------------------------------------------------
// Gmsh MSH 2.2 and 4.1 (ASCII).

static int msh_nodes_v2(lexer* lx, builder* b) {
    long long n, id;
    int hl = lx->line;
    if (!rd_int(lx, 0, 0, LLONG_MAX, "node count", &n) || !end_line(lx, "the node count") ||
        !check_count(lx, n, 8, hl, "node") || !alloc_nodes(lx, b, n))
        return 0;
    for (long long i = 0; i < n; ++i) {
        double* x = b->x + 3 * i;
        if (!record(lx, i, n, "nodes")) return 0;
        b->line[i] = lx->line;
        if (!rd_int(lx, 0, 1, LLONG_MAX, "node id", &id) || !rd_coord(lx, 0, "x coordinate", x) ||
            !rd_coord(lx, 0, "y coordinate", x + 1) || !rd_coord(lx, 0, "z coordinate", x + 2) ||
            !end_line(lx, "a node"))
            return 0;
        b->id[i] = id;
    }
    return build_map(lx, b);
}

static int msh_nodes_v4(lexer* lx, builder* b) {
    long long nb, n, lo, hi;
    int hl = lx->line;
    if (!rd_int(lx, 0, 0, LLONG_MAX, "entity block count", &nb) ||
        !rd_int(lx, 0, 0, LLONG_MAX, "node count", &n) ||
        !rd_int(lx, 0, n > 0, LLONG_MAX, "min node tag", &lo) ||
        !rd_int(lx, 0, n > 0, LLONG_MAX, "max node tag", &hi) || !end_line(lx, "the node header") ||
        !check_count(lx, nb, 8, hl, "node block") || !check_count(lx, n, 8, hl, "node") ||
        !alloc_nodes(lx, b, n))
        return 0;
    long long filled = 0;
    for (long long k = 0; k < nb; ++k) {
        long long dim, tag, param, m, id;
        if (!record(lx, k, nb, "node blocks")) return 0;
        int bl = lx->line;
        if (!rd_int(lx, 0, 0, 3, "entity dimension", &dim) ||
            !rd_int(lx, 0, LLONG_MIN, LLONG_MAX, "entity tag", &tag) ||
            !rd_int(lx, 0, 0, 1, "parametric flag", &param) ||
            !rd_int(lx, 0, 0, LLONG_MAX, "block node count", &m) ||
            !end_line(lx, "a node block header"))
            return 0;
        if (m > n - filled)
            return lx_fail(lx, bl, HS_ERR_PARSE,
                           "node blocks hold more than the %lld nodes "
                           "declared",
                           n);
        for (long long j = 0; j < m; ++j) {
            if (!record(lx, j, m, "node tags")) return 0;
            b->line[filled + j] = lx->line;
            if (!rd_int(lx, 0, lo, hi, "node tag", &id) || !end_line(lx, "a node tag")) return 0;
            b->id[filled + j] = id;
        }
        for (long long j = 0; j < m; ++j) {
            double* x = b->x + 3 * (filled + j);
            double uvw;
            if (!record(lx, j, m, "node coordinates") || !rd_coord(lx, 0, "x coordinate", x) ||
                !rd_coord(lx, 0, "y coordinate", x + 1) || !rd_coord(lx, 0, "z coordinate", x + 2))
                return 0;
            for (long long q = 0; q < (param ? dim : 0); ++q)
                if (!rd_double(lx, 0, "parametric coordinate", &uvw)) return 0;
            if (!end_line(lx, "node coordinates")) return 0;
        }
        filled += m;
    }
    if (filled != n)
        return lx_fail(lx, lx->line, HS_ERR_PARSE, "node blocks hold %lld nodes, header says %lld",
                       filled, n);
    return build_map(lx, b);
}

// One element's nodes (after its id and tags): a linear tet is kept; any other element is
// checked, counted and skipped (a triangle collected). Its nodes join the physical groups of
// `tag` in dimension `dim`: the element's own physical tag (MSH 2), or those of its entity (MSH 4,
// in_entity).
static int msh_element(lexer* lx, builder* b, long long type, long long id, int in_entity, int dim,
                       long long tag) {
    int nodes[56], k = 4;
    const int* at = nodes;
    if (type != 4) {
        ++b->skipped;
        if (!skip_element_nodes(lx, b, type, id, nodes, &k)) return 0;
    } else {
        for (int c = 0; c < 4; ++c)
            if (!rd_tet_node(lx, b, 1, c, id)) return 0;
        if (!end_line(lx, "a tetrahedron")) return 0;
        at = b->tets + 4 * b->n_tets;
        dim = 3;
    }
    if (!(in_entity ? add_entity_nodes(lx, b, dim, tag, at, k)
                    : add_group_nodes(lx, b, dim, tag, at, k)))
        return 0;
    if (type == 4)
        ++b->n_tets;
    else if (type == 2 && !add_triangle(lx, b, nodes))
        return 0;
    return 1;
}

static int msh_elements_v2(lexer* lx, builder* b) {
    long long n, id, type, ntags, tag;
    int hl = lx->line;
    if (!rd_int(lx, 0, 0, LLONG_MAX, "element count", &n) || !end_line(lx, "the element count") ||
        !check_count(lx, n, 6, hl, "element") || !alloc_tets(lx, b, n))
        return 0;
    for (long long i = 0; i < n; ++i) {
        if (!record(lx, i, n, "elements") ||
            !rd_int(lx, 0, LLONG_MIN, LLONG_MAX, "element id", &id) ||
            !rd_int(lx, 0, 1, INT_MAX, "element type", &type))
            return 0;
        if (!rd_int(lx, 0, 0, 1000, "tag count", &ntags)) return 0;
        long long phys = 0; // the first tag is the physical group (0: none)
        for (long long k = 0; k < ntags; ++k) {
            if (!rd_int(lx, 0, LLONG_MIN, LLONG_MAX, "tag", &tag)) return 0;
            if (k == 0) phys = tag;
        }
        if (!msh_element(lx, b, type, id, 0, gmsh_type_dim(type), phys)) return 0;
    }
    return 1;
}

static int msh_elements_v4(lexer* lx, builder* b) {
    long long nb, n, lo, hi;
    int hl = lx->line;
    if (!rd_int(lx, 0, 0, LLONG_MAX, "entity block count", &nb) ||
        !rd_int(lx, 0, 0, LLONG_MAX, "element count", &n) ||
        !rd_int(lx, 0, n > 0, LLONG_MAX, "min element tag", &lo) ||
        !rd_int(lx, 0, n > 0, LLONG_MAX, "max element tag", &hi) ||
        !end_line(lx, "the element header") || !check_count(lx, nb, 8, hl, "element block") ||
        !check_count(lx, n, 4, hl, "element") || !alloc_tets(lx, b, n))
        return 0;
    long long filled = 0;
    for (long long k = 0; k < nb; ++k) {
        long long dim, tag, type, m, id;
        if (!record(lx, k, nb, "element blocks")) return 0;
        int bl = lx->line;
        if (!rd_int(lx, 0, 0, 3, "entity dimension", &dim) ||
            !rd_int(lx, 0, LLONG_MIN, LLONG_MAX, "entity tag", &tag) ||
            !rd_int(lx, 0, 1, INT_MAX, "element type", &type) ||
            !rd_int(lx, 0, 0, LLONG_MAX, "block element count", &m) ||
            !end_line(lx, "an element block header"))
            return 0;
        if (m > n - filled)
            return lx_fail(lx, bl, HS_ERR_PARSE,
                           "element blocks hold more than the %lld elements declared", n);
        if (type == 4 && dim != 3)
            return lx_fail(lx, bl, HS_ERR_PARSE,
                           "a block of tetrahedra in an entity of dimension %lld", dim);
        for (long long j = 0; j < m; ++j) {
            if (!record(lx, j, m, "elements")) return 0;
            if (!rd_int(lx, 0, lo, hi, "element tag", &id)) return 0;
            if (!msh_element(lx, b, type, id, 1, (int)dim, tag)) return 0;
        }
        filled += m;
    }
    if (filled != n)
        return lx_fail(lx, lx->line, HS_ERR_PARSE,
                       "element blocks hold %lld elements, header says %lld", filled, n);
    return 1;
}

// After a section body: the next token must close it.
static int msh_section_end(lexer* lx, const char* end_tag) {
    tok t;
    char buf[48];
    if (!tok_any(lx, &t))
        return lx_fail(lx, lx->line, HS_ERR_PARSE, "file ends before %s", end_tag);
    if (!tok_is(&t, end_tag))
        return lx_fail(lx, t.line, HS_ERR_PARSE, "expected %s, found '%s'", end_tag,
                       tok_text(&t, buf));
    return end_line(lx, end_tag);
}

// $PhysicalNames: a count, then lines `dim tag "name"`.
static int msh_physical_names(lexer* lx, builder* b) {
    long long n, dim, tag;
    int hl = lx->line;
    if (!rd_int(lx, 1, 0, LLONG_MAX, "physical name count", &n) ||
        !end_line(lx, "the physical name count") || !check_count(lx, n, 6, hl, "physical name"))
        return 0;
    for (long long i = 0; i < n; ++i) {
        if (!record(lx, i, n, "physical names") ||
            !rd_int(lx, 0, 0, 3, "physical dimension", &dim) ||
            !rd_int(lx, 0, INT_MIN, INT_MAX, "physical tag", &tag))
            return 0;
        skip_blanks(lx);
        int line = lx->line;
        if (lx->p >= lx->end || *lx->p != '"')
            return lx_fail(lx, line, HS_ERR_PARSE, "physical name must be in double quotes");
        const char* s0 = ++lx->p;
        while (lx->p < lx->end && *lx->p != '"' && *lx->p != '\n') ++lx->p;
        if (lx->p >= lx->end || *lx->p != '"')
            return lx_fail(lx, line, HS_ERR_PARSE, "physical name has no closing quote");
        size_t len = (size_t)(lx->p - s0);
        ++lx->p;
        if (len == 0 || len >= HS_MESH_REGION_NAME_MAX)
            return lx_fail(lx, line, HS_ERR_PARSE, "physical name of %zu bytes (1 to %d)", len,
                           HS_MESH_REGION_NAME_MAX - 1);
        for (size_t k = 0; k < len; ++k)
            if ((unsigned char)s0[k] < 0x20)
                return lx_fail(lx, line, HS_ERR_PARSE, "control byte in a physical name");
        if (!end_line(lx, "a physical name")) return 0;
        if (!grow((void**)&b->names, &b->cap_names, b->n_names, sizeof(phys_name)))
            return nomem(lx);
        phys_name* pn = &b->names[b->n_names++];
        pn->dim = (int)dim;
        pn->tag = (int)tag;
        memcpy(pn->name, s0, len);
        pn->name[len] = '\0';
    }
    return 1;
}

// MSH 4.1 $Entities: which physical groups each point, curve, surface and volume is in.
static int msh_entities(lexer* lx, builder* b) {
    long long count[4], tag, np, phys, nbound, v;
    double c;
    int hl = lx->line;
    for (int d = 0; d < 4; ++d)
        if (!rd_int(lx, 1, 0, LLONG_MAX, "entity count", &count[d]) ||
            !check_count(lx, count[d], 8, hl, "entity"))
            return 0;
    for (int d = 0; d < 4; ++d)
        for (long long i = 0; i < count[d]; ++i) {
            if (!rd_int(lx, 1, INT_MIN, INT_MAX, "entity tag", &tag)) return 0;
            for (int k = 0; k < (d == 0 ? 3 : 6); ++k)
                if (!rd_double(lx, 1, "entity coordinate", &c)) return 0;
            if (!rd_int(lx, 1, 0, 1000, "physical tag count", &np)) return 0;
            for (long long k = 0; k < np; ++k) {
                if (!rd_int(lx, 1, INT_MIN, INT_MAX, "physical tag", &phys)) return 0;
                if (!grow((void**)&b->ents, &b->cap_ents, b->n_ents, sizeof(ent_phys)))
                    return nomem(lx);
                // Gmsh may write a negative tag for an orientation; the group is |tag|.
                b->ents[b->n_ents++] = (ent_phys){d, (int)tag, (int)(phys < 0 ? -phys : phys)};
            }
            if (d > 0) {
                if (!rd_int(lx, 1, 0, 1000000, "bounding entity count", &nbound)) return 0;
                for (long long k = 0; k < nbound; ++k)
                    if (!rd_int(lx, 1, INT_MIN, INT_MAX, "bounding entity", &v)) return 0;
            }
        }
    skip_line(lx);
    return 1;
}

static int cmp_grp(const void* pa, const void* pb) {
    const grp_entry* a = pa;
    const grp_entry* b = pb;
    if (a->dim != b->dim) return a->dim < b->dim ? -1 : 1;
    if (a->tag != b->tag) return a->tag < b->tag ? -1 : 1;
    return (a->node > b->node) - (a->node < b->node);
}

// Turns the group entries into the mesh's regions. 0 on no memory (the mesh keeps what it has).
static int build_regions(lexer* lx, builder* b, hs_mesh* m) {
    if (b->n_grp == 0) return 1;
    qsort(b->grp, (size_t)b->n_grp, sizeof(grp_entry), cmp_grp);
    int n_reg = 0;
    for (int i = 0; i < b->n_grp; ++i)
        if (i == 0 || b->grp[i].dim != b->grp[i - 1].dim || b->grp[i].tag != b->grp[i - 1].tag)
            ++n_reg;
    m->regions = hs_calloc((size_t)n_reg, sizeof(hs_mesh_region));
    if (!m->regions) return nomem(lx);
    for (int i = 0; i < b->n_grp;) {
        int j = i, u = 0;
        while (j < b->n_grp && b->grp[j].dim == b->grp[i].dim && b->grp[j].tag == b->grp[i].tag)
            ++j;
        hs_mesh_region* r = &m->regions[m->n_regions];
        r->nodes = hs_alloc((size_t)(j - i) * sizeof(int));
        if (!r->nodes) return nomem(lx);
        for (int k = i; k < j; ++k)
            if (k == i || b->grp[k].node != b->grp[k - 1].node) r->nodes[u++] = b->grp[k].node;
        r->n_nodes = u;
        r->dim = b->grp[i].dim;
        r->tag = b->grp[i].tag;
        snprintf(r->name, sizeof r->name, "%d", r->tag);
        for (int k = 0; k < b->n_names; ++k)
            if (b->names[k].dim == r->dim && b->names[k].tag == r->tag)
                memcpy(r->name, b->names[k].name, sizeof r->name);
        ++m->n_regions;
        i = j;
    }
    return 1;
}

// Triangles instead of a mesh (hs_mesh_parse_msh_triangles).
typedef struct tri_out {
    int n_nodes, n_tris;
    double* x;
    int* tris;
} tri_out;

static hs_status parse_msh(lexer* lx, hs_mesh** out, tri_out* to) {
    builder b = {0};
    b.collect_tris = to != NULL;
    tok t;
    char buf[48];
    long long ftype, dsize;
    int version = 0, have_nodes = 0, have_elems = 0;
    if (!tok_any(lx, &t) || !tok_is(&t, "$MeshFormat")) {
        lx_fail(lx, lx->line, HS_ERR_PARSE, "not a Gmsh MSH file (expected $MeshFormat)");
        goto fail;
    }
    if (!end_line(lx, "$MeshFormat")) goto fail;
    if (!tok_any(lx, &t)) {
        lx_fail(lx, lx->line, HS_ERR_PARSE, "missing MSH version");
        goto fail;
    }
    if (tok_is(&t, "2") || tok_is(&t, "2.0") || tok_is(&t, "2.1") || tok_is(&t, "2.2")) {
        version = 2;
    } else if (tok_is(&t, "4.1")) {
        version = 4;
    } else {
        lx_fail(lx, t.line, HS_ERR_UNSUPPORTED, "MSH version '%s' not supported (2.2 or 4.1)",
                tok_text(&t, buf));
        goto fail;
    }
    if (!rd_int(lx, 0, 0, 1, "file type", &ftype)) goto fail;
    if (ftype != 0) {
        lx_fail(lx, lx->line, HS_ERR_UNSUPPORTED, "binary MSH not supported (save as ASCII)");
        goto fail;
    }
    if (!rd_int(lx, 0, 1, 16, "data size", &dsize) || !end_line(lx, "the format line") ||
        !msh_section_end(lx, "$EndMeshFormat"))
        goto fail;

    while (tok_any(lx, &t)) {
        if (tok_is(&t, "$Nodes") || tok_is(&t, "$Elements")) {
            int nodes = tok_is(&t, "$Nodes");
            if (nodes ? have_nodes : have_elems) {
                lx_fail(lx, t.line, HS_ERR_PARSE, "second %s section",
                        nodes ? "$Nodes" : "$Elements");
                goto fail;
            }
            if (!nodes && !have_nodes) {
                lx_fail(lx, t.line, HS_ERR_PARSE, "$Elements before $Nodes");
                goto fail;
            }
            if (!end_line(lx, nodes ? "$Nodes" : "$Elements")) goto fail;
            int ok = nodes ? (version == 2 ? msh_nodes_v2(lx, &b) : msh_nodes_v4(lx, &b))
                           : (version == 2 ? msh_elements_v2(lx, &b) : msh_elements_v4(lx, &b));
            if (!ok || !msh_section_end(lx, nodes ? "$EndNodes" : "$EndElements")) goto fail;
            have_nodes |= nodes;
            have_elems |= !nodes;
        } else if (tok_is(&t, "$PhysicalNames") || (version == 4 && tok_is(&t, "$Entities"))) {
            int names = tok_is(&t, "$PhysicalNames");
            const char* end_tag = names ? "$EndPhysicalNames" : "$EndEntities";
            size_t el = strlen(end_tag);
            int found = 0;
            for (const char* c = lx->p; !found && c + el <= lx->end; ++c)
                found = *c == '$' && memcmp(c, end_tag, el) == 0;
            if (!found) { // the same message as for a section that is skipped
                lx_fail(lx, t.line, HS_ERR_PARSE, "section %.*s has no %s", (int)t.len, t.s,
                        end_tag);
                goto fail;
            }
            if (!end_line(lx, names ? "$PhysicalNames" : "$Entities")) goto fail;
            if (!(names ? msh_physical_names(lx, &b) : msh_entities(lx, &b)) ||
                !msh_section_end(lx, names ? "$EndPhysicalNames" : "$EndEntities"))
                goto fail;
        } else if (t.len > 1 && t.s[0] == '$') {
            // Another section ($Entities, $PhysicalNames, ...): skip lines up to $End<name>.
            char end_tag[48];
            int start = t.line;
            if (t.len > 40) {
                lx_fail(lx, t.line, HS_ERR_PARSE, "section name '%s' too long", tok_text(&t, buf));
                goto fail;
            }
            snprintf(end_tag, sizeof end_tag, "$End%.*s", (int)t.len - 1, t.s + 1);
            skip_line(lx);
            for (;;) {
                if (lx->p >= lx->end) {
                    lx_fail(lx, start, HS_ERR_PARSE, "section %.*s has no %s", (int)t.len, t.s,
                            end_tag);
                    goto fail;
                }
                tok first;
                int has = tok_line(lx, &first);
                skip_line(lx);
                if (has && tok_is(&first, end_tag)) break;
            }
        } else {
            lx_fail(lx, t.line, HS_ERR_PARSE, "unexpected '%s' outside a section",
                    tok_text(&t, buf));
            goto fail;
        }
    }
    if (!have_nodes || !have_elems) {
        lx_fail(lx, lx->line, HS_ERR_PARSE, "missing %s section",
                have_nodes ? "$Elements" : "$Nodes");
        goto fail;
    }
    if (to) {
        if (b.n_tris == 0) {
            lx_fail(lx, lx->line, HS_ERR_PARSE, "no triangles (%d tetrahedra)", b.n_tets);
            goto fail;
        }
        to->n_nodes = b.n_nodes;
        to->x = b.x;
        to->n_tris = b.n_tris;
        to->tris = b.tris;
        b.x = NULL;
        b.tris = NULL;
        builder_free(&b);
        return HS_OK;
    }
    return builder_finish(lx, &b, out);
fail:
    builder_free(&b);
    return lx->status;
}

// ---------------------------------------------------------------------------------------------
// TetGen .node / .ele: '#' comments, one record per line, ids usually from 0 or 1.

static int tetgen_nodes(lexer* lx, builder* b) {
    long long n, dim, nattr, nmark, id, mark;
    double attr;
    lx->hash_comments = 1;
    if (!next_record(lx)) return lx_fail(lx, lx->line, HS_ERR_PARSE, "empty .node file");
    int hl = lx->line;
    if (!rd_int(lx, 0, 0, LLONG_MAX, "point count", &n) ||
        !rd_int(lx, 0, 0, 3, "dimension", &dim) ||
        !rd_int(lx, 0, 0, 1000, "attribute count", &nattr) ||
        !rd_int(lx, 0, 0, 1, "boundary marker flag", &nmark) || !end_line(lx, "the header"))
        return 0;
    if (dim != 3)
        return lx_fail(lx, hl, HS_ERR_UNSUPPORTED, "dimension %lld not supported (only 3)", dim);
    if (n == 0)
        return lx_fail(lx, hl, HS_ERR_PARSE, "no points (points in a .poly file are not read)");
    if (!check_count(lx, n, 8, hl, "point") || !alloc_nodes(lx, b, n)) return 0;
    for (long long i = 0; i < n; ++i) {
        double* x = b->x + 3 * i;
        if (!record(lx, i, n, "points")) return 0;
        b->line[i] = lx->line;
        if (!rd_int(lx, 0, 0, LLONG_MAX, "point id", &id) || !rd_coord(lx, 0, "x coordinate", x) ||
            !rd_coord(lx, 0, "y coordinate", x + 1) || !rd_coord(lx, 0, "z coordinate", x + 2))
            return 0;
        for (long long k = 0; k < nattr; ++k)
            if (!rd_double(lx, 0, "attribute", &attr)) return 0;
        if (nmark && !rd_int(lx, 0, LLONG_MIN, LLONG_MAX, "boundary marker", &mark)) return 0;
        if (!end_line(lx, "a point")) return 0;
        b->id[i] = id;
    }
    if (next_record(lx))
        return lx_fail(lx, lx->line, HS_ERR_PARSE, "unexpected content after %lld points", n);
    return build_map(lx, b);
}

static int tetgen_elements(lexer* lx, builder* b) {
    long long n, npt, nreg, id, v;
    double attr;
    lx->hash_comments = 1;
    if (!next_record(lx)) return lx_fail(lx, lx->line, HS_ERR_PARSE, "empty .ele file");
    int hl = lx->line;
    if (!rd_int(lx, 0, 0, LLONG_MAX, "tetrahedron count", &n) ||
        !rd_int(lx, 0, 4, 10, "nodes per tetrahedron", &npt) ||
        !rd_int(lx, 0, 0, 1, "region attribute flag", &nreg) || !end_line(lx, "the header") ||
        !check_count(lx, n, 10, hl, "tetrahedron") || !alloc_tets(lx, b, n))
        return 0;
    if (npt != 4 && npt != 10)
        return lx_fail(lx, hl, HS_ERR_PARSE, "nodes per tetrahedron must be 4 or 10, not %lld",
                       npt);
    for (long long i = 0; i < n; ++i) {
        if (!record(lx, i, n, "tetrahedra") ||
            !rd_int(lx, 0, LLONG_MIN, LLONG_MAX, "tetrahedron id", &id))
            return 0;
        if (npt == 4) {
            for (int c = 0; c < 4; ++c)
                if (!rd_tet_node(lx, b, 0, c, id)) return 0;
        } else { // quadratic: not a linear tet, skipped after checking the line
            for (int c = 0; c < 10; ++c)
                if (!rd_int(lx, 0, 0, LLONG_MAX, "node id", &v)) return 0;
        }
        if (nreg && !rd_double(lx, 0, "region attribute", &attr)) return 0;
        if (!end_line(lx, "a tetrahedron")) return 0;
        if (npt == 4)
            ++b->n_tets;
        else
            ++b->skipped;
    }
    if (next_record(lx))
        return lx_fail(lx, lx->line, HS_ERR_PARSE, "unexpected content after %lld tetrahedra", n);
    return 1;
}

static hs_status parse_tetgen(const char* node_name, const char* node_data, size_t node_len,
                              const char* ele_name, const char* ele_data, size_t ele_len,
                              hs_mesh** out, hs_err* err) {
    builder b = {0};
    lexer ln, le;
    lx_init(&ln, node_name, node_data, node_len, err);
    lx_init(&le, ele_name, ele_data, ele_len, err);
    if (!tetgen_nodes(&ln, &b)) {
        builder_free(&b);
        return ln.status;
    }
    if (!tetgen_elements(&le, &b)) {
        builder_free(&b);
        return le.status;
    }
    return builder_finish(&le, &b, out);
}

// ---------------------------------------------------------------------------------------------
// Legacy VTK, ASCII, DATASET UNSTRUCTURED_GRID. Points and cells are free-form (any number of
// values per line). Both the classic CELLS layout and the 5.1 OFFSETS/CONNECTIVITY layout.

typedef struct vtk_cells {
    long long n; // cells
    int* start;  // [n+1] offsets into conn
    int* conn;   // point indices
} vtk_cells;

static int vtk_cells_classic(lexer* lx, vtk_cells* c, long long n_pts, int hl) {
    long long n, size, k, v;
    if (!rd_int(lx, 0, 0, LLONG_MAX, "cell count", &n) ||
        !rd_int(lx, 0, 0, LLONG_MAX, "cell list size", &size) ||
        !end_line(lx, "the CELLS header") || !check_count(lx, n, 2, hl, "cell") ||
        !check_count(lx, size, 2, hl, "cell list entry"))
        return 0;
    c->start = hs_alloc(((size_t)n + 1) * sizeof(int));
    c->conn = hs_alloc(((size_t)size + 1) * sizeof(int));
    if (!c->start || !c->conn) return nomem(lx);
    c->n = n;
    long long used = 0, nc = 0;
    c->start[0] = 0;
    for (long long i = 0; i < n; ++i) {
        if (!rd_int(lx, 1, 0, size - used - 1, "cell point count", &k)) return 0;
        used += 1 + k;
        for (long long j = 0; j < k; ++j) {
            if (!rd_int(lx, 1, 0, n_pts - 1, "point index", &v)) return 0;
            c->conn[nc++] = (int)v;
        }
        c->start[i + 1] = (int)nc;
    }
    if (used != size)
        return lx_fail(lx, hl, HS_ERR_PARSE, "CELLS size is %lld but the cells use %lld", size,
                       used);
    return 1;
}

static int vtk_cells_v5(lexer* lx, vtk_cells* c, long long n_pts, int hl) {
    long long n_off, n_conn, v;
    tok t, type;
    if (!rd_int(lx, 0, 1, LLONG_MAX, "offset count", &n_off) ||
        !rd_int(lx, 0, 0, LLONG_MAX, "connectivity size", &n_conn) ||
        !end_line(lx, "the CELLS header") || !check_count(lx, n_off, 2, hl, "offset") ||
        !check_count(lx, n_conn, 2, hl, "connectivity entry"))
        return 0;
    c->start = hs_alloc(((size_t)n_off + 1) * sizeof(int));
    c->conn = hs_alloc(((size_t)n_conn + 1) * sizeof(int));
    if (!c->start || !c->conn) return nomem(lx);
    c->n = n_off - 1;
    for (int part = 0; part < 2; ++part) {
        const char* key = part ? "CONNECTIVITY" : "OFFSETS";
        if (!tok_any(lx, &t) || !tok_is_nocase(&t, key))
            return lx_fail(lx, lx->line, HS_ERR_PARSE, "expected %s", key);
        if (!tok_line(lx, &type))
            return lx_fail(lx, t.line, HS_ERR_PARSE, "%s needs a data type", key);
        if (!end_line(lx, key)) return 0;
        long long m = part ? n_conn : n_off;
        for (long long i = 0; i < m; ++i) {
            if (part) {
                if (!rd_int(lx, 1, 0, n_pts - 1, "point index", &v)) return 0;
                c->conn[i] = (int)v;
                continue;
            }
            long long lo = i ? c->start[i - 1] : 0, hi = i ? n_conn : 0;
            if (!rd_int(lx, 1, lo, hi, "offset", &v)) return 0;
            c->start[i] = (int)v;
        }
    }
    if (c->start[c->n] != n_conn)
        return lx_fail(lx, hl, HS_ERR_PARSE, "last offset %d differs from connectivity size %lld",
                       c->start[c->n], n_conn);
    return 1;
}

// Field data (VTK writes e.g. TIME and CYCLE before POINTS): "FIELD name n", then per array
// "name components tuples type" and components * tuples values, all skipped.
static int vtk_skip_field(lexer* lx, int hl) {
    tok t;
    long long n_arrays, comps, tuples;
    if (!tok_line(lx, &t)) return lx_fail(lx, hl, HS_ERR_PARSE, "FIELD needs a name");
    if (!rd_int(lx, 0, 0, LLONG_MAX, "field array count", &n_arrays) ||
        !end_line(lx, "the FIELD header") || !check_count(lx, n_arrays, 8, hl, "field array"))
        return 0;
    for (long long a = 0; a < n_arrays; ++a) {
        if (!tok_any(lx, &t))
            return lx_fail(lx, lx->line, HS_ERR_PARSE, "file ends in FIELD array %lld", a);
        int al = t.line;
        if (!rd_int(lx, 0, 0, LLONG_MAX, "field components", &comps) ||
            !rd_int(lx, 0, 0, LLONG_MAX, "field tuples", &tuples) || !tok_line(lx, &t) ||
            !end_line(lx, "a field array header"))
            return lx->status ? 0 : lx_fail(lx, al, HS_ERR_PARSE, "field array needs a type");
        if (comps > 0 && tuples > (long long)(lx->end - lx->p) / 2 / comps + 1)
            return lx_fail(lx, al, HS_ERR_PARSE, "field array of %lld x %lld values does not fit",
                           comps, tuples);
        for (long long v = 0; v < comps * tuples; ++v)
            if (!tok_any(lx, &t))
                return lx_fail(lx, lx->line, HS_ERR_PARSE, "file ends in FIELD array %lld", a);
    }
    return 1;
}

static hs_status parse_vtk(lexer* lx, hs_mesh** out) {
    builder b = {.by_index = 1};
    vtk_cells c = {0};
    tok t;
    char buf[48];
    int have_cells = 0, have_types = 0, v5 = 0;
    // Line 1: "# vtk DataFile Version x.y"
    static const char* const head[4] = {"#", "vtk", "DataFile", "Version"};
    for (int i = 0; i < 4; ++i)
        if (!tok_line(lx, &t) || !tok_is_nocase(&t, head[i])) {
            lx_fail(lx, 1, HS_ERR_PARSE,
                    "not a legacy VTK file (expected '# vtk DataFile Version')");
            goto fail;
        }
    double version;
    if (!rd_double(lx, 0, "VTK version", &version)) goto fail;
    v5 = version >= 5.0;
    skip_line(lx);
    if (lx->p >= lx->end) {
        lx_fail(lx, lx->line, HS_ERR_PARSE, "missing title line");
        goto fail;
    }
    skip_line(lx); // title
    if (!tok_any(lx, &t)) {
        lx_fail(lx, lx->line, HS_ERR_PARSE, "missing ASCII/BINARY line");
        goto fail;
    }
    if (!tok_is_nocase(&t, "ASCII")) {
        lx_fail(lx, t.line, tok_is_nocase(&t, "BINARY") ? HS_ERR_UNSUPPORTED : HS_ERR_PARSE,
                "expected ASCII, found '%s' (binary VTK not supported)", tok_text(&t, buf));
        goto fail;
    }
    if (!end_line(lx, "ASCII")) goto fail;
    if (!tok_any(lx, &t) || !tok_is_nocase(&t, "DATASET")) {
        lx_fail(lx, lx->line, HS_ERR_PARSE, "expected DATASET UNSTRUCTURED_GRID");
        goto fail;
    }
    if (!tok_line(lx, &t) || !tok_is_nocase(&t, "UNSTRUCTURED_GRID")) {
        if (t.len && tok_is_nocase(&t, "POLYDATA"))
            lx_fail(lx, lx->line, HS_ERR_UNSUPPORTED,
                    "DATASET POLYDATA is a surface, not a volume mesh (UNSTRUCTURED_GRID): "
                    "hapsim-mesh tet --size H makes tetrahedra of it");
        else
            lx_fail(lx, lx->line, HS_ERR_UNSUPPORTED,
                    "only DATASET UNSTRUCTURED_GRID is supported");
        goto fail;
    }
    if (!end_line(lx, "DATASET")) goto fail;

    while (tok_any(lx, &t)) {
        int hl = t.line;
        long long n, type;
        if (tok_is_nocase(&t, "POINTS")) {
            tok dtype;
            if (b.x) {
                lx_fail(lx, hl, HS_ERR_PARSE, "second POINTS section");
                goto fail;
            }
            if (!rd_int(lx, 0, 0, LLONG_MAX, "point count", &n)) goto fail;
            if (!tok_line(lx, &dtype)) {
                lx_fail(lx, hl, HS_ERR_PARSE, "POINTS needs a data type");
                goto fail;
            }
            if (!end_line(lx, "the POINTS header") || !check_count(lx, n, 6, hl, "point") ||
                !alloc_nodes(lx, &b, n))
                goto fail;
            for (long long i = 0; i < 3 * n; ++i)
                if (!rd_coord(lx, 1, "point coordinate", b.x + i)) goto fail;
        } else if (tok_is_nocase(&t, "CELLS")) {
            if (!b.x || have_cells) {
                lx_fail(lx, hl, HS_ERR_PARSE,
                        have_cells ? "second CELLS section" : "CELLS before POINTS");
                goto fail;
            }
            if (!(v5 ? vtk_cells_v5(lx, &c, b.n_nodes, hl)
                     : vtk_cells_classic(lx, &c, b.n_nodes, hl)))
                goto fail;
            have_cells = 1;
        } else if (tok_is_nocase(&t, "CELL_TYPES")) {
            if (!have_cells || have_types) {
                lx_fail(lx, hl, HS_ERR_PARSE,
                        have_types ? "second CELL_TYPES section" : "CELL_TYPES before CELLS");
                goto fail;
            }
            if (!rd_int(lx, 0, 0, LLONG_MAX, "cell type count", &n) ||
                !end_line(lx, "the CELL_TYPES header") || !alloc_tets(lx, &b, c.n))
                goto fail;
            if (n != c.n) {
                lx_fail(lx, hl, HS_ERR_PARSE, "CELL_TYPES count %lld differs from %lld cells", n,
                        c.n);
                goto fail;
            }
            for (long long i = 0; i < n; ++i) {
                if (!rd_int(lx, 1, 0, INT_MAX, "cell type", &type)) goto fail;
                int k = c.start[i + 1] - c.start[i];
                if (type != 10) {
                    ++b.skipped;
                    continue;
                }
                if (k != 4) {
                    lx_fail(lx, lx->line, HS_ERR_PARSE,
                            "cell %lld is a tetra (type 10) with %d "
                            "points",
                            i, k);
                    goto fail;
                }
                memcpy(b.tets + 4 * b.n_tets, c.conn + c.start[i], 4 * sizeof(int));
                b.tline[b.n_tets] = 0;
                b.tid[b.n_tets++] = i;
            }
            have_types = 1;
        } else if (tok_is_nocase(&t, "METADATA")) {
            // VTK 9 writes METADATA blocks that end at an empty line.
            skip_line(lx);
            while (lx->p < lx->end) {
                tok first;
                int has = tok_line(lx, &first);
                skip_line(lx);
                if (!has) break;
            }
        } else if (tok_is_nocase(&t, "FIELD")) {
            if (!vtk_skip_field(lx, hl)) goto fail;
        } else if (tok_is_nocase(&t, "POINT_DATA") || tok_is_nocase(&t, "CELL_DATA")) {
            break; // attributes are not read
        } else {
            lx_fail(lx, hl, HS_ERR_PARSE, "unexpected '%s'", tok_text(&t, buf));
            goto fail;
        }
    }
    if (!b.x || !have_cells || !have_types) {
        lx_fail(lx, lx->line, HS_ERR_PARSE, "missing %s section",
                !b.x          ? "POINTS"
                : !have_cells ? "CELLS"
                              : "CELL_TYPES");
        goto fail;
    }
    hs_free(c.start);
    hs_free(c.conn);
    return builder_finish(lx, &b, out);
fail:
    hs_free(c.start);
    hs_free(c.conn);
    builder_free(&b);
    return lx->status;
}

// ---------------------------------------------------------------------------------------------
// VTK XML unstructured grid (.vtu), ASCII data arrays (as hapsim-view and ParaView's ASCII
// option write). Only <Points> and <Cells> are read; binary and appended data are refused.

// Next '<' tag from lx->p; sets name (after '<', up to blank, '>' or '/') and the tag's end.
static int vtu_next_tag(lexer* lx, const char** tag, size_t* tag_len, const char** tag_end) {
    for (;;) {
        const char* lt = memchr(lx->p, '<', (size_t)(lx->end - lx->p));
        if (!lt) return 0;
        for (const char* c = lx->p; c < lt; ++c) lx->line += *c == '\n';
        const char* gt = memchr(lt, '>', (size_t)(lx->end - lt));
        if (!gt) return lx_fail(lx, lx->line, HS_ERR_PARSE, "unterminated tag");
        lx->p = gt + 1;
        for (const char* c = lt; c < gt; ++c) lx->line += *c == '\n';
        if (lt + 1 < gt && (lt[1] == '?' || lt[1] == '!')) continue; // <?xml ?> and comments
        const char* n = lt + 1;
        const char* e = n;
        while (e < gt && !is_blank(*e) && *e != '\n' && *e != '>' && *e != '/') ++e;
        if (e == n && e < gt && *e == '/') { // closing tag: name after the slash
            ++n;
            e = n;
            while (e < gt && !is_blank(*e) && *e != '\n' && *e != '>') ++e;
            *tag = n - 1;
            *tag_len = (size_t)(e - n + 1);
        } else {
            *tag = n;
            *tag_len = (size_t)(e - n);
        }
        *tag_end = gt;
        return 1;
    }
}

// Attribute value of `key` inside [s, e) (a tag's text); 0 when absent.
static int vtu_attr(const char* s, const char* e, const char* key, const char** v, size_t* n) {
    size_t k = strlen(key);
    for (const char* c = s; c + k + 2 <= e; ++c) {
        if ((c == s || is_blank(c[-1]) || c[-1] == '\n') && memcmp(c, key, k) == 0 && c[k] == '=' &&
            (c[k + 1] == '"' || c[k + 1] == '\'')) {
            const char q = c[k + 1];
            const char* b = c + k + 2;
            const char* z = memchr(b, q, (size_t)(e - b));
            if (!z) return 0;
            *v = b;
            *n = (size_t)(z - b);
            return 1;
        }
    }
    return 0;
}

static int span_is(const char* s, size_t n, const char* lit) {
    return n == strlen(lit) && memcmp(s, lit, n) == 0;
}

typedef struct vtu_data {
    long long n_pts, n_cells;
    double* pts;     // [3 n_pts]
    long long* conn; // connectivity
    long long n_conn;
    long long* offs;  // [n_cells]
    long long* types; // [n_cells]
} vtu_data;

static void vtu_free(vtu_data* d) {
    hs_free(d->pts);
    hs_free(d->conn);
    hs_free(d->offs);
    hs_free(d->types);
    memset(d, 0, sizeof *d);
}

// Reads the numbers of a DataArray body (up to "</DataArray>") into a new array.
static int vtu_numbers(lexer* lx, int as_int, long long max_n, const char* what, void** out,
                       long long* count) {
    const char* close = NULL;
    for (const char* c = lx->p; c + 12 <= lx->end; ++c)
        if (*c == '<') {
            close = c;
            break;
        }
    if (!close) return lx_fail(lx, lx->line, HS_ERR_PARSE, "%s: no </DataArray>", what);
    lexer sub = *lx;
    sub.end = close;
    size_t cap = (size_t)(close - lx->p) / 2 + 1;
    if ((long long)cap > max_n + 1) cap = (size_t)max_n + 1;
    void* a = hs_alloc(cap * 8 + 8);
    if (!a) return nomem(lx);
    long long n = 0;
    tok t;
    char b[48];
    while (tok_any(&sub, &t)) {
        if (n >= max_n) {
            hs_free(a);
            return lx_fail(lx, t.line, HS_ERR_PARSE, "%s: more than %lld values", what, max_n);
        }
        int ok = as_int ? parse_ll(&t, (long long*)a + n)
                        : parse_double(&t, (double*)a + n) && fabs(((double*)a)[n]) <= 1e30;
        if (!ok) {
            hs_free(a);
            return lx_fail(lx, t.line, HS_ERR_PARSE, "%s: bad value '%s'", what, tok_text(&t, b));
        }
        ++n;
    }
    lx->line = sub.line;
    lx->p = close;
    *out = a;
    *count = n;
    return 1;
}

static int vtu_read(lexer* lx, vtu_data* d) {
    const char *tag = NULL, *tend = NULL;
    size_t tl = 0;
    int in_points = 0, in_cells = 0, seen_vtk = 0, pieces = 0;
    while (vtu_next_tag(lx, &tag, &tl, &tend)) {
        if (span_is(tag, tl, "VTKFile")) {
            const char* v;
            size_t n;
            if (!vtu_attr(tag, tend, "type", &v, &n) || !span_is(v, n, "UnstructuredGrid"))
                return lx_fail(lx, lx->line, HS_ERR_UNSUPPORTED,
                               "only VTKFile type=\"UnstructuredGrid\" is read");
            if (vtu_attr(tag, tend, "compressor", &v, &n))
                return lx_fail(lx, lx->line, HS_ERR_UNSUPPORTED,
                               "compressed VTU not supported (save as ASCII)");
            seen_vtk = 1;
        } else if (span_is(tag, tl, "Piece")) {
            if (++pieces > 1)
                return lx_fail(lx, lx->line, HS_ERR_UNSUPPORTED, "more than one Piece");
            const char *v1, *v2;
            size_t n1, n2;
            tok t1, t2;
            if (!vtu_attr(tag, tend, "NumberOfPoints", &v1, &n1) ||
                !vtu_attr(tag, tend, "NumberOfCells", &v2, &n2))
                return lx_fail(lx, lx->line, HS_ERR_PARSE,
                               "Piece needs NumberOfPoints and NumberOfCells");
            t1 = (tok){v1, n1, lx->line};
            t2 = (tok){v2, n2, lx->line};
            if (!parse_ll(&t1, &d->n_pts) || !parse_ll(&t2, &d->n_cells) || d->n_pts < 0 ||
                d->n_cells < 0 || d->n_pts > HS_MESH_MAX_COUNT || d->n_cells > HS_MESH_MAX_COUNT)
                return lx_fail(lx, lx->line, HS_ERR_PARSE, "bad NumberOfPoints or NumberOfCells");
        } else if (span_is(tag, tl, "Points") || span_is(tag, tl, "/Points")) {
            in_points = tag[0] != '/';
        } else if (span_is(tag, tl, "Cells") || span_is(tag, tl, "/Cells")) {
            in_cells = tag[0] != '/';
        } else if (span_is(tag, tl, "AppendedData")) {
            return lx_fail(lx, lx->line, HS_ERR_UNSUPPORTED,
                           "appended VTU data not supported (save as ASCII)");
        } else if (span_is(tag, tl, "DataArray") && (in_points || in_cells)) {
            if (!pieces) return lx_fail(lx, lx->line, HS_ERR_PARSE, "DataArray outside a Piece");
            const char *v, *nm = "";
            size_t n, nml = 0;
            if (!vtu_attr(tag, tend, "format", &v, &n) || !span_is(v, n, "ascii"))
                return lx_fail(lx, lx->line, HS_ERR_UNSUPPORTED,
                               "DataArray format is not \"ascii\" (binary VTU not supported; "
                               "save as ASCII)");
            vtu_attr(tag, tend, "Name", &nm, &nml);
            if (tend > tag && tend[-1] == '/') continue; // empty element
            long long cnt;
            void* a = NULL;
            if (in_points) {
                if (d->pts) return lx_fail(lx, lx->line, HS_ERR_PARSE, "second Points array");
                if (!vtu_numbers(lx, 0, 3 * d->n_pts, "Points", &a, &cnt)) return 0;
                d->pts = a;
                if (cnt != 3 * d->n_pts)
                    return lx_fail(lx, lx->line, HS_ERR_PARSE,
                                   "Points has %lld values, NumberOfPoints %lld needs %lld", cnt,
                                   d->n_pts, 3 * d->n_pts);
            } else if (span_is(nm, nml, "connectivity")) {
                if (d->conn) return lx_fail(lx, lx->line, HS_ERR_PARSE, "second connectivity");
                if (!vtu_numbers(lx, 1, HS_MESH_MAX_COUNT, "connectivity", &a, &cnt)) return 0;
                d->conn = a;
                d->n_conn = cnt;
            } else if (span_is(nm, nml, "offsets") || span_is(nm, nml, "types")) {
                int offs = nm[0] == 'o';
                if (offs ? d->offs != NULL : d->types != NULL)
                    return lx_fail(lx, lx->line, HS_ERR_PARSE, "second %s array",
                                   offs ? "offsets" : "types");
                if (!vtu_numbers(lx, 1, d->n_cells, offs ? "offsets" : "types", &a, &cnt)) return 0;
                if (offs)
                    d->offs = a;
                else
                    d->types = a;
                if (cnt != d->n_cells)
                    return lx_fail(lx, lx->line, HS_ERR_PARSE, "%s has %lld values for %lld cells",
                                   offs ? "offsets" : "types", cnt, d->n_cells);
            }
        }
    }
    if (lx->status) return 0;
    if (!seen_vtk) return lx_fail(lx, lx->line, HS_ERR_PARSE, "not a VTK XML file (no <VTKFile>)");
    if (!pieces) return lx_fail(lx, lx->line, HS_ERR_PARSE, "no <Piece>");
    if (!d->pts || !d->conn || !d->offs || !d->types)
        return lx_fail(lx, lx->line, HS_ERR_PARSE, "missing %s",
                       !d->pts    ? "Points"
                       : !d->conn ? "Cells connectivity"
                       : !d->offs ? "Cells offsets"
                                  : "Cells types");
    long long prev = 0;
    for (long long c = 0; c < d->n_cells; ++c) {
        if (d->offs[c] < prev || d->offs[c] > d->n_conn)
            return lx_fail(lx, lx->line, HS_ERR_PARSE, "cell %lld: offset %lld out of order", c,
                           d->offs[c]);
        prev = d->offs[c];
    }
    for (long long i = 0; i < d->n_conn; ++i)
        if (d->conn[i] < 0 || d->conn[i] >= d->n_pts)
            return lx_fail(lx, lx->line, HS_ERR_PARSE, "connectivity %lld: point %lld of %lld", i,
                           d->conn[i], d->n_pts);
    return 1;
}

// Cells of `type` with k points (10, 4: tets; 5, 3: triangles) into arrays of k ints each.
static int vtu_cells(lexer* lx, const vtu_data* d, long long type, int k, int** out, int* n_out,
                     int* skipped) {
    int* a = hs_alloc(((size_t)d->n_cells * (size_t)k + 1) * sizeof(int));
    if (!a) return nomem(lx);
    int n = 0;
    *skipped = 0;
    for (long long c = 0; c < d->n_cells; ++c) {
        long long b = c ? d->offs[c - 1] : 0;
        if (d->types[c] != type) {
            ++*skipped;
            continue;
        }
        if (d->offs[c] - b != k) {
            hs_free(a);
            return lx_fail(lx, lx->line, HS_ERR_PARSE, "cell %lld of type %lld has %lld points", c,
                           type, d->offs[c] - b);
        }
        for (int j = 0; j < k; ++j) a[(size_t)n * k + j] = (int)d->conn[b + j];
        ++n;
    }
    *out = a;
    *n_out = n;
    return 1;
}

static hs_status parse_vtu(lexer* lx, hs_mesh** out, tri_out* to) {
    vtu_data d = {0};
    builder b = {.by_index = 1};
    int* cells = NULL;
    int n = 0, skipped = 0;
    if (!vtu_read(lx, &d) || !vtu_cells(lx, &d, to ? 5 : 10, to ? 3 : 4, &cells, &n, &skipped))
        goto fail;
    if (to) {
        if (n == 0) {
            lx_fail(lx, lx->line, HS_ERR_PARSE, "no triangles (%d other cells)", skipped);
            goto fail;
        }
        to->n_nodes = (int)d.n_pts;
        to->x = d.pts;
        to->n_tris = n;
        to->tris = cells;
        d.pts = NULL;
        vtu_free(&d);
        return HS_OK;
    }
    b.n_nodes = (int)d.n_pts;
    b.x = d.pts;
    d.pts = NULL;
    b.tets = cells;
    cells = NULL;
    b.n_tets = n;
    b.skipped = skipped;
    b.tid = hs_alloc(((size_t)n + 1) * sizeof(long long));
    b.tline = hs_alloc(((size_t)n + 1) * sizeof(int));
    if (!b.tid || !b.tline) {
        nomem(lx);
        goto fail;
    }
    for (long long c = 0, k = 0; c < d.n_cells; ++c)
        if (d.types[c] == 10) {
            b.tid[k] = c;
            b.tline[k++] = 0;
        }
    vtu_free(&d);
    if (n == 0) {
        lx_fail(lx, lx->line, HS_ERR_PARSE,
                "no tetrahedra (%d other cells: a surface? use it with hapsim-mesh tet)", skipped);
        builder_free(&b);
        return lx->status;
    }
    return builder_finish(lx, &b, out);
fail:
    hs_free(cells);
    vtu_free(&d);
    builder_free(&b);
    return lx->status ? lx->status : HS_ERR_PARSE;
}

// ---------------------------------------------------------------------------------------------

hs_status hs_mesh_parse(const char* name, const char* format, const char* data, size_t len,
                        hs_mesh** out, hs_err* err) {
    if (!out) return hs_err_set(err, HS_ERR_INVALID, "out is NULL");
    *out = NULL;
    if (!format || (!data && len > 0))
        return hs_err_set(err, HS_ERR_INVALID, "format or data is NULL");
    lexer lx;
    lx_init(&lx, name, data, len, err);
    if (strcmp(format, "msh") == 0) return parse_msh(&lx, out, NULL);
    if (strcmp(format, "vtk") == 0) return parse_vtk(&lx, out);
    if (strcmp(format, "vtu") == 0) return parse_vtu(&lx, out, NULL);
    return hs_err_set(err, HS_ERR_INVALID,
                      "unknown mesh format '%.40s' (msh, vtk, vtu; TetGen via "
                      "hs_mesh_parse_tetgen)",
                      format);
}

hs_status hs_mesh_parse_triangles(const char* name, const char* format, const char* data,
                                  size_t len, int* n_nodes, double** x, int* n_tris, int** tris,
                                  hs_err* err) {
    if (!n_nodes || !x || !n_tris || !tris) return hs_err_set(err, HS_ERR_INVALID, "out is NULL");
    *n_nodes = *n_tris = 0;
    *x = NULL;
    *tris = NULL;
    if (!data && len) return hs_err_set(err, HS_ERR_INVALID, "data is NULL");
    lexer lx;
    lx_init(&lx, name, data, len, err);
    tri_out to = {0};
    if (!format || (strcmp(format, "msh") != 0 && strcmp(format, "vtu") != 0))
        return hs_err_set(err, HS_ERR_INVALID, "triangles from msh or vtu only");
    hs_status st = format[0] == 'm' ? parse_msh(&lx, NULL, &to) : parse_vtu(&lx, NULL, &to);
    if (st != HS_OK) return st;
    *n_nodes = to.n_nodes;
    *x = to.x;
    *n_tris = to.n_tris;
    *tris = to.tris;
    return HS_OK;
}

hs_status hs_mesh_parse_tetgen(const char* name, const char* node_data, size_t node_len,
                               const char* ele_data, size_t ele_len, hs_mesh** out, hs_err* err) {
    if (!out) return hs_err_set(err, HS_ERR_INVALID, "out is NULL");
    *out = NULL;
    if ((!node_data && node_len) || (!ele_data && ele_len))
        return hs_err_set(err, HS_ERR_INVALID, "data is NULL");
    char nn[512], en[512];
    snprintf(nn, sizeof nn, "%s.node", name ? name : "(memory)");
    snprintf(en, sizeof en, "%s.ele", name ? name : "(memory)");
    return parse_tetgen(nn, node_data, node_len, en, ele_data, ele_len, out, err);
}

hs_status hs_mesh_load(const char* path, hs_mesh** out, hs_err* err) {
    if (!out) return hs_err_set(err, HS_ERR_INVALID, "out is NULL");
    *out = NULL;
    if (!path) return hs_err_set(err, HS_ERR_INVALID, "path is NULL");
    char* data = NULL;
    size_t len = 0;
    hs_status st;
    if (hs_path_has_ext(path, ".msh") || hs_path_has_ext(path, ".vtk") ||
        hs_path_has_ext(path, ".vtu")) {
        st = hs_read_file(path, &data, &len, err);
        if (st != HS_OK) return st;
        lexer lx;
        lx_init(&lx, path, data, len, err);
        st = hs_path_has_ext(path, ".msh")   ? parse_msh(&lx, out, NULL)
             : hs_path_has_ext(path, ".vtu") ? parse_vtu(&lx, out, NULL)
                                             : parse_vtk(&lx, out);
        hs_free(data);
        return st;
    }
    if (hs_path_has_ext(path, ".node") || hs_path_has_ext(path, ".ele")) {
        size_t n = strlen(path), base = n - (hs_path_has_ext(path, ".node") ? 5 : 4);
        if (base > 4000) return hs_err_set(err, HS_ERR_INVALID, "path too long");
        // The other file's extension in the case of the one given (MESH.NODE -> MESH.ELE).
        const int upper = path[n - 1] >= 'A' && path[n - 1] <= 'Z';
        char node_path[4100], ele_path[4100];
        snprintf(node_path, sizeof node_path, "%.*s%s", (int)base, path, upper ? ".NODE" : ".node");
        snprintf(ele_path, sizeof ele_path, "%.*s%s", (int)base, path, upper ? ".ELE" : ".ele");
        if (hs_path_has_ext(path, ".node"))
            memcpy(node_path + base, path + base, 5);
        else
            memcpy(ele_path + base, path + base, 4);
        char* ele = NULL;
        size_t ele_len = 0;
        st = hs_read_file(node_path, &data, &len, err);
        if (st == HS_OK) st = hs_read_file(ele_path, &ele, &ele_len, err);
        if (st == HS_OK) st = parse_tetgen(node_path, data, len, ele_path, ele, ele_len, out, err);
        hs_free(data);
        hs_free(ele);
        return st;
    }
    return hs_err_set(err, HS_ERR_UNSUPPORTED,
                      "%s: unknown mesh extension (.msh, .node/.ele, .vtk, .vtu; a surface (.stl, "
                      ".obj, .ply, .off) becomes tets with hapsim-mesh tet)",
                      path);
}
