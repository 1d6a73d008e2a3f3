"""Simulated IMX219 frame timing: the camera clock the synchronisation controllers are run against.

What is modelled (and why):

- **Line time.** Mode 5 (1640x922, 2x2 binned) reads one row in 18904 ns (thesis Table B.3;
  the IMX219 driver's line length of 3448 pixels at 182.4 MHz, device/camera/modes.py).
  922 rows therefore take 17.43 ms to read, the "17.4 ms" capture time of Table B.3.
- **Rolling shutter.** ``T`` is the start of the readout of row 0 (libcamera's SensorTimestamp);
  row ``r`` is exposed during ``[T - E + r*line_time, T + r*line_time]``.
- **Frame duration control** is quantised to whole lines (frame length lines, at least the active
  rows plus ``vblank_min_lines``), exposure too (coarse integration time, at most the frame
  length minus 4 lines). The floor counts the image's 922 rows, as the thesis's sensor-cropped
  mode 5 read them; the 1640x1232 mode picamera2 runs reads all 1232 (its
  ``SensorMode.min_frame_lines``), which matters only above 41.85 frames/s. Changes take effect ``control_delay_frames`` = 2 frames after the frame
  the controller last saw, as libcamera's sensor delays for the IMX219 (exposure and vertical
  blanking delay 2). The thesis observed this delay as a lag in the step response (Figure 5.3).
- **Camera oscillator** error ``clock_ppm`` against CLOCK_MONOTONIC: every duration of the
  sensor is scaled by ``1 + clock_ppm * 1e-6``.
- **Timestamp jitter.** The SensorTimestamp is taken by the Pi's CSI-2 receiver driver in its
  frame-start interrupt, so its error is an interrupt latency: never early, usually small, with a
  tail. Modelled as an exponential latency with mean ``timestamp_jitter_s`` (a constant latency
  would only shift every timestamp and is left out).
- **Dropped frames**: with probability ``drop_probability`` a frame is exposed but not delivered;
  its sequence number is skipped (as libcamera's SensorSequence / request sequence show it).
- **Restart**: ``restart(t)`` starts the stream again at an arbitrary phase with sequence 0.

Times are seconds as floats (true time = the Pi's CLOCK_MONOTONIC, which is the reference clock
of the whole simulation); the reported timestamp is integer nanoseconds like the Pi's. Every
random draw comes from one ``numpy.random.Generator`` so a run is deterministic for a seed.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..camera.modes import IMX219_EXPOSURE_MARGIN_LINES, IMX219_VBLANK_MIN_LINES, MODE5


@dataclass(frozen=True)
class CameraTimingConfig:
    """The simulated camera's timing; the defaults are the thesis's mode 5 (device/camera/modes.py MODE5)."""

    frame_duration_s: float = 0.05
    exposure_s: float = 0.005
    line_time_s: float = MODE5.mode.line_time_s
    active_rows: int = MODE5.height
    vblank_min_lines: int = IMX219_VBLANK_MIN_LINES
    control_delay_frames: int = 2
    clock_ppm: float = 0.0
    timestamp_jitter_s: float = 10e-6
    drop_probability: float = 1e-3
    start_time_s: float = 1.0

    def __post_init__(self) -> None:
        if not (self.line_time_s > 0 and self.active_rows > 0):
            raise ValueError(f"line_time_s and active_rows must be positive, got {self.line_time_s}, {self.active_rows}")
        if not self.frame_duration_s > 0 or not self.exposure_s > 0:
            raise ValueError(f"frame_duration_s and exposure_s must be positive, got {self.frame_duration_s}, {self.exposure_s}")
        if self.timestamp_jitter_s < 0 or not 0 <= self.drop_probability < 1:
            raise ValueError("timestamp_jitter_s must be >= 0 and drop_probability in [0, 1)")
        if self.control_delay_frames < 1:
            raise ValueError(f"control_delay_frames must be >= 1, got {self.control_delay_frames}")


@dataclass(frozen=True)
class FrameTiming:
    """One frame as the camera produced it: truth and what the Pi is told."""

    sequence: int
    true_start_s: float  # T: start of row-0 readout, true CLOCK_MONOTONIC seconds
    sensor_timestamp_ns: int  # reported SensorTimestamp (T plus interrupt latency), ns
    exposure_s: float  # actual exposure (line-quantised, camera clock)
    frame_duration_s: float  # actual duration since the previous frame's T
    line_time_s: float  # actual line time (camera clock)
    dropped: bool  # exposed but never delivered

    def row_exposure(self, row: np.ndarray | float) -> tuple[np.ndarray, np.ndarray]:
        """Exposure interval of image row(s): ``[T - E + r*lt, T + r*lt]`` in true seconds."""
        r = np.asarray(row, dtype=float)
        end = self.true_start_s + r * self.line_time_s
        return end - self.exposure_s, end


def quantise_frame_duration(duration_s: float, exposure_s: float, cfg: CameraTimingConfig) -> int:
    """Frame length in lines that the sensor uses for a requested frame duration."""
    lines = int(round(duration_s / cfg.line_time_s))
    exposure_lines = int(round(exposure_s / cfg.line_time_s))
    return max(lines, cfg.active_rows + cfg.vblank_min_lines, exposure_lines + IMX219_EXPOSURE_MARGIN_LINES)


class CameraClock:
    """Frame timing of a free-running or frame-duration-controlled IMX219 (one job: when frames happen)."""

    _BLOCK = 4096

    def __init__(self, cfg: CameraTimingConfig, rng: np.random.Generator) -> None:
        self.cfg = cfg
        self._rng = rng
        self._scale = 1.0 + cfg.clock_ppm * 1e-6
        self._fll = quantise_frame_duration(cfg.frame_duration_s, cfg.exposure_s, cfg)
        self._exp_lines = max(1, int(round(cfg.exposure_s / cfg.line_time_s)))
        self._pending: list[tuple[int, int | None, int | None]] = []  # (from sequence, fll, exposure lines)
        self._seq = -1
        self._t = cfg.start_time_s - self._fll * cfg.line_time_s * self._scale
        self._refill()

    def _refill(self) -> None:
        self._lat = self._rng.exponential(1.0, self._BLOCK) * self.cfg.timestamp_jitter_s
        self._drop = self._rng.random(self._BLOCK) < self.cfg.drop_probability
        self._i = 0

    @property
    def last_sequence(self) -> int:
        return self._seq

    def request(self, frame_duration_s: float | None = None, exposure_s: float | None = None) -> None:
        """Ask for a new frame duration and/or exposure; effective ``control_delay_frames`` after the last frame."""
        fll = None
        if frame_duration_s is not None:
            if not np.isfinite(frame_duration_s) or frame_duration_s <= 0:
                raise ValueError(f"frame duration must be a positive number of seconds, got {frame_duration_s}")
            e = exposure_s if exposure_s is not None else self._exp_lines * self.cfg.line_time_s
            fll = quantise_frame_duration(frame_duration_s, e, self.cfg)
        exp = None if exposure_s is None else max(1, int(round(exposure_s / self.cfg.line_time_s)))
        self._pending.append((self._seq + self.cfg.control_delay_frames, fll, exp))

    def restart(self, at_s: float) -> None:
        """Stop and start the stream: first new frame at ``at_s`` plus a random phase, sequence 0 again."""
        self._pending.clear()
        self._seq = -1
        period = self._fll * self.cfg.line_time_s * self._scale
        self._t = at_s + self._rng.random() * period - period

    def next_frame(self) -> FrameTiming:
        seq = self._seq + 1
        if self._pending:
            keep = []
            for p in self._pending:
                if p[0] <= seq:
                    self._fll = p[1] if p[1] is not None else self._fll
                    self._exp_lines = p[2] if p[2] is not None else self._exp_lines
                else:
                    keep.append(p)
            self._pending = keep
        self._exp_lines = min(self._exp_lines, self._fll - IMX219_EXPOSURE_MARGIN_LINES)
        lt = self.cfg.line_time_s * self._scale
        duration = self._fll * lt
        self._t += duration
        self._seq = seq
        if self._i >= self._BLOCK:
            self._refill()
        lat, drop = self._lat[self._i], self._drop[self._i]
        self._i += 1
        return FrameTiming(
            sequence=seq,
            true_start_s=self._t,
            sensor_timestamp_ns=int(round((self._t + lat) * 1e9)),
            exposure_s=self._exp_lines * lt,
            frame_duration_s=duration,
            line_time_s=lt,
            dropped=bool(drop),
        )
