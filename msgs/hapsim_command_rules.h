// SPDX-License-Identifier: MIT
// hapsim protocol: the arguments a command must carry, for the server's validation and the
// client library's local check, so that a command the client lets through is one the server
// takes (header only, like hapsim_channels.h).
#ifndef HAPSIM_COMMAND_RULES_H
#define HAPSIM_COMMAND_RULES_H

#include <math.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include "hapsim_command_t.h"

#define HAPSIM_CMD_MAX_ARGS   8
#define HAPSIM_CMD_KEY_MAX    63  ///< bytes, without the NUL
#define HAPSIM_CMD_TEXT_MAX   255 ///< bytes of a value, without the NUL
#define HAPSIM_CMD_SENDER_MAX 63  ///< bytes, without the NUL

/// A key: 1..HAPSIM_CMD_KEY_MAX bytes of [a-z0-9_.].
static inline int hapsim_cmd_key_ok(const char* k) {
    size_t n = strlen(k);
    if (n < 1 || n > HAPSIM_CMD_KEY_MAX) return 0;
    for (size_t i = 0; i < n; i++)
        if (!((k[i] >= 'a' && k[i] <= 'z') || (k[i] >= '0' && k[i] <= '9') || k[i] == '_' ||
              k[i] == '.'))
            return 0;
    return 1;
}

/// Text (a value, the sender): no control bytes.
static inline int hapsim_cmd_text_ok(const char* s) {
    for (const unsigned char* c = (const unsigned char*)s; *c; ++c)
        if (*c < 0x20 || *c == 0x7f) return 0;
    return 1;
}

/// The value of key among the n arguments, or NULL.
static inline const char* hapsim_cmd_arg(int n, const char* const* keys, const char* const* values,
                                         const char* key) {
    for (int i = 0; i < n; i++)
        if (strcmp(keys[i], key) == 0) return values[i];
    return NULL;
}

enum { HAPSIM_CMD_ARGS_OK = 0, HAPSIM_CMD_ARGS_BAD = 1, HAPSIM_CMD_ARGS_NONFINITE = 2 };

static inline int hapsim_cmd_bad(const char** why, const char* text) {
    *why = text;
    return HAPSIM_CMD_ARGS_BAD;
}

/// 1 when s is a decimal number: leading spaces, [+-], digits with an optional '.', an optional
/// exponent. strtod alone also takes hexadecimal ("0x10" as 16), "inf" and "nan".
static inline int hapsim_cmd_decimal_ok(const char* s) {
    while (*s == ' ') s++;
    if (*s == '+' || *s == '-') s++;
    int digits = 0;
    while (*s >= '0' && *s <= '9') s++, digits++;
    if (*s == '.') {
        s++;
        while (*s >= '0' && *s <= '9') s++, digits++;
    }
    if (!digits) return 0;
    if (*s == 'e' || *s == 'E') {
        s++;
        if (*s == '+' || *s == '-') s++;
        if (!(*s >= '0' && *s <= '9')) return 0;
        while (*s >= '0' && *s <= '9') s++;
    }
    return *s == '\0';
}

/// The arguments kind takes, exactly: LOAD_SCENE path=NONEMPTY; SET_PARAM name=KEY value=NUMBER
/// (the whole text, finite; *number receives it); every other kind none. Keys well formed and
/// not repeated, values without control bytes. Lengths are checked where the text is read.
/// Returns HAPSIM_CMD_ARGS_*; *why (static text) says what is wrong.
static inline int hapsim_cmd_args_check(int32_t kind, int n, const char* const* keys,
                                        const char* const* values, double* number,
                                        const char** why) {
    *why = "";
    if (n < 0 || n > HAPSIM_CMD_MAX_ARGS) return hapsim_cmd_bad(why, "0..8 arguments");
    for (int i = 0; i < n; i++) {
        if (!hapsim_cmd_key_ok(keys[i]))
            return hapsim_cmd_bad(why, "a key is not [a-z0-9_.]{1,63}");
        if (!hapsim_cmd_text_ok(values[i])) return hapsim_cmd_bad(why, "a value has control bytes");
        for (int j = 0; j < i; j++)
            if (strcmp(keys[i], keys[j]) == 0) return hapsim_cmd_bad(why, "a key is given twice");
    }
    switch (kind) {
    case HAPSIM_COMMAND_T_KIND_LOAD_SCENE: {
        const char* path = hapsim_cmd_arg(n, keys, values, "path");
        if (n != 1 || !path || path[0] == '\0')
            return hapsim_cmd_bad(why, "LOAD_SCENE takes one argument, path (not empty)");
        return HAPSIM_CMD_ARGS_OK;
    }
    case HAPSIM_COMMAND_T_KIND_SET_PARAM: {
        const char* name = hapsim_cmd_arg(n, keys, values, "name");
        const char* value = hapsim_cmd_arg(n, keys, values, "value");
        if (n != 2 || !name || !value || !hapsim_cmd_key_ok(name) || value[0] == '\0')
            return hapsim_cmd_bad(why,
                                  "SET_PARAM takes two arguments, name ([a-z0-9_.]) and value");
        char* end = NULL;
        double v = strtod(value, &end);
        if (end == value || *end != '\0' || (isfinite(v) && !hapsim_cmd_decimal_ok(value)))
            return hapsim_cmd_bad(why, "SET_PARAM's value is not a number (decimal, as 5e3)");
        if (!isfinite(v)) { // "nan", "inf", 1e999
            *why = "SET_PARAM's value is not finite";
            return HAPSIM_CMD_ARGS_NONFINITE;
        }
        *number = v;
        return HAPSIM_CMD_ARGS_OK;
    }
    default:
        return n == 0 ? HAPSIM_CMD_ARGS_OK : hapsim_cmd_bad(why, "this command takes no arguments");
    }
}

/// A run-time parameter SET_PARAM changes: the values the server takes and what a change costs.
typedef struct hapsim_param_info {
    const char* name;
    double min, max;  ///< accepted: min <= v <= max (min < v when min_open)
    int min_open;     ///< 1: min itself is refused
    const char* unit; ///< "" when none
    int rebuilds;     ///< 1: the simulation is rebuilt at rest (refused after a cut); 0: at once
    const char* what;
} hapsim_param_info;

/// Every SET_PARAM parameter; *n receives the count.
static inline const hapsim_param_info* hapsim_params(int* n) {
    static const hapsim_param_info t[] = {
        {"probe_radius_m", 0, 0.1, 1, "m", 1, "radius of every probe tool"},
        {"force_max_n", 0, 100, 1, "N", 0, "force magnitude clamp"},
        {"force_rate_max_n_per_s", 0, 1e6, 1, "N/s", 0, "force rate limit"},
        {"watchdog_ms", 1, 10000, 0, "ms", 0, "force falls to zero at this pose age"},
        {"youngs_pa", 1, 1e9, 0, "Pa", 1, "Young's modulus of the tissue"},
        {"poisson", -1, 0.4999, 1, "", 1, "Poisson's ratio of the tissue"},
    };
    *n = (int)(sizeof t / sizeof t[0]);
    return t;
}

/// The parameter called name, or NULL.
static inline const hapsim_param_info* hapsim_param_find(const char* name) {
    int n;
    const hapsim_param_info* t = hapsim_params(&n);
    for (int i = 0; i < n; i++)
        if (strcmp(t[i].name, name) == 0) return &t[i];
    return NULL;
}

/// 1 when p takes v.
static inline int hapsim_param_in_range(const hapsim_param_info* p, double v) {
    return (p->min_open ? v > p->min : v >= p->min) && v <= p->max;
}

#endif
