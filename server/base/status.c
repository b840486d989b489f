// SPDX-License-Identifier: MIT
// Status text and error formatting (hapsim/status.h): in the server's base library and in the
// client library alike.
#include "hapsim/status.h"

#include <stdarg.h>
#include <stdio.h>

const char* hs_status_str(hs_status s) {
    switch (s) {
    case HS_OK:
        return "ok";
    case HS_ERR_NOMEM:
        return "out of memory";
    case HS_ERR_INVALID:
        return "invalid argument";
    case HS_ERR_IO:
        return "i/o error";
    case HS_ERR_PARSE:
        return "malformed input";
    case HS_ERR_NOT_POSDEF:
        return "matrix not positive definite";
    case HS_ERR_NOT_CONVERGED:
        return "iteration did not converge";
    case HS_ERR_NUMERIC:
        return "NaN or Inf in result";
    case HS_ERR_UNSUPPORTED:
        return "unsupported";
    case HS_WARN_NOT_CONVERGED:
        return "warning: tolerance not reached";
    case HS_WARN_MESH_REPAIRED:
        return "warning: mesh repaired on load";
    }
    return "unknown status";
}

hs_status hs_err_set(hs_err* err, hs_status code, const char* fmt, ...) {
    if (err) {
        err->code = code;
        va_list ap;
        va_start(ap, fmt);
        vsnprintf(err->msg, sizeof err->msg, fmt, ap);
        va_end(ap);
    }
    return code;
}
