"""Simulated camera: the scene renderer driven by a frame clock and a laser pulse schedule.

Without ``clock``, frame k's SensorTimestamp is ``start_ns + sum of the previous frame
durations`` and a new exposure or frame duration applies from the next frame. With ``clock`` (a
``device.sim.timing.CameraClock``) the timing is the IMX219's: line-quantised durations, changes
2 frames later, an oscillator error, a late-only timestamp jitter and dropped frames (sequence
gaps); the image is rendered at the true exposure times and the metadata reports the jittered
timestamp. Whether a frame is lit is decided by the pulse source's windows through the rolling
shutter, never by a flag.
"""

from __future__ import annotations

import numpy as np

from ..config import SensorConfig
from ..sim.pulses import PulseSource
from ..sim.render import FrameTiming, RenderOptions, SceneRenderer
from ..sim.scene import Scene
from ..sim.sensor import SIMULATOR_DEFAULT, SensorParams
from ..sim.timing import CameraClock
from ..sim.truth import FrameTruth
from .base import IMX219_LINE_TIME_NS, CameraError
from .frame import Frame


class SimulatedCamera:
    """Frames of a static scene with ground truth; deterministic for ``seed``."""

    def __init__(self, cfg: SensorConfig, scene: Scene, pulses: PulseSource, *, exposure_us: float = 40000.0,
                 frame_duration_us: float = 50000.0, start_ns: int = 1_000_000_000, seed: int = 0,
                 options: RenderOptions = RenderOptions(), sensor: SensorParams = SIMULATOR_DEFAULT,
                 line_time_ns: float = IMX219_LINE_TIME_NS, clock: CameraClock | None = None):
        if not 0 < exposure_us <= frame_duration_us:
            raise ValueError(f"exposure_us {exposure_us} must be in (0, frame_duration_us = {frame_duration_us}]")
        self.renderer = SceneRenderer(cfg, scene, sensor, options, seed)
        self.width, self.height, self.line_time_ns = cfg.width, cfg.height, line_time_ns
        self.pulses = pulses
        self._exposure_us, self._frame_duration_us = float(exposure_us), float(frame_duration_us)
        self._next_ts = int(start_ns)
        self._rng = np.random.default_rng([seed, 0xCA3])
        self._seq = 0
        self._running = False
        self.clock = clock

    def start(self) -> None:
        self._running = True

    def stop(self) -> None:
        self._running = False

    def set_frame_duration(self, frame_duration_us: float) -> None:
        if not frame_duration_us >= self._exposure_us:
            raise ValueError(f"frame duration {frame_duration_us} us is shorter than the exposure {self._exposure_us} us")
        self._frame_duration_us = float(frame_duration_us)
        if self.clock is not None:
            self.clock.request(frame_duration_s=frame_duration_us * 1e-6)

    def set_exposure(self, exposure_us: float) -> None:
        if not 0 < exposure_us <= self._frame_duration_us:
            raise ValueError(f"exposure {exposure_us} us must be in (0, frame duration {self._frame_duration_us} us]")
        self._exposure_us = float(exposure_us)
        if self.clock is not None:
            self.clock.request(exposure_s=exposure_us * 1e-6)

    def capture_with_truth(self, timeout_s: float = 1.0) -> tuple[Frame, FrameTruth]:
        if not self._running:
            raise CameraError("camera not started: call start() first")
        if self.clock is not None:
            return self._capture_clocked()
        ts = self._next_ts
        first_start = ts - int(self._exposure_us * 1e3)
        last_end = ts + int((self.height - 1) * self.line_time_ns)
        windows = tuple(self.pulses.windows(first_start, last_end))
        timing = FrameTiming(ts, self._exposure_us, self.line_time_ns, windows)
        image, truth = self.renderer.render(timing, self._rng)
        frame = Frame(image, self._seq, ts, self._exposure_us, self._frame_duration_us, self.line_time_ns,
                      lit=bool(truth.lit_rows.any()))
        self._seq += 1
        self._next_ts = ts + int(round(self._frame_duration_us * 1e3))
        return frame, truth

    def _capture_clocked(self) -> tuple[Frame, FrameTruth]:
        ft = self.clock.next_frame()
        while ft.dropped:  # exposed but never delivered: only its sequence number is missing
            ft = self.clock.next_frame()
        true_ts = int(round(ft.true_start_s * 1e9))
        exposure_us, line_ns = ft.exposure_s * 1e6, ft.line_time_s * 1e9
        windows = tuple(self.pulses.windows(true_ts - int(exposure_us * 1e3), true_ts + int((self.height - 1) * line_ns)))
        image, truth = self.renderer.render(FrameTiming(true_ts, exposure_us, line_ns, windows), self._rng)
        # Metadata as libcamera reports it: counted in the sensor's lines at the nominal line time.
        scale = self.line_time_ns / line_ns
        frame = Frame(image, ft.sequence, ft.sensor_timestamp_ns, exposure_us * scale, ft.frame_duration_s * 1e6 * scale,
                      self.line_time_ns, lit=bool(truth.lit_rows.any()))
        return frame, truth

    def capture(self, timeout_s: float = 1.0) -> Frame:
        return self.capture_with_truth(timeout_s)[0]
