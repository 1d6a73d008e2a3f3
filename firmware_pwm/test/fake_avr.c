/* The register model of test/fake_avr.h (see there for the datasheet sections it follows). */
#include "fake_avr.h"

#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "hw.h"
#include "timer1.h"

fake_avr_t fake;

static uint8_t com1a(void) { return (uint8_t)((fake.tccr1a >> COM1A0) & 3u); }

static void update_pin(void)
{
    uint8_t port = (uint8_t)((fake.portb >> PB1) & 1u);
    /* output: the compare latch if COM1A1:0 != 0, else PORTB1; input: the pull-up if PORTB1 */
    uint8_t level = (fake.ddrb & _BV(PB1)) && com1a() ? fake.oc1a : port;
    if (level == fake.pin)
        return;
    fake.pin = level;
    if (fake.n_edges < FAKE_MAX_EDGES) {
        fake.edge_t[fake.n_edges] = fake.now;
        fake.edge_level[fake.n_edges] = level;
        fake.n_edges++;
    }
}

/* What a compare match (or a FOC1A strobe) does to the latch, by COM1A1:0 (Table 16-1). */
static void compare_output_action(void)
{
    switch (com1a()) {
    case 1: fake.oc1a ^= 1u; break;
    case 2: fake.oc1a = 0; break;
    case 3: fake.oc1a = 1; break;
    default: break;
    }
    update_pin();
}

static uint64_t timer_count(void) { return fake.now - fake.timer_origin; }

/* Model time of the next timer clock after TCNT1 == v: the counter reaches v + 1 there. */
static uint64_t next_match(uint16_t v)
{
    uint64_t t = fake.timer_origin + (timer_count() & ~0xFFFFULL) + v + 1u;
    return t <= fake.now ? t + 0x10000u : t;
}

/* Runs the pending interrupts whose enable bits are set, by priority, while I is set. */
static void deliver(void)
{
    while (fake.sreg & _BV(SREG_I)) {
        void (*vector)(void);
        if ((fake.tifr1 & _BV(OCF1A)) && (fake.timsk1 & _BV(OCIE1A))) {
            fake.tifr1 &= (uint8_t)~_BV(OCF1A);
            vector = TIMER1_COMPA_vect;
        } else if ((fake.tifr1 & _BV(OCF1B)) && (fake.timsk1 & _BV(OCIE1B))) {
            fake.tifr1 &= (uint8_t)~_BV(OCF1B);
            vector = TIMER1_COMPB_vect;
        } else if ((fake.tifr1 & _BV(TOV1)) && (fake.timsk1 & _BV(TOIE1))) {
            fake.tifr1 &= (uint8_t)~_BV(TOV1);
            vector = TIMER1_OVF_vect;
        } else {
            return;
        }
        fake.sreg &= (uint8_t)~_BV(SREG_I);
        fake.in_isr++;
        if (fake.in_isr > 8) {
            fprintf(stderr, "fake_avr: interrupts nested more than 8 deep\n");
            abort();
        }
        vector();
        fake.in_isr--;
        fake.sreg |= _BV(SREG_I); /* reti */
    }
}

static void advance_to(uint64_t until)
{
    while (fake.now < until) {
        uint64_t ta = next_match(fake.ocr1a), tb = next_match(fake.ocr1b);
        uint64_t tov = fake.timer_origin + (timer_count() | 0xFFFFu) + 1u;
        uint64_t t = ta < tb ? ta : tb;
        t = t < tov ? t : tov;
        if (t > until) {
            fake.now = until;
            return;
        }
        fake.now = t;
        if (t == ta) {
            fake.tifr1 |= _BV(OCF1A);
            compare_output_action();
        }
        if (t == tb)
            fake.tifr1 |= _BV(OCF1B);
        if (t == tov)
            fake.tifr1 |= _BV(TOV1);
        deliver();
    }
}

/* The byte registers that read back what was written (NULL: one with its own rules). */
static uint8_t *plain_byte(enum fake_sfr r)
{
    switch (r) {
    case SFR_TCCR1A: return &fake.tccr1a;
    case SFR_TCCR1B: return &fake.tccr1b;
    case SFR_TIMSK1: return &fake.timsk1;
    case SFR_TIFR1: return &fake.tifr1;
    case SFR_PORTB: return &fake.portb;
    case SFR_DDRB: return &fake.ddrb;
    default: return NULL;
    }
}

uint16_t fake_sfr_read(enum fake_sfr r)
{
    uint8_t *byte = plain_byte(r);
    if (byte)
        return *byte;
    switch (r) {
    case SFR_SREG: return fake.sreg;
    case SFR_TCCR1C: return 0; /* FOC bits read as zero */
    case SFR_TCNT1:
        advance_to(fake.now + fake.tcnt_read_cost);
        return (uint16_t)timer_count();
    case SFR_OCR1A: return fake.ocr1a;
    case SFR_OCR1B: return fake.ocr1b;
    case SFR_PINB: return (uint16_t)((fake.portb & (uint8_t)~_BV(PB1)) | (fake.pin << PB1));
    default: abort();
    }
}

static void refuse(const char *what, uint16_t v)
{
    fprintf(stderr, "fake_avr: %s (0x%02x)\n", what, v);
    abort();
}

void fake_sfr_write(enum fake_sfr r, uint16_t v)
{
    if ((r == SFR_TCCR1A && (v & (_BV(WGM11) | _BV(WGM10)))) || (r == SFR_TCCR1B && (v & (_BV(WGM13) | _BV(WGM12)))))
        refuse("only normal mode is modelled", v);
    if (r == SFR_TCNT1 || r == SFR_PINB)
        refuse("the firmware never writes TCNT1 (it would block a match) or PINB (it toggles PORTB)", v);
    if (r == SFR_TIFR1) {
        fake.tifr1 &= (uint8_t)~v; /* writing one clears a flag */
        return;
    }
    uint8_t *byte = plain_byte(r);
    if (byte)
        *byte = (uint8_t)v;
    switch (r) {
    case SFR_SREG: fake.sreg = (uint8_t)v; deliver(); break;
    case SFR_TIMSK1: deliver(); break;
    case SFR_TCCR1C:
        if (v & _BV(FOC1A))
            compare_output_action(); /* no flag, no interrupt */
        break;
    case SFR_OCR1A: fake.ocr1a = v; break;
    case SFR_OCR1B: fake.ocr1b = v; break;
    default: break;
    }
    update_pin(); /* TCCR1A, PORTB and DDRB switch the pin at once */
}

void fake_cli(void) { fake.sreg &= (uint8_t)~_BV(SREG_I); }

void fake_sei(void)
{
    fake.sreg |= _BV(SREG_I);
    deliver();
}

void fake_boot(core_t *c, uint8_t reset_cause)
{
    /* the reset: registers and latch cleared, PB1 an input */
    fake.sreg = fake.tccr1a = fake.tccr1b = fake.timsk1 = fake.tifr1 = fake.portb = fake.ddrb = 0;
    fake.ocr1a = fake.ocr1b = 0;
    fake.oc1a = 0;
    fake.timer_origin = fake.now;
    update_pin();
    /* hw_avr.c: early_init, then main */
    fake.ddrb |= _BV(PB1);
    update_pin();
    fake.core = c;
    core_init(c, reset_cause);
    timer1_start(c);
    fake_sei();
}

void fake_reset(core_t *c, uint64_t now, uint8_t reset_cause)
{
    memset(&fake, 0, sizeof fake);
    fake.now = now;
    fake_boot(c, reset_cause);
    fake.timer_origin = 0; /* the timer counted from tick 0: hw_now() == now */
}

void fake_run(uint64_t until) { advance_to(until); }

void hw_tx(const uint8_t *buf, uint8_t len)
{
    if (fake.tx_len + len <= FAKE_TX_MAX) {
        memcpy(fake.tx + fake.tx_len, buf, len);
        fake.tx_len += len;
    }
}

void fake_send(core_t *c, uint8_t type, uint16_t seq, const uint8_t *payload, uint8_t len)
{
    uint8_t wire[FRAME_WIRE_MAX];
    uint8_t n = link_encode(type, seq, 0, payload, len, wire);
    for (uint8_t i = 0; i < n; i++)
        core_rx_byte(c, wire[i], hw_now());
}

int fake_reply(frame_t *f)
{
    uint32_t start = fake.tx_read;
    for (uint32_t i = start; i < fake.tx_len; i++) {
        if (fake.tx[i] == 0) {
            fake.tx_read = i + 1;
            return link_decode(fake.tx + start, (uint16_t)(i - start), f) == LINK_OK;
        }
    }
    return 0;
}
