"""A lit frame and its unlit neighbours -> ranges, quality and times on the scan's uniform
angles: what the scan source (device/scan/source.py) runs for each lit frame, made of a
device.vision Pipeline by ScanPipeline."""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Callable

import numpy as np

from device.camera.frame import Frame
from device.model.scan_frame import MAX_JUMP_RATIO, uniform_angles
from device.scan.timing import column_times_ns, scan_timing
from device.vision.kernel import columns_kernel
from device.vision.measurements import BRIDGED_SPACINGS, STATUS_U8, ColumnStatus

if TYPE_CHECKING:
    from device.vision.measurements import Pipeline

@dataclass(frozen=True)
class ScanRays:
    """Ranges (float32, REP 117) and quality (uint8) on every angle of the scan geometry, and
    when ray 0 was measured and the step per ray (device.scan.timing); ray_times_ns: each ray's
    own time (float64 CLOCK_MONOTONIC ns, NaN: not measured; None: not timed one by one);
    saturated_columns: image columns where bright light saturated the camera over the line or
    where it could be (ColumnStatus.SATURATED: their rays are NaN)."""

    ranges: np.ndarray
    quality: np.ndarray
    first_ray_ns: int
    ray_interval_ns: int
    ray_times_ns: np.ndarray | None = None
    saturated_columns: int = 0


#: (lit, the nearest unlit neighbour, the other unlit neighbour or None) -> ScanRays.
ScanFunction = Callable[[Frame, Frame, "Frame | None"], ScanRays]


class ScanPipeline:
    """ScanFunction of a device.vision Pipeline: its per-column measurements resampled onto
    ``count`` uniform angles (device.model.scan_frame.resample_scan: never across a depth
    jump), quality from the nearest measured column."""

    def __init__(self, pipeline: Pipeline, count: int):
        a = np.asarray(pipeline.geometry.column_angle, dtype=np.float64)
        a = a[np.isfinite(a)]
        if a.size < 2 or count < 2:
            raise ValueError(f"need at least 2 columns with an angle and 2 scan points, got {a.size} and {count}")
        self.pipeline = pipeline
        self.angle_min, self.angle_max = float(a.min()), float(a.max())
        self.angles = uniform_angles(self.angle_min, self.angle_max, count)
        g = pipeline.geometry
        self._middle_row = np.array((g.roi_lo.min() + g.roi_hi.max()) / 2)  # rays without a time: this row's

    def __call__(self, lit: Frame, dark: Frame, other_dark: Frame | None = None) -> ScanRays:
        meas = self.pipeline.process(lit, dark, other_unlit=other_dark)
        n = self.angles.size
        ranges, quality, rows = np.empty(n), np.empty(n, np.uint8), np.empty(n)
        # the columns' angle order, the bridged gap, resample_scan's arithmetic and the nearest
        # column's quality and row in one compiled pass (one call instead of ~100 numpy ones, each
        # paying a cold cache after the frame's wait)
        columns_kernel().scan_rays(*(np.ascontiguousarray(x, dtype=np.float64) for x in (meas.angle, meas.range, meas.quality, meas.row)),
                                   self.angles, BRIDGED_SPACINGS, MAX_JUMP_RATIO, ranges, quality, rows)
        ray_times = column_times_ns(lit, rows)  # NaN where the ray has no range (the kernel's row)
        timing = scan_timing(ray_times, column_times_ns(lit, self._middle_row))
        return ScanRays(ranges.astype(np.float32), quality, timing.first_ray_ns, timing.ray_interval_ns, ray_times,
                        int(np.count_nonzero(meas.status == STATUS_U8[ColumnStatus.SATURATED])))
