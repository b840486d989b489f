#!/bin/sh
# SPDX-License-Identifier: GPL-2.0-or-later
# Install the client (component "client") into a temporary prefix, then build two tiny consumers
# against it: one with CMake find_package(hapsim) -> hapsim::client, one with pkg-config
# (hapsim-client.pc). Both run: they create a client on memq:// buses (no network) and a mesh
# sync object, and check a few calls.
#   tests/test_client_install.sh BUILD_DIR [SANITIZER_FLAGS]
# SANITIZER_FLAGS: what the project was built with (a sanitized static library needs its
# runtime in the consumer too).
set -eu
build=$1
san=${2:-}
tmp=$(mktemp -d /tmp/hs_client_install.XXXXXX)
trap 'rm -rf "$tmp"' EXIT
prefix=$tmp/prefix
cmake --install "$build" --component client --prefix "$prefix" >"$tmp/install.log" 2>&1 ||
    { cat "$tmp/install.log"; echo "FAIL: cmake --install"; exit 1; }
for f in include/hapsim/client.h include/hapsim/status.h include/hapsim/version.h \
         include/hapsim/lcmtypes/hapsim_tool_pose_t.h include/hapsim/lcmtypes/hapsim_channels.h \
         bin/hapsim-view bin/hapsim-ctl; do
    [ -e "$prefix/$f" ] || { echo "FAIL: $f not installed"; exit 1; }
done
# include/hapsim in the tree is exactly the installed API: the same headers, nothing more.
src=$(cd "$(dirname "$0")/.." && pwd)
want=$(cd "$src/include/hapsim" && ls -- *.h)
got=$(cd "$prefix/include/hapsim" && ls -- *.h)
[ "$want" = "$got" ] || { echo "FAIL: installed headers ($got) differ from include/hapsim ($want)"; exit 1; }
pc=$(find "$prefix" -name hapsim-client.pc | head -n 1)
[ -n "$pc" ] || { echo "FAIL: hapsim-client.pc not installed"; exit 1; }

mkdir -p "$tmp/consumer"
cat >"$tmp/consumer/main.c" <<'C'
#include <hapsim/client.h>
#include <hapsim/version.h>
#include <hapsim_channels.h>
#include <hapsim_tool_pose_t.h>
#include <stdio.h>
#include <string.h>
int main(void) {
    hs_client_config cfg;
    hs_client_config_default(&cfg);
    cfg.haptic_url = "memq://";
    cfg.mesh_url = "memq://";
    hs_client* c = NULL;
    hs_err err = {0};
    if (hs_client_create(&cfg, &c, &err) != HS_OK) { printf("create: %s\n", err.msg); return 1; }
    hs_client_pose p = {0, 0, {0.01, 0.02, 0.03}, {1, 0, 0, 0}, 0};
    if (hs_client_send_pose(c, &p, &err) != HS_OK) { printf("pose: %s\n", err.msg); return 1; }
    p.orientation[0] = 2; /* not a unit quaternion: refused locally */
    if (hs_client_send_pose(c, &p, &err) != HS_ERR_INVALID) return 1;
    hs_client_stats st;
    hs_client_stats_get(c, &st);
    hs_mesh_sync* s = NULL;
    if (hs_mesh_sync_create(&s, NULL) != HS_OK || hs_mesh_sync_mesh(s)->ready) return 1;
    unsigned char junk[16] = {1, 2, 3};
    if (hs_mesh_sync_feed(s, HS_SYNC_STATE, junk, sizeof junk) != HS_SYNC_MALFORMED) return 1;
    hs_mesh_sync_destroy(&s);
    hs_client_destroy(&c);
    /* The installed status.h's functions are in the library. */
    if (strcmp(hs_status_str(HS_ERR_NOMEM), "out of memory") != 0) return 1;
    hs_err e2 = {0};
    if (hs_err_set(&e2, HS_ERR_IO, "x %d", 1) != HS_ERR_IO || strcmp(e2.msg, "x 1") != 0) return 1;
    printf("consumer ok (hapsim " HAPSIM_VERSION "): %lld pose sent, default prefix %s, %lld bytes left\n",
           (long long)st.poses_sent, HAPSIM_DEFAULT_PREFIX, (long long)hs_client_byte_count());
    return st.poses_sent == 1 && hs_client_byte_count() == 0 && c == NULL ? 0 : 1;
}
C
cat >"$tmp/consumer/CMakeLists.txt" <<'CM'
cmake_minimum_required(VERSION 3.22)
project(hapsim_consumer C)
find_package(hapsim 0.1 REQUIRED)
add_executable(consumer main.c)
target_link_libraries(consumer PRIVATE hapsim::client)
CM
cmake -S "$tmp/consumer" -B "$tmp/consumer/build" -DCMAKE_PREFIX_PATH="$prefix" \
    -DCMAKE_C_FLAGS="$san" -DCMAKE_EXE_LINKER_FLAGS="$san" >"$tmp/cfg.log" 2>&1 || { cat "$tmp/cfg.log"; echo "FAIL: consumer configure"; exit 1; }
cmake --build "$tmp/consumer/build" >"$tmp/build.log" 2>&1 ||
    { cat "$tmp/build.log"; echo "FAIL: consumer build"; exit 1; }
"$tmp/consumer/build/consumer"

# pkg-config
cc=${CC:-cc}
flags=$(PKG_CONFIG_PATH=$(dirname "$pc") pkg-config --cflags --libs hapsim-client)
$cc -std=c11 $san -o "$tmp/consumer_pc" "$tmp/consumer/main.c" $flags
"$tmp/consumer_pc"
echo "installed client OK (cmake find_package and pkg-config)"
