"""A frame pair -> ranges and quality on the scan's uniform angles: what the scan source
(device/scan/source.py) runs for each pair, made of a device.vision Pipeline by ScanPipeline."""

from __future__ import annotations

from typing import TYPE_CHECKING, Callable

import numpy as np

from device.camera.frame import Frame
from device.model.scan_frame import uniform_angles

if TYPE_CHECKING:
    from device.vision.measurements import Pipeline

#: (lit, dark) -> ranges (float32, REP 117) and quality (uint8) on every angle of the scan geometry.
ScanFunction = Callable[[Frame, Frame], tuple[np.ndarray, np.ndarray]]


class ScanPipeline:
    """ScanFunction of a device.vision Pipeline: its per-column measurements resampled onto
    ``count`` uniform angles (device.vision.measurements.to_laser_scan: never across a depth
    jump), quality from the nearest measured column."""

    def __init__(self, pipeline: Pipeline, count: int):
        a = np.asarray(pipeline.geometry.column_angle, dtype=np.float64)
        a = a[np.isfinite(a)]
        if a.size < 2 or count < 2:
            raise ValueError(f"need at least 2 columns with an angle and 2 scan points, got {a.size} and {count}")
        self.pipeline = pipeline
        self.angle_min, self.angle_max = float(a.min()), float(a.max())
        self.angles = uniform_angles(self.angle_min, self.angle_max, count)

    def __call__(self, lit: Frame, dark: Frame) -> tuple[np.ndarray, np.ndarray]:
        from device.vision.measurements import to_laser_scan

        meas = self.pipeline.process(lit, dark)
        _, ranges = to_laser_scan(meas, self.angle_min, self.angle_max, self.angles.size)
        ok = np.isfinite(meas.angle)
        order = np.argsort(meas.angle[ok])
        a, q = meas.angle[ok][order], np.asarray(meas.quality, dtype=np.float64)[ok][order]
        idx = np.clip(np.searchsorted(a, self.angles), 1, max(a.size - 1, 1))
        nearest = np.where(np.abs(a[idx - 1] - self.angles) <= np.abs(a[np.minimum(idx, a.size - 1)] - self.angles),
                           idx - 1, np.minimum(idx, a.size - 1))
        quality = np.where(np.isfinite(ranges), np.clip(np.rint(q[nearest]), 0, 255), 0).astype(np.uint8)
        return ranges.astype(np.float32), quality
