/* Register access for the Timer1 edge driver (timer1.c).
 *
 * On the ATmega328P these are the plain special function registers.  In the host unit tests
 * (test/fake_avr.h) every read and write goes to a model of the datasheet's Timer1, its Output
 * Compare unit A (the OC1A latch, COM1A modes, FOC1A strobe) and port B, which must see each
 * write in the order the silicon would: a forced compare only acts with the COM1A bits present
 * when FOC1A is written (ATmega328P datasheet, 15.7.3 "Force Output Compare"), so timer1.c writes
 * registers through SFR_WRITE, never by read-modify-write macros the model could not observe. */
#ifndef LASERPI_SFR_H
#define LASERPI_SFR_H

#ifdef __AVR__
#include <avr/interrupt.h>
#include <avr/io.h>
#define SFR_READ(reg) (reg)
#define SFR_WRITE(reg, value) ((reg) = (value))
#define IRQ_DISABLE() cli()
#define IRQ_ENABLE() sei()
#define TIMER1_ISR(vector) ISR(vector)
#else
#include "fake_avr.h"
#endif

#endif
