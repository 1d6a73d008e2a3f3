/* Compile-time configuration of the LaserPi co-MCU firmware.
 *
 * Time unit: one MCU tick = one Timer1 count = 8 CPU cycles at 16 MHz = 0.5 us.
 * The eye-safety envelope (MAX_PULSE_TICKS, MAX_DUTY_PPM, MIN_PERIOD_TICKS) is compiled in and
 * can only be changed by rebuilding (`make MAX_PULSE_TICKS=... MAX_DUTY_PPM=... MIN_PERIOD_TICKS=...`,
 * numbers from `python -m device.model.envelope`); nothing on the serial link can widen it.  Defaults, for the thesis laser (808 nm, 25 mW, 120 deg fan, 4 mm line, 1 mm
 * source): 17.4 ms maximum pulse, the pulse the thesis's Class 1 analysis was done for (mode-5
 * exposure, parameter t of sections 4.1.1/4.2; appendix B NOHD analysis: 25 mW keeps the NOHD
 * under 10 mm with 17.4 ms pulses), and 20 % maximum duty, just above the thesis operating
 * point (17.4 ms at 10 Hz = 17.4 %).  The sensor-model issue (device/model eye safety, IEC
 * 60825-1 AEL with the C5 reduction, docs/thesis-notes.md N1) computes the envelope for other lasers
 * and configurations; rebuild with its numbers.
 */
#ifndef LASERPI_CONFIG_H
#define LASERPI_CONFIG_H

#include <stdint.h>

#define TICKS_PER_SECOND 2000000UL /* 16 MHz / prescaler 8 */

#ifndef MAX_PULSE_TICKS
#define MAX_PULSE_TICKS 34800UL /* 17.4 ms */
#endif
#ifndef MAX_DUTY_PPM
#define MAX_DUTY_PPM 200000UL /* 20 % (parts per million of time) */
#endif
#ifndef MIN_PERIOD_TICKS
/* 90 ms: the shortest interval between the rises (and between the falls) of two consecutive
 * pulses, i.e. at most 11.1 pulses/s.  Short pulses (0.1-2.5 ms) are limited by the pulse-train
 * condition (C5), not by width or duty: under device/model/safety.py the thesis laser at 25 mW
 * passes 10 mm NOHD at 0.6 ms only up to ~12 Hz.  90 ms leaves the sensor's 10 Hz train (100 ms)
 * 10 ms of slack for period trims (+-1000 ppm = +-0.1 ms) and phase steps (up to 9.9 ms); the
 * whole envelope is verified by device/model/envelope.py (worst NOHD 9.8 mm at 0.625 ms). */
#define MIN_PERIOD_TICKS 180000UL
#endif
#ifndef HEARTBEAT_TIMEOUT_TICKS
/* 50 ms. Checked in the Timer1 overflow interrupt (every 32.8 ms) and in the main loop, so the
 * laser is off at most 50 + 32.8 = 82.8 ms after the last heartbeat, inside the 100 ms budget. */
#define HEARTBEAT_TIMEOUT_TICKS 100000UL
#endif

/* Shortest pulse and shortest gap the interrupt code can place without racing itself. */
#define MIN_PULSE_TICKS 200UL  /* 100 us: the fall is armed by the rise interrupt */
#define MIN_GAP_TICKS 400UL    /* 200 us */
/* An edge closer than this to "now" cannot be armed safely (interrupt latency allowance). */
#define ARM_MARGIN_TICKS 48UL  /* 24 us */
/* How far ahead a schedule may start: at least MIN_LEAD, at most MAX_LEAD ticks from now. */
#define MIN_LEAD_TICKS 200UL            /* 100 us */
#define MAX_LEAD_TICKS (10UL * TICKS_PER_SECOND) /* 10 s */
#define MAX_PATTERN_LEN 32

#define FIRMWARE_VERSION 2 /* 2: MIN_PERIOD_TICKS, INFO carries it */

/* A rise is armed on OC1A only when it is less than ARM_WINDOW_TICKS ahead, so that a stale
 * compare flag can never be mistaken for the rise (see hw_avr.c); farther rises are deferred. */
#define ARM_WINDOW_TICKS (65536UL - MAX_PULSE_TICKS - 2 * ARM_MARGIN_TICKS)
#if MAX_PULSE_TICKS + 2 * ARM_MARGIN_TICKS + 4096UL > 65536UL
#error "MAX_PULSE_TICKS must leave room in one 16-bit compare window (at most 30.7 ms)"
#endif
#if MAX_DUTY_PPM == 0 || MAX_DUTY_PPM > 1000000UL
#error "MAX_DUTY_PPM must be in 1..1000000"
#endif
#if MIN_PERIOD_TICKS < MIN_PULSE_TICKS + MIN_GAP_TICKS || MIN_PERIOD_TICKS > 0x7FFFFFFFUL
#error "MIN_PERIOD_TICKS must be in MIN_PULSE_TICKS + MIN_GAP_TICKS (600) .. 2^31 - 1"
#endif
#if MAX_PULSE_TICKS < MIN_PULSE_TICKS
#error "MAX_PULSE_TICKS below MIN_PULSE_TICKS"
#endif

#endif
