/* Compile-time configuration of the LaserPi co-MCU firmware.
 *
 * Clock.  F_CPU (Hz) comes from the Makefile: 16000000 by default (5 V board), 8000000 for the
 * 3.3 V board (`make F_CPU=8000000`, see README.md "Board variants").  One MCU tick = one Timer1
 * count = 8 CPU cycles (prescaler 8): 0.5 us at 16 MHz, 1 us at 8 MHz; TICKS_PER_SECOND =
 * F_CPU / 8, reported in INFO so that the Pi converts with the build's own rate.  The checks
 * below refuse a clock without a whole number of ticks per millisecond or without 250000 baud
 * within 0.5 %.
 *
 * Two kinds of constants follow.
 *  - Times, given in microseconds and converted with F_CPU, so that every build has the same
 *    envelope in seconds: the eye-safety envelope (MAX_PULSE_US, MIN_PERIOD_US, with
 *    MAX_DUTY_PPM), the heartbeat timeout and the schedule horizon.  Rounded to the safe side
 *    when a tick does not divide them (pulse and timeout down, period up; exact at 8 and 16 MHz).
 *  - Allowances for the firmware's own work (MIN_PULSE, MIN_GAP, ARM_MARGIN, MIN_LEAD): numbers
 *    of CPU cycles, so the same in ticks at any clock (the code needs as many cycles at 8 MHz as
 *    at 16 MHz, i.e. twice the time).  In time they are twice as long at 8 MHz: stricter.
 *
 * The envelope can only be changed by rebuilding (`make MAX_PULSE_US=... MAX_DUTY_PPM=...
 * MIN_PERIOD_US=...`, numbers from `python -m device.model.envelope`); nothing on the serial
 * link can widen it.  Defaults, for the thesis laser (808 nm, 25 mW, 120 deg fan, 4 mm line,
 * 1 mm source): 17.4 ms maximum pulse, the pulse the thesis's Class 1 analysis was done for
 * (mode-5 exposure, parameter t of sections 4.1.1/4.2; appendix B NOHD analysis: 25 mW keeps the
 * NOHD under 10 mm with 17.4 ms pulses), and 20 % maximum duty, just above the thesis operating
 * point (17.4 ms at 10 Hz = 17.4 %).  The sensor-model issue (device/model eye safety, IEC
 * 60825-1 AEL with the C5 reduction, docs/thesis-notes.md N1) computes the envelope for other lasers
 * and configurations; rebuild with its numbers.
 */
#ifndef LASERPI_CONFIG_H
#define LASERPI_CONFIG_H

#include <stdint.h>

/* ---- clock and tick ---------------------------------------------------------------------- */
#ifndef F_CPU
#error "F_CPU (Hz) is not set: build with the Makefile (make [F_CPU=8000000])"
#endif
#if F_CPU > 20000000UL
#error "F_CPU above 20 MHz, the ATmega328P's maximum (datasheet: Speed Grades)"
#endif
#define CYCLES_PER_TICK 8UL /* Timer1 prescaler clk/8 (timer1.c) */
#define TICKS_PER_SECOND (F_CPU / CYCLES_PER_TICK)
#define TICKS_PER_MS (F_CPU / (CYCLES_PER_TICK * 1000UL))
#if F_CPU % (CYCLES_PER_TICK * 1000UL) != 0
#error "F_CPU must be a multiple of 8 kHz: a whole number of Timer1 ticks per millisecond"
#endif
/* microseconds to ticks, rounded down or up; the checks below keep the products inside 32 bits */
#define US_TO_TICKS_DOWN(us) ((us) * TICKS_PER_MS / 1000UL)
#define US_TO_TICKS_UP(us) (((us) * TICKS_PER_MS + 999UL) / 1000UL)

/* ---- serial link: 250000 baud 8N1 (the Pi's PL011: 48 MHz / 16 / 250000 = 12, exact) -------- */
#define BAUD 250000UL
#define BAUD_UBRR ((F_CPU + 8UL * BAUD) / (16UL * BAUD) - 1UL) /* UBRR0 (normal speed), rounded */
#define BAUD_DIVIDED (16UL * BAUD * (BAUD_UBRR + 1UL))        /* the F_CPU that UBRR0 is exact for */
#if F_CPU < 16UL * BAUD
#error "F_CPU below 4 MHz cannot make 250000 baud"
#endif
#if (F_CPU > BAUD_DIVIDED ? F_CPU - BAUD_DIVIDED : BAUD_DIVIDED - F_CPU) * 200UL > BAUD_DIVIDED
#error "F_CPU gives no 250000 baud within 0.5 % (F_CPU / 16 / 250000 must be whole: 16 MHz -> UBRR 3, 8 MHz -> 1)"
#endif

/* ---- eye-safety envelope and other times (microseconds) ------------------------------------ */
#ifndef MAX_PULSE_US
#define MAX_PULSE_US 17400UL /* 17.4 ms */
#endif
#ifndef MAX_DUTY_PPM
#define MAX_DUTY_PPM 200000UL /* 20 % (parts per million of time) */
#endif
#ifndef MIN_PERIOD_US
/* 90 ms: the shortest interval between the rises (and between the falls) of two consecutive
 * pulses, i.e. at most 11.1 pulses/s.  Short pulses (0.1-2.5 ms) are limited by the pulse-train
 * condition (C5), not by width or duty: under device/model/safety.py the thesis laser at 25 mW
 * passes 10 mm NOHD at 0.6 ms only up to ~12 Hz.  90 ms leaves the sensor's 10 Hz train (100 ms)
 * 10 ms of slack for period trims (+-1000 ppm = +-0.1 ms) and phase steps (up to 9.9 ms); the
 * whole envelope is verified by device/model/envelope.py (worst NOHD 9.8 mm at 0.625 ms). */
#define MIN_PERIOD_US 90000UL
#endif
#ifndef HEARTBEAT_TIMEOUT_US
/* 50 ms.  Checked in every main-loop pass and, as a backstop for a stalled main loop, in the
 * Timer1 overflow interrupt (every 65536 ticks: 32.8 ms at 16 MHz, 65.5 ms at 8 MHz).  At 16 MHz
 * the laser is off at most 50 + 32.8 = 82.8 ms after the last heartbeat, inside the 100 ms
 * budget; at 8 MHz the backstop alone gives 115.5 ms (README.md, "Board variants"). */
#define HEARTBEAT_TIMEOUT_US 50000UL
#endif
#if MAX_PULSE_US > 0xFFFFFFFFUL / TICKS_PER_MS || MIN_PERIOD_US > 0xFFFFFFFFUL / TICKS_PER_MS - 1000UL || \
    HEARTBEAT_TIMEOUT_US > 0xFFFFFFFFUL / TICKS_PER_MS
#error "an envelope time is too long for this clock (32-bit tick arithmetic)"
#endif
#define MAX_PULSE_TICKS US_TO_TICKS_DOWN(MAX_PULSE_US)
#define MIN_PERIOD_TICKS US_TO_TICKS_UP(MIN_PERIOD_US)
#define HEARTBEAT_TIMEOUT_TICKS US_TO_TICKS_DOWN(HEARTBEAT_TIMEOUT_US)
/* How far ahead a schedule may start, at most. */
#define MAX_LEAD_TICKS (10UL * TICKS_PER_SECOND) /* 10 s */

/* ---- allowances for the firmware's own work (CPU cycles / 8: the same in ticks at any clock) - */
/* Shortest pulse and shortest gap the interrupt code can place without racing itself. */
#define MIN_PULSE_TICKS 200UL /* 1600 cycles (100 us at 16 MHz): the fall is armed by the rise interrupt */
#define MIN_GAP_TICKS 400UL   /* 3200 cycles (200 us at 16 MHz): the scheduler's work after a fall */
/* An edge closer than this to "now" cannot be armed safely (interrupt latency allowance). */
#define ARM_MARGIN_TICKS 48UL /* 384 cycles (24 us at 16 MHz) */
/* How far ahead a schedule may start, at least (its acceptance checks and arming run first). */
#define MIN_LEAD_TICKS 200UL  /* 1600 cycles (100 us at 16 MHz) */
#define MAX_PATTERN_LEN 32

#define FIRMWARE_VERSION 2 /* 2: MIN_PERIOD_TICKS, INFO carries it */

/* A rise is armed on OC1A only when it is less than ARM_WINDOW_TICKS ahead, so that a stale
 * compare flag can never be mistaken for the rise (see timer1.c); farther rises are deferred. */
#define ARM_WINDOW_TICKS (65536UL - MAX_PULSE_TICKS - 2 * ARM_MARGIN_TICKS)
#if MAX_PULSE_TICKS + 2 * ARM_MARGIN_TICKS + 4096UL > 65536UL
#error "MAX_PULSE_US must leave room in one 16-bit compare window (61344 ticks: 30.7 ms at 16 MHz, 61.3 ms at 8 MHz)"
#endif
#if MAX_DUTY_PPM == 0 || MAX_DUTY_PPM > 1000000UL
#error "MAX_DUTY_PPM must be in 1..1000000"
#endif
#if MIN_PERIOD_TICKS < MIN_PULSE_TICKS + MIN_GAP_TICKS || MIN_PERIOD_TICKS > 0x7FFFFFFFUL
#error "MIN_PERIOD_US must be in MIN_PULSE_TICKS + MIN_GAP_TICKS (600 ticks: 300 us at 16 MHz, 600 us at 8 MHz) .. 2^31 - 1 ticks"
#endif
#if MAX_PULSE_TICKS < MIN_PULSE_TICKS
#error "MAX_PULSE_US below MIN_PULSE_TICKS (200 ticks: 100 us at 16 MHz, 200 us at 8 MHz)"
#endif

#endif
