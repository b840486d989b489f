// SPDX-License-Identifier: GPL-2.0-or-later
// libFuzzer target: what hapsim-stylus receives from the network. The first byte picks the
// kind (even: a tool_force for device 2, odd: a SERVER_STATUS), the rest is the message. An
// accepted force model must keep the wire ranges and render a finite force anywhere; an
// accepted status must have the numbers the status line shows within [0, 1e9]; a refused one
// must leave the status zeroed. The intake's counters must add up to the messages fed.
#include <math.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include "hapsim_wire_read.h"
#include "stylus.h"
#include "wire.h"

int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size);

int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
    if (size < 1) return 0;
    const uint8_t* msg = data + 1;
    size_t len = size - 1;
    if (data[0] % 2 == 0) {
        hs_stylus_rx_state st;
        hs_stylus_rx_init(&st, 2);
        hs_stylus_model m;
        memset(&m, 0, sizeof m);
        hs_stylus_rx r = hs_stylus_rx_bytes(&st, msg, len, 5, 1700000000000000, &m);
        int64_t total = 0;
        for (int k = 0; k < 6; ++k) total += st.count[k];
        if (total != 1 || st.count[r] != 1) abort();
        if (r != HS_RX_OK) return 0;
        if (!hs_stylus_model_valid(&m) || !(m.radius_m <= HS_WIRE_RADIUS_MAX_M) ||
            !(m.timeout_s <= HS_WIRE_TIMEOUT_MAX_US * 1e-6) || m.arrival_ns != 5)
            abort();
        for (int i = 0; i < 3; ++i)
            if (!(fabs(m.force_n[i]) <= HS_WIRE_FORCE_MAX_N) ||
                !(fabs(m.anchor_m[i]) <= HS_WIRE_ANCHOR_MAX_M))
                abort();
        static const double where[3][3] = {{0, 0, 0}, {1e3, -1e3, 1e3}, {1e30, 1e30, -1e30}};
        for (int w = 0; w < 3; ++w) {
            double f[3];
            hs_stylus_model_eval(&m, where[w], f);
            for (int k = 0; k < 3; ++k)
                if (!isfinite(f[k])) abort();
        }
        return 0;
    }
    hs_stylus_srv_status s;
    if (hs_stylus_status_decode(msg, len, &s) != 0) {
        if (s.has_rt || s.rt_rate_hz != 0 || s.rt_p99_us != 0 || s.step_p99_us != 0) abort();
        return 0;
    }
    if (!(s.rt_rate_hz >= 0 && s.rt_rate_hz <= 1e9) || !(s.rt_p99_us >= 0 && s.rt_p99_us <= 1e9) ||
        !(s.step_p99_us >= 0 && s.step_p99_us <= 1e9))
        abort();
    return 0;
}
