/* ATmega328P hardware layer, besides Timer1 (src/timer1.c: the tick clock and the laser edges on
 * OC1A): boot, USART0 at 250 kbaud 8N1, the watchdog and the main loop.  All logic lives in
 * core.c; this file only moves bits.
 */
#include <avr/interrupt.h>
#include <avr/io.h>
#include <avr/wdt.h>

#include "config.h"
#include "core.h"
#include "hw.h"
#include "timer1.h"

static core_t core;

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

ISR(USART_RX_vect)
{
    uint8_t b = UDR0;
    uint8_t next = (uint8_t)((rx_head + 1) % RX_RING);
    if (next == rx_tail) {
        rx_lost = 1;
        return; /* a dropped delimiter leaves no tick: the main loop pops one per delimiter it reads */
    }
    rx_ring[rx_head] = b;
    rx_head = next;
    if (b == 0) {
        uint8_t dn = (uint8_t)((delim_head + 1) % DELIM_RING);
        if (dn != delim_tail) {
            delim_tick[delim_head] = hw_now();
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
    timer1_start(&core);
    UBRR0 = BAUD_UBRR; /* config.h: F_CPU / (16 * 250000) - 1, checked at compile time (16 MHz: 3, 8 MHz: 1) */
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
                uint8_t stamped = delim_tail != delim_head;
                if (stamped) {
                    tick = delim_tick[delim_tail];
                    delim_tail = (uint8_t)((delim_tail + 1) % DELIM_RING);
                }
                hw_irq_restore(s);
                /* More delimiters arrived than the ring holds (the Pi's frames keep coming while
                 * hw_tx sends a long reply: it waits on UDRE0 with interrupts on, and the receive
                 * interrupt runs whenever RXC0 is set and RXCIE0 and the I bit are on, ATmega328P
                 * datasheet, USART0, "Receive Compete Flag and Interrupt"): the ticks of the last ones were dropped, so a
                 * delimiter gets the tick of one that arrived after it, or none is left. Either
                 * way the time now is no earlier than its arrival and no later than its reply,
                 * the bounds PONG's rx tick promises; 0 would read as the clock going back. */
                if (!stamped)
                    tick = hw_now();
            }
            core_rx_byte(&core, b, tick);
        }
        core_poll(&core);
    }
}
