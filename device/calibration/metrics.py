"""How good a calibration is, against the truth: focal lengths, principal point, laser plane and
the range error it gives on a wall (thesis section 4.1.5, docs/thesis-notes.md N5). Used by the view bootstrap
(pipeline.py, estimate against resampled estimates) and by ``laserpi calibrate --simulate``
(estimate against the simulated truth)."""

from __future__ import annotations

import math

import numpy as np

from ..config import SensorConfig
from ..model.camera import project_points, undistort_robust
from ..model.scan_frame import scan_frame, to_scan_plane
from ..model.triangulation import RangeStatus, intersect_plane


def wall_range_error(truth: SensorConfig, estimate: SensorConfig, distance_m: float = 2.0, samples: int = 2001) -> dict[str, float]:
    """Range error of ``estimate`` on a wall ``distance_m`` ahead (perpendicular to the true scan
    frame's forward axis): true laser points on the wall are imaged with the true camera, then
    triangulated with the estimated camera and plane; ranges compared in each one's scan frame.
    Returns the RMS and the worst relative error (percent) over the columns that see the wall,
    and the error at the principal-point column (where the thesis states its 1 % at 2 m
    requirement, section 4.1.5 and docs/thesis-notes.md N5)."""
    fr = scan_frame(truth.plane)
    y = np.linspace(-4 * distance_m, 4 * distance_m, samples)
    scan_pts = np.stack([np.full_like(y, distance_m), y, np.zeros_like(y)], axis=-1)
    cam_pts = scan_pts @ fr.rotation + fr.origin
    px = project_points(cam_pts, truth.camera)
    inside = np.all(np.isfinite(px), axis=1) & (px[:, 0] >= 0) & (px[:, 0] <= truth.width - 1) & (px[:, 1] >= 0) & (px[:, 1] <= truth.height - 1)
    # the true model must itself map these pixels back (inside its invertible region)
    back = undistort_robust(px[inside], truth.camera)
    px = px[inside][back.valid]
    true_range = to_scan_plane(cam_pts[inside][back.valid], fr)[1]
    if len(px) < 2:
        raise ValueError(f"a wall at {distance_m} m is not visible to the true sensor")
    un = undistort_robust(px, estimate.camera)
    tri = intersect_plane(un.xy, estimate.plane)
    est_range = to_scan_plane(tri.points, scan_frame(estimate.plane))[1]
    ok = un.valid & (tri.status == RangeStatus.OK)
    if not ok.all():
        return {"max_pct": float("nan"), "rms_pct": float("nan"), "centre_pct": float("nan"), "columns": int(len(px))}
    rel = 100 * (est_range - true_range) / true_range
    centre = int(np.argmin(np.abs(px[:, 0] - truth.camera.intrinsics.cx)))
    return {"max_pct": float(np.max(np.abs(rel))), "rms_pct": float(np.sqrt(np.mean(rel**2))),
            "centre_pct": float(abs(rel[centre])), "columns": int(len(px))}


def compare(truth: SensorConfig, estimate: SensorConfig) -> dict[str, float]:
    """True-vs-estimated figures of ``laserpi calibrate --simulate``."""
    kt, ke = truth.camera.intrinsics, estimate.camera.intrinsics
    nt, ne = np.asarray(truth.plane.normal), np.asarray(estimate.plane.normal)
    wall = wall_range_error(truth, estimate)
    return {
        "fx_err_pct": 100 * (ke.fx - kt.fx) / kt.fx,
        "fy_err_pct": 100 * (ke.fy - kt.fy) / kt.fy,
        "cx_err_px": ke.cx - kt.cx,
        "cy_err_px": ke.cy - kt.cy,
        "plane_normal_err_deg": math.degrees(math.acos(min(1.0, abs(float(nt @ ne))))),
        "plane_offset_err_mm": 1000 * (estimate.plane.distance - truth.plane.distance),
        # headline: RMS over the whole scan; the worst column (frame corners, where the lens model
        # is extrapolated beyond the board corners) and the principal-point column beside it
        "range_err_pct_at_2m": wall["rms_pct"],
        "range_err_max_pct_at_2m": wall["max_pct"],
        "range_err_centre_pct_at_2m": wall["centre_pct"],
    }
