// SPDX-License-Identifier: GPL-2.0-or-later
// Scene files: JSON (cJSON) -> hs_scene. Every value is type- and range-checked; unknown and
// repeated keys are errors (a typo must not silently fall back to a default). Errors name the
// file, the line and the key path, e.g. "liver.json:7: key 'material.poisson': ...".
#define _DEFAULT_SOURCE // inet_aton
#include "scene.h"
#include "open_regular.h"

#include <arpa/inet.h>
#include <cJSON.h>
#include <errno.h>
#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "hapsim_channels.h" // defaults and hapsim_url_problem (header only)

#define MAX_SCENE_BYTES (1 << 20)

void hs_scene_default(hs_scene* s) {
    memset(s, 0, sizeof *s);
    s->units_scale = 1.0;
    s->model = HS_MODEL_COROTATED;
    s->rotation = HS_ROTATION_POLAR;
    s->inversion = HS_INVERSION_LINEAR_FALLBACK;
    s->locking_free = 0;
    s->material.youngs_pa = 5000.0;
    s->material.poisson = 0.45;
    s->material.density_kg_m3 = 1000.0;
    s->gravity[2] = -9.81;
    s->n_tools = 1;
    s->tools[0].kind = HS_TOOL_PROBE;
    s->tools[0].radius = 0.005;
    s->n_devices = 1;
    s->haptic_hz = 1000.0;
    s->sim_hz = 60.0;
    s->visual_hz = 30.0;
    s->status_hz = 2.0;
    s->feature_haptics = 1;
    s->feature_cutting = 0;
    s->cut_free_pieces_fall = 0;
    s->feature_visual = 1;
    s->force_max_n = 3.3;
    s->force_rate_max = 500.0;
    s->watchdog_s = 0.1;
    s->min_dihedral_deg = 0.5;
    snprintf(s->haptic_url, sizeof s->haptic_url, "%s", HAPSIM_DEFAULT_HAPTIC_URL);
    snprintf(s->mesh_url, sizeof s->mesh_url, "%s", HAPSIM_DEFAULT_MESH_URL);
    snprintf(s->prefix, sizeof s->prefix, "%s", HAPSIM_DEFAULT_PREFIX);
}

const char* hs_scene_model_name(hs_model m) {
    switch (m) {
    case HS_MODEL_LINEAR:
        return "linear";
    case HS_MODEL_COROTATED:
        return "corotated";
    case HS_MODEL_STVK:
        return "stvk";
    }
    return "unknown";
}

// ---------------------------------------------------------------------------------------------
// Locating an item in the source text. cJSON keeps no positions, so walk the (valid) text in
// step with the tree until the target item is reached; members are reported at their key.

// cJSON skips every byte from 1 to 32 as whitespace; so must the walker.
static const char* skip_ws(const char* p) {
    while (*p && (unsigned char)*p <= 32) ++p;
    return p;
}

static const char* skip_string(const char* p) {
    if (*p != '"') return p;
    for (++p; *p && *p != '"'; ++p)
        if (*p == '\\' && p[1]) ++p;
    return *p ? p + 1 : p;
}

static const char* walk(const cJSON* it, const char* p, const cJSON* target, const char** found) {
    p = skip_ws(p);
    if (it == target && !*found) *found = p;
    if (cJSON_IsObject(it) || cJSON_IsArray(it)) {
        int obj = cJSON_IsObject(it);
        if (*p) ++p; // '{' or '['
        for (const cJSON* ch = it->child; ch && !*found; ch = ch->next) {
            p = skip_ws(p);
            if (obj) {
                if (ch == target) {
                    *found = p;
                    break;
                }
                p = skip_ws(skip_string(p));
                if (*p == ':') ++p;
            }
            p = walk(ch, p, target, found);
            p = skip_ws(p);
            if (*p == ',') ++p;
        }
        p = skip_ws(p);
        if (*p) ++p; // '}' or ']'
        return p;
    }
    if (cJSON_IsString(it)) return skip_string(p);
    while ((unsigned char)*p > 32 && !strchr(",}]", *p)) ++p;
    return p;
}

// Lines end at \n, \r\n or a lone \r (old Mac files: found in review, every error said line 1).
static int line_at(const char* text, const char* at) {
    int line = 1;
    for (const char* p = text; p < at && *p; ++p)
        if (*p == '\n' || (*p == '\r' && p[1] != '\n')) ++line;
    return line;
}

typedef struct ctx {
    const char* file;
    const char* text;
    const cJSON* root;
    hs_err* err;
} ctx;

static hs_status fail(const ctx* c, const cJSON* item, const char* key, const char* fmt, ...)
    __attribute__((format(printf, 4, 5)));

static hs_status fail(const ctx* c, const cJSON* item, const char* key, const char* fmt, ...) {
    char what[320];
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(what, sizeof what, fmt, ap);
    va_end(ap);
    const char* at = NULL;
    if (item) walk(c->root, c->text, item, &at);
    if (at)
        return hs_err_set(c->err, HS_ERR_PARSE, "%s:%d: key '%s': %s", c->file,
                          line_at(c->text, at), key, what);
    return hs_err_set(c->err, HS_ERR_PARSE, "%s: key '%s': %s", c->file, key, what);
}

// Line of item in the text (for messages made after parsing), 0 if not found.
static int item_line(const ctx* c, const cJSON* item) {
    const char* at = NULL;
    walk(c->root, c->text, item, &at);
    return at ? line_at(c->text, at) : 0;
}

#define HS_SCENE_MAX_KEYS 256

// Every member must be in allowed (NULL-terminated) or start with '_' (a comment); no repeats.
static hs_status check_keys(const ctx* c, const cJSON* obj, const char* path,
                            const char* const* allowed) {
    char key[128];
    int count = 0; // the repeat check is quadratic: bound it
    for (const cJSON* m = obj->child; m; m = m->next)
        if (++count > HS_SCENE_MAX_KEYS)
            return fail(c, m, path[0] ? path : "(top level)", "more than %d keys in one object",
                        HS_SCENE_MAX_KEYS);
    for (const cJSON* m = obj->child; m; m = m->next) {
        const char* name = m->string ? m->string : "";
        snprintf(key, sizeof key, "%s%s%s", path, path[0] ? "." : "", name);
        for (const cJSON* n = obj->child; n != m; n = n->next)
            if (n->string && strcmp(n->string, name) == 0) return fail(c, m, key, "appears twice");
        if (name[0] == '_') continue;
        int ok = 0;
        for (const char* const* a = allowed; *a; ++a)
            if (strcmp(*a, name) == 0) ok = 1;
        if (!ok) {
            char list[256] = "";
            for (const char* const* a = allowed; *a; ++a) {
                strncat(list, *a, sizeof list - strlen(list) - 1);
                if (a[1]) strncat(list, ", ", sizeof list - strlen(list) - 1);
            }
            return fail(c, m, key, "unknown key (expected one of: %s)", list);
        }
    }
    return HS_OK;
}

static void join(char* out, size_t cap, const char* path, const char* name) {
    snprintf(out, cap, "%s%s%s", path, path[0] ? "." : "", name);
}

// An optional object member; *out NULL when absent. Wrong type is an error.
static hs_status get_obj(const ctx* c, const cJSON* obj, const char* path, const char* name,
                         const cJSON** out) {
    *out = cJSON_GetObjectItemCaseSensitive(obj, name);
    if (*out && !cJSON_IsObject(*out)) {
        char key[128];
        join(key, sizeof key, path, name);
        return fail(c, *out, key, "must be an object { ... }");
    }
    return HS_OK;
}

// Optional number in [lo, hi] (open ends when lo_open / hi_open); unchanged when absent.
static hs_status get_num(const ctx* c, const cJSON* obj, const char* path, const char* name,
                         double lo, double hi, int lo_open, int hi_open, double* out) {
    const cJSON* it = cJSON_GetObjectItemCaseSensitive(obj, name);
    if (!it) return HS_OK;
    char key[128];
    join(key, sizeof key, path, name);
    if (!cJSON_IsNumber(it)) return fail(c, it, key, "must be a number");
    double v = it->valuedouble;
    if (!isfinite(v)) return fail(c, it, key, "must be finite");
    if ((lo_open ? v <= lo : v < lo) || (hi_open ? v >= hi : v > hi))
        return fail(c, it, key, "must be in %s%g, %g%s, got %g", lo_open ? "(" : "[", lo, hi,
                    hi_open ? ")" : "]", v);
    *out = v;
    return HS_OK;
}

static hs_status get_int(const ctx* c, const cJSON* obj, const char* path, const char* name, int lo,
                         int hi, int* out) {
    const cJSON* it = cJSON_GetObjectItemCaseSensitive(obj, name);
    if (!it) return HS_OK;
    char key[128];
    join(key, sizeof key, path, name);
    if (!cJSON_IsNumber(it) || it->valuedouble != floor(it->valuedouble))
        return fail(c, it, key, "must be an integer");
    if (it->valuedouble < lo || it->valuedouble > hi)
        return fail(c, it, key, "must be in [%d, %d], got %g", lo, hi, it->valuedouble);
    *out = (int)it->valuedouble;
    return HS_OK;
}

static hs_status get_bool(const ctx* c, const cJSON* obj, const char* path, const char* name,
                          int* out) {
    const cJSON* it = cJSON_GetObjectItemCaseSensitive(obj, name);
    if (!it) return HS_OK;
    char key[128];
    join(key, sizeof key, path, name);
    if (!cJSON_IsBool(it)) return fail(c, it, key, "must be true or false");
    *out = cJSON_IsTrue(it) ? 1 : 0;
    return HS_OK;
}

static hs_status get_str(const ctx* c, const cJSON* obj, const char* path, const char* name,
                         char* out, size_t cap, int required) {
    const cJSON* it = cJSON_GetObjectItemCaseSensitive(obj, name);
    char key[128];
    join(key, sizeof key, path, name);
    if (!it) return required ? fail(c, obj, key, "is required") : HS_OK;
    if (!cJSON_IsString(it) || !it->valuestring) return fail(c, it, key, "must be a string");
    size_t n = strlen(it->valuestring);
    if (n == 0) return fail(c, it, key, "must not be empty");
    if (n >= cap) return fail(c, it, key, "longer than %zu bytes", cap - 1);
    // Escapes decode to control characters too (\u001b, \n): names, paths and URLs are text.
    for (size_t k = 0; k < n; ++k)
        if ((unsigned char)it->valuestring[k] < 0x20)
            return fail(c, it, key, "holds an escaped control character (byte 0x%02x)",
                        (unsigned)(unsigned char)it->valuestring[k]);
    memcpy(out, it->valuestring, n + 1);
    return HS_OK;
}

static hs_status get_vec3(const ctx* c, const cJSON* obj, const char* path, const char* name,
                          double abs_max, int required, double out[3]) {
    const cJSON* it = cJSON_GetObjectItemCaseSensitive(obj, name);
    char key[128];
    join(key, sizeof key, path, name);
    if (!it) return required ? fail(c, obj, key, "is required") : HS_OK;
    if (!cJSON_IsArray(it) || cJSON_GetArraySize(it) != 3)
        return fail(c, it, key, "must be an array of 3 numbers [x, y, z]");
    double v[3];
    int i = 0;
    for (const cJSON* e = it->child; e; e = e->next, ++i) {
        if (!cJSON_IsNumber(e) || !isfinite(e->valuedouble))
            return fail(c, it, key, "element %d is not a finite number", i);
        if (fabs(e->valuedouble) > abs_max)
            return fail(c, it, key, "element %d is %g, beyond +-%g", i, e->valuedouble, abs_max);
        v[i] = e->valuedouble;
    }
    memcpy(out, v, sizeof v);
    return HS_OK;
}

// Optional string that must be one of names[0..n-1]; *out = its index.
static hs_status get_enum(const ctx* c, const cJSON* obj, const char* path, const char* name,
                          const char* const* names, int n, int required, int* out) {
    const cJSON* it = cJSON_GetObjectItemCaseSensitive(obj, name);
    char key[128];
    join(key, sizeof key, path, name);
    if (!it) return required ? fail(c, obj, key, "is required") : HS_OK;
    if (cJSON_IsString(it) && it->valuestring)
        for (int i = 0; i < n; ++i)
            if (strcmp(it->valuestring, names[i]) == 0) {
                *out = i;
                return HS_OK;
            }
    char list[160] = "";
    for (int i = 0; i < n; ++i) {
        strncat(list, names[i], sizeof list - strlen(list) - 1);
        if (i + 1 < n) strncat(list, " | ", sizeof list - strlen(list) - 1);
    }
    return fail(c, it, key, "must be one of: %s", list);
}

#define TRY(expr)                                                                                  \
    do {                                                                                           \
        hs_status try_s_ = (expr);                                                                 \
        if (try_s_ != HS_OK) return try_s_;                                                        \
    } while (0)

// ---------------------------------------------------------------------------------------------
// Sections

static hs_status parse_material(const ctx* c, const cJSON* root, hs_scene* s) {
    const cJSON* m;
    TRY(get_obj(c, root, "", "material", &m));
    if (!m) return HS_OK;
    static const char* const keys[] = {
        "youngs_pa", "poisson", "density_kg_m3", "rayleigh_mass", "rayleigh_stiffness", NULL};
    TRY(check_keys(c, m, "material", keys));
    hs_material* mat = &s->material;
    // Tissue is 0.1 kPa-1 MPa; below 1 Pa a probe feels nothing. Above 0.4999 the volumetric
    // stiffness swamps the rest (0.4999999999 gave 3.3 N jumps and a probe through the tissue).
    TRY(get_num(c, m, "material", "youngs_pa", 1.0, 1e12, 0, 0, &mat->youngs_pa));
    TRY(get_num(c, m, "material", "poisson", -1.0, 0.4999, 1, 0, &mat->poisson));
    TRY(get_num(c, m, "material", "density_kg_m3", 0.0, 1e5, 1, 0, &mat->density_kg_m3));
    TRY(get_num(c, m, "material", "rayleigh_mass", 0.0, 1e4, 0, 0, &mat->rayleigh_mass));
    TRY(get_num(c, m, "material", "rayleigh_stiffness", 0.0, 10.0, 0, 0, &mat->rayleigh_stiffness));
    return HS_OK;
}

static const char* const solver_names[] = {"auto", "direct", "warped", "pcg"};

const char* hs_scene_solver_name(hs_scene_solver s) {
    return s >= HS_SCENE_SOLVER_AUTO && s <= HS_SCENE_SOLVER_PCG ? solver_names[s] : "?";
}

static hs_status parse_model(const ctx* c, const cJSON* root, hs_scene* s) {
    const cJSON* m;
    TRY(get_obj(c, root, "", "model", &m));
    if (!m) return HS_OK;
    static const char* const keys[] = {"type",   "rotation",        "inversion", "locking_free",
                                       "solver", "solver_accuracy", NULL};
    TRY(check_keys(c, m, "model", keys));
    static const char* const types[] = {"linear", "corotated", "stvk"};
    static const char* const rots[] = {"polar", "svd"};
    static const char* const invs[] = {"linear_fallback", "keep_reflection"};
    int v = (int)s->model;
    TRY(get_enum(c, m, "model", "type", types, 3, 0, &v));
    s->model = (hs_model)v;
    v = (int)s->rotation;
    TRY(get_enum(c, m, "model", "rotation", rots, 2, 0, &v));
    s->rotation = (hs_rotation)v;
    v = (int)s->inversion;
    TRY(get_enum(c, m, "model", "inversion", invs, 2, 0, &v));
    s->inversion = (hs_inversion)v;
    {
        // true (older scenes): the model's default mode; or a mode by name
        const cJSON* it = cJSON_GetObjectItemCaseSensitive(m, "locking_free");
        if (it && cJSON_IsBool(it)) {
            s->locking_free = cJSON_IsTrue(it) ? hs_fem_locking_free_default(s->model) : 0;
        } else if (it) {
            static const char* const lfs[] = {"none", "anp", "sns"};
            v = s->locking_free;
            if (!cJSON_IsString(it) || !it->valuestring)
                return fail(c, it, "model.locking_free", "must be true, false, none, anp or sns");
            TRY(get_enum(c, m, "model", "locking_free", lfs, 3, 0, &v));
            if (v == HS_LOCKING_FREE_SNS && s->model == HS_MODEL_STVK)
                return fail(c, it, "model.locking_free", "sns is for linear and corotated");
            s->locking_free = v;
        }
    }
    v = (int)s->solver;
    TRY(get_enum(c, m, "model", "solver", solver_names, 4, 0, &v));
    s->solver = (hs_scene_solver)v;
    static const char* const acc[] = {"equilibrium", "tangent"};
    TRY(get_enum(c, m, "model", "solver_accuracy", acc, 2, 0, &s->exact_tangent));
    return HS_OK;
}

static hs_status parse_fixed(const ctx* c, const cJSON* root, hs_scene* s) {
    const cJSON* arr = cJSON_GetObjectItemCaseSensitive(root, "fixed");
    if (!arr)
        return fail(c, root, "fixed",
                    "is required: at least one fixed region (a free body "
                    "has no rest position)");
    if (!cJSON_IsArray(arr)) return fail(c, arr, "fixed", "must be an array of regions [ {...} ]");
    int n = cJSON_GetArraySize(arr);
    if (n < 1 || n > HS_SCENE_MAX_FIXED)
        return fail(c, arr, "fixed", "needs 1 to %d regions, got %d", HS_SCENE_MAX_FIXED, n);
    s->n_fixed = 0;
    int i = 0;
    for (const cJSON* r = arr->child; r; r = r->next, ++i) {
        char path[48];
        snprintf(path, sizeof path, "fixed[%d]", i);
        if (!cJSON_IsObject(r)) return fail(c, r, path, "must be an object {\"type\": ...}");
        hs_scene_fixed* f = &s->fixed[i];
        memset(f, 0, sizeof *f);
        f->line = item_line(c, r);
        static const char* const kinds[] = {"plane",  "box",   "bbox_side", "group",
                                            "sphere", "patch", "nodes"};
        int k = 0;
        TRY(get_enum(c, r, path, "type", kinds, 7, 1, &k));
        f->kind = (hs_fixed_kind)k;
        if (f->kind == HS_FIXED_PLANE) {
            static const char* const keys[] = {"type", "point", "normal", "tolerance", NULL};
            TRY(check_keys(c, r, path, keys));
            TRY(get_vec3(c, r, path, "point", 1e3, 1, f->point));
            TRY(get_vec3(c, r, path, "normal", 1e3, 1, f->normal));
            double len = sqrt(f->normal[0] * f->normal[0] + f->normal[1] * f->normal[1] +
                              f->normal[2] * f->normal[2]);
            if (!(len > 1e-12)) {
                char key[64];
                join(key, sizeof key, path, "normal");
                return fail(c, cJSON_GetObjectItemCaseSensitive(r, "normal"), key,
                            "must not be zero");
            }
            for (int d = 0; d < 3; ++d) f->normal[d] /= len;
            TRY(get_num(c, r, path, "tolerance", 0.0, 1.0, 0, 0, &f->tolerance));
        } else if (f->kind == HS_FIXED_BOX) {
            static const char* const keys[] = {"type", "min", "max", NULL};
            TRY(check_keys(c, r, path, keys));
            TRY(get_vec3(c, r, path, "min", 1e3, 1, f->min));
            TRY(get_vec3(c, r, path, "max", 1e3, 1, f->max));
            for (int d = 0; d < 3; ++d)
                if (f->min[d] > f->max[d]) {
                    char key[64];
                    join(key, sizeof key, path, "max");
                    return fail(c, cJSON_GetObjectItemCaseSensitive(r, "max"), key,
                                "is below min in component %d", d);
                }
        } else if (f->kind == HS_FIXED_GROUP) {
            static const char* const keys[] = {"type", "name", NULL};
            TRY(check_keys(c, r, path, keys));
            const cJSON* nm = cJSON_GetObjectItemCaseSensitive(r, "name");
            char key[64];
            join(key, sizeof key, path, "name");
            if (!nm) return fail(c, r, key, "is required (a physical group of the mesh)");
            if (!cJSON_IsString(nm) || !nm->valuestring || !nm->valuestring[0] ||
                strlen(nm->valuestring) >= sizeof f->group)
                return fail(c, nm, key, "must be a non-empty string of at most %zu bytes",
                            sizeof f->group - 1);
            snprintf(f->group, sizeof f->group, "%s", nm->valuestring);
        } else if (f->kind == HS_FIXED_NODES) {
            static const char* const keys[] = {"type", "file", NULL};
            TRY(check_keys(c, r, path, keys));
            char file[HS_SCENE_PATH_MAX];
            TRY(get_str(c, r, path, "file", file, sizeof file, 1));
            // Relative to the scene file's folder, as the mesh.
            const char* slash = strrchr(s->path, '/');
            char full[HS_SCENE_PATH_MAX];
            int len = file[0] == '/' || !slash ? snprintf(full, sizeof full, "%s", file)
                                               : snprintf(full, sizeof full, "%.*s/%s",
                                                          (int)(slash - s->path), s->path, file);
            if (len >= 0 && (size_t)len < sizeof full) memcpy(f->file, full, sizeof f->file);
            if (len < 0 || (size_t)len >= sizeof full) {
                char key[64];
                join(key, sizeof key, path, "file");
                return fail(c, cJSON_GetObjectItemCaseSensitive(r, "file"), key,
                            "resolved path too long");
            }
        } else if (f->kind == HS_FIXED_SPHERE || f->kind == HS_FIXED_PATCH) {
            const char* pkey = f->kind == HS_FIXED_SPHERE ? "center" : "point";
            const char* const keys[] = {"type", pkey, "radius", NULL};
            TRY(check_keys(c, r, path, keys));
            TRY(get_vec3(c, r, path, pkey, 1e3, 1, f->point));
            f->radius = -1.0;
            TRY(get_num(c, r, path, "radius", 0.0, 10.0, 1, 0, &f->radius));
            if (f->radius < 0.0) {
                char key[64];
                join(key, sizeof key, path, "radius");
                return fail(c, r, key, "is required");
            }
        } else {
            static const char* const keys[] = {"type", "axis", "side", "depth", NULL};
            TRY(check_keys(c, r, path, keys));
            static const char* const axes[] = {"x", "y", "z"};
            static const char* const sides[] = {"min", "max"};
            int side = 0;
            TRY(get_enum(c, r, path, "axis", axes, 3, 1, &f->axis));
            TRY(get_enum(c, r, path, "side", sides, 2, 1, &side));
            f->side = side == 0 ? -1 : 1;
            f->depth = -1.0;
            TRY(get_num(c, r, path, "depth", 0.0, 1.0, 0, 0, &f->depth));
            if (f->depth < 0.0) {
                char key[64];
                join(key, sizeof key, path, "depth");
                return fail(c, r, key, "is required");
            }
        }
        s->n_fixed++;
    }
    return HS_OK;
}

static hs_status parse_tools(const ctx* c, const cJSON* root, hs_scene* s) {
    const cJSON* arr = cJSON_GetObjectItemCaseSensitive(root, "tools");
    if (!arr) return HS_OK;
    if (!cJSON_IsArray(arr)) return fail(c, arr, "tools", "must be an array of tools [ {...} ]");
    int n = cJSON_GetArraySize(arr);
    if (n > HS_SCENE_MAX_TOOLS)
        return fail(c, arr, "tools", "at most %d tools, got %d", HS_SCENE_MAX_TOOLS, n);
    s->n_tools = 0;
    int i = 0, count[2] = {0, 0};
    for (const cJSON* t = arr->child; t; t = t->next, ++i) {
        char path[48];
        snprintf(path, sizeof path, "tools[%d]", i);
        if (!cJSON_IsObject(t)) return fail(c, t, path, "must be an object {\"kind\": ...}");
        hs_scene_tool* tool = &s->tools[i];
        memset(tool, 0, sizeof *tool);
        static const char* const kinds[] = {"probe", "scalpel"};
        int k = 0;
        TRY(get_enum(c, t, path, "kind", kinds, 2, 1, &k));
        tool->kind = (hs_tool_kind)k;
        // The server simulates one probe and one scalpel (the button chooses between them); a
        // second of a kind would be validated as a tool_id and then answered as the first.
        if (count[k]++ > 0)
            return fail(c, t, path, "a second %s: a scene has at most one probe and one scalpel",
                        kinds[k]);
        char key[64];
        if (tool->kind == HS_TOOL_PROBE) {
            static const char* const keys[] = {"kind", "radius", NULL};
            TRY(check_keys(c, t, path, keys));
            tool->radius = -1.0;
            TRY(get_num(c, t, path, "radius", 0.0, 0.1, 1, 0, &tool->radius));
            join(key, sizeof key, path, "radius");
            if (tool->radius < 0.0) return fail(c, t, key, "is required (m)");
        } else {
            static const char* const keys[] = {"kind", "blade_a", "blade_b", NULL};
            TRY(check_keys(c, t, path, keys));
            TRY(get_vec3(c, t, path, "blade_a", 0.5, 1, tool->blade_a));
            TRY(get_vec3(c, t, path, "blade_b", 0.5, 1, tool->blade_b));
            double d2 = 0.0;
            for (int d = 0; d < 3; ++d)
                d2 += (tool->blade_b[d] - tool->blade_a[d]) * (tool->blade_b[d] - tool->blade_a[d]);
            join(key, sizeof key, path, "blade_b");
            if (!(d2 > 1e-12))
                return fail(c, cJSON_GetObjectItemCaseSensitive(t, "blade_b"), key,
                            "equals blade_a: the blade needs a length");
        }
        s->n_tools++;
    }
    return HS_OK;
}

static hs_status parse_rest(const ctx* c, const cJSON* root, hs_scene* s) {
    const cJSON* o;
    TRY(get_obj(c, root, "", "mesh_quality", &o));
    if (o) {
        static const char* const keys[] = {"min_dihedral_deg", NULL};
        TRY(check_keys(c, o, "mesh_quality", keys));
        TRY(get_num(c, o, "mesh_quality", "min_dihedral_deg", 0.0, 30.0, 0, 0,
                    &s->min_dihedral_deg));
    }
    TRY(get_obj(c, root, "", "workspace", &o));
    if (o) {
        static const char* const keys[] = {"min", "max", NULL};
        TRY(check_keys(c, o, "workspace", keys));
        TRY(get_vec3(c, o, "workspace", "min", 1e3, 1, s->workspace_min));
        TRY(get_vec3(c, o, "workspace", "max", 1e3, 1, s->workspace_max));
        for (int d = 0; d < 3; ++d)
            if (!(s->workspace_min[d] < s->workspace_max[d]))
                return fail(c, cJSON_GetObjectItemCaseSensitive(o, "max"), "workspace.max",
                            "must exceed min in component %d", d);
        s->has_workspace = 1;
    }
    TRY(get_obj(c, root, "", "rates", &o));
    if (o) {
        static const char* const keys[] = {"haptic_hz", "sim_hz", "visual_hz", "status_hz", NULL};
        TRY(check_keys(c, o, "rates", keys));
        TRY(get_num(c, o, "rates", "haptic_hz", 100.0, 10000.0, 0, 0, &s->haptic_hz));
        TRY(get_num(c, o, "rates", "sim_hz", 1.0, 2000.0, 0, 0, &s->sim_hz));
        // 0.1 Hz at least: its period in ns must fit the server's clock arithmetic.
        TRY(get_num(c, o, "rates", "visual_hz", 0.1, 240.0, 0, 0, &s->visual_hz));
        TRY(get_num(c, o, "rates", "status_hz", 0.1, 100.0, 0, 0, &s->status_hz));
    }
    TRY(get_obj(c, root, "", "features", &o));
    if (o) {
        static const char* const keys[] = {"haptics", "cutting", "visual_mesh", NULL};
        TRY(check_keys(c, o, "features", keys));
        TRY(get_bool(c, o, "features", "haptics", &s->feature_haptics));
        TRY(get_bool(c, o, "features", "cutting", &s->feature_cutting));
        TRY(get_bool(c, o, "features", "visual_mesh", &s->feature_visual));
    }
    TRY(get_obj(c, root, "", "cutting", &o));
    if (o) {
        static const char* const keys[] = {"free_pieces", NULL};
        TRY(check_keys(c, o, "cutting", keys));
        static const char* const rules[] = {"drop", "fall"};
        TRY(get_enum(c, o, "cutting", "free_pieces", rules, 2, 0, &s->cut_free_pieces_fall));
    }
    TRY(get_obj(c, root, "", "haptics", &o));
    if (o) {
        static const char* const keys[] = {"force_max_n", "force_rate_max_n_per_s", "watchdog_ms",
                                           NULL};
        TRY(check_keys(c, o, "haptics", keys));
        TRY(get_num(c, o, "haptics", "force_max_n", 0.0, 100.0, 1, 0, &s->force_max_n));
        TRY(get_num(c, o, "haptics", "force_rate_max_n_per_s", 0.0, 1e6, 1, 0, &s->force_rate_max));
        double ms = s->watchdog_s * 1e3;
        TRY(get_num(c, o, "haptics", "watchdog_ms", 1.0, 10000.0, 0, 0, &ms));
        s->watchdog_s = ms * 1e-3;
    }
    TRY(get_obj(c, root, "", "lcm", &o));
    if (o) {
        static const char* const keys[] = {"haptic_url", "mesh_url", "prefix", NULL};
        TRY(check_keys(c, o, "lcm", keys));
        TRY(get_str(c, o, "lcm", "haptic_url", s->haptic_url, sizeof s->haptic_url, 0));
        TRY(get_str(c, o, "lcm", "mesh_url", s->mesh_url, sizeof s->mesh_url, 0));
        const cJSON* p = cJSON_GetObjectItemCaseSensitive(o, "prefix");
        if (p) { // may be empty; only [A-Z0-9_]
            if (!cJSON_IsString(p) || !p->valuestring)
                return fail(c, p, "lcm.prefix", "must be a string");
            size_t n = strlen(p->valuestring);
            if (n >= sizeof s->prefix)
                return fail(c, p, "lcm.prefix", "longer than %zu bytes", sizeof s->prefix - 1);
            for (size_t i = 0; i < n; ++i) {
                char ch = p->valuestring[i];
                if (!((ch >= 'A' && ch <= 'Z') || (ch >= '0' && ch <= '9') || ch == '_'))
                    return fail(c, p, "lcm.prefix", "may contain only A-Z, 0-9 and _");
            }
            memcpy(s->prefix, p->valuestring, n + 1);
        }
        if (!strstr(s->haptic_url, "://"))
            return fail(c, cJSON_GetObjectItemCaseSensitive(o, "haptic_url"), "lcm.haptic_url",
                        "is not an LCM URL (provider://address...)");
        if (!strstr(s->mesh_url, "://"))
            return fail(c, cJSON_GetObjectItemCaseSensitive(o, "mesh_url"), "lcm.mesh_url",
                        "is not an LCM URL (provider://address...)");
        const char* why = hapsim_url_problem(s->haptic_url);
        if (why)
            return fail(c, cJSON_GetObjectItemCaseSensitive(o, "haptic_url"), "lcm.haptic_url",
                        "%s", why);
        if ((why = hapsim_url_problem(s->mesh_url)))
            return fail(c, cJSON_GetObjectItemCaseSensitive(o, "mesh_url"), "lcm.mesh_url", "%s",
                        why);
    }
    if (hs_scene_same_bus(s->haptic_url, s->mesh_url))
        return fail(c, o ? cJSON_GetObjectItemCaseSensitive(o, "mesh_url") : NULL, "lcm.mesh_url",
                    "must differ from lcm.haptic_url (separate buses, different ports)");
    return HS_OK;
}

// udpm's network as LCM reads it: empty is its default group and port, the address by
// inet_aton, the port by strtol base 0 (so 7667 and 0x1DF3 are one port). -1: compare as text.
static int udpm_network(const char* s, size_t n, uint32_t* addr, long* port) {
    char buf[HS_SCENE_URL_MAX];
    if (n == 0) {
        s = "239.255.76.67:7667";
        n = strlen(s);
    }
    if (n >= sizeof buf) return -1;
    memcpy(buf, s, n);
    buf[n] = '\0';
    char* colon = strchr(buf, ':');
    if (!colon) return -1;
    *colon = '\0';
    struct in_addr ia;
    char* e;
    *port = strtol(colon + 1, &e, 0);
    if (!inet_aton(buf, &ia) || e == colon + 1 || *e) return -1;
    *addr = ia.s_addr;
    return 0;
}

int hs_scene_same_bus(const char* a, const char* b) {
    static const char udpm[] = "udpm://";
    const size_t nu = sizeof udpm - 1;
    size_t na = strcspn(a, "?"), nb = strcspn(b, "?"); // options (ttl, ...) are no other bus
    if (na >= nu && nb >= nu && !strncmp(a, udpm, nu) && !strncmp(b, udpm, nu)) {
        uint32_t ga, gb;
        long pa, pb;
        if (!udpm_network(a + nu, na - nu, &ga, &pa) && !udpm_network(b + nu, nb - nu, &gb, &pb))
            return ga == gb && pa == pb;
    }
    return na == nb && !strncmp(a, b, na);
}

// Relative mesh paths are relative to the scene file's folder.
static hs_status resolve_mesh(const ctx* c, const cJSON* item, const char* scene_path,
                              const char* mesh, char* out, size_t cap) {
    int n;
    const char* slash = strrchr(scene_path, '/');
    if (mesh[0] == '/' || !slash)
        n = snprintf(out, cap, "%s", mesh);
    else
        n = snprintf(out, cap, "%.*s/%s", (int)(slash - scene_path), scene_path, mesh);
    if (n < 0 || (size_t)n >= cap) return fail(c, item, "mesh", "resolved path too long");
    return HS_OK;
}

static hs_status parse_root(const ctx* c, const cJSON* root, int check_files, hs_scene* s) {
    if (!cJSON_IsObject(root)) return fail(c, root, "(top level)", "must be an object { ... }");
    static const char* const keys[] = {
        "name",    "mesh",  "units_scale", "material",     "model", "fixed",
        "gravity", "tools", "devices",     "workspace",    "rates", "features",
        "haptics", "lcm",   "cutting",     "mesh_quality", NULL};
    TRY(check_keys(c, root, "", keys));
    char mesh[HS_SCENE_PATH_MAX];
    TRY(get_str(c, root, "", "mesh", mesh, sizeof mesh, 1));
    const cJSON* mesh_item = cJSON_GetObjectItemCaseSensitive(root, "mesh");
    TRY(resolve_mesh(c, mesh_item, s->path, mesh, s->mesh_path, sizeof s->mesh_path));
    if (check_files && access(s->mesh_path, R_OK) != 0)
        return fail(c, mesh_item, "mesh", "cannot read mesh file '%s': %s", s->mesh_path,
                    strerror(errno));
    TRY(get_str(c, root, "", "name", s->name, sizeof s->name, 0));
    TRY(get_num(c, root, "", "units_scale", 0.0, 1e3, 1, 0, &s->units_scale));
    s->mesh_line = item_line(c, mesh_item);
    s->units_line = item_line(c, cJSON_GetObjectItemCaseSensitive(root, "units_scale"));
    s->fixed_line = item_line(c, cJSON_GetObjectItemCaseSensitive(root, "fixed"));
    TRY(parse_material(c, root, s));
    TRY(parse_model(c, root, s));
    TRY(parse_fixed(c, root, s));
    TRY(get_vec3(c, root, "", "gravity", 1e3, 0, s->gravity));
    TRY(parse_tools(c, root, s));
    TRY(get_int(c, root, "", "devices", 0, HS_SCENE_MAX_DEVICES, &s->n_devices));
    TRY(parse_rest(c, root, s));

    // Cross-checks: what a feature needs must be there. The error points at features, else at
    // tools, else at the top (line 1), so it always has a line.
    const cJSON* where = cJSON_GetObjectItemCaseSensitive(root, "features");
    if (!where) where = cJSON_GetObjectItemCaseSensitive(root, "tools");
    if (!where) where = root->child ? root->child : root;
    if (s->feature_cutting && !s->feature_haptics)
        return fail(c, where, "features.cutting",
                    "needs features.haptics (the blade is moved by a device's poses)");
    if (s->feature_cutting) {
        int scalpel = 0;
        for (int i = 0; i < s->n_tools; ++i) scalpel |= s->tools[i].kind == HS_TOOL_SCALPEL;
        if (!scalpel) return fail(c, where, "features.cutting", "is on but no tool is a scalpel");
    }
    if (s->feature_haptics && (s->n_tools < 1 || s->n_devices < 1))
        return fail(c, where, "features.haptics", "is on but the scene has no tools or no devices");
    if (s->sim_hz > s->haptic_hz)
        return fail(c, cJSON_GetObjectItemCaseSensitive(root, "rates"), "rates.sim_hz",
                    "must not exceed rates.haptic_hz");
    return HS_OK;
}

// JSON strings hold no control bytes, and a \u0000 escape would end the C string cJSON returns
// (found in review: "m.msh\u0000junk" loaded as m.msh; a raw newline inside a name passed).
// Called on text cJSON parsed, so its strings are well formed; NULL, or where and why.
static const char* bad_in_string(const char* json, const char** why) {
    int in = 0;
    for (const char* p = json; *p; ++p) {
        if (!in) {
            in = *p == '"';
        } else if (*p == '"') {
            in = 0;
        } else if ((unsigned char)*p < 0x20) {
            *why = "a control byte inside a string (write \\n, \\t, ...)";
            return p;
        } else if (*p == '\\') {
            if (!strncmp(p + 1, "u0000", 5)) {
                *why = "\\u0000 inside a string (it would end the text there)";
                return p;
            }
            if (p[1]) ++p; // the escaped character
        }
    }
    return NULL;
}

hs_status hs_scene_parse(const char* text, const char* path, int check_files, hs_scene* out,
                         hs_err* err) {
    hs_scene_default(out);
    if (!path) path = "(scene)";
    if (!text) return hs_err_set(err, HS_ERR_INVALID, "%s: no scene text", path);
    if (strlen(path) >= sizeof out->path)
        return hs_err_set(err, HS_ERR_INVALID, "scene path longer than %zu bytes",
                          sizeof out->path - 1);
    snprintf(out->path, sizeof out->path, "%s", path);
    // A UTF-8 byte order mark is not JSON: cJSON skips it, and so must the line/key finder.
    const char* json = strncmp(text, "\xEF\xBB\xBF", 3) == 0 ? text + 3 : text;
    const char* end = NULL;
    cJSON* root = cJSON_ParseWithOpts(json, &end, 1);
    if (!root) {
        const char* at = end ? end : json;
        int line = line_at(json, at);
        const char* ls = at;
        while (ls > json && ls[-1] != '\n' && ls[-1] != '\r') --ls;
        int shown = 0; // the rest of that line, at most 20 bytes
        while (shown < 20 && at[shown] && at[shown] != '\n' && at[shown] != '\r') ++shown;
        return hs_err_set(err, HS_ERR_PARSE, "%s:%d:%d: malformed JSON near '%.*s'", path, line,
                          (int)(at - ls) + 1, shown, at);
    }
    const char* why = "";
    const char* bad = bad_in_string(json, &why);
    if (bad) {
        cJSON_Delete(root);
        return hs_err_set(err, HS_ERR_PARSE, "%s:%d: %s", path, line_at(json, bad), why);
    }
    ctx c = {path, json, root, err};
    // Keep the scene name we can show when the file gives none: the file name.
    hs_status st = parse_root(&c, root, check_files, out);
    cJSON_Delete(root);
    if (st != HS_OK) {
        char keep[HS_SCENE_PATH_MAX];
        snprintf(keep, sizeof keep, "%s", out->path);
        hs_scene_default(out);
        snprintf(out->path, sizeof out->path, "%s", keep);
        return st;
    }
    if (!out->name[0]) {
        const char* base = strrchr(path, '/');
        snprintf(out->name, sizeof out->name, "%s", base ? base + 1 : path);
    }
    return HS_OK;
}

hs_status hs_scene_load(const char* path, hs_scene* out, hs_err* err) {
    hs_scene_default(out);
    if (!path) return hs_err_set(err, HS_ERR_INVALID, "no scene file given");
    FILE* f = NULL;
    hs_status ost = hs_open_regular(path, &f, err);
    if (ost != HS_OK) return ost;
    char* text = hs_alloc(MAX_SCENE_BYTES + 1);
    if (!text) {
        fclose(f);
        return hs_err_set(err, HS_ERR_NOMEM, "%s: out of memory reading the scene", path);
    }
    size_t n = fread(text, 1, MAX_SCENE_BYTES + 1, f);
    int io_error = ferror(f);
    fclose(f);
    hs_status st;
    if (io_error)
        st = hs_err_set(err, HS_ERR_IO, "%s: read error", path);
    else if (n > MAX_SCENE_BYTES)
        st = hs_err_set(err, HS_ERR_PARSE, "%s: larger than %d bytes: not a scene file", path,
                        MAX_SCENE_BYTES);
    else if (memchr(text, 0, n))
        st = hs_err_set(err, HS_ERR_PARSE, "%s:%d: NUL byte: not a text file", path,
                        line_at(text, (const char*)memchr(text, 0, n)));
    else {
        text[n] = '\0';
        st = hs_scene_parse(text, path, 1, out, err);
    }
    hs_free(text);
    return st;
}

// ---------------------------------------------------------------------------------------------
// Node selection of a fixed region (shared by the server and the tools).

// A node list: indices (0-based, file order of the mesh) separated by blanks, commas or
// newlines; '#' starts a comment. Errors name the file and the line.
static hs_status select_node_list(const char* path, const hs_mesh* m, unsigned char* sel,
                                  hs_err* err) {
    FILE* f = fopen(path, "r");
    if (!f) return hs_err_set(err, HS_ERR_IO, "%s: cannot open: %s", path, strerror(errno));
    char line[512];
    int ln = 0, count = 0;
    hs_status st = HS_OK;
    while (st == HS_OK && fgets(line, sizeof line, f)) {
        ++ln;
        if (!strchr(line, '\n') && !feof(f)) {
            st = hs_err_set(err, HS_ERR_INVALID, "%s:%d: line longer than %zu bytes", path, ln,
                            sizeof line - 2);
            break;
        }
        char* hash = strchr(line, '#');
        if (hash) *hash = '\0';
        char* save = NULL;
        for (char* tok = strtok_r(line, " \t\r\n,", &save); tok && st == HS_OK;
             tok = strtok_r(NULL, " \t\r\n,", &save)) {
            char* e;
            errno = 0;
            long v = strtol(tok, &e, 10);
            if (*e || errno)
                st = hs_err_set(err, HS_ERR_INVALID, "%s:%d: '%.32s' is not a node index", path, ln,
                                tok);
            else if (v < 0 || v >= m->n_nodes)
                st = hs_err_set(err, HS_ERR_INVALID,
                                "%s:%d: node %ld out of range (the mesh has nodes 0..%d)", path, ln,
                                v, m->n_nodes - 1);
            else
                sel[v] = 1, ++count;
        }
    }
    if (st == HS_OK && ferror(f)) st = hs_err_set(err, HS_ERR_IO, "%s: read error", path);
    fclose(f);
    if (st == HS_OK && count == 0)
        st = hs_err_set(err, HS_ERR_INVALID, "%s: no node index in the list", path);
    return st;
}

hs_status hs_scene_fixed_select(const hs_scene_fixed* f, const hs_mesh* m, unsigned char* sel,
                                hs_err* err) {
    if (!f || !m || !sel) return hs_err_set(err, HS_ERR_INVALID, "region, mesh or mask is NULL");
    const int n = m->n_nodes;
    memset(sel, 0, (size_t)n);
    if (f->kind == HS_FIXED_PLANE) {
        double l = sqrt(f->normal[0] * f->normal[0] + f->normal[1] * f->normal[1] +
                        f->normal[2] * f->normal[2]);
        for (int i = 0; i < n; ++i) {
            const double* x = m->x0 + 3 * i;
            double d = ((x[0] - f->point[0]) * f->normal[0] + (x[1] - f->point[1]) * f->normal[1] +
                        (x[2] - f->point[2]) * f->normal[2]) /
                       l;
            sel[i] = d <= f->tolerance;
        }
    } else if (f->kind == HS_FIXED_BOX) {
        hs_mesh_select_box(m, f->min, f->max, sel);
    } else if (f->kind == HS_FIXED_BBOX_SIDE) {
        hs_mesh_select_plane(m, f->axis, f->side, f->depth, sel);
    } else if (f->kind == HS_FIXED_GROUP) {
        const hs_mesh_region* g = hs_mesh_find_region(m, f->group);
        if (!g) {
            char list[256] = "";
            for (int r = 0; r < m->n_regions; ++r) {
                size_t len = strlen(list);
                snprintf(list + len, sizeof list - len, "%s'%s' (dim %d)", r ? ", " : "",
                         m->regions[r].name, m->regions[r].dim);
            }
            return hs_err_set(err, HS_ERR_INVALID, "no group '%s' in the mesh (%s%s)", f->group,
                              m->n_regions ? "its groups: " : "it has no physical groups", list);
        }
        for (int i = 0; i < g->n_nodes; ++i) sel[g->nodes[i]] = 1;
    } else if (f->kind == HS_FIXED_SPHERE) {
        for (int i = 0; i < n; ++i) {
            const double* x = m->x0 + 3 * i;
            double d2 = 0;
            for (int k = 0; k < 3; ++k) d2 += (x[k] - f->point[k]) * (x[k] - f->point[k]);
            sel[i] = d2 <= f->radius * f->radius;
        }
    } else if (f->kind == HS_FIXED_PATCH) {
        // Seed: the surface node nearest the point; grow over boundary triangles while within
        // the radius, so a thin organ's far side is not taken along.
        int seed = -1;
        double best = INFINITY;
        double* d = hs_alloc(((size_t)n + 1) * sizeof(double));
        if (!d) return hs_err_set(err, HS_ERR_NOMEM, "out of memory");
        for (int i = 0; i < n; ++i) {
            const double* x = m->x0 + 3 * i;
            d[i] = sqrt((x[0] - f->point[0]) * (x[0] - f->point[0]) +
                        (x[1] - f->point[1]) * (x[1] - f->point[1]) +
                        (x[2] - f->point[2]) * (x[2] - f->point[2]));
            if (m->node_surf && m->node_surf[i] >= 0 && d[i] < best) {
                best = d[i];
                seed = i;
            }
        }
        if (seed >= 0 && d[seed] <= f->radius) {
            sel[seed] = 1;
            for (int changed = 1; changed;) {
                changed = 0;
                for (int t = 0; t < m->n_tris; ++t) {
                    const int* v = m->tris + 3 * t;
                    if (!sel[v[0]] && !sel[v[1]] && !sel[v[2]]) continue;
                    for (int k = 0; k < 3; ++k)
                        if (!sel[v[k]] && d[v[k]] <= f->radius) {
                            sel[v[k]] = 1;
                            changed = 1;
                        }
                }
            }
        }
        hs_free(d);
    } else if (f->kind == HS_FIXED_NODES) {
        return select_node_list(f->file, m, sel, err);
    } else {
        return hs_err_set(err, HS_ERR_INVALID, "unknown region kind %d", (int)f->kind);
    }
    return HS_OK;
}
