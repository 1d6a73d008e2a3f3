"""What a pipeline returns per frame pair, and the uniform-angle scan the device sends.

Every pipeline (``reference``, ``fast``) returns :class:`ColumnMeasurements`: one entry per
processed image column with the scan angle, the range with REP 117 semantics (NaN invalid,
+inf no return, -inf too close), a quality, the camera-frame 3-D point and a status code saying
why a column has no range.
"""

from __future__ import annotations

import enum
from dataclasses import dataclass
from typing import Protocol

import numpy as np

from ..camera.frame import Frame
from ..model.scan_frame import angle_order, resample_scan, uniform_angles
from ..model.triangulation import RangeStatus, Triangulation
from . import postcal
from .geometry import ColumnGeometry


class ColumnStatus(enum.IntEnum):
    """Per-column outcome (REP 117 range in brackets)."""

    OK = 0
    NO_RETURN = 1  # no laser line found in the column  [+inf]
    TOO_CLOSE = 2  # line found, nearer than the minimum range  [-inf]
    TOO_FAR = 3  # line found, farther than the maximum range  [+inf]
    BEYOND_HORIZON = 4  # line found where the camera ray never meets the laser plane  [NaN]
    INVALID_PIXEL = 5  # backward projection failed for the line's pixel  [NaN]
    UNLIT = 6  # the column's rows were not lit by the pulse, or the laser lit the "unlit" frame  [NaN]
    REJECTED = 7  # a line was found but failed a consistency check (width, ambiguity)  [NaN]
    SATURATED = 8  # bright light saturated the camera where the line is, or could be  [NaN]


#: ColumnStatus values as numpy scalars for the per-frame array operations (numpy converts an
#: IntEnum member on every use: ~4 us a comparison on a scan, against ~1.5 us).
STATUS_U8 = {s: np.uint8(s) for s in ColumnStatus}

#: each status's REP 117 range where no range was measured (statuses are 0, 1, ...)
_RANGE_OF_STATUS = np.array([{ColumnStatus.NO_RETURN: np.inf, ColumnStatus.TOO_CLOSE: -np.inf,
                              ColumnStatus.TOO_FAR: np.inf}.get(s, np.nan) for s in ColumnStatus])
_FROM_RANGE_STATUS = np.zeros(max(RangeStatus) + 1, dtype=np.uint8)  # RangeStatus -> ColumnStatus
for _r, _c in (
    (RangeStatus.OK, ColumnStatus.OK),
    (RangeStatus.INVALID_PIXEL, ColumnStatus.INVALID_PIXEL),
    (RangeStatus.BEYOND_HORIZON, ColumnStatus.BEYOND_HORIZON),
    (RangeStatus.TOO_CLOSE, ColumnStatus.TOO_CLOSE),
    (RangeStatus.TOO_FAR, ColumnStatus.TOO_FAR),
):
    _FROM_RANGE_STATUS[_r] = _c


@dataclass(frozen=True)
class ColumnMeasurements:
    """One frame pair's result, every array of length N (processed columns).

    ``column``: image column (int). ``row``: sub-pixel image row of the line, NaN where none.
    ``angle``: scan angle (rad, REP 103, in the scan frame of device.model.scan_frame).
    ``range``: scan range (m), REP 117: NaN invalid, +inf no return/too far, -inf too close.
    ``quality``: line amplitude in the difference image (8-bit levels), 0 where no line and
    where a column was filled from its neighbours (fast pipeline, small gaps inside a surface).
    ``points``: (N, 3) camera-frame point (m), NaN unless OK. ``status``: :class:`ColumnStatus`.
    """

    column: np.ndarray
    row: np.ndarray
    angle: np.ndarray
    range: np.ndarray
    quality: np.ndarray
    points: np.ndarray
    status: np.ndarray

    @property
    def valid(self) -> np.ndarray:
        return self.status == ColumnStatus.OK


class Pipeline(Protocol):
    """A frame-pair pipeline; built from a SensorConfig by :func:`device.vision.make_pipeline`.
    The device process runs one through device.scan.pipeline.ScanPipeline."""

    name: str
    geometry: ColumnGeometry

    def process(self, lit, unlit, lit_rows: np.ndarray | None = None) -> ColumnMeasurements: ...


def luminance(frame, name: str, shape: tuple[int, int] | None = None) -> np.ndarray:
    """The uint8 (H, W) luminance of a Frame or array, C-contiguous (copied only if it is a
    strided view, e.g. the Y plane cut out of a padded YUV buffer), with a clear error for
    anything else."""
    img = frame.image if isinstance(frame, Frame) else np.asarray(frame)
    if img.ndim != 2 or img.dtype != np.uint8:
        raise ValueError(f"{name} frame must be a (height, width) uint8 luminance image, got {img.shape} {img.dtype}")
    if shape is not None and img.shape != shape:
        raise ValueError(f"{name} frame is {img.shape[1]}x{img.shape[0]}, the configuration expects {shape[1]}x{shape[0]}")
    return np.ascontiguousarray(img)


def finish(
    geom: ColumnGeometry, columns: np.ndarray, rows: np.ndarray, quality: np.ndarray, line_status: np.ndarray,
    tri: Triangulation, post,
) -> ColumnMeasurements:
    """Combine line finding (``line_status``: OK where a line was measured at ``rows``) and its
    triangulation into measurements: post-calibration (eq. 6.5), scan angle/range, REP 117. Only
    the image's ``columns`` are measured: those in the frame buffer's padding beyond it
    (``geom.active_width``) hold no pixel, where "no return" (+inf) would claim free space."""
    columns = np.asarray(columns)
    image = columns < geom.active_width
    n = int(np.count_nonzero(image))
    if n < image.size:
        # the image's columns first, the padding after them (the fast pipeline's order): views of
        # the inputs (the columns copied: the measurements' own, not a pipeline's table)
        keep = slice(0, n) if image[:n].all() else image
        columns, rows, quality, line_status = columns[keep].copy(), rows[keep], quality[keep], line_status[keep]
        tri = Triangulation(tri.points[keep], tri.depth[keep], tri.status[keep])
    status = np.asarray(line_status, dtype=np.uint8)
    ok_u8 = STATUS_U8[ColumnStatus.OK]
    status = np.where(status == ok_u8, _FROM_RANGE_STATUS.take(tri.status), status)
    ok = status == ok_u8
    points = postcal.apply(post, np.where(ok[:, None], tri.points, np.nan))
    angle, rng = geom.angle_range(points)
    angle = np.where(ok, angle, geom.column_angle.take(columns))
    rng = np.where(ok, rng, _RANGE_OF_STATUS.take(status))
    none = status == STATUS_U8[ColumnStatus.NO_RETURN]
    return ColumnMeasurements(columns, np.where(none, np.nan, rows), angle, rng,
                              np.where(none, 0.0, quality), points, status)


def to_laser_scan(meas: ColumnMeasurements, angle_min: float, angle_max: float, count: int,
                  max_gap: float | None = None) -> tuple[np.ndarray, np.ndarray]:
    """(angles, ranges) of a uniform LaserScan grid, resampled without crossing depth jumps.

    ``max_gap`` (rad): largest angular gap bridged between two measured columns; default
    :func:`bridged_gap`.
    """
    grid = uniform_angles(angle_min, angle_max, count)
    a = np.asarray(meas.angle, dtype=float)
    order = angle_order(a)
    if max_gap is None:
        max_gap = bridged_gap(a[order], grid)
    return grid, resample_scan(a, meas.range, grid, max_gap, order=order)


#: The default largest gap a scan bridges between two measured columns, in median column spacings.
BRIDGED_SPACINGS = 3.0


def bridged_gap(sorted_angles: np.ndarray, grid: np.ndarray) -> float:
    """The default largest gap (rad) a scan bridges between two measured columns:
    BRIDGED_SPACINGS times the median spacing of the columns' ``sorted_angles`` (the grid's step
    with fewer than 3)."""
    if sorted_angles.size > 2:
        return BRIDGED_SPACINGS * float(np.median(np.diff(sorted_angles)))
    return grid[1] - grid[0]
