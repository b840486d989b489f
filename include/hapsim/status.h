// SPDX-License-Identifier: MIT
// hapsim status: the result codes and error detail of every fallible call, their text.
// Installed with the client library (hapsim/client.h includes it); the server's base.h
// (server/base) builds on it.
#ifndef HAPSIM_STATUS_H
#define HAPSIM_STATUS_H

#ifdef __cplusplus
extern "C" {
#endif

/// Result of a fallible call. Negative is an error, positive a warning (as CHOLMOD's status).
typedef enum hs_status {
    HS_OK = 0,
    HS_ERR_NOMEM = -1,         ///< allocation failed; partial work was released
    HS_ERR_INVALID = -2,       ///< an argument or a definition is invalid
    HS_ERR_IO = -3,            ///< a file could not be opened or read
    HS_ERR_PARSE = -4,         ///< a file is malformed (the message names file, line, problem)
    HS_ERR_NOT_POSDEF = -5,    ///< a matrix that must be SPD is not
    HS_ERR_NOT_CONVERGED = -6, ///< an iteration stopped before its tolerance
    HS_ERR_NUMERIC = -7,       ///< NaN or Inf appeared
    HS_ERR_UNSUPPORTED = -8,   ///< valid input that this build does not handle
    HS_WARN_NOT_CONVERGED = 1, ///< result usable, tolerance not reached
    HS_WARN_MESH_REPAIRED = 2, ///< the mesh was loaded with repairs (see its report)
} hs_status;

/// Static text for a status; never NULL, never freed (cf. sqlite3_errstr).
const char* hs_status_str(hs_status s);

/// Error detail for fallible calls: a code and a human-readable message.
typedef struct hs_err {
    hs_status code;
    char msg[512];
} hs_err;

/// Set code and a printf-style message; accepts err == NULL. Returns code.
/// Thread: any | Allocates: no | not for the 1 kHz path (formats text)
hs_status hs_err_set(hs_err* err, hs_status code, const char* fmt, ...)
    __attribute__((format(printf, 3, 4)));

#ifdef __cplusplus
}
#endif

#endif
