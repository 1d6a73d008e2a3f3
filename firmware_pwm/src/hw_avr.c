/* ATmega328P hardware layer: Timer1 (prescaler 8, 0.5 us ticks) extended to 64 bits, the laser
 * on OC1A (PB1, Arduino D9) driven by hardware output compare, USART0 at 250 kbaud 8N1, the
 * watchdog.  All logic lives in core.c; this file only moves bits.
 *
 * Edge placement.  An edge at absolute tick T is armed by writing OCR1A = T mod 2^16 and
 * selecting "toggle OC1A on compare match" only while 0 < T - now < ARM_WINDOW_TICKS, so the first
 * match is exactly at T.  Rises further away are deferred: OCR1B is set to T - ARM_WINDOW/2 and
 * its interrupt re-tries, by which time T is about ARM_WINDOW/2 ticks ahead.  The fall is armed
 * by the rise interrupt: T + width is always inside the 16-bit window.  The compare unit, not software,
 * moves the pin, so edges land on exact ticks whatever the interrupt latency.
 * Toggle mode (not set/clear) is used because simavr 1.6 re-applies set/clear compare outputs on
 * every overflow and OCR write as if in PWM mode; toggle is exact on hardware and in simavr.
 * TIFR1 is never written: simavr 1.6 clears every Timer1 flag on any TIFR1 write, which would
 * drop a pending overflow (and 65536 ticks of time).  A stale OCF1A (set by an earlier match
 * while the interrupt was off) fires as soon as a rise is armed; rises are armed only when less
 * than ARM_WINDOW_TICKS ahead, so the rise interrupt tells a stale flag from the real match by
 * TCNT1 - T alone, in 16-bit arithmetic, before anything else.
 * After every fall the compare output is disconnected (COM1A = 0): PORTB1 is 0, so the pin is
 * low whenever no pulse is armed.  The laser driver needs a pull-down on D9 so that the laser is
 * also off while the pin is an input (reset, bootloader).
 */
#include <avr/interrupt.h>
#include <avr/io.h>
#include <avr/wdt.h>

#include "config.h"
#include "core.h"
#include "hw.h"
#include "timeext.h"

#define BAUD_UBRR 3 /* 16 MHz / (16 * 250000) - 1, exact */

static core_t core;
static volatile uint64_t overflow_ticks; /* overflows << 16 */

enum { ARM_IDLE, ARM_RISE_DEFERRED, ARM_RISE, ARM_FALL };
static volatile uint8_t arm_state;
static volatile uint8_t in_scheduler; /* see after_fall() */
static uint64_t arm_target;

/* rx ring: bytes, plus the arrival tick of each delimiter (for PONG) */
#define RX_RING 64
static volatile uint8_t rx_ring[RX_RING];
static volatile uint8_t rx_head, rx_tail;
static volatile uint8_t rx_lost; /* a byte was dropped: the frame being assembled is damaged */
#define DELIM_RING 4
static volatile uint64_t delim_tick[DELIM_RING];
static volatile uint8_t delim_head, delim_tail;

uint8_t mcusr_at_boot __attribute__((section(".noinit")));

/* Runs before the C runtime initialises memory: laser pin low and output, watchdog off (it
 * stays enabled after a watchdog reset otherwise). */
void early_init(void) __attribute__((naked, used, section(".init3")));
void early_init(void)
{
    PORTB &= (uint8_t)~_BV(PB1);
    DDRB |= _BV(PB1);
    mcusr_at_boot = MCUSR;
    MCUSR = 0;
    wdt_disable();
}

/* Interrupts disabled.  TCNT1 first, then TOV1: see timeext.h for the overflow race. */
static uint64_t now_locked(void)
{
    uint16_t t = TCNT1;
    uint8_t pending = (TIFR1 & _BV(TOV1)) != 0;
    return time_extend(overflow_ticks, t, pending);
}

uint64_t hw_now(void)
{
    uint8_t s = SREG;
    cli();
    uint64_t t = now_locked();
    SREG = s;
    return t;
}

uint8_t hw_irq_save(void)
{
    uint8_t s = SREG;
    cli();
    return s;
}

void hw_irq_restore(uint8_t saved) { SREG = saved; }

uint8_t hw_force_off(void)
{
    uint8_t s = SREG;
    cli();
    uint8_t was_high = (PINB & _BV(PB1)) != 0;
    TCCR1A = 0;                      /* disconnect OC1A: the pin follows PORTB1 */
    PORTB &= (uint8_t)~_BV(PB1);     /* = 0 (the write also resyncs simavr's pin state) */
    TIMSK1 &= (uint8_t)~(_BV(OCIE1A) | _BV(OCIE1B));
    arm_state = ARM_IDLE;
    SREG = s;
    return was_high;
}

/* Interrupts disabled.  Arms an edge at t: ARMED (OC1A armed, the match is at t), DEFERRED
 * (more than one 16-bit window ahead: OCR1B retries later) or LATE (too close or past). */
enum { ARMED, DEFERRED, LATE };
static uint8_t arm_at(uint64_t t)
{
    uint64_t now = now_locked();
    if (t <= now + ARM_MARGIN_TICKS)
        return LATE;
    if (t - now < ARM_WINDOW_TICKS) {
        OCR1A = (uint16_t)t;
        TIMSK1 |= _BV(OCIE1A);
        TCCR1A = _BV(COM1A0); /* toggle OC1A on compare match */
        return ARMED;
    }
    OCR1B = (uint16_t)(t - ARM_WINDOW_TICKS / 2);
    TIMSK1 |= _BV(OCIE1B);
    return DEFERRED;
}

/* Interrupts disabled, pin low.  0 if the rise at t is armed or deferred, 1 if too late.
 * Replaces a rise armed before (a TRIM re-arms the next rise while it is still far ahead). */
static uint8_t arm_rise(uint64_t t)
{
    TCCR1A = 0;
    TIMSK1 &= (uint8_t)~(_BV(OCIE1A) | _BV(OCIE1B));
    arm_target = t;
    switch (arm_at(t)) {
    case ARMED: arm_state = ARM_RISE; return 0;
    case DEFERRED: arm_state = ARM_RISE_DEFERRED; return 0;
    default: arm_state = ARM_IDLE; return 1;
    }
}

uint8_t hw_arm_rise(uint64_t t)
{
    uint8_t s = SREG;
    cli();
    uint8_t r = arm_rise(t);
    SREG = s;
    return r;
}

ISR(TIMER1_OVF_vect)
{
    overflow_ticks += 0x10000u;
    if (!in_scheduler) /* the guards never run in the middle of a scheduler update */
        core_guard(&core, now_locked());
}

ISR(TIMER1_COMPB_vect)
{
    if (arm_state != ARM_RISE_DEFERRED) {
        TIMSK1 &= (uint8_t)~_BV(OCIE1B);
        return;
    }
    uint8_t r = arm_at(arm_target); /* DEFERRED again: still a window away, OCR1B retries */
    if (r == ARMED) {
        TIMSK1 &= (uint8_t)~_BV(OCIE1B);
        arm_state = ARM_RISE;
    } else if (r == LATE) {
        arm_state = ARM_IDLE;
        core_fault(&core, FAULT_LATE, now_locked());
    }
}

/* COMPA interrupt, after a fall (pin low, nothing armed): the scheduler's 64-bit work runs with
 * the UART receive and Timer1 overflow interrupts allowed to nest (the compare interrupts are
 * masked; the overflow interrupt only counts while `in_scheduler` is set), so that a received
 * byte never waits for it (a 250 kbaud byte lasts 640 cycles and the USART holds two).  TOIE1
 * stays enabled: in simavr 1.6 a flag raised while its interrupt is masked never triggers it
 * once unmasked, which would lose an overflow.  The next rise
 * is armed with interrupts disabled again. */
static void after_fall(uint64_t t, uint8_t flags)
{
    TIMSK1 = _BV(TOIE1);
    in_scheduler = 1;
    sei();
    uint64_t next;
    uint8_t more = core_fall_done(&core, t, flags, &next);
    cli();
    in_scheduler = 0;
    if (more && arm_rise(next))
        core_fault(&core, FAULT_LATE, now_locked());
}

ISR(TIMER1_COMPA_vect)
{
    if (arm_state == ARM_RISE) {
        /* The pin just rose at arm_target (or this is a stale flag, see below).  Everything up
         * to the OCR1A write is 16-bit: the width is below one timer window, so the next match
         * of OCR1A = (T + width) mod 2^16 is the fall if written before TCNT1 gets there. */
        uint16_t t16 = (uint16_t)arm_target;
        uint16_t w16 = (uint16_t)core.width;
        uint16_t elapsed = (uint16_t)(TCNT1 - t16);
        if (elapsed > MAX_PULSE_TICKS + ARM_MARGIN_TICKS)
            return; /* a stale flag: rises are armed less than ARM_WINDOW_TICKS ahead, so a
                     * match before T shows more than 2^16 - ARM_WINDOW_TICKS here */
        OCR1A = (uint16_t)(t16 + w16);
        elapsed = (uint16_t)(TCNT1 - t16);
        uint64_t fall = core_rise_done(&core, arm_target);
        arm_target = fall;
        arm_state = ARM_FALL;
        if (elapsed + 2u >= w16) { /* too late to place the fall: end the pulse now */
            uint64_t now = now_locked();
            TCCR1A = 0;
            PORTB &= (uint8_t)~_BV(PB1);
            TIMSK1 &= (uint8_t)~_BV(OCIE1A);
            arm_state = ARM_IDLE;
            after_fall(now, EDGE_FALL_FORCED);
        }
    } else if (arm_state == ARM_FALL) {
        if ((uint16_t)(TCNT1 - (uint16_t)arm_target) >= 0x8000u)
            return; /* not yet due: cannot happen, the flag was cleared at the rise */
        TCCR1A = 0; /* disconnect: the pin stays low (PORTB1 = 0) */
        TIMSK1 &= (uint8_t)~_BV(OCIE1A);
        arm_state = ARM_IDLE;
        after_fall(arm_target, 0);
    } else {
        TIMSK1 &= (uint8_t)~_BV(OCIE1A);
    }
}

ISR(USART_RX_vect)
{
    uint8_t b = UDR0;
    uint8_t next = (uint8_t)((rx_head + 1) % RX_RING);
    if (next != rx_tail) {
        rx_ring[rx_head] = b;
        rx_head = next;
    } else {
        rx_lost = 1;
    }
    if (b == 0) {
        uint8_t dn = (uint8_t)((delim_head + 1) % DELIM_RING);
        if (dn != delim_tail) {
            delim_tick[delim_head] = now_locked();
            delim_head = dn;
        }
    }
}

void hw_tx(const uint8_t *buf, uint8_t len)
{
    while (len--) {
        while (!(UCSR0A & _BV(UDRE0)))
            ;
        UDR0 = *buf++;
    }
}

int main(void)
{
    TCCR1A = 0;
    TCCR1B = _BV(CS11); /* normal mode, clk/8 */
    TIMSK1 = _BV(TOIE1);
    UBRR0 = BAUD_UBRR;
    UCSR0A = 0;
    UCSR0B = _BV(RXEN0) | _BV(TXEN0) | _BV(RXCIE0);
    UCSR0C = _BV(UCSZ01) | _BV(UCSZ00); /* 8N1 */
    core_init(&core, mcusr_at_boot);
    wdt_enable(WDTO_60MS); /* a wedged main loop resets the MCU; the pin is low after reset */
    sei();
    core_send_info(&core, 0); /* unsolicited at boot: tells the Pi the MCU (re)started */
    for (;;) {
        /* a bounded number of bytes per pass, so that the watchdog is fed and the guards and
         * EDGE reports get their turn even while a stream of garbage keeps the receiver busy */
        wdt_reset();
        for (uint8_t k = 0; k < 16 && rx_tail != rx_head; k++) {
            uint8_t b = rx_ring[rx_tail];
            rx_tail = (uint8_t)((rx_tail + 1) % RX_RING);
            uint64_t tick = 0;
            if (rx_lost) { /* bytes (maybe a delimiter) were dropped: never act on a merged frame */
                rx_lost = 0;
                core_rx_damaged(&core);
            }
            if (b == 0) {
                uint8_t s = hw_irq_save();
                if (delim_tail != delim_head) {
                    tick = delim_tick[delim_tail];
                    delim_tail = (uint8_t)((delim_tail + 1) % DELIM_RING);
                }
                hw_irq_restore(s);
            }
            core_rx_byte(&core, b, tick);
        }
        core_poll(&core);
    }
}
