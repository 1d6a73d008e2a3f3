"""Per-column geometry precomputed from the calibration: where the laser can land (region of
interest) and a row -> ray table for fast triangulation (thesis eq. 3.5-3.11, 3.17).

For every column u and every integer row v of the band the camera can see the laser in, the
table holds the undistorted normalised ray (x_n, y_n) of pixel (u, v) (robust backward
projection, :func:`device.model.camera.undistort_robust`). A sub-pixel row is triangulated by
linear interpolation of the ray between the two neighbouring rows followed by the exact
ray/plane intersection. The ray is a smooth function of the row (only the lens distortion bends
it), so the interpolation error is tiny, whereas interpolating depth itself would not be: depth
goes as 1/(distance to the horizon). ``tests/test_vision_geometry.py`` bounds the error against
direct backward projection.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np

from ..config import SensorConfig
from ..model.camera import undistort_robust
from ..model.scan_frame import ScanFrame, scan_frame, to_scan_plane
from ..model.triangulation import HORIZON_EPS, LaserPlane, RangeStatus, Triangulation, intersect_plane
from .kernel import columns_kernel

#: The RangeStatus codes in the kernel's order.
_RANGE_CODES = tuple(int(s) for s in (RangeStatus.OK, RangeStatus.INVALID_PIXEL, RangeStatus.BEYOND_HORIZON,
                                      RangeStatus.TOO_CLOSE, RangeStatus.TOO_FAR))
#: Rows added on each side of the region of interest so the line profile is whole at the limits.
ROI_MARGIN_ROWS = 8


@dataclass(frozen=True)
class ColumnGeometry:
    """Precomputed per-column geometry of one sensor configuration.

    ``top``/``bottom``: rows [top, bottom) covered by the ray table ``xn``/``yn`` (rows, W).
    ``roi_lo``/``roi_hi``: (W,) rows [lo, hi) where the laser line can appear for depths in
    [min_m, max_m], widened by ``margin`` rows. ``column_angle``: (W,) scan angle of each column's
    laser point at 2 m (or the nearest depth in range), for columns without a return; NaN in the
    frame buffer's padding columns. ``active_width``: the image's columns [0, active_width) of the
    buffer's ``width`` (the configuration's ``[image] active_width``): the columns beyond hold no
    pixel (device/camera/picamera2_camera.py places the 1640-column Y plane at the left of a
    zeroed 1664-column buffer), so no pipeline measures there and no scan has a ray there.
    ``near_below``: nearer depths lie at larger rows (the camera looks down onto the plane).
    """

    width: int
    height: int
    plane: LaserPlane
    scan: ScanFrame
    min_m: float
    max_m: float
    top: int
    bottom: int
    xn: np.ndarray
    yn: np.ndarray
    roi_lo: np.ndarray
    roi_hi: np.ndarray
    column_angle: np.ndarray
    near_below: bool
    inv_depth: np.ndarray  # (rows, W) 1/z of each table pixel on the plane (<= 0 beyond the horizon)
    active_width: int

    def triangulate(self, rows: np.ndarray, columns: np.ndarray | None = None) -> Triangulation:
        """Sub-pixel rows (one per column, NaN: none) -> points on the laser plane, by the table.

        Rows outside the table's band give status INVALID_PIXEL; limits as :func:`intersect_plane`.
        """
        rows = np.asarray(rows, dtype=np.float64)
        cols = np.arange(self.width) if columns is None else np.asarray(columns)
        if rows.shape != cols.shape:
            raise ValueError(f"rows {rows.shape} and columns {cols.shape} must have the same shape")
        # the ray/plane intersection of intersect_plane (eq. 3.13, 3.17), same arithmetic, one ray
        # per row in the compiled kernel (its generic (..., 2) handling costs more than the maths)
        points, depth = np.empty(rows.shape + (3,)), np.empty(rows.shape)
        status = np.empty(rows.shape, np.uint8)
        columns_kernel().triangulate(rows.ravel(), np.ascontiguousarray(cols, np.intp).ravel(), self.xn, self.yn,
                                     self.top, (*self.plane.normal, self.plane.distance),
                                     (self.min_m, self.max_m, HORIZON_EPS), _RANGE_CODES, points.reshape(-1, 3),
                                     depth.reshape(-1), status.reshape(-1))
        return Triangulation(points, depth, status)

    def inverse_depth(self, rows: np.ndarray, columns: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """(1/z, d(1/z)/d row) at sub-pixel rows, one per column (default all columns, else
        ``columns``), NaN outside the table: the cheap depth cue
        for comparing candidates and sizing depth jumps. 1/z = (n . p) / d is linear in the ray,
        so interpolating it is as exact as interpolating the ray."""
        rows = np.asarray(rows, dtype=np.float64)
        r = rows - self.top
        n = self.bottom - self.top
        inside = (r >= 0) & (r <= n - 1)  # False for NaN
        r = np.where(inside, r, 0.0)
        r0 = np.minimum(r.astype(np.intp), max(n - 2, 0))
        cols = np.arange(self.width) if columns is None else np.asarray(columns)
        flat = self.inv_depth.reshape(-1)
        i0 = r0 * self.width + cols
        a, b = flat.take(i0), flat.take(i0 + self.width if n > 1 else i0)
        t = r - r0
        return np.where(inside, a + (b - a) * t, np.nan), np.where(inside, b - a, np.nan)

    def angle_range(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Camera-frame points (..., 3) -> (scan angle, scan range); NaN stays NaN.

        to_scan_plane's arithmetic in the compiled kernel (columns_scan_plane), each operation
        rounded: numpy's matmul there goes through BLAS, whose fused multiply-adds give other last
        bits on other machines (an aarch64 Pi's among them)."""
        p = np.asarray(points, dtype=np.float64)
        if p.ndim < 1 or p.shape[-1] != 3:
            raise ValueError(f"points must have shape (..., 3), got {p.shape}")
        p = np.ascontiguousarray(p)
        angle, rng = np.empty(p.shape[:-1]), np.empty(p.shape[:-1])
        sf = self.scan
        columns_kernel().scan_plane(p.reshape(-1, 3), np.ascontiguousarray(sf.rotation, np.float64),
                                    np.ascontiguousarray(sf.origin, np.float64), angle.reshape(-1), rng.reshape(-1))
        return angle, rng


def column_geometry(config: SensorConfig, min_m: float | None = None, max_m: float | None = None,
                    margin: int = ROI_MARGIN_ROWS) -> ColumnGeometry:
    """The geometry of ``config`` for depth limits [min_m, max_m] (default: the config's
    ``[range]``). Cached: building it unprojects the whole band once (a few seconds)."""
    lo_m = config.range.min_m if min_m is None else float(min_m)
    hi_m = config.range.max_m if max_m is None else float(max_m)
    if not (0 <= lo_m < hi_m) or not math.isfinite(lo_m):
        raise ValueError(f"range limits must satisfy 0 <= min_m < max_m, got [{lo_m}, {hi_m}]")
    if margin < 0:
        raise ValueError(f"margin must be >= 0 rows, got {margin}")
    return _build(config, lo_m, hi_m, int(margin))


def _unproject_rows(config: SensorConfig, rows: np.ndarray) -> np.ndarray:
    u, v = np.meshgrid(np.arange(config.width, dtype=np.float64), rows.astype(np.float64))
    return undistort_robust(np.stack([u, v], axis=-1), config.camera).xy


@functools.lru_cache(maxsize=8)
def _build(config: SensorConfig, min_m: float, max_m: float, margin: int) -> ColumnGeometry:
    W, H = config.width, config.height
    # coarse pass over every 8th row to find the band, then the exact table over the band
    coarse_rows = np.unique(np.append(np.arange(0, H, 8), H - 1))
    z = intersect_plane(_unproject_rows(config, coarse_rows), config.plane, min_m, max_m).status == RangeStatus.OK
    hit = np.nonzero(z.any(axis=1))[0]
    if hit.size == 0:
        raise ValueError(
            f"{config.name}: the laser plane is nowhere in view for depths [{min_m}, {max_m}] m; "
            "check the plane and the range limits"
        )
    top = max(int(coarse_rows[max(hit[0] - 1, 0)]) - margin, 0)
    bottom = min(int(coarse_rows[min(hit[-1] + 1, coarse_rows.size - 1)]) + margin + 1, H)
    rows = np.arange(top, bottom)
    xy = _unproject_rows(config, rows)
    tri = intersect_plane(xy, config.plane, min_m, max_m)
    ok = tri.status == RangeStatus.OK  # (rows, W)
    any_ok = ok.any(axis=0)
    first = np.where(any_ok, np.argmax(ok, axis=0), 0)
    last = np.where(any_ok, ok.shape[0] - 1 - np.argmax(ok[::-1], axis=0), -1)
    roi_lo = np.where(any_ok, np.clip(top + first - margin, 0, H), 0)
    roi_hi = np.where(any_ok, np.clip(top + last + 1 + margin, 0, H), 0)
    # nominal angle per column: its laser point nearest 2 m depth
    sf = scan_frame(config.plane)
    unlimited = intersect_plane(xy, config.plane)
    dz = np.where(np.isfinite(unlimited.depth), np.abs(unlimited.depth - min(max(2.0, min_m), max_m)), np.inf)
    best = np.argmin(dz, axis=0)
    pts = unlimited.points[best, np.arange(W)]
    angle, _ = to_scan_plane(pts, sf)
    active = config.active_width or W
    angle[active:] = np.nan  # the buffer's padding: no pixel, no scan angle
    zc = unlimited.depth[:, int(np.argmax(any_ok))] if not any_ok[W // 2] else unlimited.depth[:, W // 2]
    fin = np.nonzero(np.isfinite(zc))[0]
    near_below = bool(zc[fin[-1]] < zc[fin[0]]) if fin.size > 1 else True
    n = np.asarray(config.plane.normal)
    inv = (xy @ n[:2] + n[2]) / config.plane.distance
    for a in (xy, roi_lo, roi_hi, angle, inv):
        a.setflags(write=False)
    return ColumnGeometry(
        W, H, config.plane, sf, min_m, max_m, top, bottom,
        np.ascontiguousarray(xy[..., 0]), np.ascontiguousarray(xy[..., 1]), roi_lo, roi_hi, angle, near_below, inv,
        active,
    )
