// SPDX-License-Identifier: GPL-2.0-or-later
// libFuzzer target: the command handler (hs_net_validate_command) on raw LCM payloads.
// The input is fed twice to one state: the second copy of an accepted command must come back
// as a duplicate. Output strings must be terminated within their fixed storage.
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include "hapsim_command_ack_t.h"
#include "hapsim_command_t.h"
#include "validate.h"

int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size);

static void check_strings(const hs_net_command* c) {
    if (c->n_args < 0 || c->n_args > HS_NET_CMD_MAX_ARGS) abort();
    for (int i = 0; i < c->n_args; ++i) {
        if (!memchr(c->keys[i], 0, sizeof c->keys[i])) abort();
        if (!memchr(c->values[i], 0, sizeof c->values[i])) abort();
    }
    if (!memchr(c->sender, 0, sizeof c->sender)) abort();
}

int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
    hs_net_command_state st;
    hs_net_command_state_init(&st);
    hs_net_command c;
    int32_t prev = 0;
    hs_net_reject r1 = hs_net_validate_command(&st, data, (int64_t)size, &c, &prev);
    if ((int)r1 < 0 || r1 >= HS_NET_REJ_COUNT) abort();
    if (r1 == HS_NET_ACCEPT) {
        check_strings(&c);
        if (c.request_id == 0 || c.kind < HAPSIM_COMMAND_T_KIND_RESET ||
            c.kind > HAPSIM_COMMAND_T_KIND_REQUEST_TOPOLOGY)
            abort();
    }
    hs_net_reject r2 = hs_net_validate_command(&st, data, (int64_t)size, &c, &prev);
    if (r1 == HS_NET_ACCEPT &&
        (r2 != HS_NET_REJ_DUPLICATE || prev != HAPSIM_COMMAND_ACK_T_STATUS_PENDING))
        abort();
    if (r1 != HS_NET_ACCEPT && r2 != r1) abort(); // rejection is a pure function of the bytes
    if (st.counters.received != 2 ||
        st.counters.accepted + hs_net_counters_rejected(&st.counters) != 2)
        abort();
    return 0;
}
