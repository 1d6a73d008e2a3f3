"""The laser as the device process sees it: the co-MCU (device/comcu.py) driven by the
synchronisation controller (device/sync/control.py), behind device.process.Laser.

* ``start(frame)``: opens the co-MCU link if needed, stops any old schedule (stale state from an
  earlier run), pings it a few times for the clock map and hands it to a new SyncController; the
  controller places the pulse train on the camera's frames as they come.
* ``frame_lit(frame)``: per frame, feeds the controller the co-MCU's edge reports, the laser
  trigger line's GPIO edges (when wired) and a ping now and then, and returns the controller's
  label (lit / unlit / None while not locked).
* A heartbeat thread keeps the co-MCU's schedule alive (its firmware switches the laser off when
  heartbeats stop) only while frames keep being serviced: if the frame loop hangs, the heartbeats
  stop too and the firmware turns the laser off by itself.
* Failures become ``LaserError``: "lost" (no answer, port gone), "reset" (the co-MCU announced a
  new boot or forgot its schedule), "refused" (a NACK, e.g. outside the eye-safety envelope),
  "fault" (the firmware latched a fault such as a missed heartbeat).
"""

from __future__ import annotations

import logging
import threading
import time
from typing import Callable

from device.camera.frame import Frame
from device.comcu import CoMcu, CoMcuError, CoMcuNack, CoMcuTrain
from device.process import LaserError
from device.sync.control import FrameInfo, SyncConfig, SyncController, SyncState
from protocol import mcu

log = logging.getLogger(__name__)


class LockedComcu:
    """A CoMcu shared by the frame loop and the heartbeat thread: one request at a time, the
    lock held for one request only, so a heartbeat waits at most one round trip."""

    def __init__(self, comcu: CoMcu):
        self.comcu = comcu
        self.lock = threading.Lock()

    def __getattr__(self, name):
        attr = getattr(self.comcu, name)
        if not callable(attr):
            return attr

        def locked(*args, **kwargs):
            with self.lock:
                return attr(*args, **kwargs)

        return locked


def _laser_error(exc: Exception) -> LaserError:
    if isinstance(exc, (CoMcuNack, ValueError)):  # refused by the firmware or by the placement
        return LaserError("refused", str(exc))
    return LaserError("lost", f"{type(exc).__name__}: {exc}")


class SyncedLaser:
    """device.process.Laser: see the module docstring.

    open_comcu: opens the link and returns a CoMcu (raises OSError/CoMcuError when it cannot).
    gpio_edges: returns the laser trigger line's new edges [(CLOCK_MONOTONIC ns, rising)], or None
    when the line is not wired (the clock map then uses pings only, less accurately).
    """

    def __init__(self, open_comcu: Callable[[], CoMcu], sync: SyncConfig, *,
                 gpio_edges: Callable[[], list[tuple[int, bool]]] | None = None,
                 ping_interval_s: float = 0.05, heartbeat_s: float | None = 0.005, watchdog_s: float = 0.3,
                 pings_at_start: int = 4, clock_ns: Callable[[], int] = time.monotonic_ns):
        """heartbeat_s: interval of the heartbeat thread; None = no thread, whoever owns the
        clock calls ``heartbeat()`` (the simulated hardware does, every 10 ms of its time).
        clock_ns: CLOCK_MONOTONIC of the Pi (simulated time in simulation)."""
        self.clock_ns = clock_ns
        self.open_comcu = open_comcu
        self.sync = sync
        self.gpio_edges = gpio_edges
        self.ping_interval_s = ping_interval_s
        self.heartbeat_s = heartbeat_s
        self.watchdog_s = watchdog_s
        self.pings_at_start = pings_at_start
        self.comcu: LockedComcu | None = None
        self.controller: SyncController | None = None
        self._lock = threading.Lock()  # start/stop/frame_lit against each other
        self._boots = 0
        self._last_ping = 0.0
        self._serviced = 0.0
        self._failure: LaserError | None = None  # seen by the heartbeat thread
        self._hb_stop = threading.Event()
        self._hb: threading.Thread | None = None

    @property
    def locked(self) -> bool:
        c = self.controller
        return c is not None and c.state is SyncState.LOCKED

    def start(self, frame: Frame) -> None:
        self._stop_heartbeat()
        with self._lock:
            try:
                if self.comcu is None:
                    self.comcu = LockedComcu(self.open_comcu())
                    self._boots = len(self.comcu.boot_infos)
                self.comcu.stop()  # whatever an earlier run left scheduled
                controller = SyncController(self.sync, CoMcuTrain(self.comcu))
                for _ in range(self.pings_at_start):
                    self._ping(controller)
                self.comcu.edges()  # drop reports of an older schedule
            except (CoMcuError, OSError) as exc:
                self._drop_link()
                raise _laser_error(exc) from exc
            self._boots = len(self.comcu.boot_infos)
            self.controller = controller
            self._failure = None
            self._serviced = self._now()
        if self.gpio_edges is not None:
            self.gpio_edges()  # edges from before this schedule pair with nothing
        if self.heartbeat_s is not None:
            self._hb_stop.clear()
            self._hb = threading.Thread(target=self._heartbeat_loop, name="comcu-heartbeat", daemon=True)
            self._hb.start()

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
                if self._now() - self._last_ping >= self.ping_interval_s:
                    self._ping(controller)
                edges = self.comcu.edges()
                if len(self.comcu.boot_infos) != self._boots:
                    self._boots = len(self.comcu.boot_infos)
                    raise LaserError("reset", f"the co-MCU rebooted (reset cause 0x{self.comcu.boot_infos[-1].reset_cause:02x})")
                # a cut pulse or a forced (late) fall is not where the schedule put it: not evidence
                controller.on_mcu_edges([(e.rise_ticks, e.fall_ticks) for e in edges if not e.flags])
                controller.on_gpio_edges(gpio)
                info = FrameInfo(frame.seq, frame.sensor_timestamp_ns, frame.exposure_us * 1e-6,
                                 frame.line_time_ns * 1e-9, frame.frame_duration_us * 1e-6)
                label = controller.on_frame(info, self.clock_ns())
                if label.lit is None and controller.state is SyncState.LOCKED:
                    log.debug("frame %d not labelled while locked: %s", frame.seq, label.reason)
            except CoMcuNack as exc:
                raise self._refusal(exc) from exc
            except (CoMcuError, OSError, ValueError) as exc:
                if isinstance(exc, OSError):
                    self._drop_link()
                raise _laser_error(exc) from exc
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
    def _ping(self, controller: SyncController) -> None:
        p = self.comcu.ping()
        controller.on_ping(p.host_send_ns, p.mcu_rx_ticks, p.host_recv_ns)  # tick when the PING arrived
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
        A failure is kept and raised by the next ``frame_lit``."""
        comcu, controller = self.comcu, self.controller
        if comcu is None or controller is None or self._failure is not None:
            return
        if self._now() - self._serviced > self.watchdog_s:
            return
        try:
            state, fault = comcu.heartbeat()
        except (CoMcuError, OSError) as exc:
            self._failure = _laser_error(exc)
            return
        if fault:
            self._failure = LaserError("fault", f"co-MCU latched {fault!r} (state {state.name})")
        elif len(comcu.boot_infos) != self._boots:
            self._failure = LaserError("reset", "the co-MCU rebooted")

    def _heartbeat_loop(self) -> None:
        while not self._hb_stop.wait(self.heartbeat_s) and self._failure is None:
            self.heartbeat()

    def _stop_heartbeat(self) -> None:
        self._hb_stop.set()
        if self._hb is not None and self._hb is not threading.current_thread():
            self._hb.join(timeout=1.0)
        self._hb = None
