/* The thin hardware layer the firmware logic (core.c) calls.  hw_avr.c implements it on the
 * ATmega328P (Timer1 output compare on OC1A, USART0); test/fake_hw.c implements it for the
 * host-compiled unit tests. */
#ifndef LASERPI_HW_H
#define LASERPI_HW_H
#include <stdint.h>

/* Current 64-bit MCU time in ticks.  Safe to call with interrupts enabled or disabled. */
uint64_t hw_now(void);
/* Arms the hardware to raise the laser pin at tick t (and to call core_rise_done then).
 * Returns 0 if armed, 1 if t is too close or in the past (nothing armed). */
uint8_t hw_arm_rise(uint64_t t);
/* Laser pin low now, every pending edge disarmed.  Returns 1 if the pin was high. */
uint8_t hw_force_off(void);
/* Sends len bytes on the serial link (blocking). */
void hw_tx(const uint8_t *buf, uint8_t len);
/* Interrupt masking for the few sections shared with interrupt handlers. */
uint8_t hw_irq_save(void);
void hw_irq_restore(uint8_t saved);
#endif
