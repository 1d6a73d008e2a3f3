/* Firmware logic without hardware registers: link parser and command handling, pulse
 * scheduler (pattern, trims), eye-safety interlock and guards.  Time is 64-bit MCU ticks. */
#ifndef LASERPI_CORE_H
#define LASERPI_CORE_H
#include <stdint.h>
#include "link.h"
#include "msg.h"

#define EDGE_QUEUE 4
#define RX_ENC_MAX 64

typedef struct {
    uint32_t index;
    uint64_t rise, fall;
    uint8_t flags;
} edge_t;

typedef struct {
    /* link */
    uint8_t rx[RX_ENC_MAX];
    uint8_t rx_len, rx_overflow;
    uint32_t frames_ok;
    uint16_t crc_errors, malformed, unknown, refused, late;
    /* state */
    uint8_t state, faults, reset_cause, stream_edges;
    uint64_t last_heartbeat;
    /* schedule: pulse `index` rises at `next_rise`; pattern bit (index % n) of mask says lit */
    uint32_t period, width, mask;
    uint8_t n;
    uint32_t min_gap;        /* smallest off time the duty envelope allows before/after `width` */
    uint64_t next_rise;      /* next lit pulse (armed or about to be) */
    uint32_t next_index;
    uint8_t next_pos, cur_pos; /* index mod n, kept incrementally (no division in interrupts) */
    uint32_t slot_floor;     /* first slot after the last pulse or the last slot a trim moved
                                (0 at the start): trims never move a slot before it */
    uint8_t pin_high;        /* a pulse is in flight (rise done, fall pending) */
    uint64_t cur_rise;
    uint32_t cur_index;
    int32_t trim_phase, trim_period;
    uint8_t trim_pending;
    /* history (for the run-time interlock and STATUS) */
    uint8_t have_last;
    uint64_t last_rise, last_fall;
    uint32_t last_min_gap;   /* off time the last pulse requires before the next one */
    uint32_t pulses;
    edge_t edges[EDGE_QUEUE];
    uint8_t edge_head, edge_count;
} core_t;

void core_init(core_t *c, uint8_t reset_cause);
/* Main context: one received byte, rx_tick = MCU time the byte arrived (used for PONG). */
void core_rx_byte(core_t *c, uint8_t b, uint64_t rx_tick);
/* Main context: the receiver dropped bytes; the frame being assembled is refused (malformed). */
void core_rx_damaged(core_t *c);
/* Main context: runs the guards and sends at most one queued EDGE report. */
void core_poll(core_t *c);
/* Interrupt context (interrupts disabled): the armed rise happened at tick t.
 * Returns the tick at which the pulse must fall. */
uint64_t core_rise_done(core_t *c, uint64_t t);
/* Interrupt context: the pulse fell at tick t (flags: EDGE_FALL_FORCED if software had to end it).
 * Returns 1 and sets *next to the next rise to arm, or 0 if nothing is to be armed. */
uint8_t core_fall_done(core_t *c, uint64_t t, uint8_t flags, uint64_t *next);
/* Interrupt or main context with interrupts disabled: heartbeat timeout and pulse-width guard.
 * Switches the laser off itself (hw_force_off) when a guard trips. */
void core_guard(core_t *c, uint64_t now);
/* Interrupts disabled: a fault switches the laser off and latches `flag`. */
void core_fault(core_t *c, uint8_t flag);
/* Main context: sends the INFO message (envelope, version, reset cause). */
void core_send_info(core_t *c, uint16_t seq);

/* Interlock arithmetic, exposed for the unit tests. */
uint32_t interlock_min_gap(uint32_t width);
/* Off time the rate rule needs between pulses of widths w1 then w2: MIN_PERIOD - min(w1, w2). */
uint32_t interlock_rate_gap(uint32_t w1, uint32_t w2);
uint8_t pattern_min_spacing(uint32_t mask, uint8_t n);
#endif
