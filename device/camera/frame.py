"""The frame record every camera backend produces (picamera2, simulator, replay)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Frame:
    """One luminance frame and its metadata.

    ``image``: (height, width) uint8 luminance (the Y plane of YUV420 on a Pi).
    ``sensor_timestamp_ns``: start of row-0 readout on CLOCK_MONOTONIC (libcamera SensorTimestamp);
    row r is exposed during [T - exposure + r * line_time, T + r * line_time] (rolling shutter).
    ``lit``: whether the laser was scheduled to fire in this frame (docs/thesis-notes.md N10), None if unknown.
    """

    image: np.ndarray
    seq: int
    sensor_timestamp_ns: int
    exposure_us: float
    frame_duration_us: float
    line_time_ns: float
    lit: bool | None = None

    def __post_init__(self) -> None:
        if self.image.ndim != 2 or self.image.dtype != np.uint8:
            raise ValueError(f"frame image must be (height, width) uint8, got {self.image.shape} {self.image.dtype}")

    def row_exposure_ns(self, row: int | np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(start, end) of the exposure of image row(s) ``row``, CLOCK_MONOTONIC ns."""
        end = self.sensor_timestamp_ns + np.asarray(row, dtype=np.float64) * self.line_time_ns
        return end - self.exposure_us * 1e3, end
