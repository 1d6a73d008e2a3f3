/* Timer1 edge driver: the 64-bit tick clock and the laser pulse edges on OC1A (PB1, Arduino D9),
 * implementing the timer half of hw.h (hw_now, hw_arm_rise, hw_force_off, hw_irq_save/restore)
 * and the Timer1 interrupts, which report edges to the core. */
#ifndef LASERPI_TIMER1_H
#define LASERPI_TIMER1_H
#include "core.h"

/* Interrupts disabled.  Starts Timer1 (normal mode, clk/8), laser pin low, the overflow
 * interrupt on; edges are reported to `core`. */
void timer1_start(core_t *core);
#endif
