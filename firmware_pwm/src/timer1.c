/* Timer1 edge driver (ATmega328P; the host unit tests run this same file against a register
 * model, test/fake_avr.c).  Timer1 runs in normal mode at clk/8, extended to 64 bits by the
 * overflow interrupt; the laser is on OC1A (PB1, Arduino D9), driven by the output compare unit.
 *
 * The pin as the silicon drives it (ATmega328P datasheet, Atmel-8271, 16.7 Output Compare
 * Units, 16.7.1 Force Output Compare, 16.7.3 Using the Output Compare Unit, 16.8 Compare Match
 * Output Unit, Table 16-1, 16.11.3 TCCR1C): while COM1A1:0 != 0 the pin shows the internal OC1A
 * register, a latch that only a compare match or a FOC1A strobe changes, by the COM1A1:0 bits
 * present then; writing PORTB does not touch it, and a change of COM1A1:0 switches the pin's
 * source at once.  So the driver keeps one invariant: whenever the output is disconnected
 * (COM1A1:0 = 0) the latch is 0.  Reset clears it; every pulse is ended by a match in clear mode
 * or, in software, by oc1a_force_low() (a FOC1A strobe in clear mode) before disconnecting.  Each
 * edge is placed in its own mode, set (11) for a rise and clear (10) for a fall, never toggle, so
 * no edge depends on the latch's history.
 *
 * Edge placement.  An edge at absolute tick T is armed by writing OCR1A = T mod 2^16 only while
 * 0 < T - now < ARM_WINDOW_TICKS, so the first match is exactly at T (the pin moves at the timer
 * clock after it, T + 1).  Rises further away are deferred: OCR1B is set to T - ARM_WINDOW/2 and
 * its interrupt re-tries, by which time T is about ARM_WINDOW/2 ticks ahead.  The fall is armed
 * by the rise interrupt: T + width is always inside the 16-bit window.  The compare unit, not
 * software, moves the pin, so edges land on exact ticks whatever the interrupt latency.  A rise
 * armed before is only replaced (TRIM) while it is still ARM_MARGIN_TICKS ahead: one closer, or
 * already past with its interrupt pending, is in flight, and hw_arm_rise says so (HW_IN_FLIGHT).
 * TIFR1 is never written: simavr 1.6 clears every Timer1 flag on any TIFR1 write, which would
 * drop a pending overflow (and 65536 ticks of time).  A stale OCF1A (set by an earlier match
 * while the interrupt was off) fires as soon as a rise is armed; rises are armed only when less
 * than ARM_WINDOW_TICKS ahead, so the rise interrupt tells a stale flag from the real match by
 * TCNT1 - T alone, in 16-bit arithmetic, before anything else (a stale match found the output
 * disconnected or in clear mode with the latch at 0: it moved nothing).
 * After every fall the compare output is disconnected: PORTB1 is 0, so the pin is low whenever
 * no pulse is armed.  The laser driver needs a pull-down on D9 so that the laser is also off
 * while the pin is an input (reset, bootloader).  simavr 1.6 models none of this latch (its pin
 * follows PORTB, and it re-applies set/clear outputs at every overflow as in PWM modes, and has
 * no FOC1A): the emulator harness computes the true pin itself (harness/harness.c).
 */
#include "timer1.h"

#include "config.h"
#include "hw.h"
#include "sfr.h"
#include "timeext.h"

static core_t *core;
static volatile uint64_t overflow_ticks; /* overflows << 16 */

enum { ARM_IDLE, ARM_RISE_DEFERRED, ARM_RISE, ARM_FALL };

/* COM1A1:0 in TCCR1A (Table 16-1, non-PWM): the action of the next match on the OC1A latch */
#define OC1A_DISCONNECTED 0
#define OC1A_CLEAR_ON_MATCH _BV(COM1A1)
#define OC1A_SET_ON_MATCH (_BV(COM1A1) | _BV(COM1A0))
static volatile uint8_t arm_state;
static volatile uint8_t in_scheduler; /* see after_fall() */
static uint64_t arm_target;

void timer1_start(core_t *c)
{
    core = c;
    overflow_ticks = 0;
    arm_state = ARM_IDLE;
    in_scheduler = 0;
    SFR_WRITE(TCCR1A, OC1A_DISCONNECTED); /* the latch is 0 after reset (16.8) */
    SFR_WRITE(TCCR1B, _BV(CS11)); /* normal mode, clk/8 */
    SFR_WRITE(TIMSK1, _BV(TOIE1));
}

/* Interrupts disabled.  TCNT1 first, then TOV1: see timeext.h for the overflow race. */
static uint64_t now_locked(void)
{
    uint16_t t = SFR_READ(TCNT1);
    uint8_t pending = (SFR_READ(TIFR1) & _BV(TOV1)) != 0;
    return time_extend(overflow_ticks, t, pending);
}

uint64_t hw_now(void)
{
    uint8_t s = SFR_READ(SREG);
    IRQ_DISABLE();
    uint64_t t = now_locked();
    SFR_WRITE(SREG, s);
    return t;
}

uint8_t hw_irq_save(void)
{
    uint8_t s = SFR_READ(SREG);
    IRQ_DISABLE();
    return s;
}

void hw_irq_restore(uint8_t saved) { SFR_WRITE(SREG, saved); }

/* Interrupts disabled.  Ends any pulse now and restores the invariant: the latch is cleared
 * by a FOC1A strobe in clear mode (16.7.1: "the OC1x pin will be updated as if a real compare
 * match had occurred"; no flag, no interrupt), then the output is disconnected (PORTB1 = 0). */
static void oc1a_force_low(void)
{
    SFR_WRITE(TCCR1A, OC1A_CLEAR_ON_MATCH);
    SFR_WRITE(TCCR1C, _BV(FOC1A));
    SFR_WRITE(TCCR1A, OC1A_DISCONNECTED);
}

uint8_t hw_force_off(uint64_t *rose_at)
{
    uint8_t s = SFR_READ(SREG);
    IRQ_DISABLE();
    uint8_t rise_armed = arm_state == ARM_RISE;
    oc1a_force_low();
    SFR_WRITE(PORTB, SFR_READ(PORTB) & (uint8_t)~_BV(PB1));
    SFR_WRITE(TIMSK1, SFR_READ(TIMSK1) & (uint8_t)~(_BV(OCIE1A) | _BV(OCIE1B)));
    arm_state = ARM_IDLE;
    /* The armed rise's match acts at T + 1: read after the cut, a count past T means it may have
     * acted before the cut (then the pin was high until it); counted as risen, at most a few
     * ticks too many, never too few. */
    uint8_t risen = rise_armed && arm_target < now_locked();
    if (risen)
        *rose_at = arm_target;
    SFR_WRITE(SREG, s);
    return risen;
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
        SFR_WRITE(OCR1A, (uint16_t)t);
        SFR_WRITE(TIMSK1, SFR_READ(TIMSK1) | _BV(OCIE1A));
        SFR_WRITE(TCCR1A, OC1A_SET_ON_MATCH); /* the latch is 0 (invariant): the pin stays low */
        return ARMED;
    }
    SFR_WRITE(OCR1B, (uint16_t)(t - ARM_WINDOW_TICKS / 2));
    SFR_WRITE(TIMSK1, SFR_READ(TIMSK1) | _BV(OCIE1B));
    return DEFERRED;
}

/* Interrupts disabled, no pulse in flight.  HW_ARMED if the rise at t is armed or deferred,
 * HW_LATE if t is too close, HW_IN_FLIGHT if the rise armed before cannot be replaced any more:
 * it is less than ARM_MARGIN_TICKS ahead or has happened, its interrupt pending (nothing is
 * changed then).  Replaces a rise armed before (a TRIM re-arms the next rise while it is still
 * far ahead). */
static uint8_t arm_rise(uint64_t t)
{
    if (arm_state == ARM_FALL || (arm_state == ARM_RISE && arm_target <= now_locked() + ARM_MARGIN_TICKS))
        return HW_IN_FLIGHT;
    oc1a_force_low(); /* whatever was armed before: latch 0, output disconnected */
    SFR_WRITE(TIMSK1, SFR_READ(TIMSK1) & (uint8_t)~(_BV(OCIE1A) | _BV(OCIE1B)));
    arm_target = t;
    switch (arm_at(t)) {
    case ARMED: arm_state = ARM_RISE; return HW_ARMED;
    case DEFERRED: arm_state = ARM_RISE_DEFERRED; return HW_ARMED;
    default: arm_state = ARM_IDLE; return HW_LATE;
    }
}

uint8_t hw_arm_rise(uint64_t t)
{
    uint8_t s = SFR_READ(SREG);
    IRQ_DISABLE();
    uint8_t r = arm_rise(t);
    SFR_WRITE(SREG, s);
    return r;
}

TIMER1_ISR(TIMER1_OVF_vect)
{
    overflow_ticks += 0x10000u;
    if (!in_scheduler) /* the guards never run in the middle of a scheduler update */
        core_guard(core, now_locked());
}

TIMER1_ISR(TIMER1_COMPB_vect)
{
    if (arm_state != ARM_RISE_DEFERRED) {
        SFR_WRITE(TIMSK1, SFR_READ(TIMSK1) & (uint8_t)~_BV(OCIE1B));
        return;
    }
    uint8_t r = arm_at(arm_target); /* DEFERRED again: still a window away, OCR1B retries */
    if (r == ARMED) {
        SFR_WRITE(TIMSK1, SFR_READ(TIMSK1) & (uint8_t)~_BV(OCIE1B));
        arm_state = ARM_RISE;
    } else if (r == LATE) {
        arm_state = ARM_IDLE;
        core_fault(core, FAULT_LATE);
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
    SFR_WRITE(TIMSK1, _BV(TOIE1));
    in_scheduler = 1;
    IRQ_ENABLE();
    uint64_t next;
    uint8_t more = core_fall_done(core, t, flags, &next);
    IRQ_DISABLE();
    in_scheduler = 0;
    if (more && arm_rise(next) != HW_ARMED)
        core_fault(core, FAULT_LATE);
}

TIMER1_ISR(TIMER1_COMPA_vect)
{
    if (arm_state == ARM_RISE) {
        /* The pin just rose at arm_target (or this is a stale flag, see below).  Everything up
         * to the OCR1A write is 16-bit: the width is below one timer window, so the next match
         * of OCR1A = (T + width) mod 2^16 is the fall if written before TCNT1 gets there. */
        uint16_t t16 = (uint16_t)arm_target;
        uint16_t w16 = (uint16_t)core->width;
        uint16_t elapsed = (uint16_t)(SFR_READ(TCNT1) - t16);
        if (elapsed > MAX_PULSE_TICKS + ARM_MARGIN_TICKS)
            return; /* a stale flag: rises are armed less than ARM_WINDOW_TICKS ahead, so a
                     * match before T shows more than 2^16 - ARM_WINDOW_TICKS here */
        SFR_WRITE(TCCR1A, OC1A_CLEAR_ON_MATCH); /* the latch is 1: the pin stays high, and the
                                                 * next match (the fall) clears it */
        SFR_WRITE(OCR1A, (uint16_t)(t16 + w16));
        elapsed = (uint16_t)(SFR_READ(TCNT1) - t16);
        uint64_t fall = core_rise_done(core, arm_target);
        arm_target = fall;
        arm_state = ARM_FALL;
        if (elapsed + 2u >= w16) { /* too late to place the fall: end the pulse now */
            oc1a_force_low();
            SFR_WRITE(TIMSK1, SFR_READ(TIMSK1) & (uint8_t)~_BV(OCIE1A));
            arm_state = ARM_IDLE;
            after_fall(now_locked(), EDGE_FALL_FORCED); /* the time after the cut, as core_fault */
        }
    } else if (arm_state == ARM_FALL) {
        if ((uint16_t)(SFR_READ(TCNT1) - (uint16_t)arm_target) >= 0x8000u)
            return; /* not yet due: cannot happen, the flag was cleared at the rise */
        SFR_WRITE(TCCR1A, OC1A_DISCONNECTED); /* the match cleared the latch; the pin follows PORTB1 = 0 */
        SFR_WRITE(TIMSK1, SFR_READ(TIMSK1) & (uint8_t)~_BV(OCIE1A));
        arm_state = ARM_IDLE;
        after_fall(arm_target, 0);
    } else {
        SFR_WRITE(TIMSK1, SFR_READ(TIMSK1) & (uint8_t)~_BV(OCIE1A));
    }
}
