"""The co-MCU's eye-safety envelope, fuzzed in the emulator and judged on the true laser pin.

The real firmware ELF runs in simavr (device.sim.comcu_emulator.SteppedMcuPort: lock-step, so a run
is deterministic whatever the load of the machine).  Random command *sequences* go to it back to
back, a *batch* of them (default 1000) in one emulator process, and the whole pin log of the
batch (the harness's true OC1A pin, computed from the registers by the datasheet's output compare
rules) is checked against the envelope the firmware announces in its boot INFO
(firmware_pwm/README.md "Eye-safety interlock"; the rules are proven in firmware_pwm/src/core.c):

    width      every pulse's on-time <= MAX_PULSE_TICKS + 1 tick (compare lag, see below)
    duty       consecutive pulses of on-times w1, w2 with off time g:
               g * D >= max(w1, w2) * (1e6 - D)  with D = MAX_DUTY_PPM
    rate       consecutive pulses: rise to rise and fall to fall >= MIN_PERIOD_TICKS (a pulse cut
               short by STOP, a fault or a reset is judged on its scheduled fall here: cutting only
               removes light)
    quiet      the pin is low, and stays low, from each STOP's ACK, each fault the MCU reports and
               each reset until the next SCHEDULE enters the MCU
    heartbeat  the pin is low from 100 ms after the last accepted HEARTBEAT or SCHEDULE was
               answered until the next one enters the MCU (README: off 83 ms after the last one)
    end        the pin is low at the end of the batch

Times are Timer1 counts of the pin's edges ((cycle - timer start) // 8), exact within one boot:
the compare unit moves the pin at count T + 1 for an edge armed at T (the "+1 tick" above only
matters for a pulse that ends in software).  Consecutive pulses on both sides of an MCU reset
are checked by the same rules, in CPU cycles / 8.  Each violation says whether its two pulses
were on both sides of a reset (``across_reset``) and whether the first was cut short
(``after_cut``), and by how many ticks the limit was missed.

A *sequence* is 1..12 commands (uniform), each followed by a random simulated delay (a quarter
up to 1 ms, most 1-30 ms, some 30-60 ms), then a STATUS request.  In three sequences out of five
the driver also sends a HEARTBEAT every 20, 30 or 40 ms during delays, like the Pi's heartbeat
thread; in the others a running schedule lives only on the sequence's own HEARTBEATs.
The commands (COMMANDS, by weight):

    schedule        SCHEDULE around the width, duty and rate limits (exact boundaries included),
                    1..6-slot patterns, leads from the past to 10 s ahead: about half refused
    trim            TRIM: ppm-scale period, phase steps of up to 20 ms, period changes to
                    80-115 ms between lit pulses, or anything within +-30 ms
    trim_raced      the same, timed to reach the MCU within -1.5..+0.3 ms of the next fall or rise
    stop            STOP at a random moment
    stop_mid_pulse  STOP timed to arrive while a pulse is high
    stop_schedule   STOP, then at once a SCHEDULE whose first rise is on or next to the rate or
                    duty boundary after the last pulse on the pin, or, early in a boot, the end of
                    its quiet time (in three of ten without waiting for the STOP's ACK)
    heartbeat       HEARTBEAT
    silence         60-200 ms without a byte (the heartbeat timeout)
    garbage         1-90 random bytes, half of them delimiters
    corrupt         a real command with one bit flipped, or cut short
    reset           MCU reset through the harness (power-on or watchdog), then 0-10 ms of boot

The result counts how often each path of the firmware was taken (``paths``: refusals by reason,
faults by kind, STOPs that cut a pulse, trims that arrived in a pulse or just before a rise, ...)
so a reader sees what the fuzz exercised.  Imports only the emulator port and the protocol.
"""

from __future__ import annotations

import bisect
import dataclasses
import math
import random
import time
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path

from device.sim.comcu_emulator import CPU_HZ, CYCLES_PER_TICK, ELF, HARNESS, SteppedMcuPort
from protocol import mcu
from protocol.framing import MAX_PAYLOAD_MCU, FrameError, decode_frame

MS = mcu.TICKS_PER_SECOND // 1000   # ticks per millisecond
CYCLES_PER_MS = CPU_HZ // 1000
#: firmware_pwm/src/config.h MIN_PULSE_TICKS (100 us; not announced in INFO)
MIN_PULSE_TICKS = 200
#: simavr's UART: 11 bits of 64 cycles per byte at 250 kbaud
CYCLES_PER_BYTE = 704
#: the pin is low this long after the last accepted HEARTBEAT/SCHEDULE (README: 83 ms)
HEARTBEAT_BUDGET_CYCLES = 100 * CYCLES_PER_MS
#: the driver collects the MCU's replies at least this often
CHUNK_CYCLES = 5 * CYCLES_PER_MS


@dataclass(frozen=True)
class Envelope:
    """The compiled-in limits, as the firmware's INFO announces them."""

    max_pulse_ticks: int
    max_duty_ppm: int
    min_period_ticks: int

    def min_gap(self, width: int) -> int:
        """Shortest off time after or before a pulse of `width` ticks under the duty rule."""
        return -(-width * (1_000_000 - self.max_duty_ppm) // self.max_duty_ppm)


# ---- the envelope on the pin (pure: a pin log in, violations out) --------------------------------

@dataclass(frozen=True)
class PinLog:
    """What one emulator process recorded, in CPU cycles."""

    edges: list[tuple[int, int]]          # (cycle, level) of the laser pin, levels alternating
    timer_starts: list[int]               # Timer1 starts: counts are (cycle - start) // 8
    resets: list[int]                     # MCU resets
    keepalives: list[tuple[int, int]]     # accepted HEARTBEAT/SCHEDULE: (entered the UART, ACK read)
    widths: list[tuple[int, int]]         # accepted SCHEDULEs: (entered the UART, width in ticks)
    quiet: list[tuple[int, int, str]]     # (from, to, why): the pin must be low from..to
    end: int                              # last cycle simulated


@dataclass(frozen=True)
class Pulse:
    rise: int          # cpu cycles
    fall: int
    rise_tick: float   # Timer1 count of the boot it is in, offset by that boot's start / 8
    fall_tick: float
    boot: int          # resets before the rise
    scheduled_width: int   # of the last SCHEDULE accepted before the rise (0: none known)

    @property
    def width(self) -> float:
        return self.fall_tick - self.rise_tick

    @property
    def cut(self) -> bool:
        """Ended before its scheduled width (by STOP, a fault or a reset)."""
        return 0 < self.scheduled_width and self.width + 1 < self.scheduled_width


@dataclass(frozen=True)
class Violation:
    rule: str
    cycle: int
    detail: str
    across_reset: bool = False   # the two pulses are on both sides of an MCU reset
    after_cut: bool = False      # the earlier pulse was cut short (its fall made in software)
    missed_by: float = 0.0       # ticks past the limit (width, duty: off time, rate)


@dataclass(frozen=True)
class PinCheck:
    pulses: list[Pulse]
    violations: list[Violation]
    extremes: dict[str, float]   # the closest the pin came to each limit (pairs within one boot,
                                 # and pairs across a reset)
    cut_falls: int               # fall-to-fall checks of a cut pulse made on its scheduled fall


def pin_pulses(log: PinLog) -> list[Pulse]:
    """Every complete pulse of the pin log (a pulse still high at the end is not one)."""
    def tick(cycle: int) -> float:
        i = bisect.bisect_right(log.timer_starts, cycle) - 1
        start = log.timer_starts[i] if i >= 0 else 0
        return start / CYCLES_PER_TICK + (cycle - start) // CYCLES_PER_TICK

    def scheduled(rise: int) -> int:
        i = bisect.bisect_right(log.widths, (rise, math.inf)) - 1
        return log.widths[i][1] if i >= 0 else 0

    rises = [c for c, level in log.edges if level]
    falls = [c for c, level in log.edges if not level]
    if len(falls) > len(rises):
        raise ValueError("the pin log starts with a fall: the pin was high before the MCU booted")
    return [Pulse(r, f, tick(r), tick(f), bisect.bisect_right(log.resets, r), scheduled(r))
            for r, f in zip(rises, falls)]


def check_pin(log: PinLog, env: Envelope) -> PinCheck:
    """The envelope rules of the module doc on one pin log."""
    levels = [level for _, level in log.edges]
    if any(a == b for a, b in zip(levels, levels[1:])) or (levels and levels[0] != 1):
        raise ValueError("pin log levels must alternate, starting with a rise")
    pulses = pin_pulses(log)
    out: list[Violation] = []
    d, period = env.max_duty_ppm, env.min_period_ticks
    extremes = {"longest_pulse_ticks": 0.0}
    for suffix in ("", "_across_reset"):
        extremes.update({"shortest_rise_to_rise_ticks" + suffix: math.inf,
                         "shortest_fall_to_fall_ticks" + suffix: math.inf,
                         "smallest_duty_gap_ratio" + suffix: math.inf})
    for p in pulses:
        extremes["longest_pulse_ticks"] = max(extremes["longest_pulse_ticks"], p.width)
        if p.width > env.max_pulse_ticks + 1:
            out.append(Violation("width", p.rise, f"on for {p.width:g} ticks",
                                 missed_by=p.width - env.max_pulse_ticks - 1))
    cut_falls = 0
    for a, b in zip(pulses, pulses[1:]):
        gap, wide = b.rise_tick - a.fall_tick, max(a.width, b.width)
        rr, ff = b.rise_tick - a.rise_tick, b.fall_tick - a.fall_tick
        if b.cut and ff < period:
            # cutting a pulse only removes light: its early fall is judged where it was scheduled
            ff = b.rise_tick + b.scheduled_width - a.fall_tick
            cut_falls += 1
        ratio = gap * d / (wide * (1_000_000 - d))
        pair = {"across_reset": a.boot != b.boot, "after_cut": a.cut}
        if ratio < 1:
            out.append(Violation("duty", b.rise, f"off {gap:g} ticks between pulses of {a.width:g} and "
                                 f"{b.width:g}", missed_by=wide * (1_000_000 - d) / d - gap, **pair))
        if rr < period:
            out.append(Violation("rate", b.rise, f"rises {rr:g} ticks apart", missed_by=period - rr, **pair))
        if ff < period:
            out.append(Violation("rate", b.fall, f"falls {ff:g} ticks apart", missed_by=period - ff, **pair))
        suffix = "_across_reset" if pair["across_reset"] else ""
        for key, value in (("shortest_rise_to_rise_ticks", rr), ("shortest_fall_to_fall_ticks", ff),
                           ("smallest_duty_gap_ratio", ratio)):
            extremes[key + suffix] = min(extremes[key + suffix], value)
    for start, end, why in log.quiet:
        out += [Violation("quiet", c, f"pin high {(c - start) / CYCLES_PER_MS:.3f} ms after {why}")
                for c in _high_during(log.edges, start, end)]
    # processed after it entered and before its ACK was read: the budget runs from the ACK, the
    # next keepalive counts from when it entered
    keep = sorted(log.keepalives)
    for (_, read), (entered_next, _) in zip(keep, keep[1:] + [(log.end, log.end)]):
        out += [Violation("heartbeat", c, f"pin high {(c - read) / CYCLES_PER_MS:.1f} ms after the last "
                          "keepalive was answered") for c in _high_during(log.edges, read + HEARTBEAT_BUDGET_CYCLES,
                                                                           entered_next)]
    if levels and levels[-1]:
        out.append(Violation("end", log.edges[-1][0], "pin high at the end"))
    return PinCheck(pulses, out, extremes, cut_falls)


def _high_during(edges: list[tuple[int, int]], start: int, end: int) -> list[int]:
    """The first cycle in [start, end) at which the pin is high, as a list of none or one."""
    if end <= start:
        return []
    i = bisect.bisect_right(edges, (start, 2))
    if i and edges[i - 1][1]:
        return [start]
    return [c for c, level in edges[i:i + 1] if level and c < end]


# ---- command generation ---------------------------------------------------------------------------

def lit_spacing(mask: int, n: int) -> int:
    """Fewest slots between two consecutive lit slots of a pattern (0: none lit)."""
    lit = [i for i in range(n) if mask >> i & 1]
    return min(((b - a) % n or n for a, b in zip(lit, lit[1:] + lit[:1])), default=0)


def random_schedule(rng: random.Random, env: Envelope, now: int) -> mcu.Schedule:
    """A SCHEDULE around the width, duty and rate limits."""
    n = rng.choice((1, 1, 1, 2, 2, 3, 4, 6))
    mask = rng.randint(1, 2**n - 1)
    if rng.random() < 0.03:  # patterns the firmware must refuse
        mask, n = rng.choice(((0, 2), (0b100, 2), (1, 0), (1, 33)))
    if rng.random() < 0.15:
        width = rng.choice((env.max_pulse_ticks, env.max_pulse_ticks + 1, MIN_PULSE_TICKS, MIN_PULSE_TICKS - 1))
    else:
        width = rng.randint(MIN_PULSE_TICKS // 2, env.max_pulse_ticks + 2 * MS)
    need = max(width + env.min_gap(width), env.min_period_ticks)   # shortest lit spacing allowed
    slots = lit_spacing(mask, n) or 1
    if rng.random() < 0.25:
        period = -(-need // slots) + rng.choice((-1, 0, 1))
    else:
        period = round(need / slots * rng.uniform(0.8, 1.4))
    lead = rng.choices(((-MS, 2 * MS), (2 * MS, 30 * MS), (30 * MS, 150 * MS), (10_000 * MS, 10_010 * MS)),
                       weights=(5, 70, 23, 2))[0]
    return mcu.Schedule(max(now + rng.randint(*lead), 0), period, width, mask, n, rng.random() < 0.5)


def random_trim(rng: random.Random, period: int, slots: int) -> mcu.Trim:
    """A TRIM like the sync's (ppm, phase steps) or hostile (big period changes, anything)."""
    kind = rng.random()
    if kind < 0.35:
        return mcu.Trim(0, rng.randint(-period // 1000, period // 1000))
    if kind < 0.65:
        return mcu.Trim(rng.randint(-20 * MS, 20 * MS), 0)
    if kind < 0.85:
        return mcu.Trim(0, rng.randint(80 * MS, 115 * MS) // max(slots, 1) - period)
    return mcu.Trim(rng.randint(-30 * MS, 30 * MS), rng.randint(-30 * MS, 30 * MS))


def random_garbage(rng: random.Random) -> bytes:
    return bytes(rng.choice((0, rng.randint(1, 255))) for _ in range(rng.randint(1, 90)))


def corrupted(rng: random.Random, wire: bytes) -> bytes:
    """A frame (delimiter last) with one bit flipped before the delimiter, or cut short."""
    body = bytearray(wire[:-1])
    if rng.random() < 0.8:
        body[rng.randrange(len(body))] ^= 1 << rng.randrange(8)
    else:
        del body[rng.randrange(1, len(body)):]
    return bytes(body) + b"\x00"


# ---- driving one emulator process ---------------------------------------------------------------

@dataclass
class _Request:
    msg: object
    sequence: int
    delim: int                 # index in the port's rx_delims of the frame's last delimiter
    arrival: int               # estimated cycle at which its last byte reaches the firmware
    extra: dict = field(default_factory=dict)


@dataclass
class BatchResult:
    """One emulator process: its sequences, pin check and path counts."""

    first: int
    sequences: int
    pulses: int
    simulated_s: float
    violations: list[dict]
    paths: dict[str, tuple[int, int]]       # path -> (sequences that took it, times taken)
    extremes: dict[str, float]
    cut_falls: int
    envelope: Envelope


class FuzzDriver:
    """Runs random sequences on one SteppedMcuPort and keeps what the checks need."""

    def __init__(self, port: SteppedMcuPort, rng: random.Random, first_sequence: int = 0):
        self.port, self.rng = port, rng
        self.first = self.sequence = first_sequence
        self._seq = 0
        self._zeros = 0                   # delimiters written so far (index into port.rx_delims)
        self._rx = bytearray()
        self.pending: dict[int, _Request] = {}
        self.events: list[tuple[str, int]] = []            # (path, sequence)
        self.keepalives: list[tuple[int, int]] = []          # (request delim index, ACK read)
        self.off_events: list[tuple[int, int, int, str]] = []   # (last delim before, observed, sequence, why)
        self.requests: list[_Request] = []                  # every command sent, in order
        self.widths: list[tuple[int, int]] = []             # (schedule delim index, width) accepted
        self.sequence_starts: list[int] = []                # cycle at which each sequence began
        self.faults_seen = 0
        self.model = None                                    # the last accepted mcu.Schedule
        self.model_period = 0
        self.heartbeat_every = 0
        self._last_heartbeat = 0
        self._resets_unseen = 0                               # resets whose boot INFO has not come
        self.envelope: Envelope | None = None
        self.first_rise_min_ticks = 0  # the boot's quiet time, from its INFO (only aimed at, never judged by)
        self.run(50 * CYCLES_PER_MS, until=lambda: self.envelope is not None, step=CYCLES_PER_MS)
        if self.envelope is None:
            raise RuntimeError("the firmware sent no boot INFO")

    # wire ------------------------------------------------------------------------------------
    def send(self, msg, **extra) -> _Request:
        self._seq = self._seq % 0xFFFF + 1
        return self.send_bytes(b"\x00" + mcu.encode_message(msg, self._seq), msg, **extra)

    def send_bytes(self, wire: bytes, msg=None, **extra) -> _Request | None:
        zeros = wire.count(0)
        self.port.write(wire)
        self._zeros += zeros
        if msg is None:
            return None
        req = _Request(msg, self.sequence, self._zeros - 1, self.port.cycle + len(wire) * CYCLES_PER_BYTE, extra)
        self.pending[self._seq] = req
        self.requests.append(req)
        return req

    def sent(self, kind: type) -> list[_Request]:
        return [r for r in self.requests if type(r.msg) is kind]

    def _heartbeat(self) -> None:
        self.send(mcu.Heartbeat())
        self._last_heartbeat = self.port.cycle

    def run(self, cycles: int, heartbeats: bool = True, until=None, step: int = CHUNK_CYCLES) -> bool:
        """Simulates `cycles` (or less, once `until()` is true), reading the replies every `step`
        and sending the sequence's heartbeats; returns `until()`."""
        end = self.port.cycle + cycles
        while self.port.cycle < end and not (until and until()):
            if heartbeats and self.heartbeat_every and self.port.cycle - self._last_heartbeat >= self.heartbeat_every:
                self._heartbeat()
            self.port.run_cycles(min(step, end - self.port.cycle))
            self._read_replies()
        return bool(until and until())

    def ticks_at(self, cycle: int) -> int:
        """Timer1 count at `cycle` of the current boot (negative before it)."""
        starts = self.port.timer_starts
        return (cycle - (starts[-1] if starts else 0)) // CYCLES_PER_TICK

    def now_ticks(self) -> int:
        return self.ticks_at(self.port.cycle)

    def pin_high(self) -> bool:
        return bool(self.port.edges) and self.port.edges[-1][1] == 1

    # replies ---------------------------------------------------------------------------------
    def _read_replies(self) -> None:
        self._rx += self.port.read(self.port.in_waiting)
        *frames, rest = bytes(self._rx).split(b"\x00")
        self._rx = bytearray(rest)
        for wire in frames:
            if not wire:
                continue
            try:
                frame = decode_frame(wire, max_payload=MAX_PAYLOAD_MCU)
                msg = mcu.decode_message(frame)
            except (FrameError, ValueError):
                self.events.append(("reply.undecodable", self.sequence))  # cut by a reset
                continue
            REPLIES.get(type(msg), FuzzDriver._unexpected)(self, msg, frame.seq)

    def _on_ack(self, ack: mcu.Ack, seq: int) -> None:
        req = self.pending.get(seq)
        if req is None or req.msg.MSG_TYPE != ack.acked_type:
            self.events.append(("reply.unmatched", self.sequence))
            return
        del self.pending[seq]
        self.events.append((f"{type(req.msg).__name__.lower()}.accepted", req.sequence))
        req.extra["outcome"] = "accepted"
        ACCEPTED.get(type(req.msg), FuzzDriver._ignore)(self, req, ack.info)

    def _accepted_schedule(self, req: _Request, info: int) -> None:
        self.keepalives.append((req.delim, self.port.cycle))
        self.widths.append((req.delim, req.msg.width_ticks))
        self.model, self.model_period = req.msg, req.msg.period_ticks

    def _accepted_trim(self, req: _Request, info: int) -> None:
        self.model_period += req.msg.period_ticks

    def _accepted_heartbeat(self, req: _Request, info: int) -> None:  # info: state | faults << 8
        self.keepalives.append((req.delim, self.port.cycle))
        self._faults(info >> 8, req)

    def _accepted_stop(self, req: _Request, info: int) -> None:
        self.faults_seen = 0
        self.model = None
        self.off_events.append((req.delim, self.port.cycle, req.sequence, "STOP"))

    def _on_nack(self, nack: mcu.Nack, seq: int) -> None:
        req = self.pending.get(seq)
        if req is None or req.msg.MSG_TYPE != nack.acked_type:  # garbage and corrupted frames
            self.events.append((f"link.nack.{nack.reason_name}", self.sequence))
            return
        del self.pending[seq]
        self.events.append((f"{type(req.msg).__name__.lower()}.refused.{nack.reason_name}", req.sequence))
        req.extra["outcome"] = "refused"
        if nack.reason == mcu.NackReason.BUSY and nack.detail == mcu.McuState.FAULT:
            self.off_events.append((req.delim, self.port.cycle, req.sequence, "a fault (SCHEDULE busy)"))

    def _on_status(self, status: mcu.Status, seq: int) -> None:
        req = self.pending.pop(seq, None)
        if req is not None:
            self._faults(status.faults, req)

    def _faults(self, faults: int, req: _Request) -> None:
        if faults:
            self.off_events.append((req.delim, self.port.cycle, req.sequence, f"fault {mcu.Fault(faults)!r}"))
        for bit in mcu.Fault:
            if faults & bit and not self.faults_seen & bit:
                self.events.append((f"fault.{bit.name.lower()}", req.sequence))
        self.faults_seen = faults

    def _on_info(self, info: mcu.Info, seq: int) -> None:
        if seq == 0:
            self.events.append((f"boot.reset_cause_0x{info.reset_cause:02x}", self.sequence))
            if self.envelope is not None and self._resets_unseen == 0:  # not one we caused
                self.events.append(("boot.unexpected", self.sequence))
            self._resets_unseen = max(self._resets_unseen - 1, 0)
            self.faults_seen = 0
            self.model = None
            self.envelope = Envelope(info.max_pulse_ticks, info.max_duty_ppm, info.min_period_ticks)
            self.first_rise_min_ticks = info.first_rise_min_ticks

    def _on_edge(self, edge: mcu.Edge, seq: int) -> None:
        self.events.append(("edge_report.cut" if edge.flags & mcu.EdgeFlag.CUT else "edge_report", self.sequence))
        if edge.flags & mcu.EdgeFlag.FALL_FORCED:
            self.events.append(("edge_report.fall_forced", self.sequence))

    def _ignore(self, *_) -> None:
        pass

    def _unexpected(self, msg, seq: int) -> None:  # a Pi -> MCU message from the MCU
        self.events.append((f"reply.unexpected_{type(msg).__name__.lower()}", self.sequence))

    # commands --------------------------------------------------------------------------------
    def cmd_schedule(self) -> None:
        self.send(random_schedule(self.rng, self.envelope, self.now_ticks()))

    def cmd_trim(self) -> None:
        self.send(self._trim())

    def _trim(self) -> mcu.Trim:
        slots = lit_spacing(self.model.mask, self.model.n) if self.model else 1
        return random_trim(self.rng, self.model_period or 200_000, slots)

    def cmd_trim_raced(self) -> None:
        msg, model, period = self._trim(), self.model, self.model_period  # a reply may reset them meanwhile
        length = len(mcu.encode_message(msg, 1)) + 1
        if model and self.run(120 * CYCLES_PER_MS, until=self.pin_high, step=CYCLES_PER_MS):
            rise = self.port.edges[-1][0]
            spacing = lit_spacing(model.mask, model.n) * period
            edge = rise + self.rng.choice((model.width_ticks, spacing)) * CYCLES_PER_TICK
            self._run_until(edge + self.rng.randint(-3 * CYCLES_PER_MS // 2, CYCLES_PER_MS * 3 // 10)
                            - length * CYCLES_PER_BYTE)
        self.send(msg)

    def _run_until(self, cycle: int) -> None:
        if cycle - self.port.cycle > 10 * CYCLES_PER_MS:
            self.run(cycle - self.port.cycle - 5 * CYCLES_PER_MS)
        if cycle > self.port.cycle:
            self.port.run_cycles(cycle - self.port.cycle)

    def cmd_stop(self) -> None:
        self.send(mcu.Stop())

    def cmd_stop_mid_pulse(self) -> None:
        model = self.model  # a reply may reset it meanwhile
        if model and self.run(120 * CYCLES_PER_MS, until=self.pin_high, step=CYCLES_PER_MS):
            rise = self.port.edges[-1][0]
            self._run_until(rise + int(self.rng.uniform(0.05, 0.95) * model.width_ticks * CYCLES_PER_TICK)
                            - 14 * CYCLES_PER_BYTE)
        self.cmd_stop()

    def cmd_stop_schedule(self) -> None:
        """STOP, then a SCHEDULE on or next to the boundary after the last pulse on the pin."""
        env, now = self.envelope, self.now_ticks()
        msg = random_schedule(self.rng, env, now)
        boundaries = []
        if self.port.edges and not self.pin_high():  # the last pulse in MCU ticks (pin count - 1)
            rise, fall = (self.ticks_at(c) - 1 for c, _ in self.port.edges[-2:])
            boundaries += [rise + env.min_period_ticks,                        # rise to rise
                           fall + env.min_period_ticks - msg.width_ticks,      # fall to fall
                           fall + env.min_gap(max(msg.width_ticks, fall - rise))]  # duty
        if now < self.first_rise_min_ticks:  # a boot's quiet time (the last pulse may be before the reset)
            boundaries.append(self.first_rise_min_ticks)
        if boundaries:
            aim = self.rng.choice(boundaries)
            first = aim + self.rng.choice((-2, -1, 0, 1, 2, self.rng.randint(-5 * MS, 5 * MS)))
            if first > now + 3 * MS:
                msg = dataclasses.replace(msg, first_rise_ticks=first)
                if aim == self.first_rise_min_ticks:
                    self.events.append(("schedule.at_the_end_of_a_boot_quiet_time", self.sequence))
        stop = self.send(mcu.Stop())
        if self.rng.random() < 0.7:  # else back to back: the SCHEDULE is on its way before the ACK
            self.run(20 * CYCLES_PER_MS, until=lambda: "outcome" in stop.extra, step=CYCLES_PER_MS // 4)
        self.send(msg)

    def cmd_heartbeat(self) -> None:
        self._heartbeat()

    def cmd_silence(self) -> None:
        self.run(self.rng.randint(60, 200) * CYCLES_PER_MS, heartbeats=False)

    def cmd_garbage(self) -> None:
        self.send_bytes(random_garbage(self.rng))

    def cmd_corrupt(self) -> None:
        msg = self.rng.choice((random_schedule(self.rng, self.envelope, self.now_ticks()), self._trim(),
                               mcu.Stop(), mcu.Heartbeat()))
        self.send_bytes(b"\x00" + corrupted(self.rng, mcu.encode_message(msg, 0)))  # seq 0: no request's

    def cmd_reset(self) -> None:
        cause = self.rng.choice(("power", "wdt"))
        if self.pin_high():
            self.events.append(("reset.mid_pulse", self.sequence))
        self.port.reset(cause)
        self._resets_unseen += 1
        self.events.append((f"reset.{cause}", self.sequence))
        self.off_events.append((self._zeros - 1, self.port.cycle, self.sequence, f"a {cause} reset"))
        self.run(self.rng.randint(0, 10 * CYCLES_PER_MS), heartbeats=False)

    # sequences -------------------------------------------------------------------------------
    def run_sequence(self) -> None:
        rng = self.rng
        self.sequence_starts.append(self.port.cycle)
        self.heartbeat_every = rng.choice((20, 30, 40, 0, 0)) * CYCLES_PER_MS
        names, weights = zip(*((name, w) for name, (w, _) in COMMANDS.items()))
        for name in rng.choices(names, weights, k=rng.randint(1, 12)):
            self.events.append((name, self.sequence))
            COMMANDS[name][1](self)
            lo, hi = rng.choices(((0, 1), (1, 30), (30, 60)), weights=(25, 60, 15))[0]
            self.run(int(rng.uniform(lo, hi) * CYCLES_PER_MS))
        self.send(mcu.StatusRequest())
        self.sequence += 1

    def finish(self) -> None:
        """STOP, wait out any pulse, read everything: the end of a batch."""
        self.heartbeat_every = 0
        self.send(mcu.Stop())
        self.run(60 * CYCLES_PER_MS)
        self.send(mcu.StatusRequest())
        self.run(10 * CYCLES_PER_MS)

    # after the batch -------------------------------------------------------------------------
    def pin_log(self) -> PinLog:
        delims = self.port.rx_delims
        entered = [(r.delim, delims[r.delim]) for r in self.sent(mcu.Schedule) if r.delim < len(delims)]
        quiet = []
        for after, observed, _, why in self.off_events:
            # SCHEDULEs written after the request (or reset): one that entered before the answer
            # was read may legitimately have lit the pin by then (no window); else the first of
            # them to enter ends the window
            j = bisect.bisect_right(entered, (after, math.inf))
            first_later = entered[j][1] if j < len(entered) else self.port.cycle
            if first_later >= observed:
                quiet.append((observed, first_later, why))
        keep = [(delims[i] if i < len(delims) else read, read) for i, read in self.keepalives]
        widths = sorted((delims[i], w) for i, w in self.widths if i < len(delims))
        return PinLog(list(self.port.edges), list(self.port.timer_starts), list(self.port.resets),
                      keep, widths, quiet, self.port.cycle)

    def classify(self, pulses: list[Pulse]) -> None:
        """Paths seen on the pin: STOPs and TRIMs that met a pulse, pulses cut short."""
        rises = [p.rise for p in pulses]

        def pulse_at(cycle):
            i = bisect.bisect_right(rises, cycle) - 1
            return pulses[i] if i >= 0 and pulses[i].fall > cycle else None

        for stop in self.sent(mcu.Stop):
            p = pulse_at(stop.arrival)
            if p is not None:
                self.events.append(("stop.arrived_mid_pulse", stop.sequence))
                self.events.append(("stop.cut_pulse" if p.cut else "stop.pulse_ended_first", stop.sequence))
        for trim in self.sent(mcu.Trim):
            outcome = trim.extra.get("outcome", "unanswered")
            if pulse_at(trim.arrival) is not None:
                self.events.append((f"trim.arrived_mid_pulse.{outcome}", trim.sequence))
            i = bisect.bisect_right(rises, trim.arrival)
            if i < len(rises) and rises[i] - trim.arrival <= CYCLES_PER_MS:
                self.events.append((f"trim.arrived_under_1ms_before_a_rise.{outcome}", trim.sequence))
        for p in pulses:
            self.events.append(("pulse", self.sequence_of(p.rise)))
            if p.cut:
                self.events.append(("pulse.cut_short", self.sequence_of(p.rise)))

    def sequence_of(self, cycle: int) -> int:
        return self.first + max(bisect.bisect_right(self.sequence_starts, cycle) - 1, 0)


COMMANDS = {  # name -> (weight, FuzzDriver method)
    "schedule": (3, FuzzDriver.cmd_schedule),
    "trim": (2.5, FuzzDriver.cmd_trim),
    "trim_raced": (1, FuzzDriver.cmd_trim_raced),
    "stop": (0.5, FuzzDriver.cmd_stop),
    "stop_mid_pulse": (0.7, FuzzDriver.cmd_stop_mid_pulse),
    "stop_schedule": (0.8, FuzzDriver.cmd_stop_schedule),
    "heartbeat": (2, FuzzDriver.cmd_heartbeat),
    "silence": (0.3, FuzzDriver.cmd_silence),
    "garbage": (0.6, FuzzDriver.cmd_garbage),
    "corrupt": (0.6, FuzzDriver.cmd_corrupt),
    "reset": (0.25, FuzzDriver.cmd_reset),
}

ACCEPTED = {  # command type -> what its ACK tells the driver
    mcu.Schedule: FuzzDriver._accepted_schedule,
    mcu.Trim: FuzzDriver._accepted_trim,
    mcu.Heartbeat: FuzzDriver._accepted_heartbeat,
    mcu.Stop: FuzzDriver._accepted_stop,
}

REPLIES = {  # reply message type -> FuzzDriver handler
    mcu.Ack: FuzzDriver._on_ack,
    mcu.Nack: FuzzDriver._on_nack,
    mcu.Status: FuzzDriver._on_status,
    mcu.Info: FuzzDriver._on_info,
    mcu.Edge: FuzzDriver._on_edge,
    mcu.Pong: FuzzDriver._ignore,
}


def run_batch(first: int, count: int, seed: int, harness: Path = HARNESS, elf: Path = ELF) -> BatchResult:
    """Sequences first .. first + count - 1 in one emulator process, then the pin check."""
    rng = random.Random(f"{seed}/{first}")
    with SteppedMcuPort(harness, elf) as port:
        driver = FuzzDriver(port, rng, first)
        for _ in range(count):
            driver.run_sequence()
        driver.finish()
        log = driver.pin_log()
        check = check_pin(log, driver.envelope)
        driver.classify(check.pulses)
    sequences_by_path: dict[str, set[int]] = {}
    for path, seq in driver.events:
        sequences_by_path.setdefault(path, set()).add(seq)
    times = Counter(path for path, _ in driver.events)
    violations = [dict(vars(v), sequence=driver.sequence_of(v.cycle), batch_first=first) for v in check.violations]
    return BatchResult(first, count, len(check.pulses), log.end / CPU_HZ, violations,
                       {p: (len(s), times[p]) for p, s in sequences_by_path.items()}, check.extremes,
                       check.cut_falls, driver.envelope)


def violation_kind(v: dict) -> str:
    """rule, and whether the pair was across a reset or after a pulse cut short."""
    return v["rule"] + "".join(f" ({name.replace('_', ' ')})" for name in ("across_reset", "after_cut") if v[name])


def merge(results: list[BatchResult]) -> dict:
    """One summary of many batches (JSON-ready)."""
    # shown also when never taken: every fault kind, and a boot the fuzz did not cause (watchdog)
    paths: dict[str, list[int]] = {p: [0, 0] for p in [f"fault.{bit.name.lower()}" for bit in mcu.Fault]
                                   + ["boot.unexpected"]}
    for r in results:
        for p, (s, n) in r.paths.items():
            acc = paths.setdefault(p, [0, 0])
            acc[0] += s
            acc[1] += n
    extremes = {}
    for key in results[0].extremes if results else ():
        pick = max if key.startswith("longest") else min
        extremes[key] = pick(r.extremes[key] for r in results)
    violations = [v for r in results for v in r.violations]
    kinds: dict[str, dict] = {}
    for v in violations:
        k = kinds.setdefault(violation_kind(v), {"count": 0, "most_missed_by": 0.0, "first": []})
        k["count"] += 1
        k["most_missed_by"] = max(k["most_missed_by"], round(v["missed_by"], 4))
        if len(k["first"]) < 5:
            k["first"].append(v)
    env = results[0].envelope if results else None
    return {
        "sequences": sum(r.sequences for r in results),
        "batches": len(results),
        "pulses": sum(r.pulses for r in results),
        "simulated_s": round(sum(r.simulated_s for r in results), 1),
        "envelope": vars(env) if env else None,
        "violations": len(violations),
        "violations_within_boot": sum(not v["across_reset"] for v in violations),
        "violations_across_reset": sum(v["across_reset"] for v in violations),
        "violations_by_kind": kinds,
        "cut_pulse_falls_judged_as_scheduled": sum(r.cut_falls for r in results),
        "extremes": {k: (None if math.isinf(v) else round(v, 4)) for k, v in extremes.items()},
        "paths": {p: {"sequences": s, "times": n} for p, (s, n) in sorted(paths.items())},
    }


def fuzz(sequences: int, seed: int = 1, jobs: int = 1, batch: int = 1000, first: int = 0,
         harness: Path = HARNESS, elf: Path = ELF, minutes: float | None = None, progress=None) -> dict:
    """Sequences first .. first + sequences - 1 in batches of `batch`, `jobs` processes at once.
    With `minutes`, no batch starts after that long: the summary says how many ran.  `progress`
    is called with each BatchResult as it comes in."""
    todo = [(s, min(batch, first + sequences - s)) for s in range(first, first + sequences, batch)]
    t0 = time.monotonic()

    def in_time() -> bool:
        return minutes is None or time.monotonic() - t0 < minutes * 60

    def finished(result: BatchResult) -> None:
        results.append(result)
        if progress:
            progress(result)

    results: list[BatchResult] = []
    if jobs == 1:
        for start, count in todo:
            if not in_time():
                break
            finished(run_batch(start, count, seed, harness, elf))
    else:
        from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
        with ProcessPoolExecutor(jobs) as pool:
            running = set()
            while todo or running:
                while todo and len(running) < jobs and in_time():
                    start, count = todo.pop(0)
                    running.add(pool.submit(run_batch, start, count, seed, harness, elf))
                if not running:
                    break
                done, running = wait(running, return_when=FIRST_COMPLETED)
                for f in done:
                    finished(f.result())
    results.sort(key=lambda r: r.first)
    summary = merge(results)
    duration = time.monotonic() - t0
    summary.update(seed=seed, first=first, batch=batch, jobs=jobs, duration_s=round(duration, 1),
                   sequences_per_s=round(summary["sequences"] / duration, 2))
    return summary
