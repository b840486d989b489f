// SPDX-License-Identifier: GPL-2.0-or-later
// Opening input files without blocking on what is not one (server internal).
#ifndef HS_BASE_OPEN_REGULAR_H
#define HS_BASE_OPEN_REGULAR_H

#include <stdio.h>

#include "base.h"

/// Open path for reading as a binary stream. A FIFO, device or folder is refused without
/// blocking on it (opened non-blocking, checked, then made blocking): HS_ERR_IO naming the path
/// and what it is. Thread: any | Allocates: the stream. @param out OUT, NULL on failure
hs_status hs_open_regular(const char* path, FILE** out, hs_err* err);

#endif
