/* laserpi_harness: runs the real firmware ELF on libsimavr (ATmega328P, 16 or 8 MHz).
 *
 *   laserpi_harness FIRMWARE.elf [--cpu-hz HZ] [--stepped] [--realtime FACTOR] [--trace-interrupts]
 *
 * --cpu-hz: the CPU clock the ELF was built for (the Makefile's F_CPU; default 16000000, the
 * 8 MHz board's ELF needs 8000000).  The ELF does not record it; given the wrong one, the firmware
 * runs at the wrong speed in simulated seconds.  It sets simavr's avr->frequency, from which
 * simavr times the UART (avr_uart.c: the baud rate from UBRR and the clock, the byte time from the
 * baud rate) and the watchdog (avr_watchdog.c: its 128 kHz oscillator's periods in CPU cycles), and
 * here the free-running mode's boot, step and wall-clock pacing.  The events below are in CPU
 * cycles and the laser pin is computed in cycles (a Timer1 tick is 8 cycles at every clock:
 * prescaler 8), so they need no conversion.
 * Free-running mode (default): the UART is bridged to a pseudo-terminal whose path is printed
 * first as "pty /dev/pts/N"; open it with pyserial like a real serial port.  Simulated time is
 * paced to FACTOR x wall-clock time (default 1.0; 0 = as fast as possible).  The path is
 * printed after 5 ms of simulated boot, once the firmware listens.
 * Stepped mode (--stepped, used by the tests): simulated time only advances on command, so runs
 * are deterministic whatever the load of the machine.  stdin takes lines
 *     rx <hex bytes>     queue bytes for the MCU's UART receiver
 *     run <cycles>       simulate that many CPU cycles, then answer "at <cycle>"
 *     quit
 * and the UART's output comes back on stdout as "tx <hex bytes>" lines.
 *     reset <power|wdt>  reset the MCU now, as a power-on or a watchdog reset does (simavr's
 *                        avr_reset, then PORF or WDRF in MCUSR, as avr_watchdog.c does)
 * Both modes report on stdout, one event a line, with the CPU cycle count (62.5 ns at 16 MHz, 125 ns at 8 MHz):
 *     edge <cycle> <level>   the laser pin PB1/OC1A changed level: the true pin, computed here
 *                            from the registers (see "The laser pin" below), not simavr's
 *     rxdelim <cycle>        a frame delimiter (0x00) entered the MCU's UART receiver
 *     int <cycle> <vector>   (--trace-interrupts) the CPU entered interrupt vector n, or
 *                            returned to vector 0 = main code
 *     timer1 <cycle> <tccr1b> TCCR1B was written: the timer counts from this cycle, so the
 *                            Timer1 count at cycle c is (c - cycle) / 8 with prescaler 8
 * simavr's UART is not timed like a physical line (bytes move in batches), so link latency is
 * not measured here; pin edges and timer counts are cycle-exact.
 *
 * The laser pin.  simavr 1.6 does not model the output compare latch: its OC1A pin follows
 * PORTB (a toggle reads PORTB1), it re-applies set/clear outputs at every overflow as in PWM
 * modes, and it ignores FOC1A.  So the harness computes the pin itself from what the CPU writes
 * (every write to DDRB, PORTB, TCCR1A, TCCR1B, TCCR1C, OCR1AH/L, hooked before simavr's own
 * handlers) and the timer count, by the ATmega328P datasheet (Atmel-8271): 16.3 Accessing
 * 16-bit Registers (OCR1AH goes to TEMP, the OCR1AL write moves both); 16.7 Output Compare
 * Units (TCNT1 == OCR1A is a match; the output acts at the next timer clock, count OCR1A + 1);
 * 16.7.1 / 16.11.3 Force Output Compare (FOC1A acts on the latch as a match, by the COM1A1:0
 * present then); 16.8 Compare Match Output Unit, Table 16-1 (the OC1A latch: 01 toggle, 10
 * clear, 11 set, 00 no action; the pin shows the latch while COM1A1:0 != 0, PORTB1 otherwise,
 * and only while DDRB1 is set; the latch survives COM1A changes and is cleared by reset);
 * 14.2 Ports (an input with PORTB1 = 1 has its pull-up on: counted as high, never safe).
 * Timer1 must run in normal mode at clk/8 (the firmware's only setting); the count starts at
 * the TCCR1B write, as the tests' timer_count_at assumes.  simavr's timer is used for nothing
 * here but the firmware's own interrupts.
 */
#define _GNU_SOURCE
#include <errno.h>
#include <fcntl.h>
#include <inttypes.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <termios.h>
#include <time.h>
#include <unistd.h>

#include "avr_ioport.h"
#include "avr_uart.h"
#include "sim_avr.h"
#include "sim_elf.h"
#include "sim_interrupts.h"
#include "sim_irq.h"

#define QUEUE 65536

static avr_t *avr;
static uint32_t cpu_hz = 16000000; /* --cpu-hz */
static int stepped;
static int pty_fd = -1;
static uint8_t in_q[QUEUE];
static size_t in_head, in_tail;
static int uart_xoff;
static int pin_level; /* last reported laser pin level */
static char tx_line[8192];
static size_t tx_line_len;
static avr_irq_t *uart_in;

static void logger(avr_t *a, const int level, const char *fmt, va_list ap)
{
    (void)a;
    if (level <= LOG_WARNING)
        vfprintf(stderr, fmt, ap);
}

static void flush_tx_line(void)
{
    if (tx_line_len) {
        printf("tx %.*s\n", (int)tx_line_len, tx_line);
        tx_line_len = 0;
    }
}

static void on_uart_out(struct avr_irq_t *irq, uint32_t value, void *param)
{
    (void)irq;
    (void)param;
    uint8_t b = (uint8_t)value;
    if (stepped) {
        if (tx_line_len + 2 >= sizeof tx_line)
            flush_tx_line();
        tx_line_len += (size_t)sprintf(tx_line + tx_line_len, "%02x", b);
    } else if (pty_fd >= 0) {
        if (write(pty_fd, &b, 1) < 0 && errno != EAGAIN)
            perror("harness: pty write");
    }
}

static void on_xon(struct avr_irq_t *irq, uint32_t value, void *param)
{
    (void)irq; (void)value; (void)param;
    uart_xoff = 0;
}

static void on_xoff(struct avr_irq_t *irq, uint32_t value, void *param)
{
    (void)irq; (void)param;
    if (value)
        uart_xoff = 1;
}

/* ---- the true laser pin (file comment) ---------------------------------------------------- */
enum { REG_DDRB = 0x24, REG_PORTB = 0x25, REG_TCCR1A = 0x80, REG_TCCR1B = 0x81, REG_TCCR1C = 0x82,
       REG_OCR1AL = 0x88, REG_OCR1AH = 0x89 };
static struct {
    uint8_t ddrb, portb, tccr1a, temp, oc1a;
    uint16_t ocr1a;
    int running;          /* Timer1 counting at clk/8 */
    uint64_t start;       /* cycle of the TCCR1B write that started it */
    uint64_t next_match;  /* cycle at which the next compare match acts (count OCR1A + 1) */
} pin;
static void (*simavr_reset)(avr_t *);

static void pin_update(uint64_t cycle)
{
    int output = (pin.ddrb >> 1) & 1, port = (pin.portb >> 1) & 1;
    int level = output && (pin.tccr1a >> 6) ? pin.oc1a : port;
    if (level != pin_level) {
        pin_level = level;
        printf("edge %" PRIu64 " %d\n", cycle, level);
    }
}

static void pin_compare_action(uint64_t cycle) /* a match or a FOC1A strobe: Table 16-1 */
{
    switch (pin.tccr1a >> 6) {
    case 1: pin.oc1a ^= 1; break;
    case 2: pin.oc1a = 0; break;
    case 3: pin.oc1a = 1; break;
    }
    pin_update(cycle);
}

static void pin_schedule_match(uint64_t after) /* the first match acting after cycle `after` */
{
    if (!pin.running)
        return;
    uint64_t count = (after - pin.start) / 8, base = count & ~0xFFFFULL;
    uint64_t at = base + pin.ocr1a + 1;
    if (pin.start + at * 8 <= after)
        at += 0x10000;
    pin.next_match = pin.start + at * 8;
}

static void pin_advance(uint64_t cycle) /* every match acting up to and including `cycle` */
{
    while (pin.running && pin.next_match <= cycle) {
        uint64_t at = pin.next_match;
        pin_compare_action(at);
        pin_schedule_match(at);
    }
}

/* simavr's own write handler of each watched register (NULL: the core just stores the byte) */
static struct { avr_io_write_t c; void *param; } simavr_write[0x100];

static void on_register_write(struct avr_t *a, avr_io_addr_t addr, uint8_t v, void *param)
{
    (void)param;
    if (simavr_write[addr].c)
        simavr_write[addr].c(a, addr, v, simavr_write[addr].param);
    else
        a->data[addr] = v;
    pin_advance(a->cycle);
    switch (addr) {
    case REG_DDRB: pin.ddrb = v; break;
    case REG_PORTB: pin.portb = v; break;
    case REG_TCCR1A:
        if (v & 3)
            fprintf(stderr, "harness: TCCR1A = 0x%02x: only normal mode is modelled\n", v);
        pin.tccr1a = v;
        break;
    case REG_TCCR1B:
        if ((v & 0x18) || ((v & 7) != 0 && (v & 7) != 2))
            fprintf(stderr, "harness: TCCR1B = 0x%02x: only normal mode at clk/8 is modelled\n", v);
        pin.running = (v & 7) == 2;
        pin.start = a->cycle;
        pin_schedule_match(a->cycle);
        break;
    case REG_TCCR1C:
        if (v & 0x80)
            pin_compare_action(a->cycle);
        break;
    case REG_OCR1AH: pin.temp = v; break;
    case REG_OCR1AL:
        pin.ocr1a = (uint16_t)(pin.temp << 8 | v);
        pin_schedule_match(a->cycle);
        break;
    }
    pin_update(a->cycle);
}

static void on_reset(avr_t *a) /* every reset: the registers and the latch are cleared */
{
    if (simavr_reset)
        simavr_reset(a);
    pin_advance(a->cycle);
    memset(&pin, 0, sizeof pin);
    pin_update(a->cycle);
}

/* Our handler in front of simavr's (set directly: simavr 1.6's avr_register_io_write has too
 * few shared slots for seven registers). */
static void hook_register(avr_io_addr_t addr)
{
    avr_io_addr_t io = AVR_DATA_TO_IO(addr);
    simavr_write[addr].c = avr->io[io].w.c;
    simavr_write[addr].param = avr->io[io].w.param;
    avr->io[io].w.c = on_register_write;
    avr->io[io].w.param = NULL;
}

static void on_interrupt(struct avr_irq_t *irq, uint32_t value, void *param)
{
    (void)irq; (void)param;
    printf("int %" PRIu64 " %u\n", (uint64_t)avr->cycle, value);
}

static void on_tccr1b(struct avr_irq_t *irq, uint32_t value, void *param)
{
    (void)irq; (void)param;
    printf("timer1 %" PRIu64 " %u\n", (uint64_t)avr->cycle, value & 0xFF);
}

static void queue_bytes(const uint8_t *b, size_t n)
{
    for (size_t i = 0; i < n; i++) {
        size_t next = (in_head + 1) % QUEUE;
        if (next == in_tail) {
            fprintf(stderr, "harness: input queue full, byte dropped\n");
            return;
        }
        in_q[in_head] = b[i];
        in_head = next;
    }
}

static void feed_uart(void)
{
    while (!uart_xoff && in_tail != in_head) {
        uint8_t b = in_q[in_tail];
        in_tail = (in_tail + 1) % QUEUE;
        if (b == 0)
            printf("rxdelim %" PRIu64 "\n", (uint64_t)avr->cycle);
        avr_raise_irq(uart_in, b);
    }
}

static int run_cycles(uint64_t cycles)
{
    uint64_t end = avr->cycle + cycles;
    while (avr->cycle < end) {
        feed_uart();
        int state = avr_run(avr);
        if (state == cpu_Done || state == cpu_Crashed) {
            printf("crash %" PRIu64 " %d\n", (uint64_t)avr->cycle, state);
            fflush(stdout);
            return -1;
        }
    }
    return 0;
}

static void no_sleep(avr_t *a, avr_cycle_count_t how_long) { (void)a; (void)how_long; }

static int open_pty(void)
{
    int fd = posix_openpt(O_RDWR | O_NOCTTY);
    if (fd < 0 || grantpt(fd) || unlockpt(fd))
        return -1;
    struct termios t;
    if (tcgetattr(fd, &t) == 0) {
        cfmakeraw(&t);
        tcsetattr(fd, TCSANOW, &t);
    }
    /* keep one slave descriptor open so that reads do not fail while no client is attached */
    if (open(ptsname(fd), O_RDWR | O_NOCTTY) < 0)
        return -1;
    fcntl(fd, F_SETFL, fcntl(fd, F_GETFL) | O_NONBLOCK);
    return fd;
}

static double wall_seconds(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (double)ts.tv_sec + ts.tv_nsec * 1e-9;
}

static int hexval(int c)
{
    if (c >= '0' && c <= '9') return c - '0';
    if (c >= 'a' && c <= 'f') return c - 'a' + 10;
    if (c >= 'A' && c <= 'F') return c - 'A' + 10;
    return -1;
}

static int stepped_loop(void)
{
    static char line[QUEUE * 2 + 64];
    while (fgets(line, sizeof line, stdin)) {
        if (strncmp(line, "rx ", 3) == 0) {
            uint8_t buf[QUEUE / 2];
            size_t n = 0;
            for (char *p = line + 3; hexval(p[0]) >= 0 && hexval(p[1]) >= 0 && n < sizeof buf; p += 2)
                buf[n++] = (uint8_t)(hexval(p[0]) * 16 + hexval(p[1]));
            queue_bytes(buf, n);
        } else if (strncmp(line, "run ", 4) == 0) {
            uint64_t cycles = strtoull(line + 4, NULL, 10);
            int r = run_cycles(cycles);
            pin_advance(avr->cycle);
            flush_tx_line();
            printf("at %" PRIu64 "\n", (uint64_t)avr->cycle);
            fflush(stdout);
            if (r)
                return 1;
        } else if (strncmp(line, "reset ", 6) == 0) {
            int wdt = strncmp(line + 6, "wdt", 3) == 0;
            avr_reset(avr);
            avr_regbit_set(avr, wdt ? avr->reset_flags.wdrf : avr->reset_flags.porf);
        } else if (strncmp(line, "quit", 4) == 0) {
            return 0;
        } else {
            fprintf(stderr, "harness: unknown command: %s", line);
            return 2;
        }
    }
    return 0;
}

static int free_loop(double realtime)
{
    pty_fd = open_pty();
    if (pty_fd < 0) {
        perror("harness: cannot open a pseudo-terminal");
        return 1;
    }
    /* boot first: the MCU's UART drops bytes until the firmware has enabled its receiver */
    if (run_cycles(cpu_hz / 200))
        return 1;
    printf("pty %s\n", ptsname(pty_fd));
    fflush(stdout);
    double t0 = wall_seconds();
    uint64_t c0 = avr->cycle;
    for (;;) {
        uint8_t buf[256];
        ssize_t n = read(pty_fd, buf, sizeof buf);
        if (n > 0)
            queue_bytes(buf, (size_t)n);
        if (run_cycles(cpu_hz / 10000)) /* 100 us of simulated time */
            return 1;
        pin_advance(avr->cycle);
        fflush(stdout);
        if (realtime > 0) {
            double ahead = (double)(avr->cycle - c0) / cpu_hz / realtime - (wall_seconds() - t0);
            if (ahead > 0.001)
                usleep((useconds_t)(ahead * 1e6));
        }
    }
}

int main(int argc, char **argv)
{
    const char *elf = NULL;
    double realtime = 1.0;
    int trace_interrupts = 0;
    for (int i = 1; i < argc; i++) {
        if (strcmp(argv[i], "--stepped") == 0)
            stepped = 1;
        else if (strcmp(argv[i], "--trace-interrupts") == 0)
            trace_interrupts = 1;
        else if (strcmp(argv[i], "--realtime") == 0 && i + 1 < argc)
            realtime = atof(argv[++i]);
        else if (strcmp(argv[i], "--cpu-hz") == 0 && i + 1 < argc) {
            char *end;
            unsigned long long hz = strtoull(argv[++i], &end, 10);
            if (*end || hz < 1000000 || hz > 20000000) { /* the ATmega328P runs at most 20 MHz */
                fprintf(stderr, "harness: --cpu-hz %s: give the ELF's F_CPU in Hz, 1000000..20000000\n", argv[i]);
                return 2;
            }
            cpu_hz = (uint32_t)hz;
        }
        else if (argv[i][0] != '-' && !elf)
            elf = argv[i];
        else {
            fprintf(stderr, "usage: %s FIRMWARE.elf [--cpu-hz HZ] [--stepped] [--realtime FACTOR] [--trace-interrupts]\n", argv[0]);
            return 2;
        }
    }
    if (!elf) {
        fprintf(stderr, "usage: %s FIRMWARE.elf [--cpu-hz HZ] [--stepped] [--realtime FACTOR] [--trace-interrupts]\n", argv[0]);
        return 2;
    }
    avr_global_logger_set(logger);
    elf_firmware_t fw;
    memset(&fw, 0, sizeof fw);
    if (elf_read_firmware(elf, &fw) != 0) {
        fprintf(stderr, "harness: cannot read %s\n", elf);
        return 1;
    }
    avr = avr_make_mcu_by_name(fw.mmcu[0] ? fw.mmcu : "atmega328p");
    if (!avr) {
        fprintf(stderr, "harness: simavr has no model of %s\n", fw.mmcu);
        return 1;
    }
    avr_init(avr);
    avr->frequency = cpu_hz;
    avr->sleep = no_sleep;
    avr_load_firmware(avr, &fw);
    avr->frequency = cpu_hz;

    uint32_t flags = 0; /* no stdio echo of the UART, no host sleeps while the firmware polls */
    avr_ioctl(avr, AVR_IOCTL_UART_SET_FLAGS('0'), &flags);
    uart_in = avr_io_getirq(avr, AVR_IOCTL_UART_GETIRQ('0'), UART_IRQ_INPUT);
    avr_irq_register_notify(avr_io_getirq(avr, AVR_IOCTL_UART_GETIRQ('0'), UART_IRQ_OUTPUT), on_uart_out, NULL);
    avr_irq_register_notify(avr_io_getirq(avr, AVR_IOCTL_UART_GETIRQ('0'), UART_IRQ_OUT_XON), on_xon, NULL);
    avr_irq_register_notify(avr_io_getirq(avr, AVR_IOCTL_UART_GETIRQ('0'), UART_IRQ_OUT_XOFF), on_xoff, NULL);
    simavr_reset = avr->reset;
    avr->reset = on_reset;
    const avr_io_addr_t watched[] = {REG_DDRB, REG_PORTB, REG_TCCR1A, REG_TCCR1B, REG_TCCR1C, REG_OCR1AH, REG_OCR1AL};
    for (size_t i = 0; i < sizeof watched / sizeof watched[0]; i++)
        hook_register(watched[i]);
    avr_irq_register_notify(avr_iomem_getirq(avr, 0x81 /* TCCR1B */, NULL, AVR_IOMEM_IRQ_ALL), on_tccr1b, NULL);

    if (trace_interrupts)
        avr_irq_register_notify(avr->interrupts.irq + AVR_INT_IRQ_RUNNING, on_interrupt, NULL);

    return stepped ? stepped_loop() : free_loop(realtime);
}
