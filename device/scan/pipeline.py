"""A lit frame and its unlit neighbours -> ranges, quality and times on the scan's uniform
angles: what the scan source (device/scan/source.py) runs for each lit frame, made of a
device.vision Pipeline by ScanPipeline."""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Callable

import numpy as np

from device.camera.frame import Frame
from device.model.scan_frame import uniform_angles
from device.scan.timing import column_times_ns, scan_timing

if TYPE_CHECKING:
    from device.vision.measurements import Pipeline

@dataclass(frozen=True)
class ScanRays:
    """Ranges (float32, REP 117) and quality (uint8) on every angle of the scan geometry, and
    when ray 0 was measured and the step per ray (device.scan.timing); ray_times_ns: each ray's
    own time (float64 CLOCK_MONOTONIC ns, NaN: not measured; None: not timed one by one)."""

    ranges: np.ndarray
    quality: np.ndarray
    first_ray_ns: int
    ray_interval_ns: int
    ray_times_ns: np.ndarray | None = None


#: (lit, the nearest unlit neighbour, the other unlit neighbour or None) -> ScanRays.
ScanFunction = Callable[[Frame, Frame, "Frame | None"], ScanRays]


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

    def __call__(self, lit: Frame, dark: Frame, other_dark: Frame | None = None) -> ScanRays:
        from device.vision.measurements import to_laser_scan

        meas = self.pipeline.process(lit, dark, other_unlit=other_dark)
        _, ranges = to_laser_scan(meas, self.angle_min, self.angle_max, self.angles.size)
        ok = np.isfinite(meas.angle)
        order = np.argsort(meas.angle[ok])
        a, q = meas.angle[ok][order], np.asarray(meas.quality, dtype=np.float64)[ok][order]
        idx = np.clip(np.searchsorted(a, self.angles), 1, max(a.size - 1, 1))
        nearest = np.where(np.abs(a[idx - 1] - self.angles) <= np.abs(a[np.minimum(idx, a.size - 1)] - self.angles),
                           idx - 1, np.minimum(idx, a.size - 1))
        quality = np.where(np.isfinite(ranges), np.clip(np.rint(q[nearest]), 0, 255), 0).astype(np.uint8)
        times = column_times_ns(lit, np.asarray(meas.row, dtype=np.float64)[ok][order])[nearest]
        g = self.pipeline.geometry
        ray_times = np.where(np.isfinite(ranges), times, np.nan)
        timing = scan_timing(ray_times, column_times_ns(lit, np.array((g.roi_lo.min() + g.roi_hi.max()) / 2)))
        return ScanRays(ranges.astype(np.float32), quality, timing.first_ray_ns, timing.ray_interval_ns, ray_times)
