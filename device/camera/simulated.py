"""Simulated camera: the scene renderer driven by a frame clock and a laser pulse schedule.

Frame k's SensorTimestamp is ``start_ns + sum of the previous frame durations``; a new exposure
or frame duration applies from the next frame (the IMX219's 2-frame latency and timestamp
jitter belong to the timing simulation, device/sim/timing.py, which replaces this clock when it
lands). Whether a frame is lit is decided by the pulse source's windows through the rolling
shutter, never by a flag.
"""

from __future__ import annotations

import numpy as np

from ..config import SensorConfig
from ..sim.pulses import PulseSource
from ..sim.render import FrameTiming, RenderOptions, SceneRenderer
from ..sim.scene import Scene
from ..sim.sensor import SIMULATOR_DEFAULT, SensorParams
from ..sim.truth import FrameTruth
from .base import IMX219_LINE_TIME_NS, CameraError
from .frame import Frame


class SimulatedCamera:
    """Frames of a static scene with ground truth; deterministic for ``seed``."""

    def __init__(self, cfg: SensorConfig, scene: Scene, pulses: PulseSource, *, exposure_us: float = 40000.0,
                 frame_duration_us: float = 50000.0, start_ns: int = 1_000_000_000, seed: int = 0,
                 options: RenderOptions = RenderOptions(), sensor: SensorParams = SIMULATOR_DEFAULT,
                 line_time_ns: float = IMX219_LINE_TIME_NS):
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

    def start(self) -> None:
        self._running = True

    def stop(self) -> None:
        self._running = False

    def set_frame_duration(self, frame_duration_us: float) -> None:
        if not frame_duration_us >= self._exposure_us:
            raise ValueError(f"frame duration {frame_duration_us} us is shorter than the exposure {self._exposure_us} us")
        self._frame_duration_us = float(frame_duration_us)

    def set_exposure(self, exposure_us: float) -> None:
        if not 0 < exposure_us <= self._frame_duration_us:
            raise ValueError(f"exposure {exposure_us} us must be in (0, frame duration {self._frame_duration_us} us]")
        self._exposure_us = float(exposure_us)

    def capture_with_truth(self, timeout_s: float = 1.0) -> tuple[Frame, FrameTruth]:
        if not self._running:
            raise CameraError("camera not started: call start() first")
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

    def capture(self, timeout_s: float = 1.0) -> Frame:
        return self.capture_with_truth(timeout_s)[0]
