/* Firmware logic: command handling, pulse scheduler, eye-safety interlock (no AVR registers).
 *
 * Duty rule (interlock_min_gap).  For every two consecutive pulses of widths w1, w2 separated by
 * an off time g, the firmware requires  g >= max(w1, w2) * (1 - D) / D  with D = MAX_DUTY_PPM.
 * For a regular train (every k-th frame lit, frame period P) this is exactly the usual duty
 * limit w <= D * k * P; for irregular patterns it is stricter than the average duty, never
 * looser.  It is checked when a SCHEDULE or TRIM arrives (refused with a reason) and again, at
 * run time, on the actual edge times before every rise is armed, so no sequence of trims or
 * schedules can build a denser train: a violation at run time is a fault (laser off).
 * Width: every pulse is armed to fall at rise + width <= MAX_PULSE_TICKS; a guard in the timer
 * overflow interrupt and the main loop switches the laser off if a pulse is ever seen longer.
 *
 * Rate rule (interlock_rate_gap).  With P = MIN_PERIOD_TICKS, two consecutive pulses of widths
 * w1 (rise r1, fall f1 = r1 + w1) and w2 (rise r2 = f1 + g, fall f2 = r2 + w2) need
 *     g >= P - min(w1, w2).
 * Claim: then r2 - r1 >= P and f2 - f1 >= P, whatever w1 and w2 are.  Proof: r2 - r1 = w1 + g
 * >= P + w1 - min(w1, w2) >= P, and f2 - f1 = g + w2 >= P + w2 - min(w1, w2) >= P.  (A rule on
 * one width only would not do: g >= P - w1 lets a wide pulse follow a narrow one with its fall
 * less than P after the narrow one's fall; g >= P - w2 the converse for rises.)  Consecutive
 * rises, and consecutive falls, being each at least P apart, any time window of length L holds at
 * most floor(L / P) + 1 rises (and as many falls): no more pulses than a regular train of period P
 * holds, which is what device/model/envelope.py verifies against the safety model for every width
 * the envelope allows (there a hair below P, so that floor(L / P) + 1 is counted even when L / P is
 * whole).  Conservative across schedule changes: the run-time check takes w1 from the last pulse's
 * actual edges (last_fall - last_rise, also when it was cut short) and w2 from the pulse about to
 * be armed, and it runs before every rise is armed whichever path computed it (SCHEDULE after a
 * STOP, a TRIM's phase step or period change, the next slot at a fall); the acceptance checks of
 * SCHEDULE and TRIM apply the same rule first and refuse with NACK_ENVELOPE_RATE.
 */
#include "core.h"
#include "config.h"
#include "hw.h"

uint32_t interlock_min_gap(uint32_t width)
{
    uint64_t num = (uint64_t)width * (1000000UL - MAX_DUTY_PPM);
    uint64_t gap = (num + MAX_DUTY_PPM - 1) / MAX_DUTY_PPM;
    if (gap < MIN_GAP_TICKS)
        gap = MIN_GAP_TICKS;
    return gap > 0xFFFFFFFFULL ? 0xFFFFFFFFUL : (uint32_t)gap;
}

uint32_t interlock_rate_gap(uint32_t w1, uint32_t w2)
{
    uint32_t narrow = w1 < w2 ? w1 : w2;
    return MIN_PERIOD_TICKS > narrow ? MIN_PERIOD_TICKS - narrow : 0;
}

/* Width of the last pulse from its actual edges (the longest possible if none is complete). */
static uint32_t actual_width(uint64_t rise, uint64_t fall)
{
    return fall >= rise && fall - rise < 0xFFFFFFFFULL ? (uint32_t)(fall - rise) : 0xFFFFFFFFUL;
}

uint8_t pattern_min_spacing(uint32_t mask, uint8_t n)
{
    uint8_t best = 0;
    for (uint8_t i = 0; i < n; i++) {
        if (!((mask >> i) & 1u))
            continue;
        for (uint8_t d = 1; d <= n; d++) {
            if ((mask >> ((i + d) % n)) & 1u) {
                if (best == 0 || d < best)
                    best = d;
                break;
            }
        }
    }
    return best;
}

/* The interlock's memory across a reset.  A reset (power-on, brown-out, watchdog, the external
 * pin) erases the last pulse's edges, but not the eye's exposure to it: the pulse before the reset
 * may have ended at the reset itself.  So the firmware boots as if a pulse of the longest width had
 * just fallen at tick 0 and as if it had been of zero width for the rate rule: the first rise must
 * then come at least max(interlock_min_gap(MAX_PULSE_TICKS), MIN_PERIOD_TICKS) after tick 0.
 * Tick 0 is when timer1_start() started Timer1, after the reset: at the reset every I/O register,
 * TCCR1B included, returns to its initial value (datasheet 11.1 "Resetting the AVR": "All I/O
 * Registers are set to their initial value"; 16.11.2: TCCR1B initial value 0, clock stopped), and
 * the pin is an input, held low by the driver's pull-down, from the reset on (11.1: "The I/O ports
 * of the AVR are immediately reset to their initial state when a reset source goes active").  So
 * tick 0 is never before the last pre-reset fall, and both rules hold across the reset with the
 * pre-reset pulse as w1: its rise and fall were at or before tick 0 (file comment's proof with
 * w1 = 0 and a gap measured from tick 0).  The cost: nothing can light in the first
 * MIN_PERIOD_TICKS after a boot (90 ms in the default build); the Pi schedules its first pulse
 * well after the INFO that a boot sends. */
void core_init(core_t *c, uint8_t reset_cause)
{
    uint8_t *p = (uint8_t *)c;
    for (uint16_t i = 0; i < sizeof *c; i++)
        p[i] = 0;
    c->reset_cause = reset_cause;
    c->state = STATE_IDLE;
    c->have_last = 1;                                   /* last_rise = last_fall = 0: tick 0 */
    c->last_min_gap = interlock_min_gap(MAX_PULSE_TICKS);
}

/* ---- replies ---------------------------------------------------------------------------- */

static void reply(uint8_t type, uint16_t seq, const uint8_t *payload, uint8_t len)
{
    uint8_t out[FRAME_WIRE_MAX];
    uint8_t n = link_encode(type, seq, 0, payload, len, out);
    hw_tx(out, n);
}

static void ack(uint8_t acked, uint16_t seq, uint32_t info)
{
    uint8_t p[LEN_ACK];
    p[0] = acked;
    put_u32(p + 1, info);
    reply(MSG_ACK, seq, p, sizeof p);
}

static void nack(uint8_t acked, uint16_t seq, uint8_t reason, uint32_t detail)
{
    uint8_t p[LEN_NACK];
    p[0] = acked;
    p[1] = reason;
    put_u32(p + 2, detail);
    reply(MSG_NACK, seq, p, sizeof p);
}

static void refuse(core_t *c, uint8_t acked, uint16_t seq, uint8_t reason, uint32_t detail)
{
    c->refused++;
    nack(acked, seq, reason, detail);
}

void core_send_info(core_t *c, uint16_t seq)
{
    uint8_t p[LEN_INFO];
    p[0] = FIRMWARE_VERSION;
    p[1] = c->reset_cause;
    put_u16(p + 2, (uint16_t)(HEARTBEAT_TIMEOUT_TICKS / (TICKS_PER_SECOND / 1000)));
    put_u32(p + 4, MAX_PULSE_TICKS);
    put_u32(p + 8, MAX_DUTY_PPM);
    put_u32(p + 12, TICKS_PER_SECOND);
    put_u32(p + 16, MIN_PERIOD_TICKS);
    reply(MSG_INFO, seq, p, sizeof p);
}

static void send_status(core_t *c, uint16_t seq)
{
    uint8_t p[LEN_STATUS];
    uint8_t s = hw_irq_save();
    p[0] = c->state;
    p[1] = c->faults;
    p[2] = c->reset_cause;
    p[3] = c->stream_edges;
    put_u32(p + 4, c->frames_ok);
    put_u16(p + 8, c->crc_errors);
    put_u16(p + 10, c->malformed);
    put_u16(p + 12, c->unknown);
    put_u16(p + 14, c->refused);
    put_u16(p + 16, c->late);
    put_u32(p + 18, c->pulses);
    put_u32(p + 22, c->pin_high ? c->cur_index : c->next_index);
    put_u64(p + 26, c->last_rise);
    put_u64(p + 34, c->last_fall);
    hw_irq_restore(s);
    reply(MSG_STATUS, seq, p, sizeof p);
}

/* ---- edges (interrupt context) ---------------------------------------------------------- */

static void record_fall(core_t *c, uint64_t t, uint8_t flags)
{
    c->pin_high = 0;
    c->last_fall = t;
    c->have_last = 1;
    c->last_min_gap = c->min_gap;
    c->pulses++;
    if (c->stream_edges) {
        uint8_t slot = (uint8_t)((c->edge_head + c->edge_count) % EDGE_QUEUE);
        if (c->edge_count == EDGE_QUEUE) { /* full: drop the oldest, keep the newest */
            c->edge_head = (uint8_t)((c->edge_head + 1) % EDGE_QUEUE);
            c->edge_count--;
        }
        c->edges[slot].index = c->cur_index;
        c->edges[slot].rise = c->cur_rise;
        c->edges[slot].fall = t;
        c->edges[slot].flags = flags;
        c->edge_count++;
    }
}

/* The run-time interlock, on the actual edges: may a pulse of the current width rise at `rise`
 * after the last real fall?  Returns 0 if so, else the fault: FAULT_DUTY (duty rule) or
 * FAULT_RATE (rate rule, file comment).  No division: it runs in the fall interrupt.  Checked
 * before every rise is armed, whatever path computed it. */
static uint8_t gap_fault(const core_t *c, uint64_t rise)
{
    if (!c->have_last)
        return 0;
    uint32_t need = c->last_min_gap > c->min_gap ? c->last_min_gap : c->min_gap;
    if (rise <= c->last_fall || rise - c->last_fall < need)
        return FAULT_DUTY;
    if (rise - c->last_fall < interlock_rate_gap(actual_width(c->last_rise, c->last_fall), c->width))
        return FAULT_RATE;
    return 0;
}

/* Interrupts disabled: arms the next rise after the run-time interlock; a fault otherwise. */
static void arm_next(core_t *c)
{
    uint8_t fault = gap_fault(c, c->next_rise);
    if (fault)
        core_fault(c, fault);
    else if (hw_arm_rise(c->next_rise))
        core_fault(c, FAULT_LATE);
}

/* Interrupts disabled.  Ends the pulse on the pin, if any, and records it as cut: also one whose
 * rise the hardware made while the caller ran with interrupts off (its interrupt never came), so
 * the interlock counts every pulse the pin had.  The fall is the time read after the cut: never
 * earlier than the pin's. */
static void cut_pulse(core_t *c)
{
    uint64_t rose_at;
    uint8_t was_high = c->pin_high;
    if (hw_force_off(&rose_at) && !was_high) {
        core_rise_done(c, rose_at);
        was_high = 1;
    }
    if (was_high)
        record_fall(c, hw_now(), EDGE_CUT);
}

void core_fault(core_t *c, uint8_t flag)
{
    cut_pulse(c);
    c->faults |= flag;
    c->state = STATE_FAULT;
    c->trim_pending = 0;
}

uint64_t core_rise_done(core_t *c, uint64_t t)
{
    c->pin_high = 1;
    c->cur_rise = t;
    c->cur_index = c->next_index;
    c->cur_pos = c->next_pos;
    c->last_rise = t;
    return t + c->width;
}

uint8_t core_fall_done(core_t *c, uint64_t t, uint8_t flags, uint64_t *next)
{
    if (flags & EDGE_FALL_FORCED)
        c->late++;
    record_fall(c, t, flags);
    if (c->state != STATE_RUNNING)
        return 0;
    /* A pending trim moves the start of the slot after this pulse by trim_phase (that slot
     * still follows at the old period) and sets the period for the slots after it. */
    uint32_t step = c->period;
    int64_t phase = 0;
    if (c->trim_pending) {
        c->period = (uint32_t)((int64_t)c->period + c->trim_period);
        phase = c->trim_phase;
        c->trim_pending = 0;
        c->trim_phase = 0;
        c->trim_period = 0;
    }
    uint32_t index = c->cur_index + 1;
    uint8_t pos = (uint8_t)(c->cur_pos + 1 == c->n ? 0 : c->cur_pos + 1);
    uint64_t rise = (uint64_t)((int64_t)(c->cur_rise + step) + phase);
    while (!((c->mask >> pos) & 1u)) { /* ends: the accepted mask has a lit bit below n */
        index++;
        pos = (uint8_t)(pos + 1 == c->n ? 0 : pos + 1);
        rise += c->period;
    }
    uint8_t fault = gap_fault(c, rise); /* run-time interlock on the actual edges */
    if (fault) {
        core_fault(c, fault);
        return 0;
    }
    c->next_rise = rise;
    c->next_index = index;
    c->next_pos = pos;
    c->slot_floor = c->cur_index + 1;
    *next = rise;
    return 1;
}

void core_guard(core_t *c, uint64_t now)
{
    if (c->pin_high && now - c->cur_rise > MAX_PULSE_TICKS + 2 * ARM_MARGIN_TICKS)
        core_fault(c, FAULT_WIDTH);
    if (c->state == STATE_RUNNING && now - c->last_heartbeat > HEARTBEAT_TIMEOUT_TICKS)
        core_fault(c, FAULT_HEARTBEAT);
}

/* ---- commands (main context) ------------------------------------------------------------ */

static void do_schedule(core_t *c, const frame_t *f)
{
    uint64_t first = get_u64(f->payload);
    uint32_t period = get_u32(f->payload + 8);
    uint32_t width = get_u32(f->payload + 12);
    uint32_t mask = get_u32(f->payload + 16);
    uint8_t n = f->payload[20];
    uint8_t flags = f->payload[21];
    uint32_t low = (n >= 32) ? 0xFFFFFFFFUL : ((1UL << n) - 1);

    if (n < 1 || n > MAX_PATTERN_LEN || (mask & ~low) || !(mask & low)) {
        refuse(c, f->msg_type, f->seq, NACK_BAD_PATTERN, n);
        return;
    }
    if (width > MAX_PULSE_TICKS) {
        refuse(c, f->msg_type, f->seq, NACK_ENVELOPE_WIDTH, MAX_PULSE_TICKS);
        return;
    }
    if (width < MIN_PULSE_TICKS) {
        refuse(c, f->msg_type, f->seq, NACK_BAD_VALUE, MIN_PULSE_TICKS);
        return;
    }
    uint32_t min_gap = interlock_min_gap(width);
    uint64_t spacing = (uint64_t)pattern_min_spacing(mask, n) * period;
    if (spacing < (uint64_t)width + min_gap) {
        refuse(c, f->msg_type, f->seq, NACK_ENVELOPE_DUTY, min_gap);
        return;
    }
    if (spacing < MIN_PERIOD_TICKS) {
        refuse(c, f->msg_type, f->seq, NACK_ENVELOPE_RATE, MIN_PERIOD_TICKS);
        return;
    }
    uint8_t s = hw_irq_save();
    if (c->state != STATE_IDLE) {
        uint8_t state = c->state;
        hw_irq_restore(s);
        refuse(c, f->msg_type, f->seq, NACK_BUSY, state);
        return;
    }
    uint64_t now = hw_now();
    uint8_t index = 0; /* first lit slot: below n <= 32 */
    uint64_t rise = first;
    while (!((mask >> index) & 1u)) {
        index++;
        rise += period;
    }
    uint8_t reason = 0;
    uint32_t detail = 0;
    if (first < now + MIN_LEAD_TICKS || rise > now + MAX_LEAD_TICKS) {
        reason = NACK_BAD_TIME;
        detail = (uint32_t)now;
    } else if (c->have_last) {
        uint32_t need = c->last_min_gap > min_gap ? c->last_min_gap : min_gap;
        if (rise <= c->last_fall || rise - c->last_fall < need) {
            reason = NACK_ENVELOPE_DUTY;
            detail = need;
        } else if (rise - c->last_fall < interlock_rate_gap(actual_width(c->last_rise, c->last_fall), width)) {
            reason = NACK_ENVELOPE_RATE;
            detail = MIN_PERIOD_TICKS;
        }
    }
    if (!reason) {
        c->period = period;
        c->width = width;
        c->mask = mask;
        c->n = n;
        c->min_gap = min_gap;
        c->next_rise = rise;
        c->next_index = index;
        c->next_pos = index;
        c->slot_floor = 0;
        c->trim_pending = 0;
        c->trim_phase = 0;
        c->trim_period = 0;
        c->stream_edges = flags & SCHEDULE_FLAG_STREAM_EDGES;
        c->last_heartbeat = now;
        c->state = STATE_RUNNING;
        arm_next(c);
    }
    hw_irq_restore(s);
    if (reason)
        refuse(c, f->msg_type, f->seq, reason, detail);
    else
        ack(f->msg_type, f->seq, index);
}

/* Slots (of the pattern) from `pos` to the next lit one: 1..n. */
static uint8_t slots_to_next_lit(uint32_t mask, uint8_t n, uint8_t pos)
{
    uint8_t m = 0;
    do {
        m++;
        pos = (uint8_t)(pos + 1 == n ? 0 : pos + 1);
    } while (!((mask >> pos) & 1u));
    return m;
}

/* TRIM: the first slot that starts more than MIN_LEAD_TICKS after the command arrives has its
 * start moved by dphase; the slots after it follow at period + dperiod.  If the next lit pulse
 * is still far enough ahead its rise is re-armed now; otherwise (a pulse in flight, or the next
 * rise too close) the trim waits in trim_phase/trim_period and applies at the next fall, to the
 * slot right after that pulse (trims waiting together add up).  ACK.info = the slot moved. */
static void do_trim(core_t *c, const frame_t *f)
{
    int32_t dphase = (int32_t)get_u32(f->payload);
    int32_t dperiod = (int32_t)get_u32(f->payload + 4);
    uint8_t reason = 0;
    uint32_t info = 0;
    /* The checks (64-bit products) run with interrupts enabled on a snapshot, so that they never
     * delay an edge interrupt; the result is committed only if the snapshot is still current. */
    for (;;) {
        struct {
            uint8_t state, pin_high, trim_pending, n, have_last, cur_pos, next_pos;
            uint32_t period, width, mask, min_gap, last_min_gap, cur_index, next_index, slot_floor;
            int32_t trim_phase, trim_period;
            uint64_t next_rise, last_fall, last_rise;
        } snap;
        uint8_t s = hw_irq_save();
        snap.state = c->state; snap.pin_high = c->pin_high; snap.trim_pending = c->trim_pending;
        snap.n = c->n; snap.have_last = c->have_last; snap.cur_pos = c->cur_pos; snap.next_pos = c->next_pos;
        snap.period = c->period; snap.width = c->width; snap.mask = c->mask; snap.min_gap = c->min_gap;
        snap.last_min_gap = c->last_min_gap; snap.cur_index = c->cur_index; snap.next_index = c->next_index;
        snap.slot_floor = c->slot_floor; snap.trim_phase = c->trim_phase; snap.trim_period = c->trim_period;
        snap.next_rise = c->next_rise; snap.last_fall = c->last_fall; snap.last_rise = c->last_rise;
        hw_irq_restore(s);
        if (snap.state != STATE_RUNNING) {
            reason = NACK_NOT_RUNNING;
            info = snap.state;
            break;
        }
        int64_t phase = (int64_t)snap.trim_phase + dphase;
        int64_t period = (int64_t)snap.period + snap.trim_period + dperiod;
        if (phase > INT32_MAX || phase < INT32_MIN || period < (int64_t)(MIN_PULSE_TICKS + MIN_GAP_TICKS) ||
            period > 0x7FFFFFFFL) {
            reason = NACK_BAD_VALUE;
            break;
        }
        /* steady state at the new period, then the one gap the phase changes */
        int64_t need = (int64_t)snap.width + snap.min_gap;
        int64_t spacing = (int64_t)pattern_min_spacing(snap.mask, snap.n) * period;
        if (spacing < need) {
            reason = NACK_ENVELOPE_DUTY;
            info = snap.min_gap;
            break;
        }
        if (spacing < (int64_t)MIN_PERIOD_TICKS) {
            reason = NACK_ENVELOPE_RATE;
            info = MIN_PERIOD_TICKS;
            break;
        }
        uint8_t pulse_pos = snap.pin_high ? snap.cur_pos : snap.next_pos;
        uint32_t pulse_index = snap.pin_high ? snap.cur_index : snap.next_index;
        uint8_t m = slots_to_next_lit(snap.mask, snap.n, pulse_pos);
        /* a) applied at the fall of that pulse: the lit slot after it */
        int64_t later_gap = (int64_t)snap.period + phase + (int64_t)(m - 1) * period - snap.width;
        /* b) applied now, to the next lit pulse (not in flight, not yet too close) */
        uint32_t slot = snap.next_index;
        uint64_t start = snap.next_rise;
        int64_t now_rise = 0;
        uint64_t now = hw_now();
        uint8_t immediate = !snap.pin_high && !snap.trim_pending && snap.next_rise > now + MIN_LEAD_TICKS;
        if (immediate) {
            while (slot > snap.slot_floor && start - snap.period > now + MIN_LEAD_TICKS) {
                slot--;
                start -= snap.period;
            }
            now_rise = (int64_t)start + phase + (int64_t)(snap.next_index - slot) * period;
            if (now_rise <= (int64_t)(now + MIN_LEAD_TICKS)) {
                reason = NACK_BAD_TIME;
                info = (uint32_t)now;
                break;
            }
            uint32_t last_need = snap.last_min_gap > snap.min_gap ? snap.last_min_gap : snap.min_gap;
            if (snap.have_last && ((uint64_t)now_rise <= snap.last_fall ||
                                   (uint64_t)now_rise - snap.last_fall < last_need)) {
                reason = NACK_ENVELOPE_DUTY;
                info = last_need;
                break;
            }
            if (snap.have_last && (uint64_t)now_rise - snap.last_fall <
                                      interlock_rate_gap(actual_width(snap.last_rise, snap.last_fall), snap.width)) {
                reason = NACK_ENVELOPE_RATE;
                info = MIN_PERIOD_TICKS;
                break;
            }
        } else if (later_gap < (int64_t)snap.min_gap) {
            reason = NACK_ENVELOPE_DUTY;
            info = snap.min_gap;
            break;
        } else if (later_gap < (int64_t)interlock_rate_gap(snap.width, snap.width)) {
            reason = NACK_ENVELOPE_RATE;
            info = MIN_PERIOD_TICKS;
            break;
        }
        s = hw_irq_save();
        uint8_t same = c->state == snap.state && c->pin_high == snap.pin_high && c->period == snap.period &&
                       c->next_rise == snap.next_rise && c->trim_pending == snap.trim_pending &&
                       c->trim_phase == snap.trim_phase && c->trim_period == snap.trim_period;
        if (same && immediate) {
            /* The run-time interlock first: its 64-bit work takes up to ~50 us on the AVR
             * (measured in simavr), and a time check made before it let a phase step that
             * lands the rise just ahead be armed too late (a LATE fault).  Then the time check,
             * right before arming, with room for hw_arm_rise's own work (~30 us). */
            uint8_t fault = gap_fault(c, (uint64_t)now_rise);
            if (!fault && (uint64_t)now_rise <= hw_now() + 3 * ARM_MARGIN_TICKS) {
                hw_irq_restore(s); /* now too close: decide again */
                continue;
            }
            if (fault) {
                core_fault(c, fault);
            } else {
                /* re-arm: replaces the rise armed before, unless that one is already in flight
                 * (it rose, or is about to, while this ran with interrupts off): then decide
                 * again once its interrupt has run, and the trim waits for its fall */
                uint8_t armed = hw_arm_rise((uint64_t)now_rise);
                if (armed == HW_IN_FLIGHT) {
                    hw_irq_restore(s);
                    continue;
                }
                if (armed == HW_LATE)
                    core_fault(c, FAULT_LATE);
            }
            c->period = (uint32_t)period;
            c->next_rise = (uint64_t)now_rise;
            c->slot_floor = slot; /* slots before it keep their (old-period) starts */
            info = slot;
            hw_irq_restore(s);
            break;
        }
        if (same && !immediate) {
            c->trim_phase = (int32_t)phase;
            c->trim_period = (int32_t)(period - (int64_t)snap.period);
            c->trim_pending = 1;
            info = pulse_index + 1;
            hw_irq_restore(s);
            break;
        }
        hw_irq_restore(s); /* changed underneath (or now too close): decide again */
    }
    if (reason)
        refuse(c, f->msg_type, f->seq, reason, info);
    else
        ack(f->msg_type, f->seq, info);
}

static void do_stop(core_t *c, const frame_t *f)
{
    uint8_t s = hw_irq_save();
    cut_pulse(c);
    c->state = STATE_IDLE;
    c->faults = 0;
    c->trim_pending = 0;
    uint32_t pulses = c->pulses;
    hw_irq_restore(s);
    ack(f->msg_type, f->seq, pulses);
}

static uint8_t expected_len(uint8_t type)
{
    switch (type) {
    case MSG_SCHEDULE: return LEN_SCHEDULE;
    case MSG_TRIM: return LEN_TRIM;
    case MSG_PING: case MSG_STOP: case MSG_STATUS_REQ: case MSG_HEARTBEAT: case MSG_INFO_REQ: return 0;
    default: return 0xFF;
    }
}

static void handle_frame(core_t *c, uint64_t rx_tick)
{
    frame_t f;
    uint8_t r = link_decode(c->rx, c->rx_len, &f);
    if (r == LINK_CRC) {
        c->crc_errors++;
        nack(f.msg_type, f.seq, NACK_CRC, 0);
        return;
    }
    if (r != LINK_OK) {
        c->malformed++;
        nack(f.msg_type, f.seq, NACK_MALFORMED, 0);
        return;
    }
    uint8_t want = expected_len(f.msg_type);
    if (want == 0xFF) {
        c->unknown++;
        nack(f.msg_type, f.seq, NACK_UNKNOWN_TYPE, 0);
        return;
    }
    if (f.len != want) {
        c->malformed++;
        nack(f.msg_type, f.seq, NACK_MALFORMED, want);
        return;
    }
    c->frames_ok++;
    switch (f.msg_type) {
    case MSG_PING: {
        uint8_t p[LEN_PONG];
        put_u64(p, rx_tick);
        put_u64(p + 8, hw_now());
        reply(MSG_PONG, f.seq, p, sizeof p);
        break;
    }
    case MSG_SCHEDULE: do_schedule(c, &f); break;
    case MSG_TRIM: do_trim(c, &f); break;
    case MSG_STOP: do_stop(c, &f); break;
    case MSG_STATUS_REQ: send_status(c, f.seq); break;
    case MSG_INFO_REQ: core_send_info(c, f.seq); break;
    case MSG_HEARTBEAT: {
        uint8_t s = hw_irq_save();
        c->last_heartbeat = hw_now();
        uint32_t info = c->state | ((uint32_t)c->faults << 8);
        hw_irq_restore(s);
        ack(f.msg_type, f.seq, info);
        break;
    }
    }
}

void core_rx_byte(core_t *c, uint8_t b, uint64_t rx_tick)
{
    if (b != 0) {
        if (c->rx_len < RX_ENC_MAX)
            c->rx[c->rx_len++] = b;
        else
            c->rx_overflow = 1;
        return;
    }
    if (c->rx_overflow) { /* longer than any valid frame: count and answer, never act */
        c->malformed++;
        nack(0, 0, NACK_MALFORMED, 0);
    } else if (c->rx_len > 0) {
        handle_frame(c, rx_tick);
    } /* an empty frame (a lone delimiter) only resynchronises */
    c->rx_len = 0;
    c->rx_overflow = 0;
}

void core_rx_damaged(core_t *c) { c->rx_overflow = 1; }

void core_poll(core_t *c)
{
    uint8_t s = hw_irq_save();
    core_guard(c, hw_now());
    if (c->edge_count == 0) {
        hw_irq_restore(s);
        return;
    }
    /* one report per call: commands stay responsive even when reports outrun the link
     * (then the queue drops the oldest reports; STATUS still counts every pulse) */
    edge_t e = c->edges[c->edge_head];
    c->edge_head = (uint8_t)((c->edge_head + 1) % EDGE_QUEUE);
    c->edge_count--;
    hw_irq_restore(s);
    uint8_t p[LEN_EDGE];
    put_u32(p, e.index);
    put_u64(p + 4, e.rise);
    put_u64(p + 12, e.fall);
    p[20] = e.flags;
    reply(MSG_EDGE, 0, p, sizeof p);
}
