// SPDX-License-Identifier: MIT
// hapsim's version, and the --version flag every program takes.
#ifndef HAPSIM_VERSION_H
#define HAPSIM_VERSION_H

#include <stdio.h>
#include <string.h>

/// The release; CMake refuses to configure when project(VERSION) says otherwise.
#define HAPSIM_VERSION "0.1.0"

/// 1 (after printing "PROG VERSION") when argv holds --version: the caller exits 0.
static inline int hapsim_version_asked(int argc, char** argv, const char* prog) {
    for (int i = 1; i < argc; ++i)
        if (strcmp(argv[i], "--version") == 0) {
            printf("%s %s\n", prog, HAPSIM_VERSION);
            return 1;
        }
    return 0;
}

#endif
