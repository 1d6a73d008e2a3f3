"""The laser as the device process sees it: the co-MCU (device/laser/comcu.py) driven by the
synchronisation controller (device/sync/control.py), behind device.laser.base.Laser.

* ``start(frame)``: opens the co-MCU link if needed, stops any old schedule (stale state from an
  earlier run), asks its INFO for its tick rate (2 MHz in the 16 MHz firmware, 1 MHz in the 8 MHz
  one: firmware_pwm/README.md "Board variants"), pings it a few times for the clock map and hands
  it to a new SyncController running on that rate; the
  controller places the pulse train on the camera's frames as they come. It returns True when it
  finds that the co-MCU rebooted while it was not answering (a reset not reported yet: its boot
  announcement came late, or was garbled and its clock went back).
* ``frame_lit(frame)``: per frame, feeds the controller the co-MCU's edge reports, the laser
  trigger line's GPIO edges (when wired) and a ping now and then, and returns the controller's
  label (lit / unlit / None while not locked).
* A heartbeat thread keeps the co-MCU's schedule alive (its firmware switches the laser off when
  heartbeats stop) only while frames keep being serviced: if the frame loop hangs, the heartbeats
  stop too and the firmware turns the laser off by itself.
* Failures become ``LaserError``: "lost" (no answer, port gone), "reset" (the co-MCU announced a
  new boot, also when a request then went unanswered because it was restarting), "refused" (a
  NACK, e.g. outside the eye-safety envelope), "fault" (the firmware latched a fault such as a
  missed heartbeat).
"""

from __future__ import annotations

import logging
import threading
import time
from dataclasses import replace
from typing import Callable

from device.camera.frame import Frame
from device.laser.base import LaserError
from device.laser.comcu import CoMcu, CoMcuError, CoMcuNack, CoMcuTrain
from device.sync.control import FrameInfo, SyncConfig, SyncController, SyncState
from protocol import mcu

log = logging.getLogger(__name__)

#: Heartbeat interval: the firmware switches the laser off 50 ms after the last heartbeat
#: (firmware_pwm/src/config.h HEARTBEAT_TIMEOUT_TICKS), so 15 ms leaves three chances in that
#: window; each one is a 12-byte write (CoMcu.send_heartbeat), its ACK read by the frame loop.
HEARTBEAT_S = 0.015
#: Heartbeats written without an ACK read back before the link counts as lost: ~0.2 s of them,
#: four times the firmware's timeout (a busy frame loop reads the ACKs late, not never).
UNANSWERED_HEARTBEATS = 12


def pause_between_heartbeats(stop: threading.Event, interval_s: float) -> bool:
    """The heartbeat thread's wait: one interval asleep, then whether ``stop`` was set.

    A plain sleep, not ``stop.wait(interval_s)``: a timed Event.wait allocates a lock for the
    Condition's waiter list on every call, and on waking re-takes the Condition's lock and takes
    the waiter off the list (CPython's Lib/threading.py, ``Condition.wait``), and this thread
    wakes ~67 times a second. Measured on this project's machine (BENCHMARKS.md "Device
    process"), a wake-up of the timed Event.wait cost ~2x the CPU of a sleep's. The price: a set
    ``stop`` is seen up to one interval late, so ``_stop_heartbeat`` waits up to HEARTBEAT_S for
    the thread before the STOP goes out (the firmware's own timeout is the laser's backstop
    either way)."""
    time.sleep(interval_s)
    return stop.is_set()


class LockedComcu:
    """A CoMcu shared by the frame loop and the heartbeat thread: one request at a time, the
    lock held for one request only, so a heartbeat waits at most one round trip. A method's
    locked form is made at its first use and kept as an attribute of this object, so that later
    calls do not go through ``__getattr__`` and a new closure (67 heartbeats and ~60 other calls
    a second at 20 scans/s); it looks the method up on the CoMcu at each call. Values (counters,
    the heartbeat state, the port) are read from the CoMcu at every access."""

    def __init__(self, comcu: CoMcu):
        self.comcu = comcu
        self.lock = threading.Lock()

    def __getattr__(self, name):
        comcu = self.comcu
        attr = getattr(comcu, name)
        if not callable(attr):
            return attr

        def locked(*args, **kwargs):
            with self.lock:
                return getattr(comcu, name)(*args, **kwargs)

        setattr(self, name, locked)
        return locked


def _laser_error(exc: Exception) -> LaserError:
    if isinstance(exc, (CoMcuNack, ValueError)):  # refused by the firmware or by the placement
        return LaserError("refused", str(exc))
    return LaserError("lost", f"{type(exc).__name__}: {exc}")


class SyncedLaser:
    """device.laser.base.Laser: see the module docstring.

    open_comcu: opens the link and returns a CoMcu (raises OSError/CoMcuError when it cannot).
    gpio_edges: returns the laser trigger line's new edges [(CLOCK_MONOTONIC ns, rising)], or None
    when the line is not wired (the clock map then uses pings only, less accurately).
    """

    def __init__(self, open_comcu: Callable[[], CoMcu], sync: SyncConfig, *,
                 gpio_edges: Callable[[], list[tuple[int, bool]]] | None = None,
                 ping_interval_s: float = 0.05, ping_interval_gpio_s: float = 0.5,
                 heartbeat_s: float | None = HEARTBEAT_S, watchdog_s: float = 0.3,
                 pings_at_start: int = 4, clock_ns: Callable[[], int] = time.monotonic_ns,
                 envelope_refusal: Callable[[mcu.Info], str | None] | None = None):
        """ping_interval_s: pings while the clock map runs on pings; ping_interval_gpio_s: while it
        runs on the trigger line's GPIO edges, when the pings only keep the fallback map and the
        reboot check (its clock going back) alive: each is a round trip on the UART.
        heartbeat_s: interval of the heartbeat thread; None = no thread, whoever owns the
        clock calls ``heartbeat()`` (the simulated hardware does, every HEARTBEAT_S of its time).
        clock_ns: CLOCK_MONOTONIC of the Pi (simulated time in simulation).
        envelope_refusal: why the co-MCU's compiled-in envelope (its INFO) is not Class 1 for this
        laser, or None (device.service.assembly.envelope_refusal); ``start`` then refuses."""
        self.clock_ns = clock_ns
        self.open_comcu = open_comcu
        self.sync = sync
        self.gpio_edges = gpio_edges
        self.ping_interval_s = ping_interval_s
        self.ping_interval_gpio_s = ping_interval_gpio_s
        self.heartbeat_s = heartbeat_s
        self.watchdog_s = watchdog_s
        self.pings_at_start = pings_at_start
        self.envelope_refusal = envelope_refusal
        self.comcu: LockedComcu | None = None
        self.controller: SyncController | None = None
        self._lock = threading.Lock()  # start/stop/frame_lit against each other
        self._boots = 0  # boot announcements of the co-MCU accounted for (reported as a reset, or the first)
        self._mcu_ticks: int | None = None  # co-MCU clock at the last ping
        self._clock_went_back: str | None = None  # a reboot seen in the pings, not yet accounted for
        self._last_ping = 0.0
        self._serviced = 0.0
        self._failure: LaserError | None = None  # seen by the heartbeat thread
        self._hb_stop = threading.Event()
        self._hb: threading.Thread | None = None
        self._hb_acked = self._hb_sent_at_ack = 0  # heartbeat ACKs read, and heartbeats sent when the newest was

    @property
    def locked(self) -> bool:
        c = self.controller
        return c is not None and c.state is SyncState.LOCKED

    def start(self, frame: Frame) -> bool:
        """Schedule the laser from the frames after ``frame``; True if the co-MCU turned out to
        have rebooted since the last schedule without that having been reported (see above)."""
        self._stop_heartbeat()
        with self._lock:
            fresh = self.comcu is None
            try:
                if fresh:
                    self.comcu = LockedComcu(self.open_comcu())
                self.comcu.stop()  # whatever an earlier run left scheduled
                info = self.comcu.info()  # the firmware's clock and envelope, whatever its build
                why = self.envelope_refusal(info) if self.envelope_refusal is not None else None
                if why is not None:
                    raise LaserError("refused", why)
                controller = SyncController(replace(self.sync, tick_hz=info.ticks_per_second,
                                                    first_rise_min_tick=info.first_rise_min_ticks),
                                            CoMcuTrain(self.comcu))
                for _ in range(self.pings_at_start):
                    self._ping(controller)
                self.comcu.edges()  # drop reports of an older schedule
            except (CoMcuError, OSError) as exc:
                failure = _laser_error(exc) if fresh else self._classify(exc)  # a new link: its boot is no reset
                self._drop_link()
                raise failure from exc
            if fresh:
                self._boots = len(self.comcu.boot_infos)  # a new link: its boot announcement is no reset
            rebooted = self._reboot_seen(self.comcu)
            if rebooted:
                log.warning("the co-MCU rebooted while it did not answer: %s", rebooted)
            self._account_reboots(self.comcu)
            self.controller = controller
            self._failure = None
            self._serviced = self._now()
            self._hb_acked, self._hb_sent_at_ack = self.comcu.heartbeat_acks, self.comcu.heartbeats_sent
        if self.gpio_edges is not None:
            self.gpio_edges()  # edges from before this schedule pair with nothing
        if self.heartbeat_s is not None:
            self._hb_stop.clear()
            self._hb = threading.Thread(target=self._heartbeat_loop, name="comcu-heartbeat", daemon=True)
            self._hb.start()
        return rebooted is not None

    def stop(self) -> None:
        self._stop_heartbeat()
        with self._lock:
            self.controller = None
            if self.comcu is not None:
                try:
                    self.comcu.stop()
                except (CoMcuError, OSError) as exc:
                    log.warning("co-MCU did not acknowledge STOP (%s); its heartbeat timeout stops the laser", exc)

    def frame_lit(self, frame: Frame) -> bool | None:
        self._serviced = self._now()
        if self._failure is not None:
            raise self._failure
        gpio = self.gpio_edges() if self.gpio_edges is not None else []
        with self._lock:
            controller = self.controller
            if controller is None or self.comcu is None:
                raise LaserError("lost", "laser not started")
            try:
                # the map of the last frame's step: the fit again here would cost as much as the step's own
                interval = self.ping_interval_gpio_s if controller.clock_source == "gpio" else self.ping_interval_s
                if self._now() - self._last_ping >= interval:
                    self._ping(controller)
                edges = self.comcu.edges()
                rebooted = self._reboot_seen(self.comcu)
                if rebooted:
                    raise self._reset(self.comcu, rebooted)
                self._check_heartbeats(self.comcu)
                # a cut pulse or a forced (late) fall is not where the schedule put it: not evidence
                controller.on_mcu_edges([(e.rise_ticks, e.fall_ticks) for e in edges if not e.flags])
                controller.on_gpio_edges(gpio)
                info = FrameInfo(frame.seq, frame.sensor_timestamp_ns, frame.exposure_us * 1e-6,
                                 frame.line_time_ns * 1e-9, frame.frame_duration_us * 1e-6, frame.readout_offset_rows)
                label = controller.on_frame(info, self.clock_ns())
                if label.lit is None and controller.state is SyncState.LOCKED:
                    log.debug("frame %d not labelled while locked: %s", frame.seq, label.reason)
            except CoMcuNack as exc:
                raise self._refusal(exc) from exc
            except (CoMcuError, OSError, ValueError) as exc:
                failure = self._classify(exc)
                if isinstance(exc, OSError):
                    self._drop_link()
                raise failure from exc
        return label.lit

    def _refusal(self, exc: CoMcuNack) -> LaserError:
        """A NACK; when it is because the co-MCU is in FAULT (not_running, busy), name its faults."""
        if exc.reason in ("not_running", "busy"):
            try:
                faults = self.comcu.status().faults
            except (CoMcuError, OSError):
                faults = 0
            if faults:
                return LaserError("fault", f"{exc}; the co-MCU latched {mcu.Fault(faults)!r}")
        return LaserError("refused", str(exc))

    # internals
    def _check_heartbeats(self, comcu) -> None:
        """The heartbeats' ACKs read so far: a fault the MCU latched, or none answered for longer
        than the firmware's timeout takes to end a pulse (then the link is lost)."""
        hb = comcu.heartbeat_state
        if hb is not None and hb[1]:
            raise LaserError("fault", f"co-MCU latched {hb[1]!r} (state {hb[0].name})")
        sent, acked = comcu.heartbeats_sent, comcu.heartbeat_acks
        if acked > self._hb_acked:
            self._hb_acked, self._hb_sent_at_ack = acked, sent
        elif sent - self._hb_sent_at_ack > UNANSWERED_HEARTBEATS:
            raise LaserError("lost", f"co-MCU answered none of the last {sent - self._hb_sent_at_ack} heartbeats")

    def _reboot_seen(self, comcu) -> str | None:
        """How we know that ``comcu`` rebooted since its reboots were last accounted for, or None."""
        if len(comcu.boot_infos) != self._boots:
            return f"it announced a new boot (reset cause 0x{comcu.boot_infos[-1].reset_cause:02x})"
        return self._clock_went_back

    def _account_reboots(self, comcu) -> None:
        self._boots = len(comcu.boot_infos)
        self._clock_went_back = None

    def _reset(self, comcu, why: str) -> LaserError:
        """The co-MCU rebooted (``why``): a "reset", accounted for so that start() does not count it again."""
        self._account_reboots(comcu)
        self._mcu_ticks = None  # pings from here on are of the new boot
        return LaserError("reset", f"the co-MCU rebooted: {why}")

    def _classify(self, exc: Exception) -> LaserError:
        """A failed request as a LaserError: "reset" if the co-MCU rebooted meanwhile (the request
        reached it while it was restarting), otherwise "refused" or "lost"."""
        comcu = self.comcu
        rebooted = self._reboot_seen(comcu) if comcu is not None else None
        if rebooted:
            return self._reset(comcu, f"{rebooted}, and did not answer ({type(exc).__name__}: {exc})")
        return _laser_error(exc)

    def _ping(self, controller: SyncController) -> None:
        p = self.comcu.ping()
        controller.on_ping(p.host_send_ns, p.mcu_rx_ticks, p.host_recv_ns)  # tick when the PING arrived
        if self._mcu_ticks is not None and p.mcu_ticks < self._mcu_ticks:  # its clock counts from its boot
            self._clock_went_back = f"its clock went back from {self._mcu_ticks} to {p.mcu_ticks} ticks"
        self._mcu_ticks = p.mcu_ticks
        self._last_ping = self._now()

    def _drop_link(self) -> None:
        closer = getattr(getattr(self.comcu, "port", None), "close", None)
        if closer is not None:
            try:
                closer()
            except OSError:
                pass
        self.comcu = None

    def _now(self) -> float:
        return self.clock_ns() * 1e-9

    def heartbeat(self) -> None:
        """One heartbeat, if the laser runs and frames are being serviced (the watchdog: if the
        frame loop stops, heartbeats stop and the firmware switches the laser off by itself).
        Only written (CoMcu.send_heartbeat): ``frame_lit`` reads the ACKs, and a failure to write
        is kept and raised by the next ``frame_lit``."""
        comcu, controller = self.comcu, self.controller
        if comcu is None or controller is None or self._failure is not None:
            return
        if self._now() - self._serviced > self.watchdog_s:
            return
        try:
            comcu.send_heartbeat()
        except OSError as exc:
            self._failure = self._classify(exc)

    def _heartbeat_loop(self) -> None:
        while not pause_between_heartbeats(self._hb_stop, self.heartbeat_s) and self._failure is None:
            self.heartbeat()

    def _stop_heartbeat(self) -> None:
        self._hb_stop.set()
        if self._hb is not None and self._hb is not threading.current_thread():
            self._hb.join(timeout=1.0)
        self._hb = None
