#!/bin/sh
# SPDX-License-Identifier: GPL-2.0-or-later
# Run a command inside a private network namespace with multicast on loopback, so LCM tests
# cannot hear (or disturb) other runs and nothing leaves the machine.
#   tests/netns.sh COMMAND [ARGS...]
# Exit 77 (CTest SKIP_RETURN_CODE) when namespaces are not permitted here.
# HS_NETNS_RMEM (bytes, default 4194304): raise net.core.rmem_max in the namespace to at least
# this, so receivers can ask for large recv_buf_size values (fragmented mesh messages).
set -u

if [ $# -lt 1 ]; then
    echo "usage: $0 COMMAND [ARGS...]" >&2
    exit 2
fi

if [ "${HS_NETNS_INSIDE:-0}" != 1 ]; then
    for tool in unshare ip; do
        if ! command -v "$tool" >/dev/null 2>&1; then
            echo "SKIP: '$tool' not found (Debian: util-linux, iproute2)"
            exit 77
        fi
    done
    if ! unshare -n true 2>/dev/null; then
        echo "SKIP: cannot create a network namespace (unshare -n needs root or CAP_SYS_ADMIN;" \
             "in a container, run it with --privileged or --cap-add SYS_ADMIN)"
        exit 77
    fi
    HS_NETNS_INSIDE=1 exec unshare -n "$0" "$@"
fi

# Inside the fresh namespace: only a downed loopback exists.
ip link set lo up || { echo "SKIP: cannot bring up lo in the namespace"; exit 77; }
ip link set lo multicast on
ip route add 224.0.0.0/4 dev lo || { echo "SKIP: cannot add a multicast route"; exit 77; }

want=${HS_NETNS_RMEM:-4194304}
if [ -r /proc/sys/net/core/rmem_max ]; then
    have=$(cat /proc/sys/net/core/rmem_max)
    if [ "$have" -lt "$want" ]; then
        # Per-namespace on recent kernels; on older ones this is the host's value, so only try.
        if ! (echo "$want" >/proc/sys/net/core/rmem_max) 2>/dev/null; then
            echo "note: net.core.rmem_max is $have and cannot be raised; large LCM messages may" \
                 "be lost (raise it: sysctl -w net.core.rmem_max=$want)" >&2
        fi
    fi
fi

exec "$@"
