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

/// The arguments kind takes, exactly: LOAD_SCENE path=NONEMPTY; SET_PARAM name=KEY value=NUMBER
/// (the whole text, finite; *number receives it); every other kind none. Keys well formed and
/// not repeated, values without control bytes. Lengths are checked where the text is read.
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

#endif
