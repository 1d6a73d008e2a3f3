/* 64-bit MCU time from the 16-bit Timer1 counter plus a software overflow counter.
 *
 * The overflow race: TCNT1 can wrap between the last overflow interrupt and the read (with
 * interrupts disabled the TIMER1_OVF interrupt is then pending and the count is one short).
 * Rule used everywhere (interrupts disabled): read TCNT1 first, then the TOV1 flag.  If TOV1 is
 * set the wrap happened before or after the TCNT1 read; a small count (< 0x8000) means before
 * (add the missing overflow), a large count means after (the read belongs to the old period).
 * This holds as long as the code between the two reads and any interrupt-disabled section is
 * shorter than half a timer period (16 ms), which it is by orders of magnitude. */
#ifndef LASERPI_TIMEEXT_H
#define LASERPI_TIMEEXT_H
#include <stdint.h>

/* high = (overflows counted so far) << 16, kept pre-shifted by the overflow interrupt so that
 * reading the time costs two 64-bit additions and no 64-bit shift (cheap inside interrupts). */
static inline uint64_t time_extend(uint64_t high, uint16_t tcnt, uint8_t tov_pending)
{
    if (tov_pending && tcnt < 0x8000u)
        high += 0x10000u;
    return high + tcnt;
}
#endif
