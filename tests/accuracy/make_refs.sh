#!/bin/sh
# SPDX-License-Identifier: GPL-2.0-or-later
# Regenerate the CalculiX references under tests/accuracy/refs (tests/accuracy/README.md).
# Needs ccx (Debian package calculix-ccx) and python3; the tests themselves need neither.
# usage: tests/accuracy/make_refs.sh [--install] [--only gravity|tip|bar]
set -eu
here=$(cd "$(dirname "$0")" && pwd)
if [ "${1:-}" = "--install" ]; then
    shift
    command -v ccx > /dev/null || { apt-get update && apt-get install -y calculix-ccx; }
fi
if ! command -v ccx > /dev/null; then
    echo "make_refs.sh: ccx not found; install the Debian package calculix-ccx" \
         "(or run with --install as root)" >&2
    exit 1
fi
command -v python3 > /dev/null || { echo "make_refs.sh: python3 not found" >&2; exit 1; }
# One thread: the references are small, and the machine is shared.
export OMP_NUM_THREADS=1
exec python3 "$here/ccx_refs.py" "$@"
