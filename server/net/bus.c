// SPDX-License-Identifier: GPL-2.0-or-later
// LCM bus wrapper: create, poll()-based handle, URL and kernel buffer queries.
#define _POSIX_C_SOURCE 200809L // readlink
#include "bus.h"

#include "hapsim_channels.h"

#include <dirent.h>
#include <errno.h>
#include <poll.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

struct hs_net_bus {
    lcm_t* lcm;
    char url[256];
};

hs_status hs_net_bus_create(const char* url, hs_net_bus** out, hs_err* err) {
    *out = NULL;
    if (!url || strlen(url) >= sizeof((hs_net_bus*)0)->url)
        return hs_err_set(err, HS_ERR_INVALID, "LCM URL missing or longer than 255 bytes");
    // The server serves other processes: memq:// (in-process), file:// (a log) and an empty
    // URL reach nobody, and tcpq:// crashed LCM 1.3.1 with nothing listening.
    if (strncmp(url, "udpm://", 7) != 0)
        return hs_err_set(err, HS_ERR_INVALID,
                          "LCM URL '%s': the server's buses are UDP multicast (udpm://GROUP:PORT"
                          "?ttl=0); memq://, file://, tcpq:// and an empty URL serve no other "
                          "program",
                          url);
    const char* why = hapsim_url_problem(url);
    if (why) return hs_err_set(err, HS_ERR_INVALID, "LCM URL '%s' %s", url, why);
    hs_net_bus* b = hs_calloc(1, sizeof *b);
    if (!b) return hs_err_set(err, HS_ERR_NOMEM, "out of memory opening LCM bus %s", url);
    snprintf(b->url, sizeof b->url, "%s", url);
    b->lcm = lcm_create(url);
    if (!b->lcm) {
        hs_free(b);
        return hs_err_set(err, HS_ERR_IO,
                          "cannot open LCM bus '%s' (bad URL, or no multicast route: "
                          "ip route add 224.0.0.0/4 dev lo)",
                          url);
    }
    *out = b;
    return HS_OK;
}

void hs_net_bus_destroy(hs_net_bus** bus) {
    if (!bus || !*bus) return;
    lcm_destroy((*bus)->lcm);
    hs_free(*bus);
    *bus = NULL;
}

lcm_t* hs_net_bus_lcm(hs_net_bus* bus) {
    return bus->lcm;
}

const char* hs_net_bus_url(const hs_net_bus* bus) {
    return bus->url;
}

int hs_net_bus_handle(hs_net_bus* bus, int timeout_ms) {
    struct pollfd pfd = {.fd = lcm_get_fileno(bus->lcm), .events = POLLIN, .revents = 0};
    if (pfd.fd < 0) return -1;
    int r = poll(&pfd, 1, timeout_ms);
    if (r < 0) return errno == EINTR ? 0 : -1;
    if (r == 0) return 0;
    if (pfd.revents & (POLLERR | POLLNVAL)) return -1;
    return lcm_handle(bus->lcm) == 0 ? 1 : -1;
}

int64_t hs_net_bus_kernel_drops(const hs_net_bus* bus) {
    const long port = hapsim_url_port(bus->url);
    if (port < 0) return -1;
    // This process's socket inodes (LCM owns the sockets; /proc/self/fd names them).
    unsigned long ino[64];
    int n = 0;
    DIR* d = opendir("/proc/self/fd");
    if (!d) return -1;
    for (struct dirent* e; (e = readdir(d)) && n < 64;) {
        char path[300], link[64];
        snprintf(path, sizeof path, "/proc/self/fd/%s", e->d_name);
        ssize_t k = readlink(path, link, sizeof link - 1);
        if (k <= 0) continue;
        link[k] = '\0';
        unsigned long i;
        if (sscanf(link, "socket:[%lu]", &i) == 1) ino[n++] = i;
    }
    closedir(d);
    int64_t drops = 0;
    int found = 0;
    const char* tables[2] = {"/proc/net/udp", "/proc/net/udp6"};
    for (int t = 0; t < 2; ++t) {
        FILE* f = fopen(tables[t], "r");
        if (!f) continue;
        char line[512];
        if (!fgets(line, sizeof line, f)) line[0] = '\0'; // the header
        while (fgets(line, sizeof line, f)) {
            unsigned lport;
            unsigned long inode;
            long long dr;
            // sl local:port remote st tx:rx tr:when retrnsmt uid timeout inode ref ptr drops
            if (sscanf(line, " %*s %*[0-9A-Fa-f]:%x %*s %*s %*s %*s %*s %*s %*s %lu %*s %*s %lld",
                       &lport, &inode, &dr) != 3 ||
                (long)lport != port)
                continue;
            for (int q = 0; q < n; ++q)
                if (ino[q] == inode) {
                    drops += dr;
                    found = 1;
                }
        }
        fclose(f);
    }
    return found ? drops : -1;
}

int64_t hs_net_url_recv_buf(const char* url) {
    const char* q = url ? strchr(url, '?') : NULL;
    while (q) {
        q++;
        if (strncmp(q, "recv_buf_size=", 14) == 0) {
            char* end = NULL;
            long long v = strtoll(q + 14, &end, 10);
            if (end == q + 14 || (*end != '\0' && *end != '&') || v <= 0) return 0;
            return (int64_t)v;
        }
        q = strchr(q, '&');
    }
    return 0;
}

static int64_t read_sysctl(const char* path) {
    FILE* f = fopen(path, "r");
    if (!f) return -1;
    long long v = -1;
    if (fscanf(f, "%lld", &v) != 1) v = -1;
    fclose(f);
    return (int64_t)v;
}

int64_t hs_net_rmem_max(void) {
    return read_sysctl("/proc/sys/net/core/rmem_max");
}

int64_t hs_net_rmem_default(void) {
    return read_sysctl("/proc/sys/net/core/rmem_default");
}

int hs_net_size_note(const char* what, int64_t bytes, int64_t rmem_default, int64_t rmem_max,
                     char* out, size_t cap) {
    // The kernel counts a datagram's overhead against the buffer too: ask for twice the bytes.
    const long long want = 2 * (long long)bytes;
    int level = 0;
    if (rmem_max > 0 && bytes > rmem_max)
        level = 2;
    else if (rmem_default > 0 && want > rmem_default)
        level = 1;
    if (cap) out[0] = '\0';
    if (level == 2)
        snprintf(out, cap,
                 "a %s message is %lld bytes, more than net.core.rmem_max (%lld): no receiver on "
                 "this host gets it until rmem_max is raised (sysctl -w net.core.rmem_max=%lld) "
                 "and its URL asks for recv_buf_size=%lld (docs/protocol.md)",
                 what, (long long)bytes, (long long)rmem_max, want, want);
    else if (level == 1)
        snprintf(
            out, cap,
            "a %s message is %lld bytes, more than half of net.core.rmem_default (%lld, a "
            "socket's buffer when it asks for none): only receivers whose URL asks for "
            "recv_buf_size=%lld or more surely get it (the hapsim client library asks for 4 MB; "
            "docs/protocol.md)",
            what, (long long)bytes, (long long)rmem_default, want);
    return level;
}
