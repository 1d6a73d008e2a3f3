"""Simulated camera: the scene renderer driven by the simulated camera clock and a pulse schedule.

Frame times come from :class:`device.sim.timing.CameraClock` (line-quantised frame duration and
exposure, changes effective 2 frames later as on the IMX219, timestamp latency jitter, dropped
frames: a dropped frame's sequence number is skipped). Each frame is rendered at its *true*
row exposure windows, and its Frame carries the *reported* SensorTimestamp. Whether a frame is
lit is decided by the pulse source's windows through the rolling shutter, never by a flag.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from ..config import SensorConfig
from ..sim.pulses import PulseSource
from ..sim.render import FrameTiming, RenderOptions, SceneRenderer
from ..sim.scene import Scene
from ..sim.sensor import SIMULATOR_DEFAULT, SensorParams
from ..sim.timing import CameraClock, CameraTimingConfig
from ..sim.truth import FrameTruth
from .base import CameraError
from .frame import Frame

#: The prototype's timing: 20 frames/s (lit every other frame: 10 scans/s), 40 ms exposure.
DEFAULT_TIMING = CameraTimingConfig(frame_duration_s=0.05, exposure_s=0.04)


class SimulatedCamera:
    """Frames of a static scene with ground truth; deterministic for ``seed``."""

    def __init__(self, cfg: SensorConfig, scene: Scene, pulses: PulseSource, *,
                 timing: CameraTimingConfig | None = None, exposure_us: float | None = None,
                 frame_duration_us: float | None = None, start_ns: int | None = None, line_time_ns: float | None = None,
                 seed: int = 0, options: RenderOptions = RenderOptions(), sensor: SensorParams = SIMULATOR_DEFAULT):
        """``timing``: the camera clock's configuration (default DEFAULT_TIMING). Or give plain
        ``exposure_us``/``frame_duration_us``/``start_ns``/``line_time_ns`` (each optional) for an
        ideal clock: the same line quantisation and control delay, no jitter, no dropped frames."""
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
        self.renderer = SceneRenderer(cfg, scene, sensor, options, seed)
        self.width, self.height, self.line_time_ns = cfg.width, cfg.height, timing.line_time_s * 1e9
        self.pulses = pulses
        self.clock = CameraClock(timing, np.random.default_rng([seed, 0xC10C]))
        self._rng = np.random.default_rng([seed, 0xCA3])
        self._running = False

    def start(self) -> None:
        self._running = True

    def stop(self) -> None:
        self._running = False

    def set_frame_duration(self, frame_duration_us: float) -> None:
        self.clock.request(frame_duration_s=frame_duration_us * 1e-6)

    def set_exposure(self, exposure_us: float) -> None:
        if not exposure_us > 0:
            raise ValueError(f"exposure must be positive, got {exposure_us} us")
        self.clock.request(exposure_s=exposure_us * 1e-6)

    def capture_with_truth(self, timeout_s: float = 1.0) -> tuple[Frame, FrameTruth]:
        if not self._running:
            raise CameraError("camera not started: call start() first")
        ft = self.clock.next_frame()
        while ft.dropped:  # exposed but never delivered
            ft = self.clock.next_frame()
        t_ns = int(round(ft.true_start_s * 1e9))
        lt_ns = ft.line_time_s * 1e9
        exposure_us = ft.exposure_s * 1e6
        first_start = t_ns - int(round(ft.exposure_s * 1e9))
        last_end = t_ns + int((self.height - 1) * lt_ns)
        timing = FrameTiming(t_ns, exposure_us, lt_ns, tuple(self.pulses.windows(first_start, last_end)))
        image, truth = self.renderer.render(timing, self._rng)
        frame = Frame(image, ft.sequence, ft.sensor_timestamp_ns, exposure_us, ft.frame_duration_s * 1e6, lt_ns,
                      lit=bool(truth.lit_rows.any()))
        return frame, truth

    def capture(self, timeout_s: float = 1.0) -> Frame:
        return self.capture_with_truth(timeout_s)[0]
