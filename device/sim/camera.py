"""Simulated camera: the scene renderer driven by the simulated camera clock and a pulse schedule.

Frame times come from :class:`device.sim.timing.CameraClock` (line-quantised frame duration and
exposure, changes effective 2 frames later as on the IMX219, timestamp latency jitter, dropped
frames: a dropped frame's sequence number is skipped). Each frame is rendered at its *true*
row exposure windows, and its Frame carries the *reported* SensorTimestamp: as on a Pi, the frame
start of the sensor mode's whole readout, ``cfg.window.top`` rows (the ISP's crop, Frame's
``readout_offset_rows``) before image row 0 is read. Whether a frame is lit is decided by the
pulse source's windows through the rolling shutter, never by a flag.

Frames are delivered at once, one after the other (``laserpi simulate``, ``evaluate``,
calibration), or, given the simulated Pi (``hardware``, device/sim/hardware.py), in simulated
real time for the device process (``laserpi serve --simulate``): the camera clock starts 50 ms
after each ``start()`` on the Pi's clock, and a frame is rendered ``ready_margin_s`` after its
last row is read out on that clock, with the laser's on-windows of the co-MCU's pin as they were
then (the hardware is the pulse source too).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from ..camera.base import CameraError, CaptureTimeout
from ..camera.frame import Frame
from ..config import SensorConfig
from .pulses import PulseSource
from .render import FrameTiming, RenderOptions, SceneRenderer
from .scene import Scene
from .sensor import SIMULATOR_DEFAULT, SensorParams
from .timing import CameraClock, CameraTimingConfig, FrameTiming as ClockFrame
from .truth import FrameTruth

#: The prototype's timing: 20 frames/s (lit every other frame: 10 scans/s), 40 ms exposure.
DEFAULT_TIMING = CameraTimingConfig(frame_duration_s=0.05, exposure_s=0.04)


class SimulatedCamera:
    """Frames of a static scene with ground truth; deterministic for ``seed``."""

    def __init__(self, cfg: SensorConfig, scene: Scene, pulses: PulseSource, *,
                 timing: CameraTimingConfig | None = None, exposure_us: float | None = None,
                 frame_duration_us: float | None = None, start_ns: int | None = None, line_time_ns: float | None = None,
                 seed: int = 0, options: RenderOptions = RenderOptions(), sensor: SensorParams = SIMULATOR_DEFAULT,
                 hardware=None, ready_margin_s: float = 0.001):
        """``timing``: the camera clock's configuration (default DEFAULT_TIMING). Or give plain
        ``exposure_us``/``frame_duration_us``/``start_ns``/``line_time_ns`` (each optional) for an
        ideal clock: the same line quantisation and control delay, no jitter, no dropped frames.
        ``hardware``: the simulated Pi (``now_ns()``, ``wait_until(t_ns, timeout_s)``,
        ``limit_ns``) whose clock delivers the frames in real time (module docstring)."""
        plain = {"exposure_us": exposure_us, "frame_duration_us": frame_duration_us, "start_ns": start_ns,
                 "line_time_ns": line_time_ns}
        given = [k for k, v in plain.items() if v is not None]
        if timing is not None and given:
            raise ValueError(f"give either timing or plain values ({', '.join(given)}), not both")
        if timing is None:
            timing = replace(DEFAULT_TIMING, timestamp_jitter_s=0.0, drop_probability=0.0) if given else DEFAULT_TIMING
            if exposure_us is not None:
                timing = replace(timing, exposure_s=exposure_us * 1e-6)
            if frame_duration_us is not None:
                timing = replace(timing, frame_duration_s=frame_duration_us * 1e-6)
            if start_ns is not None:
                timing = replace(timing, start_time_s=start_ns * 1e-9)
            if line_time_ns is not None:
                timing = replace(timing, line_time_s=line_time_ns * 1e-9)
        if timing.exposure_s > timing.frame_duration_s:
            raise ValueError(f"exposure {timing.exposure_s * 1e6:g} us exceeds the frame duration "
                             f"{timing.frame_duration_s * 1e6:g} us")
        if timing.active_rows > cfg.height:
            raise ValueError(f"timing has {timing.active_rows} active rows, the frame only {cfg.height}")
        self.renderer = SceneRenderer(cfg, scene, sensor, options, seed, time_zero_ns=int(round(timing.start_time_s * 1e9)))
        self.width, self.height, self.line_time_ns = cfg.width, cfg.height, timing.line_time_s * 1e9
        self.readout_offset_rows = cfg.window.top
        self.pulses = pulses
        self.hardware = hardware
        self.ready_margin_s = ready_margin_s
        self.stall_until_ns = 0  # fault injection (with hardware): no frame is delivered before this time
        self._timing = timing
        self._clock_rng = np.random.default_rng([seed, 0xC10C])
        self.clock = None if hardware is not None else CameraClock(timing, self._clock_rng)
        self._rng = np.random.default_rng([seed, 0xCA3])
        self._next: ClockFrame | None = None  # a frame that was not ready when its capture timed out
        self._running = False

    def start(self) -> None:
        if self.hardware is not None:
            start_s = self.hardware.now_ns() * 1e-9 + 0.05
            self.clock = CameraClock(replace(self._timing, start_time_s=start_s), self._clock_rng)
            self.renderer.time_zero_ns = int(round(start_s * 1e9))
            self._next = None
        self._running = True

    def stop(self) -> None:
        self._running = False
        if self.hardware is not None:
            self.hardware.limit_ns = None

    def set_frame_duration(self, frame_duration_us: float) -> None:
        self.clock.request(frame_duration_s=frame_duration_us * 1e-6)

    def set_exposure(self, exposure_us: float) -> None:
        if not exposure_us > 0:
            raise ValueError(f"exposure must be positive, got {exposure_us} us")
        self.clock.request(exposure_s=exposure_us * 1e-6)

    def capture_with_truth(self, timeout_s: float = 1.0) -> tuple[Frame, FrameTruth]:
        if not self._running:
            raise CameraError("camera not started: call start() first")
        ft = self._next or self._delivered_frame()
        self._next = None
        if self.hardware is not None:
            ft = self._wait_until_read_out(ft, timeout_s)
        t_ns = int(round(ft.true_start_s * 1e9))
        lt_ns = ft.line_time_s * 1e9
        exposure_us = ft.exposure_s * 1e6
        first_start = t_ns - int(round(ft.exposure_s * 1e9))
        last_end = t_ns + int((self.height - 1) * lt_ns)
        timing = FrameTiming(t_ns, exposure_us, lt_ns, tuple(self.pulses.windows(first_start, last_end)))
        image, truth = self.renderer.render(timing, self._rng)
        # the clock's T is image row 0's readout; the frame start is the crop's rows before it
        frame_start_ns = ft.sensor_timestamp_ns - int(round(self.readout_offset_rows * lt_ns))
        frame = Frame(image, ft.sequence, frame_start_ns, exposure_us, ft.frame_duration_s * 1e6, lt_ns,
                      lit=bool(truth.lit_rows.any()), readout_offset_rows=self.readout_offset_rows)
        return frame, truth

    def capture(self, timeout_s: float = 1.0) -> Frame:
        return self.capture_with_truth(timeout_s)[0]

    def _delivered_frame(self) -> ClockFrame:
        ft = self.clock.next_frame()
        while ft.dropped:  # exposed but never delivered
            ft = self.clock.next_frame()
        return ft

    def _ready_ns(self, ft: ClockFrame) -> int:
        return int((ft.true_start_s + (self.height - 1) * ft.line_time_s + self.ready_margin_s) * 1e9)

    def _wait_until_read_out(self, ft: ClockFrame, timeout_s: float) -> ClockFrame:
        """``ft``, or the first frame after a stall, once the simulated clock has read it out;
        CaptureTimeout if that takes longer than ``timeout_s``. The clock is held one frame
        beyond it (``limit_ns``) so that it never runs away from a slow consumer."""
        while self._ready_ns(ft) < self.stall_until_ns:  # frames of a stalled camera never arrive
            ft = self._delivered_frame()
        ready_ns = self._ready_ns(ft)
        self.hardware.limit_ns = ready_ns + int(ft.frame_duration_s * 1e9)
        if not self.hardware.wait_until(ready_ns, timeout_s):
            self._next = ft
            raise CaptureTimeout(f"no simulated frame within {timeout_s} s")
        return ft
