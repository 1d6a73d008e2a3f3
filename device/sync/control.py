"""Laser-camera synchronisation controllers: the thesis's P controller (baseline) and ours.

**Thesis (section 5.2.2, 5.3.2), ``ThesisController``.** The pulse train is started once and its
start is estimated with Algorithm 1 (``algorithm1_start_estimate``): ``T_pwm`` within an interval
of ~185 us. Every frame, with ``p`` the frame period,

    k = floor((T_pts - T_pwm) / p)                          (5.1)
    T_last = T_pwm + k p                                    (5.2)
    e = T_pts - T_last + delta - interval / 2               (5.3)

wrapped into (-p/2, p/2), and a P controller with gain 0.233 f (P = 7 at 30 Hz) sets the camera's
frame rate ``f = f0 (1 + 0.233 e / p)``. The prediction ``T_pwm + k p`` assumes the pulse train
runs at exactly ``p`` on the Pi's clock: the MCU's drift is never observed (thesis 7.2.3: "an open
loop system"), so the true error grows by drift x elapsed time while the controller reports lock.

**Ours, ``SyncController``.** The camera runs free at a fixed frame duration; nothing is asked of
it. The MCU's pulse train is placed on the camera instead: from the camera's timestamps (a
lower-envelope line of SensorTimestamp against sequence number, robust to dropped frames and
timestamp latency) and the MCU->Pi clock map (``clock_map``: GPIO edge pairs, ping fallback), it
computes for each coming frame the ROI's exposure window (``placement``), converts it to MCU
ticks and trims the train's phase and period (closed loop on drift). It verifies every lit pulse
from the MCU's own edge report mapped to Pi time, and only then labels a frame lit.

Lock: ``lock_pulses`` consecutive lit pulses measured inside the window with the guard (the
guard is ``guard_sigmas`` times the 1-sigma placement uncertainty, at least ``min_guard_s``).
Re-lock: dropped frames are bridged by the camera line (sequence numbers); a camera restart
(sequence going back, or timestamps off the line) or an MCU reset (its tick going back, or the
expected pulse reports missing) drops to ACQUIRING and starts a new train; so does a command
the co-MCU refuses (the reason is kept). A guard above ``max_guard_s`` stops the laser and stays
ACQUIRING; an MCU drift beyond ``max_drift_ppm`` is the ERROR state: the laser is stopped rather
than run on a schedule that cannot be trusted, and ``reason`` says why.

Which frames are lit follows ``pattern`` on the camera's sequence number
(``lit = pattern[sequence % len(pattern)]``, e.g. every other frame for differencing, docs/thesis-notes.md N10);
the controller's ``FrameLabel`` for each frame carries it (None while not locked).
"""

from __future__ import annotations

import enum
import logging
import math
from dataclasses import dataclass, field
from typing import Callable, Protocol, Sequence


from device.sync.clock_map import (ClockEstimate, EdgePairing, GpioClockMap, LineFit, PingClockMap, Window,
                                   lower_envelope_fit, refit_due)
from device.sync.placement import check_separation, roi_exposure_window

log = logging.getLogger(__name__)

THESIS_GAIN_PER_HZ = 7.0 / 30.0  # thesis 5.3.2: P = 7 at 30 Hz, i.e. 0.233 f
TRIM_LEAD_S = 100e-6  # firmware_pwm: a TRIM never moves a slot starting sooner than this after it arrives
#: A pulse may start up to this many ticks early or late of where its frame wants it without a
#: TRIM (each one is a round trip on the UART: issue 18); the train is that much wider on each
#: side, so the frame's window stays covered: start in [want - 2 D, want], see _start_train.
TRIM_DEADBAND_TICKS = 1


class LaserScheduler(Protocol):
    """The co-MCU's pulse train, as the controllers use it (the real one is ``device.laser.comcu``).

    - ``schedule``: replace the train (stopping a running one) from ``first_start_tick`` on: slot n starts at
      ``first_start_tick + n * period_ticks`` and is lit (for ``width_ticks``) if
      ``pattern[n % len(pattern)]``. Returns the first lit slot (the firmware's ACK.info).
    - ``trim``: as the firmware's TRIM (firmware_pwm/README.md) with the new period absolute: the
      first slot, lit or not, starting at least ``TRIM_LEAD_S`` after the trim arrives moves by
      ``phase_ticks``; the slots after it follow at ``period_ticks``; trims waiting together add up.
      Returns the slot it moved (firmware_pwm/src/core.c do_trim: ACK.info), counted from the
      schedule's slot 0.
    - ``stop``: laser off, train cleared.
    Out-of-envelope or impossible requests raise an exception naming the reason.
    """

    def schedule(self, first_start_tick: int, period_ticks: int, width_ticks: int, pattern: Sequence[bool]) -> int: ...

    def trim(self, phase_ticks: int, period_ticks: int) -> int: ...

    def stop(self) -> None: ...


class FrameDurationControl(Protocol):
    """The camera's frame-duration control (libcamera FrameDurationLimits), used by the thesis controller."""

    def request(self, frame_duration_s: float | None = None, exposure_s: float | None = None) -> None: ...


@dataclass(frozen=True)
class FrameInfo:
    """What a controller reads from one delivered frame's metadata."""

    sequence: int
    sensor_timestamp_ns: int
    exposure_s: float  # ExposureTime metadata (nominal line time x lines)
    line_time_s: float  # nominal line time of the sensor mode
    frame_duration_s: float  # FrameDuration metadata (nominal line time x frame length lines)
    readout_offset_rows: int = 0  # sensor rows read before image row 0 (device.camera.frame.Frame)


class SyncState(enum.Enum):
    ACQUIRING = "acquiring"
    LOCKED = "locked"
    ERROR = "error"


@dataclass(frozen=True)
class FrameLabel:
    """Goes into the frame's metadata: whether the laser lit this frame's ROI (None: unknown)."""

    sequence: int
    lit: bool | None
    state: SyncState
    verified: bool  # lit/unlit confirmed from the MCU's edge report of this frame's slot
    reason: str = ""


@dataclass(frozen=True)
class SyncConfig:
    row_min: int
    row_max: int
    frame_duration_s: float
    pattern: tuple[bool, ...] = (True, False)
    tick_hz: float = 2e6
    first_rise_min_tick: int = 0  # the co-MCU lights nothing before this tick of its boot (mcu.Info.first_rise_min_ticks)
    guard_sigmas: float = 5.0
    guard_headroom: float = 1.3  # a new train's guard over the one needed now, so it is not widened every frame
    narrow_interval_s: float = 1.0  # narrow the guard (a new schedule) at most this often
    min_guard_s: float = 2e-6
    max_guard_s: float = 2e-3
    lock_pulses: int = 2
    unlock_misses: int = 2
    max_drift_ppm: float = 2000.0
    cmd_latency_max_s: float = 3e-3
    report_wait_s: float = 5e-3
    gpio_latency_min_s: float = 3e-6
    gpio_prior_jitter_s: float = 50e-6
    gpio_window: int = 256
    gpio_stale_s: float = 2.0
    # PING (14 bytes on the line incl. delimiters) and PONG (29 bytes) at device.laser.comcu's 250000 baud 8N1
    link_up_min_s: float = 14 * 10 / 250_000
    link_down_min_s: float = 29 * 10 / 250_000
    camera_window: int = 256
    camera_prior_jitter_s: float = 50e-6
    camera_jump_s: float = 1e-3

    def __post_init__(self) -> None:
        if not self.pattern or not any(self.pattern):
            raise ValueError("pattern must light at least one frame")
        if not 0 <= self.row_min <= self.row_max:
            raise ValueError(f"ROI rows must satisfy 0 <= row_min <= row_max, got {self.row_min}..{self.row_max}")
        if self.guard_sigmas <= 0 or self.min_guard_s <= 0 or self.max_guard_s < self.min_guard_s:
            raise ValueError("guard_sigmas and min_guard_s must be positive and max_guard_s >= min_guard_s")

    def lit(self, sequence: int) -> bool:
        return bool(self.pattern[sequence % len(self.pattern)])


class CameraTimeline:
    """SensorTimestamp (ns) as a line in the sequence number, with restart detection (one job)."""

    def __init__(self, window: int, prior_jitter_s: float, jump_s: float) -> None:
        self._w = Window(window)
        self.prior = prior_jitter_s
        self.jump_s = jump_s
        self._fit: LineFit | None = None
        self._off = 0
        self._since_fit = 0
        self.restarts = 0

    def clear(self) -> None:
        self._w.clear()
        self._fit = None
        self._off = 0

    def add(self, seq: int, ts_ns: int) -> bool:
        """Add a frame; True if it shows the camera restarted (the line was cleared)."""
        last = self._w.last()
        restarted = False
        if last is not None and seq <= last[0]:
            restarted = True
            last = None
        elif self._fit is not None:
            off = (ts_ns - self.predict_ns(seq)) * 1e-9
            if abs(off) > max(self.jump_s, 20 * self.sigma_s(seq)):
                self._off += 1
                if self._off < 2:
                    return False  # one stray timestamp: ignore it
                restarted = True
            else:
                self._off = 0
        if restarted:
            self.clear()
            self.restarts += 1
            if last is not None:
                self._w.append(*last)
        self._w.append(seq, ts_ns)
        self._since_fit += 1
        if self._fit is None or restarted or refit_due(len(self._w), self._since_fit):
            self._refit()
        return restarted

    def _refit(self) -> None:
        self._since_fit = 0
        if len(self._w) < 3:
            self._fit = None
            return
        s, ns = self._w.a, self._w.b
        self._ref = (int(s[-1]), int(ns[-1]))
        self._fit = lower_envelope_fit((s - s[-1]).astype(float), (ns - ns[-1]) * 1e-9, prior_sigma=self.prior)

    @property
    def ready(self) -> bool:
        return self._fit is not None

    @property
    def period_s(self) -> float:
        return self._fit.b

    def predict_ns(self, seq: int) -> float:
        return self._ref[1] + 1e9 * self._fit.predict(float(seq - self._ref[0]))

    def sigma_s(self, seq: int) -> float:
        return float(self._fit.sigma(float(seq - self._ref[0])))


def _sigma_at(est: ClockEstimate, pi_ns: float) -> float:
    return float(est.sigma_s(est.pi_to_mcu_tick(pi_ns)))


@dataclass
class _Train:
    """The controller's copy of the MCU's train: slot n <-> camera frame ``frame0 + n``."""

    frame0: int
    ref_slot: int
    ref_tick: int
    period: int
    width: int
    guard_s: float
    scheduled_ns: int
    pending_reports: dict[int, int] = field(default_factory=dict)  # rise tick -> fall tick

    def start(self, slot: int) -> int:
        return self.ref_tick + (slot - self.ref_slot) * self.period


class SyncController:
    """Ours: free-running camera, MCU phase and period trimmed to it through the clock map."""

    def __init__(self, cfg: SyncConfig, scheduler: LaserScheduler) -> None:
        self.cfg = cfg
        self.mcu = scheduler
        self.gpio_map = GpioClockMap(cfg.tick_hz, cfg.gpio_latency_min_s, cfg.gpio_window, cfg.gpio_prior_jitter_s)
        self.ping_map = PingClockMap(cfg.tick_hz, cfg.link_up_min_s, cfg.link_down_min_s)
        self.pairing = EdgePairing()
        self.camera = CameraTimeline(cfg.camera_window, cfg.camera_prior_jitter_s, cfg.camera_jump_s)
        self.state = SyncState.ACQUIRING
        self.reason = "starting"
        self.train: _Train | None = None
        self._good = 0
        self._bad = 0
        self._last_report_tick = -1
        self._last_pair_ns: int | None = None
        self._now_ns = 0
        self.events: list[tuple[int, str]] = []  # (Pi ns, what happened): resets, restarts, locks
        #: the source ("gpio", "ping") of the clock map the last control step placed pulses with, or None
        self.clock_source: str | None = None
        self.refusals = 0

    # --- inputs --------------------------------------------------------------------------------
    def on_ping(self, send_ns: int, tick: int, recv_ns: int) -> None:
        last = self.ping_map.last_tick
        if last is not None and tick < last:
            self._mcu_reset(recv_ns, f"MCU tick went back from {last} to {tick}")
        self.ping_map.add(send_ns, tick, recv_ns)

    def on_mcu_edges(self, reports: Sequence[tuple[int, int]]) -> None:
        for rise, fall in reports:
            if rise < self._last_report_tick:
                self._mcu_reset(self._now_ns, f"MCU edge tick went back from {self._last_report_tick} to {rise}")
            self._last_report_tick = rise
            self.pairing.add_mcu(rise, fall)
            if self.train is not None:
                self.train.pending_reports[rise] = fall

    def on_gpio_edges(self, events: Sequence[tuple[int, bool]]) -> None:
        for ns, rising in events:
            self.pairing.add_gpio(ns, rising)

    def _mcu_reset(self, now_ns: int, why: str) -> None:
        log.warning("co-MCU reset detected: %s", why)
        self.events.append((now_ns, "mcu-reset"))
        self.gpio_map.clear()
        self.ping_map.clear()
        self.pairing.clear()
        self._last_report_tick = -1
        self._last_pair_ns = None
        self._unlock(f"MCU reset ({why})")
        self.train = None

    def _unlock(self, why: str) -> None:
        if self.state is SyncState.LOCKED:
            log.info("sync lost: %s", why)
            self.events.append((self._now_ns, "unlock"))
        if self.state is not SyncState.ERROR:
            self.state = SyncState.ACQUIRING
        self.reason = why
        self._good = 0
        self._bad = 0

    # --- the clock map -----------------------------------------------------------------------
    def clock(self) -> ClockEstimate | None:
        """The best MCU->Pi map now: the GPIO pairs' if fresh and no less certain than the
        pings' (from a few pulses it may not be yet: a pair of close block minima leaves its slope
        loose, and a controller that then refused to pulse would never get the pairs that tighten
        it), else the pings', else None."""
        gpio, ping = self.gpio_map.estimate(), self.ping_map.estimate()
        if gpio is None or self._last_pair_ns is None or self._now_ns - self._last_pair_ns >= self.cfg.gpio_stale_s * 1e9:
            return ping
        # compared where the pulses are placed: two frames ahead (on_frame's guard), where a loose
        # slope has strayed further than now
        ahead_ns = self._now_ns + 2 * self.cfg.frame_duration_s * 1e9
        if ping is not None and _sigma_at(ping, ahead_ns) < _sigma_at(gpio, ahead_ns):
            return ping
        return gpio

    def _update_pairs(self) -> None:
        est = self.gpio_map.estimate() or self.ping_map.estimate()
        if est is None:
            return
        for tick, ns in self.pairing.pair(est, self._now_ns, max_window_s=0.25 * self.cfg.frame_duration_s):
            self.gpio_map.add(tick, ns)
            self._last_pair_ns = ns

    # --- the control step --------------------------------------------------------------------
    def on_frame(self, frame: FrameInfo, now_ns: int) -> FrameLabel:
        """One control step per delivered frame; returns the label for that frame's metadata."""
        cfg = self.cfg
        self._now_ns = now_ns
        if self.camera.add(frame.sequence, frame.sensor_timestamp_ns):
            log.warning("camera restart detected at sequence %d", frame.sequence)
            self.events.append((now_ns, "camera-restart"))
            self._unlock("camera restarted")
            self.train = None  # a new train is placed on the new frame phase
        self._update_pairs()
        est = self.clock()
        self.clock_source = None if est is None else est.source
        if est is None or not self.camera.ready:
            return self._label(frame, None, "no clock map yet" if est is None else "camera line not ready")
        if est.n_samples >= 16 and abs(est.drift_ppm) > cfg.max_drift_ppm:
            return self._error(frame, f"MCU clock drift {est.drift_ppm:+.0f} ppm is beyond the +-{cfg.max_drift_ppm:.0f} ppm "
                                      "the controller accepts (wrong MCU clock or a failing oscillator)")
        guard = self._guard(est, frame.sequence + 2)
        if guard > cfg.max_guard_s:
            return self._fail_acquire(frame, f"timing uncertainty {guard / cfg.guard_sigmas * 1e6:.0f} us needs a guard "
                                             f"above the {cfg.max_guard_s * 1e6:.0f} us limit")
        if self.state is SyncState.ERROR:
            self.state = SyncState.ACQUIRING
        # this frame's pulse decides the lock before the train is re-placed (_needs_new_width)
        label = self._update_lock(frame, self._verify(frame, est))
        if self.train is not None and self._needs_new_width(frame, est, guard):
            self.train = None
        if self.train is None:
            self._start_train(frame, est)
        else:
            self._trim(frame, est)
        return label

    def _placement_sigma(self, est: ClockEstimate, seq: int) -> float:
        return math.hypot(_sigma_at(est, self.camera.predict_ns(seq)), self.camera.sigma_s(seq))

    def _guard(self, est: ClockEstimate, seq: int) -> float:
        """The guard that placing frame ``seq``'s pulse with ``est`` needs."""
        return max(self.cfg.min_guard_s, self.cfg.guard_sigmas * self._placement_sigma(est, seq))

    def _needs_new_width(self, frame: FrameInfo, est: ClockEstimate, guard: float) -> bool:
        """Widen at once when the uncertainty grew past the guard; narrow when it fell: at once
        when it fell by much and the new train would cost no scan (while acquiring, or locked with
        no lit frame before the first one it reaches: e.g. at 20 scans/s the command latency puts
        that beyond the next lit frame), otherwise at most every ``narrow_interval_s``."""
        g = self.train.guard_s
        if guard > g:
            return True
        recent = self._now_ns - self.train.scheduled_ns < self.cfg.narrow_interval_s * 1e9
        need = guard * self.cfg.guard_headroom
        if need < 0.4 * g and (self.state is not SyncState.LOCKED or not self._scans_lost(frame, est)):
            return True
        return not recent and need < 0.75 * g

    def _scans_lost(self, frame: FrameInfo, est: ClockEstimate) -> bool:
        """Whether a new train now would leave a lit frame without a verified pulse (the train
        before it is stopped at once: firmware_pwm SCHEDULE needs a STOP first)."""
        first = self._new_train(frame, est)[0]
        return any(self.cfg.lit(s) for s in range(frame.sequence + 1, first))

    def _window_ns(self, seq: int, frame: FrameInfo) -> tuple[float, float]:
        """ROI exposure window of frame ``seq`` (Pi ns) on the camera line.

        Exposure and line time are nominal (counted in lines of the sensor's own clock); the
        camera oscillator's error shows as the ratio of the measured frame period to the
        nominal frame duration, and scales both.
        """
        scale = self.camera.period_s / frame.frame_duration_s * 1e9
        t = self.camera.predict_ns(seq)
        off = frame.readout_offset_rows
        s, e = roi_exposure_window(t, frame.exposure_s * scale, frame.line_time_s * scale, self.cfg.row_min + off,
                                   self.cfg.row_max + off)
        return float(s), float(e)

    def _first_reachable(self, frame: FrameInfo, est: ClockEstimate, guard: float) -> tuple[int, float, float, float]:
        """The first frame after ``frame`` that a train scheduled now can light with ``guard``:
        (its sequence, the MCU tick where its pulse must begin, its ROI window in Pi ns)."""
        cfg = self.cfg
        earliest = self._now_ns + (cfg.cmd_latency_max_s + 1e-3) * 1e9
        seq = frame.sequence + 1
        while True:
            ws, we = self._window_ns(seq, frame)
            start = float(est.pi_to_mcu_tick(ws - guard * 1e9))  # MCU tick where the pulse must begin
            if ws - guard * 1e9 > earliest and start >= cfg.first_rise_min_tick:
                return seq, start, ws, we
            seq += 1

    def _new_train(self, frame: FrameInfo, est: ClockEstimate) -> tuple[int, float, float, float, float]:
        """Where a train scheduled now begins: ``_first_reachable`` and its guard. The guard covers
        the frames until the train's own first lit pulse has fed the clock map (that frame + 2, as
        ``on_frame`` looks ahead): the map gets no new edges before, and with few pairs its
        uncertainty grows by tens of percent a frame meanwhile; sized for the next frames only,
        the train would be widened again before its first pulse, and each new train costs the lit
        frames before it."""
        cfg = self.cfg
        seq = frame.sequence + 1
        while True:  # the guard depends on the first frame the train reaches, and that on the guard
            first_lit = next(s for s in range(seq, seq + len(cfg.pattern)) if cfg.lit(s))
            guard = min(self._guard(est, first_lit + 2) * cfg.guard_headroom, cfg.max_guard_s)
            seq, start, ws, we = self._first_reachable(frame, est, guard)
            if first_lit >= seq:
                return seq, start, ws, we, guard

    def _start_train(self, frame: FrameInfo, est: ClockEstimate) -> None:
        cfg = self.cfg
        period_s = self.camera.period_s
        seq, start, ws, we, guard = self._new_train(frame, est)
        check_separation(period_s, frame.exposure_s, frame.line_time_s, cfg.row_min, cfg.row_max, guard)
        d = TRIM_DEADBAND_TICKS  # aimed d early, trimmed only beyond +-d: starts in [t0 - d, t0 + d]
        t0 = math.floor(start) - d
        t1 = math.ceil(float(est.pi_to_mcu_tick(we + guard * 1e9))) + d
        period = int(round(period_s / est.fit.b * cfg.tick_hz))
        width = t1 - t0 + 1
        pattern = [cfg.lit(seq + i) for i in range(len(cfg.pattern))]
        if self._command(self.mcu.schedule, t0, period, width, pattern) is None:
            return
        self.train = _Train(frame0=seq, ref_slot=0, ref_tick=t0, period=period, width=width, guard_s=guard,
                            scheduled_ns=self._now_ns)
        log.debug("train scheduled: frame %d at tick %d, period %d, width %d (guard %.1f us)", seq, t0, period, width, guard * 1e6)

    def _trim(self, frame: FrameInfo, est: ClockEstimate) -> None:
        """Move the first slot the trim can still reach onto its frame's window (``LaserScheduler.trim``)."""
        cfg, tr = self.cfg, self.train
        reach = self._now_ns + (cfg.cmd_latency_max_s + TRIM_LEAD_S) * 1e9
        slot = max(frame.sequence - tr.frame0 + 1, 0)
        while est.mcu_to_pi_ns(tr.start(slot)) <= reach:
            slot += 1
        ws, _ = self._window_ns(tr.frame0 + slot, frame)
        want = math.floor(float(est.pi_to_mcu_tick(ws - tr.guard_s * 1e9))) - TRIM_DEADBAND_TICKS
        period = int(round(self.camera.period_s / est.fit.b * cfg.tick_hz))
        phase = want - tr.start(slot)
        if abs(phase) <= TRIM_DEADBAND_TICKS and period == tr.period:
            return
        moved = self._command(self.mcu.trim, phase, period)
        if moved is None:
            return
        # The trim arrives somewhere in the command latency: it moves ``slot`` or, when it arrives
        # before the slot ahead of it begins, that one; the MCU's answer says which. The copy
        # follows it (a slot's start moves by the phase, the slots after it follow the new period;
        # trims waiting for one slot add up, as the copy's start then already holds the first).
        # Waiting until neither could be moved instead never trims at all when the frames arrive
        # at a phase where the next slot always begins within the latency (the simulated serve's:
        # 110 frames untrimmed, the train drifted out of its guard at frame 128).
        tr.ref_slot, tr.ref_tick, tr.period = moved, tr.start(moved) + phase, period

    def _command(self, send: Callable[..., int], *args) -> int | None:
        """Send a schedule/trim and return the MCU's answer (``LaserScheduler``); None after a refusal
        or a dead link, which drop to ACQUIRING (a new train next frame)."""
        try:
            return send(*args)
        except (ValueError, RuntimeError) as exc:  # ScheduleRefused / CoMcuNack / CoMcuTimeout name the reason
            why = f"co-MCU refused a command: {exc}"
            (log.debug if why == self.reason else log.warning)("%s (%s)", why, getattr(send, "__name__", send))
            self.refusals += 1
            self._unlock(why)
            self.train = None
            return None

    def _verify(self, frame: FrameInfo, est: ClockEstimate) -> str:
        """Was this frame's pulse where it had to be? "ok", "bad", "missing", "pending" or "n/a"."""
        tr = self.train
        if tr is None or frame.sequence < tr.frame0 or not self.cfg.lit(frame.sequence):
            return "n/a"
        expect = tr.start(frame.sequence - tr.frame0)
        half = tr.period // 2
        for r in [r for r in tr.pending_reports if r < expect - half]:
            del tr.pending_reports[r]  # reports of earlier slots (already judged) or of an older train
        rise = next((r for r in tr.pending_reports if abs(r - expect) < half), None)
        if rise is None:
            due = float(est.mcu_to_pi_ns(expect + tr.width)) + self.cfg.report_wait_s * 1e9
            return "pending" if due > self._now_ns else "missing"
        fall = tr.pending_reports.pop(rise)
        ws, we = self._window_ns(frame.sequence, frame)
        margin_start = (ws - float(est.mcu_to_pi_ns(rise))) * 1e-9
        margin_end = (float(est.mcu_to_pi_ns(fall)) - we) * 1e-9
        top = 2 * tr.guard_s + 2 / self.cfg.tick_hz
        if 0.0 < margin_start < top and 0.0 < margin_end < top:
            return "ok"
        log.info("frame %d: its pulse began %.1f us before its window and ended %.1f us after it "
                 "(each must be within 0-%.1f us)", frame.sequence, margin_start * 1e6, margin_end * 1e6, top * 1e6)
        return "bad"

    def _update_lock(self, frame: FrameInfo, status: str) -> FrameLabel:
        cfg = self.cfg
        if status == "ok":
            self._good += 1
            self._bad = 0
        elif status in ("bad", "missing"):
            self._bad += 1
            self._good = 0
        if self.state is SyncState.ACQUIRING and self._good >= cfg.lock_pulses:
            self.state = SyncState.LOCKED
            self.reason = ""
            self.events.append((self._now_ns, "lock"))
            log.info("sync locked at sequence %d", frame.sequence)
        elif self.state is SyncState.LOCKED and self._bad >= cfg.unlock_misses:
            self._unlock(f"lit pulses {status} (outside the window or not reported)")
            self.train = None
        if self.state is not SyncState.LOCKED:
            return self._label(frame, None, self.reason)
        if status == "n/a":  # an unlit slot; a lit one before the current train began is not known
            lit = cfg.lit(frame.sequence)
            return FrameLabel(frame.sequence, None if lit else False, self.state, not lit,
                              "before the current pulse train" if lit else "")
        if status == "ok":
            return FrameLabel(frame.sequence, True, self.state, True)
        return FrameLabel(frame.sequence, None, self.state, False, f"this frame's pulse is {status}")

    def _label(self, frame: FrameInfo, lit: bool | None, reason: str) -> FrameLabel:
        return FrameLabel(frame.sequence, lit, self.state, False, reason)

    def _fail_acquire(self, frame: FrameInfo, why: str) -> FrameLabel:
        self._unlock(why)
        if self.train is not None:
            self.mcu.stop()
            self.train = None
        return self._label(frame, None, why)

    def _error(self, frame: FrameInfo, why: str) -> FrameLabel:
        if self.state is not SyncState.ERROR:
            log.error("sync error: %s", why)
            self.events.append((self._now_ns, "error"))
        self._unlock(why)
        self.state = SyncState.ERROR
        self.reason = why
        self.gpio_map.clear()  # its pairs may be what is wrong; the ping map re-checks the drift
        self.pairing.clear()
        self._last_pair_ns = None
        if self.train is not None:
            self.mcu.stop()
            self.train = None
        return self._label(frame, None, why)


# --- the thesis's scheme ------------------------------------------------------------------------

def algorithm1_start_estimate(start_pwm: Callable[[], None], time_cpu_ns: Callable[[], int],
                              time_gpu_ns: Callable[[], int], interval_max_ns: int,
                              max_tries: int = 100) -> tuple[int, int]:
    """Thesis Algorithm 1: (T_pwm, interval): the train started within [T_pwm, T_pwm + interval)."""
    for _ in range(max_tries):
        t1 = time_cpu_ns()
        start_pwm()
        t_gpu = time_gpu_ns()
        t2 = time_cpu_ns()
        interval = t2 - t1
        if interval < interval_max_ns:
            return t_gpu - interval, interval
    raise RuntimeError(f"PWM start interval stayed above {interval_max_ns} ns in {max_tries} tries")


def thesis_error_s(t_pts_s: float, t_pwm_s: float, period_s: float, delta_s: float, interval_s: float) -> float:
    """Eq. 5.1-5.3, wrapped into (-p/2, p/2] as in section 5.2.2."""
    k = math.floor((t_pts_s - t_pwm_s) / period_s)  # (5.1)
    t_last = t_pwm_s + k * period_s  # (5.2)
    e = t_pts_s - t_last + delta_s - interval_s / 2  # (5.3)
    e = math.fmod(e, period_s)
    if e > period_s / 2:
        e -= period_s
    elif e <= -period_s / 2:
        e += period_s
    return e


class ThesisController:
    """Baseline: P controller on the camera frame rate against the predicted pulse train (open loop in drift).

    With a pattern (docs/thesis-notes.md N10) a frame is labelled lit if the slot eq. 5.1 assigns it is lit.
    """

    def __init__(self, cfg: SyncConfig, camera: FrameDurationControl, t_pwm_ns: int, interval_ns: int,
                 delta_s: float, pattern: Sequence[bool], lock_frames: int = 5) -> None:
        self.cfg = cfg
        self.pattern = tuple(pattern)  # the train's pattern from its first slot (slot 0 = T_pwm)
        self.camera = camera
        self.t_pwm_s = t_pwm_ns * 1e-9
        self.interval_s = interval_ns * 1e-9
        self.delta_s = delta_s
        self.f0 = 1.0 / cfg.frame_duration_s
        self.gain = THESIS_GAIN_PER_HZ * self.f0
        self.lock_frames = lock_frames
        self.state = SyncState.ACQUIRING
        self._good = 0

    def on_frame(self, frame: FrameInfo, now_ns: int) -> FrameLabel:
        p = self.cfg.frame_duration_s
        e = thesis_error_s(frame.sensor_timestamp_ns * 1e-9, self.t_pwm_s, p, self.delta_s, self.interval_s)
        f = self.f0 + self.gain * (e / p)
        self.camera.request(frame_duration_s=1.0 / f)
        self._good = self._good + 1 if abs(e) < self.interval_s else 0
        if self.state is SyncState.ACQUIRING and self._good >= self.lock_frames:
            self.state = SyncState.LOCKED
        if self.state is not SyncState.LOCKED:
            return FrameLabel(frame.sequence, None, self.state, False, "error above the system error")
        slot = round((frame.sensor_timestamp_ns * 1e-9 + self.delta_s - self.interval_s / 2 - self.t_pwm_s) / p)
        return FrameLabel(frame.sequence, bool(self.pattern[slot % len(self.pattern)]), self.state, False)
