/* Host model of the ATmega328P parts the firmware's hardware layer touches, for the host unit
 * tests: src/timer1.c runs against it unchanged (through src/sfr.h), so these tests exercise
 * the register-level edge driver, not a stand-in for it.
 *
 * Modelled after the ATmega328P datasheet (Atmel-8271, "ATmega48A/PA/88A/PA/168A/PA/328/P"):
 *  - 16.7 Output Compare Units: TCNT1 == OCR1A signals a match; the flag OCF1A is set, and the
 *    compare output acts, at the next timer clock (so an edge armed for tick T shows at T + 1).
 *  - 16.8 Compare Match Output Unit and Table 16-1 (non-PWM): the pin OC1A shows the internal
 *    OC1A register (a latch) whenever COM1A1:0 != 0, and PORTB1 otherwise; DDRB1 must be set for
 *    either to drive the pin.  The latch changes only on a compare match or a FOC1A strobe, by
 *    the COM1A1:0 present then (01 toggle, 10 clear, 11 set; 00 no action).  A change of
 *    COM1A1:0 switches the pin's source at once (16.7.3 "Using the Output Compare Unit"); the
 *    latch keeps its value through it.  Reset clears the latch.
 *  - 16.7.1 / 16.11.3 TCCR1C: a FOC1A strobe acts on the latch as a match would, sets no flag
 *    and raises no interrupt; it reads back as zero.
 *  - 16.9.1 Normal mode: TCNT1 counts up and wraps at 0xFFFF -> 0 setting TOV1.  Only normal
 *    mode is modelled (the model aborts on other WGM bits).
 *  - 16.11.8 TIFR1: a flag is cleared by writing one to it, and when its interrupt vector runs.
 *  - 14.2 Ports as General Digital I/O: with DDRB1 = 0 the pin is an input; PORTB1 = 1 then
 *    turns on the internal pull-up, which the model counts as high (it may beat the driver's
 *    pull-down: never safe).
 *  - 7.7 Reset and Interrupt Handling: the I bit of SREG; a vector clears I and its flag; pending
 *    interrupts run by vector priority (COMPA 11, COMPB 12, OVF 13) as soon as I is set.
 * Time is in timer clocks (ticks), counted from reset; the timer is started at tick 0.
 * Instruction time is modelled only where a test asks for it: each TCNT1 read costs
 * `tcnt_read_cost` ticks (0 by default), so that a test can make a critical section long enough
 * for a compare match to happen inside it, as on the MCU. */
#ifndef FAKE_AVR_H
#define FAKE_AVR_H
#include <stdint.h>
#include "core.h"

enum fake_sfr {
    SFR_SREG, SFR_TCCR1A, SFR_TCCR1B, SFR_TCCR1C, SFR_TCNT1, SFR_OCR1A, SFR_OCR1B, SFR_TIMSK1, SFR_TIFR1,
    SFR_PORTB, SFR_DDRB, SFR_PINB,
};
#define SREG SFR_SREG
#define TCCR1A SFR_TCCR1A
#define TCCR1B SFR_TCCR1B
#define TCCR1C SFR_TCCR1C
#define TCNT1 SFR_TCNT1
#define OCR1A SFR_OCR1A
#define OCR1B SFR_OCR1B
#define TIMSK1 SFR_TIMSK1
#define TIFR1 SFR_TIFR1
#define PORTB SFR_PORTB
#define DDRB SFR_DDRB
#define PINB SFR_PINB
/* bit numbers as in <avr/iom328p.h> */
#define COM1A1 7
#define COM1A0 6
#define WGM11 1
#define WGM10 0
#define WGM13 4
#define WGM12 3
#define CS11 1
#define FOC1A 7
#define OCIE1B 2
#define OCIE1A 1
#define TOIE1 0
#define OCF1B 2
#define OCF1A 1
#define TOV1 0
#define PB1 1
#define SREG_I 7
#define _BV(bit) (1u << (bit))

uint16_t fake_sfr_read(enum fake_sfr r);
void fake_sfr_write(enum fake_sfr r, uint16_t value);
void fake_cli(void);
void fake_sei(void);
#define SFR_READ(reg) fake_sfr_read(reg)
#define SFR_WRITE(reg, value) fake_sfr_write((reg), (uint16_t)(value))
#define IRQ_DISABLE() fake_cli()
#define IRQ_ENABLE() fake_sei()
#define TIMER1_ISR(vector) void vector(void)
void TIMER1_COMPA_vect(void);
void TIMER1_COMPB_vect(void);
void TIMER1_OVF_vect(void);

#define FAKE_MAX_EDGES 8192
#define FAKE_TX_MAX 16384

typedef struct {
    core_t *core;          /* the firmware's core, as timer1_start() was given it */
    uint64_t now;          /* ticks of the model's clock (continues across MCU resets) */
    uint64_t timer_origin; /* `now` at the last reset: TCNT1 = (now - timer_origin) mod 2^16 */
    uint8_t sreg, tccr1a, tccr1b, timsk1, tifr1, portb, ddrb;
    uint16_t ocr1a, ocr1b;
    uint8_t oc1a;          /* the compare output latch (the OC1A register of 16.8) */
    uint8_t pin;           /* the level on PB1 */
    uint8_t in_isr;        /* nesting depth of running vectors */
    uint32_t tcnt_read_cost;
    /* every level change of the pin: time and new level */
    uint64_t edge_t[FAKE_MAX_EDGES];
    uint8_t edge_level[FAKE_MAX_EDGES];
    uint32_t n_edges;
    uint8_t tx[FAKE_TX_MAX];
    uint32_t tx_len, tx_read;
} fake_avr_t;

extern fake_avr_t fake;

/* Power-on at model tick `now` (< 2^16: the timer counts from the reset), pin log cleared,
 * then fake_boot(c, reset_cause). */
void fake_reset(core_t *c, uint64_t now, uint8_t reset_cause);
/* An MCU reset now (watchdog, brown-out, external): every register and the OC1A latch cleared
 * (PB1 an input: the pin is low), the timer restarts at 0; then the firmware boots as
 * hw_avr.c does: PB1 low and output, core_init(c, reset_cause), timer1_start(c), interrupts on.
 * The pin log and the model's clock go on. */
void fake_boot(core_t *c, uint8_t reset_cause);
/* Advances time to `until` (main context, interrupts as SREG says), delivering compare matches,
 * overflows and the interrupts they raise. */
void fake_run(uint64_t until);
/* Sends one frame to the core as if received on the UART now (main context). */
void fake_send(core_t *c, uint8_t type, uint16_t seq, const uint8_t *payload, uint8_t len);
/* Next frame the firmware sent, decoded; 0 if none. */
int fake_reply(frame_t *f);
#endif
