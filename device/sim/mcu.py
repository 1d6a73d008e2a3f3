"""Simulated co-MCU: a drifting 2 MHz tick clock, the laser pulse train, its edge reports, the GPIO wire.

Models the ATmega328P's Timer1 at 16 MHz / 8 (tick = 0.5 us), extended to 64 bits, running on a
crystal or resonator that is ``drift_ppm`` fast against the Pi's CLOCK_MONOTONIC, optionally with a
slow sinusoidal wander (temperature) of ``wander_ppm``. Pulses start and end on exact ticks
(hardware output compare), so the truth of every edge is the true time of a tick.

The link and the wire:

- Commands (schedule / trim / stop) reach the MCU ``cmd_latency`` after they are sent (uniform in
  ``[cmd_latency_min_s, cmd_latency_max_s]``: serial frame time plus USB-serial latency), in the
  order they were sent: one serial line carries them byte after byte into the USART's receive
  FIFO (ATmega48A/PA/88A/PA/168A/PA/328/P datasheet, DS40002061A, 20.11.1 UDRn: "The receive
  buffer consists of a two level FIFO"), so none arrives before one sent earlier (a STOP and the
  SCHEDULE after it, sent within a latency's spread of each other, must not swap).
  Trims behave as the firmware's (firmware_pwm/README.md, TRIM): the first slot, lit or not,
  that starts at least 100 us after the trim arrives moves by the phase and the slots after it
  follow the new period; trims waiting together add up.
- Every pulse is reported with its rising and falling tick; the report arrives after the falling
  edge plus a link latency.
- The laser trigger is wired to a Pi GPIO whose edges the kernel timestamps in its interrupt
  handler: the timestamp is late by a fixed ``gpio_latency_min_s`` plus an exponential excess with
  mean ``gpio_jitter_s``; a fraction ``gpio_outlier_prob`` of edges is delayed by 0.1-2 ms more
  (an interrupt held off), and ``gpio_spurious_hz`` adds glitch edges at random times.
  Interrupt latency cannot be negative, so the jitter is one-sided.
- PING: the MCU stamps its tick when the request's last byte arrives; each leg takes its frame's
  serial time (PING 14 bytes, PONG 29 bytes) plus a USB latency (uniform 0-1 ms plus an
  exponential tail).
- The firmware's eye-safety envelope (maximum width and duty) refuses out-of-envelope requests.

This module implements ``device.sync.control.LaserScheduler``; the harness sets ``now_s`` (the
Pi's clock) before it lets the controller send commands, and ``advance_to`` runs the MCU forward.
"""

from __future__ import annotations

import bisect
import math
from dataclasses import dataclass, field
from typing import Sequence

import numpy as np

TICK_HZ = 16e6 / 8
TRIM_LEAD_S = 100e-6  # firmware_pwm: a TRIM moves the first slot starting at least 100 us after it arrives


class ScheduleRefused(ValueError):
    """The MCU refused a command; the message names the reason."""


@dataclass(frozen=True)
class McuConfig:
    drift_ppm: float = 100.0
    wander_ppm: float = 0.0
    wander_period_s: float = 600.0
    tick_hz: float = TICK_HZ
    boot_s: float = 0.0
    cmd_latency_min_s: float = 0.5e-3
    cmd_latency_max_s: float = 2.5e-3
    report_latency_s: float = 2e-3
    link_up_min_s: float = 14 * 10 / 250_000  # PING, 14 bytes at 250000 baud 8N1 (device.laser.comcu)
    link_down_min_s: float = 29 * 10 / 250_000  # PONG, 29 bytes
    usb_latency_max_s: float = 1e-3
    gpio_connected: bool = True
    gpio_latency_min_s: float = 3e-6
    gpio_jitter_s: float = 20e-6
    gpio_outlier_prob: float = 0.005
    gpio_spurious_hz: float = 0.0
    # the 16 MHz firmware's compiled-in envelope (firmware_pwm/Makefile, in ticks of tick_hz)
    max_width_ticks: int = 34_800  # 17.4 ms, MAX_PULSE_US
    max_duty: float = 0.2  # MAX_DUTY_PPM 200 000
    min_period_ticks: int = 180_000  # 90 ms between lit rises, MIN_PERIOD_US


@dataclass
class PulseLog:
    """Truth of every pulse the MCU produced (ticks of its own clock, true Pi seconds)."""

    rise_tick: list[int] = field(default_factory=list)
    fall_tick: list[int] = field(default_factory=list)
    rise_s: list[float] = field(default_factory=list)
    fall_s: list[float] = field(default_factory=list)


class SimulatedMcu:
    """One job: produce the pulse train the commands ask for, on a drifting clock, with its reports."""

    def __init__(self, cfg: McuConfig, rng: np.random.Generator) -> None:
        self.cfg = cfg
        self._rng = rng
        self.now_s = 0.0
        self._boot = cfg.boot_s
        self._train: dict | None = None
        self._pending: list[tuple[float, str, tuple]] = []
        self._t = 0.0  # simulated up to here
        self.pulses = PulseLog()
        self.resets: list[float] = []
        self._reports: list[tuple[float, int, int]] = []  # (arrival s, rise tick, fall tick)
        self._gpio: list[tuple[int, bool]] = []  # (timestamp ns, rising)
        self._last_spurious = 0.0
        self._last_receipt = -math.inf  # when the last command sent reaches the MCU (the link keeps their order)

    # --- clock -------------------------------------------------------------------------------
    def tick_at(self, t: float) -> float:
        """Continuous tick count at true time ``t`` (floor of it is what the counter shows)."""
        c = self.cfg
        dt = t - self._boot
        if c.wander_ppm == 0:
            return c.tick_hz * dt * (1 + c.drift_ppm * 1e-6)
        w = c.wander_ppm * 1e-6 * c.wander_period_s / (2 * math.pi) * math.sin(2 * math.pi * dt / c.wander_period_s)
        return c.tick_hz * (dt * (1 + c.drift_ppm * 1e-6) + w)

    def time_of_tick(self, tick: float) -> float:
        """True time at which the counter reaches ``tick`` (Newton on ``tick_at``)."""
        c = self.cfg
        t = self._boot + tick / (c.tick_hz * (1 + c.drift_ppm * 1e-6))
        if c.wander_ppm == 0:
            return t
        for _ in range(3):
            dt = t - self._boot
            rate = c.tick_hz * (1 + c.drift_ppm * 1e-6 + c.wander_ppm * 1e-6 * math.cos(2 * math.pi * dt / c.wander_period_s))
            t -= (self.tick_at(t) - tick) / rate
        return t

    # --- LaserScheduler ------------------------------------------------------------------------
    def _receipt(self) -> float:
        """When a command sent now reaches the MCU: its latency, but not before the one sent before it."""
        self._last_receipt = max(self.now_s + self._rng.uniform(self.cfg.cmd_latency_min_s, self.cfg.cmd_latency_max_s),
                                 self._last_receipt)
        return self._last_receipt

    def _check_envelope(self, period: int, width: int, pattern: Sequence[bool]) -> None:
        if width <= 0 or period <= 0:
            raise ScheduleRefused(f"width {width} and period {period} ticks must be positive")
        if width >= period:
            raise ScheduleRefused(f"width {width} ticks must be shorter than the period {period}")
        if width > self.cfg.max_width_ticks:
            raise ScheduleRefused(f"width {width} ticks exceeds the envelope's {self.cfg.max_width_ticks}")
        duty = width * sum(bool(p) for p in pattern) / (period * len(pattern))
        if duty > self.cfg.max_duty:
            raise ScheduleRefused(f"duty {duty:.3f} exceeds the envelope's {self.cfg.max_duty}")
        lit = [i for i, p in enumerate(pattern) if p]
        spacing = min((lit[(k + 1) % len(lit)] - i) % len(pattern) or len(pattern) for k, i in enumerate(lit))
        if spacing * period < self.cfg.min_period_ticks:
            raise ScheduleRefused(f"lit pulses every {spacing * period} ticks: faster than the envelope's "
                                  f"minimum period of {self.cfg.min_period_ticks} ticks (envelope_rate)")

    def schedule(self, first_start_tick: int, period_ticks: int, width_ticks: int, pattern: Sequence[bool]) -> int:
        if not pattern or not any(pattern):
            raise ScheduleRefused("pattern must light at least one slot")
        self._check_envelope(period_ticks, width_ticks, pattern)
        at = self._receipt()
        if first_start_tick <= self.tick_at(at):
            raise ScheduleRefused(f"first start tick {first_start_tick} is in the past")
        self._pending.append((at, "schedule", (int(first_start_tick), int(period_ticks), int(width_ticks), tuple(bool(p) for p in pattern))))
        return next(i for i, p in enumerate(pattern) if p)  # the firmware's ACK.info: the first lit slot

    def trim(self, phase_ticks: int, period_ticks: int) -> int:
        """Returns the slot it moves, as the firmware's ACK does (known here when it is sent: the
        simulation does not model the answer's delay, only the command's)."""
        if self._train is None and not any(k == "schedule" for _, k, _ in self._pending):
            raise ScheduleRefused("no pulse train to trim")
        pattern = self._train["pattern"] if self._train else next(a[3] for _, k, a in reversed(self._pending) if k == "schedule")
        width = self._train["width"] if self._train else next(a[2] for _, k, a in reversed(self._pending) if k == "schedule")
        self._check_envelope(period_ticks, width, pattern)
        # effective for the first slot starting TRIM_LEAD_S after it arrives (a slot in flight is never moved)
        at = self._receipt() + TRIM_LEAD_S
        moved = self._slot_starting_from(at)
        self._pending.append((at, "trim", (int(phase_ticks), int(period_ticks))))
        return moved

    def _slot_starting_from(self, t: float) -> int:
        """The first slot, lit or not, of the train running at ``t`` that starts at or after ``t``,
        once the commands and slots before ``t`` have run (a dry run of ``advance_to``)."""
        live = self._train, self._pending, self._boot, self.resets
        self._train = None if self._train is None else dict(self._train)
        self._pending, self.resets = list(self._pending), list(self.resets)
        try:
            self._run(math.nextafter(t, -math.inf), emit=False)
            if self._train is None:
                raise ScheduleRefused("no pulse train when the trim arrives")
            return self._train["slot"]
        finally:
            self._train, self._pending, self._boot, self.resets = live

    def stop(self) -> None:
        self._pending.append((self._receipt(), "stop", ()))

    def start_now(self, period_ticks: int, width_ticks: int, pattern: Sequence[bool], delay_s: float) -> None:
        """Start a train ``delay_s`` from now at whatever tick that is (the thesis's START_PWM, Algorithm 1)."""
        self._check_envelope(period_ticks, width_ticks, pattern)
        at = self.now_s + delay_s
        self._pending.append((at, "start", (int(period_ticks), int(width_ticks), tuple(bool(p) for p in pattern))))

    # --- simulation ----------------------------------------------------------------------------
    def reset_at(self, t: float) -> None:
        """Schedule an MCU reset: the counter restarts at 0 and the train is gone (laser pin low)."""
        self._pending.append((t, "reset", ()))

    def _apply(self, at: float, kind: str, args: tuple) -> None:
        if kind == "schedule":
            s, p, w, pat = args
            self._train = {"next": s, "period": p, "width": w, "pattern": pat, "slot": 0, "trim": None}
        elif kind == "start":
            p, w, pat = args
            self._train = {"next": math.ceil(self.tick_at(at)), "period": p, "width": w, "pattern": pat, "slot": 0, "trim": None}
        elif kind == "trim":  # trims add up until they apply, as in the firmware
            if self._train is not None:
                pending = self._train["trim"]
                phase = args[0] + (pending[0] if pending is not None else 0)
                self._train["trim"] = (phase, args[1])
        elif kind == "stop":
            self._train = None
        elif kind == "reset":
            self._boot = at
            self._train = None
            self.resets.append(at)

    def advance_to(self, t: float) -> None:
        """Run the MCU (commands, slots, edges) up to true time ``t``."""
        self._run(t, emit=True)
        self._spurious(t)
        self._t = t

    def _run(self, t: float, emit: bool) -> None:
        """Commands and slots up to true time ``t``, the lit slots' edges emitted if ``emit``."""
        self._pending.sort(key=lambda e: e[0])
        while True:
            next_cmd = self._pending[0][0] if self._pending else math.inf
            tr = self._train
            next_slot = self.time_of_tick(tr["next"]) if tr is not None else math.inf
            if min(next_cmd, next_slot) > t:
                break
            if next_cmd <= next_slot:
                self._apply(*self._pending.pop(0))
                continue
            if tr["trim"] is not None:  # this slot moves by the phase; the slots after it follow the new period
                phase, tr["period"] = tr["trim"]
                tr["trim"] = None
                tr["next"] += phase
                continue
            start = tr["next"]
            if emit and tr["pattern"][tr["slot"] % len(tr["pattern"])]:
                self._emit(start, start + tr["width"])
            tr["slot"] += 1
            tr["next"] = start + tr["period"]

    def _emit(self, rise: int, fall: int) -> None:
        c = self.cfg
        rs, fs = self.time_of_tick(rise), self.time_of_tick(fall)
        p = self.pulses
        p.rise_tick.append(rise)
        p.fall_tick.append(fall)
        p.rise_s.append(rs)
        p.fall_s.append(fs)
        self._reports.append((fs + c.report_latency_s, rise, fall))
        if c.gpio_connected:
            for ts, rising in ((rs, True), (fs, False)):
                late = c.gpio_latency_min_s + self._rng.exponential(c.gpio_jitter_s) if c.gpio_jitter_s > 0 else c.gpio_latency_min_s
                if self._rng.random() < c.gpio_outlier_prob:
                    late += self._rng.uniform(100e-6, 2e-3)
                self._gpio.append((int(round((ts + late) * 1e9)), rising))

    def _spurious(self, t: float) -> None:
        c = self.cfg
        if not (c.gpio_connected and c.gpio_spurious_hz > 0) or t <= self._t:
            return
        n = self._rng.poisson(c.gpio_spurious_hz * (t - self._t))
        for ts in np.sort(self._rng.uniform(self._t, t, n)):
            self._gpio.append((int(round(ts * 1e9)), bool(self._rng.random() < 0.5)))

    def take_edge_reports(self, until_s: float) -> list[tuple[int, int]]:
        """Edge reports (rise tick, fall tick) that have reached the Pi by ``until_s``."""
        got = [(r, f) for a, r, f in self._reports if a <= until_s]
        self._reports = [e for e in self._reports if e[0] > until_s]
        return got

    def take_gpio_events(self, until_s: float) -> list[tuple[int, bool]]:
        """GPIO edge events (timestamp ns, rising) timestamped by ``until_s``, in time order."""
        lim = int(until_s * 1e9)
        self._gpio.sort()
        got = [e for e in self._gpio if e[0] <= lim]
        self._gpio = self._gpio[len(got):]
        return got

    def windows(self, start_ns: int, end_ns: int) -> list[tuple[int, int]]:
        """The laser's true on-windows overlapping [start_ns, end_ns] (a ``device.sim.pulses.PulseSource``).

        Runs the MCU up to ``end_ns`` first, so the renderer sees every pulse of the frame.
        """
        self.advance_to(max(self._t, end_ns * 1e-9))
        p = self.pulses
        i = max(bisect.bisect_left(p.rise_s, start_ns * 1e-9) - 1, 0)
        return [(int(round(r * 1e9)), int(round(f * 1e9))) for r, f in zip(p.rise_s[i:], p.fall_s[i:])
                if f * 1e9 >= start_ns and r * 1e9 <= end_ns]

    def ping(self, t_send_s: float) -> tuple[int, int, int]:
        """A PING exchange sent at ``t_send_s``: (Pi send ns, MCU tick, Pi receive ns)."""
        c = self.cfg
        up = c.link_up_min_s + self._rng.uniform(0, c.usb_latency_max_s) + self._rng.exponential(50e-6)
        down = c.link_down_min_s + self._rng.uniform(0, c.usb_latency_max_s) + self._rng.exponential(50e-6)
        tick = math.floor(self.tick_at(t_send_s + up))
        return int(round(t_send_s * 1e9)), tick, int(round((t_send_s + up + 20e-6 + down) * 1e9))
