"""The scan source of the whole sensor: camera -> synchronised laser (co-MCU) -> pipeline -> scans.

Composed of narrow interfaces so that the same orchestration runs on a Pi and in simulation:

* the camera (device.camera.base.Camera): ``start()``, ``stop()``, ``capture(timeout_s)``
  (no frame in time: CaptureTimeout, or None);
* the laser (device.laser.base.Laser): the line laser pulsed by the co-MCU and kept in step with
  the camera: ``start(frame)``, ``stop()``, ``frame_lit(frame)``, ``locked``;
* the scan function (device.scan.pipeline.ScanFunction): ``(lit, dark, other_dark) -> ScanRays``
  (ranges, quality and ray times on the scan's angles); a device.vision pipeline through ScanPipeline.

``SensorSource`` joins them into the ScanSource the link server (protocol/server.py) streams from.
It pairs each lit frame with its neighbouring unlit frames (frame differencing, docs/thesis-notes.md N10;
both neighbours, device/scan/pairing.py) into one scan, and it never raises out of ``next_scan``: every failure degrades and is reported in
``status()`` (HEALTH.errors, codes protocol.messages.ErrorCode, and HEALTH's fault counters) and
``LinkSupervisor.health()`` (device/link/supervisor.py) instead:

* camera error or stall (no frame for ``stall_timeout_s``): laser off, error CAMERA_FAULT,
  camera restarted (counted), the laser re-synchronised on the first new frame;
* co-MCU lost or reset (``LaserError``): laser off, error LASER_FAULT + SYNC_LOST, retried every
  ``laser_retry_s`` until it answers again; while it is away no scan is made;
* a frame sequence gap (dropped frames, counted) breaks the pairing: no scan from frames that
  are not neighbours;
* a pipeline exception: that scan is skipped and counted, the error is logged;
* a laser synchronised without the trigger line's GPIO edges (``sync_degraded``, PING only):
  error SYNC_DEGRADED for as long as the process runs;
* bright light saturating the camera where the line is or could be (``ScanRays.saturated_columns``:
  those rays are NaN, never "no return"): error SATURATED from a scan with such columns until
  ``SATURATED_CLEAR_SCANS`` scans in a row have none.

The scan then gets the host's settings: the region of interest, ``min_quality`` and the median
filter (protocol/median.py).
"""

from __future__ import annotations

import logging
import threading
import time
from dataclasses import dataclass
from typing import Callable

import numpy as np

from device.camera.base import Camera, CaptureTimeout
from device.camera.frame import Frame
from device.laser.base import Laser, LaserError
from device.scan.pairing import NeighbourPairing
from device.scan.pipeline import ScanFunction
from protocol import messages as m
from protocol.median import scan_filters
from protocol.server import ScanGeometry, SourceScan, SourceStatus

log = logging.getLogger(__name__)

#: Scans in a row without saturated columns that clear error SATURATED (0.5 s at 10 scans/s).
SATURATED_CLEAR_SCANS = 5


# --- counters --------------------------------------------------------------------------------
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


# --- the scan source -------------------------------------------------------------------------
class SensorSource:
    """ScanSource (protocol/server.py) of the whole sensor; see the module docstring."""

    def __init__(self, camera: Camera, laser: Laser, pipeline: ScanFunction, geometry: ScanGeometry, *,
                 stall_timeout_s: float = 0.5, laser_retry_s: float = 0.5,
                 clock: Callable[[], float] = time.monotonic, sync_degraded: bool = False):
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
        self._pairing = NeighbourPairing()
        self._errors: set[int] = {m.ErrorCode.SYNC_DEGRADED} if sync_degraded else set()
        self._unsaturated_scans = 0  # scans in a row without saturated columns (_saturated)

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
            self._pairing.reset()
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
            self._pairing.reset()
        self._last_seq = frame.seq
        cpu = time.thread_time()
        lit = self._service_laser(frame, now)
        self.counters.cpu_laser_s += time.thread_time() - cpu
        if lit is None:
            self._pairing.reset()
            return None
        frames = self._pairing.push(frame, lit)
        return None if frames is None else self._scan(frames.lit, frames.unlit, frames.other_unlit)

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

    def _scan(self, lit: Frame, dark: Frame, other_dark: Frame | None) -> SourceScan | None:
        n = self._geometry.angles.size
        cpu = time.thread_time()
        try:
            rays = self.pipeline(lit, dark, other_dark)
            ranges = np.asarray(rays.ranges, dtype=np.float32)
            quality = np.asarray(rays.quality, dtype=np.uint8)
            saturated = int(rays.saturated_columns)
            if ranges.shape != (n,) or quality.shape != (n,):
                raise ValueError(f"pipeline returned {ranges.shape} ranges and {quality.shape} qualities for {n} angles")
        except Exception as exc:
            self.counters.pipeline_errors += 1
            self._errors.add(m.ErrorCode.PIPELINE_FAULT)
            log.exception("pipeline failed on lit frame %d: %s", lit.seq, exc)
            return None
        finally:
            self.counters.cpu_pipeline_s += time.thread_time() - cpu
        self._errors.discard(m.ErrorCode.PIPELINE_FAULT)
        self._saturated(saturated, lit.seq)
        s = self._settings
        sl = slice(s.roi_first, s.roi_first + s.roi_count)
        ranges, quality = ranges[sl], quality[sl]
        ranges = scan_filters(ranges, quality, s.min_quality, s.median_window)
        self.counters.scans_made += 1
        # the host's region of interest starts at ray roi_first: its time moves with it
        first_ns = rays.first_ray_ns + s.roi_first * rays.ray_interval_ns
        times = None if rays.ray_times_ns is None else rays.ray_times_ns[sl]
        return SourceScan(round(first_ns / 1000), ranges, quality, first_index=s.roi_first,
                          ray_interval_ns=rays.ray_interval_ns, ray_times_ns=times)

    def _saturated(self, columns: int, seq: int) -> None:
        """Error SATURATED from a scan with columns where bright light saturated the camera
        (their rays NaN, anywhere in the field of view) until SATURATED_CLEAR_SCANS scans in a
        row had none (a lamp at the edge of saturation does not flap it, nor the log), logged
        when it begins and ends."""
        was = m.ErrorCode.SATURATED in self._errors
        self._unsaturated_scans = 0 if columns else self._unsaturated_scans + 1
        if columns and not was:
            log.warning("lit frame %d: bright light saturates the camera in %d image columns; their rays are NaN "
                        "(a lamp, a window or sunlight in view, or too long an exposure)", seq, columns)
            self._errors.add(m.ErrorCode.SATURATED)
        elif was and self._unsaturated_scans >= SATURATED_CLEAR_SCANS:
            log.info("lit frame %d: the camera is no longer saturated", seq)
            self._errors.discard(m.ErrorCode.SATURATED)

    # failures
    def _camera_failed(self, why: str) -> None:
        log.error("camera fault (%s): laser off, restarting the camera", why)
        self._errors.add(m.ErrorCode.CAMERA_FAULT)
        self._laser_off()
        self._pairing.reset()
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
