/* Host stand-in for the hardware layer: a simulated 64-bit tick clock, one armed rise, the
 * pending fall, and the compare/overflow interrupts delivered by fake_run(). */
#ifndef FAKE_HW_H
#define FAKE_HW_H
#include <stdint.h>
#include "core.h"

#define FAKE_MAX_EDGES 4096
#define FAKE_TX_MAX 8192

typedef struct {
    uint64_t now;
    uint8_t pin;
    uint8_t rise_armed, fall_armed;
    uint64_t rise_t, fall_t;
    /* every level change of the pin: time and new level */
    uint64_t edge_t[FAKE_MAX_EDGES];
    uint8_t edge_level[FAKE_MAX_EDGES];
    uint32_t n_edges;
    uint8_t tx[FAKE_TX_MAX];
    uint32_t tx_len, tx_read;
} fake_hw_t;

extern fake_hw_t fake;

void fake_reset(uint64_t now);
/* Advances time to `until`, delivering the compare matches and overflow interrupts due. */
void fake_run(core_t *c, uint64_t until);
/* Sends one frame to the core as if received on the UART at the current time. */
void fake_send(core_t *c, uint8_t type, uint16_t seq, const uint8_t *payload, uint8_t len);
/* Next frame the firmware sent, decoded; 0 if none. */
int fake_reply(frame_t *f);
#endif
