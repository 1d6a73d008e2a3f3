"""The device process: camera -> synchronised laser (co-MCU) -> pipeline -> scans -> host link.

Composed of narrow interfaces so that the same orchestration runs on a Pi and in simulation:

* ``Camera``: ``start()``, ``stop()``, ``capture(timeout_s) -> Frame | None`` (device/camera);
* ``Laser``: the line laser pulsed by the co-MCU and kept in step with the camera
  (device/comcu.py + device/sync): ``start(frame)``, ``stop()``, ``frame_lit(frame)``, ``locked``;
* ``Pipeline``: ``(lit, dark) -> (ranges_m, quality)`` on the scan's angles (device/vision).

``SensorSource`` joins them into the ScanSource the link server (device/link.py) streams from.
It pairs each lit frame with its neighbouring unlit frame (frame differencing, docs/thesis-notes.md N10) into
one scan, and it never raises out of ``next_scan``: every failure degrades and is reported in
``status()`` (HEALTH.errors, codes protocol.messages.ErrorCode, and HEALTH's fault counters) and
``LinkSupervisor.health()`` instead:

* camera error or stall (no frame for ``stall_timeout_s``): laser off, error CAMERA_FAULT,
  camera restarted (counted), the laser re-synchronised on the first new frame;
* co-MCU lost or reset (``LaserError``): laser off, error LASER_FAULT + SYNC_LOST, retried every
  ``laser_retry_s`` until it answers again; while it is away no scan is made;
* a frame sequence gap (dropped frames, counted) breaks the pairing: no scan from frames that
  are not neighbours;
* a pipeline exception: that scan is skipped and counted, the error is logged.

``LinkSupervisor`` runs the link server over a port and opens it again when the host side fails
(a USB gadget port that vanishes when the host is unplugged); host garbage and scans dropped on
a slow link are counted by the link server into one LinkCounters for all sessions, so HEALTH
(and ``ProcessHealth``, for logs and ``serve --stats-file``) report totals since the process started.
"""

from __future__ import annotations

import logging
import threading
import time
from dataclasses import dataclass
from typing import Callable, Protocol

import numpy as np

from device.analytic_source import median_filter
from device.camera.base import CaptureTimeout
from device.camera.frame import Frame
from device.link import DeviceConfig, LinkCounters, LinkServer, ScanGeometry, SourceScan, SourceStatus
from protocol import messages as m

log = logging.getLogger(__name__)


# --- interfaces ------------------------------------------------------------------------------
class Camera(Protocol):
    def start(self) -> None:
        """Start streaming frames (may be called again after ``stop()`` to restart)."""

    def stop(self) -> None:
        """Stop streaming; must not raise on a camera that has failed."""

    def capture(self, timeout_s: float) -> Frame | None:
        """The next frame, or None (or CaptureTimeout) if none arrived within ``timeout_s``;
        raises on a camera error."""


class LaserError(RuntimeError):
    """The co-MCU cannot drive the laser now. ``reason``: "lost" (no answer), "reset" (it
    restarted and forgot the schedule), "fault" (it latched a fault and switched the laser off)
    or "refused" (it declined the schedule)."""

    def __init__(self, reason: str, detail: str):
        super().__init__(f"co-MCU {reason}: {detail}")
        self.reason = reason


class Laser(Protocol):
    locked: bool  # pulses are synchronised to the camera's exposure

    def start(self, frame: Frame) -> bool | None:
        """Schedule pulses for the frames after ``frame`` (its timestamp gives the camera's
        phase); raises LaserError. Returns True if it found that the co-MCU had rebooted since
        the last schedule without a LaserError "reset" having said so (e.g. during an outage)."""

    def stop(self) -> None:
        """Laser off now; best effort, never raises (the co-MCU also stops by itself when its
        heartbeats stop)."""

    def frame_lit(self, frame: Frame) -> bool | None:
        """Service the co-MCU for a new frame (heartbeat, synchronisation step) and say whether
        the schedule lit this frame; None while that is not known (not locked). Raises LaserError."""


class Pipeline(Protocol):
    def __call__(self, lit: Frame, dark: Frame) -> tuple[np.ndarray, np.ndarray]:
        """Ranges (float32, REP 117) and quality (uint8) on every angle of the scan geometry."""


# --- health ----------------------------------------------------------------------------------
@dataclass
class SourceCounters:
    """Totals since the process started."""

    frames: int = 0
    frames_dropped: int = 0  # sequence gaps in the camera stream
    camera_errors: int = 0  # capture raised
    camera_stalls: int = 0  # no frame within stall_timeout_s
    camera_restarts: int = 0
    comcu_lost: int = 0  # the co-MCU stopped answering
    comcu_resets: int = 0  # the co-MCU restarted (reset cause reported by it)
    laser_starts: int = 0  # successful (re)schedules
    pipeline_errors: int = 0
    scans_made: int = 0
    # CPU seconds (thread time) spent in each part, for the cost per scan
    cpu_camera_s: float = 0.0  # capture (in simulation: rendering the frame)
    cpu_laser_s: float = 0.0  # co-MCU requests and the synchronisation step
    cpu_pipeline_s: float = 0.0  # frame pair -> scan


@dataclass(frozen=True)
class ProcessHealth:
    """Everything the process knows about its own health, for logs, tests and the soak run."""

    scanning: bool
    laser_on: bool
    sync_locked: bool
    errors: tuple[int, ...]
    source: SourceCounters
    scans_sent: int = 0
    scans_dropped: int = 0  # whole scans dropped because the host link was slow
    host_bytes_discarded: int = 0  # host bytes that were not part of an intact frame
    host_frames_rejected: int = 0  # CRC, decode and oversize errors from the host
    host_sessions: int = 0  # times the link was (re)opened

    def line(self) -> str:
        s = self.source
        errs = ",".join(m.ErrorCode(e).name if e in m.ErrorCode._value2member_map_ else str(e) for e in self.errors)
        return (f"scanning={self.scanning} laser={'on' if self.laser_on else 'off'} locked={self.sync_locked} "
                f"errors=[{errs}] frames={s.frames} dropped_frames={s.frames_dropped} scans={s.scans_made} "
                f"sent={self.scans_sent} dropped_scans={self.scans_dropped} camera_restarts={s.camera_restarts} "
                f"comcu_lost={s.comcu_lost} comcu_resets={s.comcu_resets} pipeline_errors={s.pipeline_errors} "
                f"host_bytes_discarded={self.host_bytes_discarded} host_frames_rejected={self.host_frames_rejected} "
                f"host_sessions={self.host_sessions}")


# --- the scan source -------------------------------------------------------------------------
class SensorSource:
    """ScanSource (device/link.py) of the whole sensor; see the module docstring."""

    def __init__(self, camera: Camera, laser: Laser, pipeline: Pipeline, geometry: ScanGeometry, *,
                 stall_timeout_s: float = 0.5, laser_retry_s: float = 0.5,
                 clock: Callable[[], float] = time.monotonic):
        if not stall_timeout_s > 0 or not laser_retry_s > 0:
            raise ValueError(f"stall_timeout_s and laser_retry_s must be positive, got {stall_timeout_s}, {laser_retry_s}")
        self.camera = camera
        self.laser = laser
        self.pipeline = pipeline
        self._geometry = geometry
        self.stall_timeout_s = stall_timeout_s
        self.laser_retry_s = laser_retry_s
        self.clock = clock
        self.counters = SourceCounters()
        self._settings: m.ScanSettings | None = None
        self._io = threading.RLock()  # camera and co-MCU calls; held by next_scan and start/stop
        self._running = False
        self._camera_ok = False
        self._laser_on = False
        self._next_laser_try = 0.0
        self._last_frame_at = 0.0
        self._last_seq: int | None = None
        self._pending: tuple[Frame, bool] | None = None
        self._errors: set[int] = set()

    # ScanSource
    def geometry(self) -> ScanGeometry:
        return self._geometry

    def apply(self, settings: m.ScanSettings) -> None:
        current = self._settings
        if current is not None:
            fixed = [n for n in ("scan_rate_hz", "exposure_us", "laser_power_mw")
                     if getattr(settings, n) != getattr(current, n)]
            if fixed:
                raise ValueError(f"{', '.join(fixed)} cannot be changed while the device runs "
                                 "(set them in the sensor configuration)")
        self._settings = settings

    def start(self) -> None:
        with self._io:
            if self._running:
                return
            self._running = True
            self._restart_camera(first=True)

    def stop(self) -> None:
        with self._io:
            self._running = False
            self._laser_off()
            self._pending = None
            try:
                self.camera.stop()
            except Exception as exc:  # a failed camera must not keep the laser or the process hostage
                log.warning("camera stop failed: %s", exc)
            self._camera_ok = False

    def status(self) -> SourceStatus:
        # Without the I/O lock: the host's HEALTH must not wait for a frame. Each field is read
        # atomically (set.copy under the GIL); together they may be one frame apart.
        errors = tuple(sorted(self._errors.copy()))
        laser_on = self._laser_on
        c = self.counters
        return SourceStatus(laser_on=laser_on, sync_locked=laser_on and bool(self.laser.locked),
                            frames_dropped=c.frames_dropped, errors=errors, camera_restarts=c.camera_restarts,
                            comcu_resets=c.comcu_resets, comcu_lost=c.comcu_lost, pipeline_errors=c.pipeline_errors)

    def next_scan(self, timeout_s: float) -> SourceScan | None:
        deadline = self.clock() + timeout_s
        while True:
            with self._io:
                if not self._running:
                    return None
                scan = self._step(max(0.0, min(0.1, deadline - self.clock())))
            if scan is not None or self.clock() >= deadline:
                return scan

    # one frame
    def _step(self, timeout_s: float) -> SourceScan | None:
        now = self.clock()
        if not self._camera_ok:
            if now - self._last_frame_at >= self.stall_timeout_s:
                self._restart_camera()
            return None
        cpu = time.thread_time()
        try:
            frame = self.camera.capture(timeout_s)
        except CaptureTimeout:
            frame = None
        except Exception as exc:
            self.counters.camera_errors += 1
            self._camera_failed(f"capture failed: {type(exc).__name__}: {exc}")
            return None
        finally:
            self.counters.cpu_camera_s += time.thread_time() - cpu
        now = self.clock()
        if frame is None:
            if now - self._last_frame_at >= self.stall_timeout_s:
                self.counters.camera_stalls += 1
                self._camera_failed(f"no frame for {now - self._last_frame_at:.2f} s")
            return None
        self._last_frame_at = now
        self._errors.discard(m.ErrorCode.CAMERA_FAULT)
        self.counters.frames += 1
        if self._last_seq is not None and frame.seq != self._last_seq + 1:
            gap = frame.seq - self._last_seq - 1
            if gap > 0:
                self.counters.frames_dropped += gap
            self._pending = None
        self._last_seq = frame.seq
        cpu = time.thread_time()
        lit = self._service_laser(frame, now)
        self.counters.cpu_laser_s += time.thread_time() - cpu
        if lit is None:
            self._pending = None
            return None
        if self._pending is None or self._pending[1] == lit:
            self._pending = (frame, lit)
            return None
        (other, _), self._pending = self._pending, None
        lit_frame, dark_frame = (frame, other) if lit else (other, frame)
        return self._scan(lit_frame, dark_frame)

    def _service_laser(self, frame: Frame, now: float) -> bool | None:
        try:
            if not self._laser_on:
                if now < self._next_laser_try:
                    return None
                if self.laser.start(frame):
                    self.counters.comcu_resets += 1
                self._laser_on = True
                self.counters.laser_starts += 1
                self._errors.difference_update((m.ErrorCode.LASER_FAULT, m.ErrorCode.SYNC_LOST))
                log.info("laser scheduled on the co-MCU (start %d)", self.counters.laser_starts)
                return None  # the schedule applies from the next frames on
            lit = self.laser.frame_lit(frame)
        except LaserError as exc:
            if exc.reason == "reset":
                self.counters.comcu_resets += 1
            elif exc.reason == "lost" and (self._laser_on or m.ErrorCode.LASER_FAULT not in self._errors):
                self.counters.comcu_lost += 1
            if m.ErrorCode.LASER_FAULT not in self._errors:
                log.error("%s; laser off, retrying every %.1f s", exc, self.laser_retry_s)
            self._laser_off()
            self._errors.update((m.ErrorCode.LASER_FAULT, m.ErrorCode.SYNC_LOST))
            self._next_laser_try = now + self.laser_retry_s
            return None
        if lit is None:
            self._errors.add(m.ErrorCode.SYNC_LOST)
        else:
            self._errors.discard(m.ErrorCode.SYNC_LOST)
        return lit

    def _scan(self, lit: Frame, dark: Frame) -> SourceScan | None:
        n = self._geometry.angles.size
        cpu = time.thread_time()
        try:
            ranges, quality = self.pipeline(lit, dark)
            ranges = np.asarray(ranges, dtype=np.float32)
            quality = np.asarray(quality, dtype=np.uint8)
            if ranges.shape != (n,) or quality.shape != (n,):
                raise ValueError(f"pipeline returned {ranges.shape} ranges and {quality.shape} qualities for {n} angles")
        except Exception as exc:
            self.counters.pipeline_errors += 1
            self._errors.add(m.ErrorCode.PIPELINE_FAULT)
            log.exception("pipeline failed on frames %d/%d: %s", lit.seq, dark.seq, exc)
            return None
        finally:
            self.counters.cpu_pipeline_s += time.thread_time() - cpu
        self._errors.discard(m.ErrorCode.PIPELINE_FAULT)
        s = self._settings
        sl = slice(s.roi_first, s.roi_first + s.roi_count)
        ranges, quality = ranges[sl], quality[sl]
        if s.min_quality:
            ranges = np.where(quality < s.min_quality, np.float32(np.nan), ranges)
        if s.median_window > 1:
            ranges = median_filter(ranges, s.median_window)
        self.counters.scans_made += 1
        return SourceScan(lit.sensor_timestamp_ns // 1000, ranges, quality, first_index=s.roi_first)

    # failures
    def _camera_failed(self, why: str) -> None:
        log.error("camera fault (%s): laser off, restarting the camera", why)
        self._errors.add(m.ErrorCode.CAMERA_FAULT)
        self._laser_off()
        self._pending = None
        self._restart_camera()

    def _restart_camera(self, first: bool = False) -> None:
        self._last_frame_at = self.clock()  # the stall clock starts again
        self._last_seq = None
        try:
            if not first:
                self.camera.stop()
                self.counters.camera_restarts += 1
            self.camera.start()
            self._camera_ok = True
        except Exception as exc:
            self._camera_ok = False
            self.counters.camera_errors += 1
            self._errors.add(m.ErrorCode.CAMERA_FAULT)
            log.error("camera start failed (%s); next try in %.1f s", exc, self.stall_timeout_s)

    def _laser_off(self) -> None:
        if self._laser_on:
            log.info("laser off")
        self._laser_on = False
        try:
            self.laser.stop()
        except Exception as exc:  # the interface says never; the heartbeat timeout still holds
            log.error("laser stop raised %s; the co-MCU switches off on missing heartbeats", exc)


# --- the link, reopened when the host side fails -----------------------------------------------
class LinkSupervisor:
    """Serve ``source`` (a ScanSource, usually a SensorSource) to a host over ports from
    ``open_port`` until ``stop`` is set.

    A link server whose port fails (host unplugged from a USB gadget port, serial error) ends its
    session; the supervisor opens the port again with back-off and serves a new session with
    the same source, so the sensor keeps running. On exit the source is stopped (laser off).
    """

    def __init__(self, open_port: Callable[[], object], source, config: DeviceConfig, *,
                 health_log_s: float = 10.0, reopen_backoff_s: tuple[float, float] = (0.1, 2.0),
                 on_health: Callable[[ProcessHealth], None] | None = None):
        """on_health: called with the health at every health log line and once at the end."""
        self.open_port = open_port
        self.source = source
        self.config = config
        self.health_log_s = health_log_s
        self.on_health = on_health
        self.reopen_backoff_s = reopen_backoff_s
        self.server: LinkServer | None = None
        self.counters = LinkCounters()  # shared by every session: HEALTH reports process totals

    @property
    def sessions(self) -> int:
        return self.counters.sessions

    def health(self) -> ProcessHealth:
        c = self.counters
        st = self.source.status()
        return ProcessHealth(
            scanning=bool(self.server and self.server._scanning), laser_on=st.laser_on, sync_locked=st.sync_locked,
            errors=st.errors, source=SourceCounters(**vars(getattr(self.source, "counters", SourceCounters()))),
            scans_sent=c.scans_sent, scans_dropped=c.scans_dropped, host_bytes_discarded=c.host.bytes_discarded,
            host_frames_rejected=c.host_frames_rejected, host_sessions=c.sessions)

    def run(self, stop: threading.Event) -> None:
        backoff = self.reopen_backoff_s[0]
        next_log = time.monotonic() + self.health_log_s
        try:
            while not stop.is_set():
                try:
                    port = self.open_port()
                except OSError as exc:
                    log.warning("cannot open the host port (%s); again in %.1f s", exc, backoff)
                    stop.wait(backoff)
                    backoff = min(2 * backoff, self.reopen_backoff_s[1])
                    continue
                backoff = self.reopen_backoff_s[0]
                self.server = LinkServer(port, self.source, self.config, self.counters).start()
                log.info("host link session %d open", self.sessions)
                while not stop.wait(0.1) and not self.server.stopped:
                    if time.monotonic() >= next_log:
                        self._report(self.health(), "health")
                        next_log = time.monotonic() + self.health_log_s
                self.server.close()
                self.server = None
                closer = getattr(port, "close", None)
                if closer is not None:
                    try:
                        closer()
                    except OSError:
                        pass
                if not stop.is_set():
                    log.warning("host link session %d ended; reopening", self.sessions)
        finally:
            self.source.stop()
            self._report(self.health(), "device process stopped, laser off")

    def _report(self, health: ProcessHealth, what: str) -> None:
        log.info("%s; %s", what, health.line())
        if self.on_health is not None:
            self.on_health(health)
