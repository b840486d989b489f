// SPDX-License-Identifier: GPL-2.0-or-later
// libFuzzer target: the tool_pose handler (hs_net_validate_pose) on raw LCM payloads.
// The input is split into up to 8 messages by 0xFF 0xFE separators and fed in order to one
// validator state, so seq / session tracking is exercised; invariants are checked after each.
#include <math.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include "hapsim_tool_pose_t.h"
#include "validate.h"

int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size);

int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
    hs_net_limits lim = hs_net_default_limits();
    lim.n_devices = 2;
    lim.n_tools = 2;
    hs_net_pose_state st;
    hs_net_pose_state_init(&st);
    int64_t now = 1000;
    size_t start = 0;
    uint64_t sent = 0;
    for (int m = 0; m < 8 && start <= size; ++m) {
        size_t end = start;
        while (end + 1 < size && !(data[end] == 0xFF && data[end + 1] == 0xFE)) ++end;
        if (end + 1 >= size) end = size;
        hs_net_pose p;
        hs_net_reject r =
            hs_net_validate_pose(&lim, &st, data + start, (int64_t)(end - start), now, &p);
        sent++;
        if ((int)r < 0 || r >= HS_NET_REJ_COUNT) abort();
        if (r == HS_NET_ACCEPT) {
            double qn = 0;
            for (int i = 0; i < 4; ++i) qn += p.orientation[i] * p.orientation[i];
            if (!(fabs(qn - 1.0) < 1e-9)) abort();
            for (int i = 0; i < 3; ++i)
                if (!(p.position[i] >= lim.workspace_min[i] &&
                      p.position[i] <= lim.workspace_max[i]))
                    abort();
            if (p.device_id < 0 || p.device_id >= lim.n_devices || p.lost < 0) abort();
            if (st.dev[p.device_id].last_seq != p.seq) abort();
        }
        if (st.counters.received != sent ||
            st.counters.accepted + hs_net_counters_rejected(&st.counters) != sent)
            abort();
        now += 1000;
        start = end + 2;
    }
    return 0;
}
