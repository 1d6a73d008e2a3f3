#include "fake_hw.h"
#include <string.h>
#include "config.h"
#include "hw.h"

fake_hw_t fake;

static void set_pin(uint8_t level)
{
    if (fake.pin == level)
        return;
    fake.pin = level;
    if (fake.n_edges < FAKE_MAX_EDGES) {
        fake.edge_t[fake.n_edges] = fake.now;
        fake.edge_level[fake.n_edges] = level;
        fake.n_edges++;
    }
}

void fake_reset(uint64_t now)
{
    memset(&fake, 0, sizeof fake);
    fake.now = now;
}

uint64_t hw_now(void) { return fake.now; }

uint8_t hw_arm_rise(uint64_t t)
{
    if (t <= fake.now + ARM_MARGIN_TICKS)
        return 1;
    fake.rise_armed = 1;
    fake.rise_t = t;
    return 0;
}

uint8_t hw_force_off(void)
{
    uint8_t was = fake.pin;
    set_pin(0);
    fake.rise_armed = fake.fall_armed = 0;
    return was;
}

void hw_tx(const uint8_t *buf, uint8_t len)
{
    if (fake.tx_len + len <= FAKE_TX_MAX) {
        memcpy(fake.tx + fake.tx_len, buf, len);
        fake.tx_len += len;
    }
}

uint8_t hw_irq_save(void) { return 0; }
void hw_irq_restore(uint8_t saved) { (void)saved; }

void fake_run(core_t *c, uint64_t until)
{
    for (;;) {
        uint64_t next_ovf = (fake.now | 0xFFFFULL) + 1;
        uint64_t t = next_ovf;
        int kind = 0; /* 0 overflow, 1 rise, 2 fall */
        if (fake.rise_armed && fake.rise_t <= t) { t = fake.rise_t; kind = 1; }
        if (fake.fall_armed && fake.fall_t <= t) { t = fake.fall_t; kind = 2; }
        if (t > until) {
            fake.now = until;
            return;
        }
        fake.now = t;
        if (kind == 0) {
            core_guard(c, t);
        } else if (kind == 1) {
            fake.rise_armed = 0;
            set_pin(1);
            fake.fall_t = core_rise_done(c, t);
            fake.fall_armed = 1;
        } else {
            fake.fall_armed = 0;
            set_pin(0);
            uint64_t next;
            if (core_fall_done(c, t, 0, &next) && hw_arm_rise(next))
                core_fault(c, FAULT_LATE, t);
        }
    }
}

void fake_send(core_t *c, uint8_t type, uint16_t seq, const uint8_t *payload, uint8_t len)
{
    uint8_t wire[FRAME_WIRE_MAX];
    uint8_t n = link_encode(type, seq, 0, payload, len, wire);
    for (uint8_t i = 0; i < n; i++)
        core_rx_byte(c, wire[i], fake.now);
}

int fake_reply(frame_t *f)
{
    uint32_t start = fake.tx_read;
    for (uint32_t i = start; i < fake.tx_len; i++) {
        if (fake.tx[i] == 0) {
            fake.tx_read = i + 1;
            return link_decode(fake.tx + start, (uint16_t)(i - start), f) == LINK_OK;
        }
    }
    return 0;
}
