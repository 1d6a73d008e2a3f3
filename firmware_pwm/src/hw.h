/* The thin hardware layer the firmware logic (core.c) calls.  hw_avr.c implements it on the
 * ATmega328P (Timer1 output compare on OC1A, USART0); test/fake_hw.c implements it for the
 * host-compiled unit tests. */
#ifndef LASERPI_HW_H
#define LASERPI_HW_H
#include <stdint.h>

/* Current 64-bit MCU time in ticks.  Safe to call with interrupts enabled or disabled. */
uint64_t hw_now(void);
/* Arms the hardware to raise the laser pin at tick t (and to call core_rise_done then),
 * replacing a rise armed before.  Returns HW_ARMED; HW_LATE if t is too close or in the past
 * (nothing armed, the laser pin stays low); HW_IN_FLIGHT if the rise armed before is too close
 * to replace or has already happened (nothing changed: its pulse goes on). */
enum { HW_ARMED = 0, HW_LATE = 1, HW_IN_FLIGHT = 2 };
uint8_t hw_arm_rise(uint64_t t);
/* Laser pin low now, every pending edge disarmed, the output compare latch cleared.  Returns 1
 * and sets *rose_at if the armed rise had already happened, its interrupt not yet run (a pulse
 * the core was never told of, on the pin from *rose_at until now); 0 otherwise. */
uint8_t hw_force_off(uint64_t *rose_at);
/* Sends len bytes on the serial link (blocking). */
void hw_tx(const uint8_t *buf, uint8_t len);
/* Interrupt masking for the few sections shared with interrupt handlers. */
uint8_t hw_irq_save(void);
void hw_irq_restore(uint8_t saved);
#endif
