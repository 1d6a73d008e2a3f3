"""Laser plane from the laser line on calibrated checkerboards (thesis section 4.2.2), automatic.

The thesis picked the laser pixels by hand and nudged them for 15 iterations until the plane
fitted (Table 4.7; section 7.2.2 asks for automation). Here, per board:

1. the line is extracted from the lit and unlit frames, masked to the board's quadrilateral
   (projected with the calibrated camera and that view's pose), one sub-pixel peak per column
   (:func:`device.vision.peaks.column_peaks`, 3-point Gaussian estimator);
   the difference is divided by the unlit frame, which cancels the board's reflectance so a
   black/white edge inside the line profile cannot shift the peak;
2. each peak's ray (backward projection, :func:`undistort_robust`) is intersected with that
   board's plane (eq. 3.17 with the board as the plane): a 3-D sample of the laser plane.

The samples of all boards are fitted by total least squares inside RANSAC, then refined by
iteratively reweighted TLS in which each point is weighted by how far a one-pixel error of its
peak moves it off the plane (points on far or grazing boards count less) with a Cauchy loss.
Uncertainty: bootstrap over boards (a board's pose error is shared by all its points).
Degenerate sets raise :class:`~device.calibration.intrinsics.CalibrationError` naming what to
capture next.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass

import numpy as np

from ..model.camera import CameraModel, project_points, undistort_robust
from ..model.triangulation import LaserPlane
from ..vision.peaks import column_peaks
from .intrinsics import CalibrationError

log = logging.getLogger(__name__)

#: Fewest laser points and boards for a plane fit.
MIN_POINTS = 50
MIN_BOARDS = 3
#: s2/s1 of the point cloud below which the samples span a line, not a plane.
MIN_SPREAD_RATIO = 0.05
#: A fitted plane nearer the optical centre than this has no usable baseline (metres).
MIN_PLANE_DISTANCE_M = 0.005
#: Peak must exceed this many robust noise sigmas of the (lit - unlit) / unlit image.
PEAK_SNR = 6.0
#: Shortest run of neighbouring columns accepted as a piece of laser line (pixels).
MIN_RUN_PX = 15
#: Smallest unlit level used as the divisor (DN), so dark pixels do not blow up the ratio.
UNLIT_FLOOR_DN = 4.0


@dataclass(frozen=True)
class BoardLine:
    """Laser samples on one board: pixels (M, 2), camera-frame points (M, 3) and the metres that a
    one-pixel shift of each peak along its image column moves the point, (M, 3)."""

    name: str
    pixels: np.ndarray
    points: np.ndarray
    row_steps: np.ndarray


@dataclass
class PlaneFit:
    plane: LaserPlane
    inliers: np.ndarray  # (N,) bool
    residuals_m: np.ndarray  # (N,) signed point-to-plane distances, all points
    rms_m: float  # of the inliers
    normal_std_deg: float  # bootstrap over boards
    offset_std_m: float
    per_board_rms_m: dict[str, float]
    spread_ratio: float  # s2 / s1 of the inlier cloud


def board_mask(cam: CameraModel, rotation: np.ndarray, translation: np.ndarray, outline_board: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """(H, W) bool mask of a board's quadrilateral (``outline_board`` (4, 3) board-frame corners),
    projected with the lens model along densely sampled edges so distortion bends them right."""
    import cv2

    s = np.linspace(0.0, 1.0, 32, endpoint=False)[:, None]
    edges = np.concatenate([outline_board[i] + s * (outline_board[(i + 1) % 4] - outline_board[i]) for i in range(4)])
    px = project_points(edges @ rotation.T + translation, cam)
    mask = np.zeros(shape, np.uint8)
    if np.all(np.isfinite(px)):
        cv2.fillPoly(mask, [np.round(px).astype(np.int32)], 1)
    return mask.astype(bool)


def _mask_rows(mask: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per column, the [first, last + 1) rows of a convex mask (an empty interval where none)."""
    any_ = mask.any(axis=0)
    lo = np.where(any_, np.argmax(mask, axis=0), 0)
    hi = np.where(any_, mask.shape[0] - np.argmax(mask[::-1], axis=0), 0)
    return lo, hi


def _continuous(rows: np.ndarray, max_jump_px: float = 1.5, min_run: int = MIN_RUN_PX) -> np.ndarray:
    """Keep only runs of neighbouring columns whose peaks move smoothly (a laser line, not noise)."""
    keep = np.zeros(rows.shape, bool)
    cols = np.flatnonzero(np.isfinite(rows))
    if len(cols) == 0:
        return keep
    breaks = np.flatnonzero((np.diff(cols) > 2) | (np.abs(np.diff(rows[cols])) > max_jump_px)) + 1
    for run in np.split(cols, breaks):
        if len(run) >= min_run:
            keep[run] = True
    return keep


def extract_line(lit: np.ndarray, unlit: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """(M, 2) sub-pixel laser pixels (x = column, y = row) inside ``mask``; empty if no line.

    Detection uses (lit - unlit) / sqrt(unlit), whose noise is about level-independent for shot
    noise, against PEAK_SNR robust sigmas; the peak is located on (lit - unlit) / unlit, which
    cancels the board's reflectance (a checker edge inside the line profile would pull it).
    """
    if lit.shape != unlit.shape or lit.shape != mask.shape:
        raise ValueError(f"lit {lit.shape}, unlit {unlit.shape} and mask {mask.shape} must have one shape")
    import cv2

    # erode so that the board's own outline (which moves between frames only by noise) is not taken
    inner = cv2.erode(mask.astype(np.uint8), np.ones((5, 5), np.uint8)).astype(bool)
    if not inner.any():
        return np.empty((0, 2))
    lit_f, unlit_f = lit.astype(np.float64), unlit.astype(np.float64)
    diff = lit_f - unlit_f
    base = np.maximum(unlit_f, UNLIT_FLOOR_DN)
    snr = diff / np.sqrt(base)
    vals = snr[inner]
    noise = 1.4826 * np.median(np.abs(vals - np.median(vals))) + 1e-9
    lo, hi = _mask_rows(inner)
    peaks = column_peaks(diff / base, estimator="gaussian", row_lo=lo, row_hi=hi, min_peak=0.0)
    rows = peaks.row
    cols = np.arange(lit.shape[1])
    k = np.clip(peaks.argmax, 0, lit.shape[0] - 1)
    rows = np.where((peaks.argmax >= 0) & (snr[k, cols] > PEAK_SNR * noise), rows, np.nan)
    rows = np.where(_continuous(rows), rows, np.nan)
    cols = np.flatnonzero(np.isfinite(rows))
    return np.stack([cols.astype(np.float64), rows[cols]], axis=-1)


def line_points(name: str, pixels: np.ndarray, cam: CameraModel, rotation: np.ndarray, translation: np.ndarray) -> BoardLine:
    """Intersect the rays of laser ``pixels`` with the board plane (pose board -> camera)."""
    n = rotation[:, 2]
    d = float(n @ translation)

    def to_board(px):
        un = undistort_robust(px, cam)
        rays = np.concatenate([un.xy, np.ones((len(px), 1))], axis=-1)
        with np.errstate(invalid="ignore", divide="ignore"):
            return rays * (d / (rays @ n))[:, None]

    pts = to_board(pixels)
    step = to_board(pixels + np.array([0.0, 1.0])) - pts
    ok = np.all(np.isfinite(pts), axis=1) & np.all(np.isfinite(step), axis=1) & (pts[:, 2] > 0)
    return BoardLine(name, pixels[ok], pts[ok], step[ok])


# ---------------------------------------------------------------- fitting
def _weighted_tls(points: np.ndarray, w: np.ndarray) -> tuple[np.ndarray, float]:
    """Plane n . X = d minimising sum w (n . X - d)^2 with |n| = 1; d >= 0."""
    c = (w[:, None] * points).sum(0) / w.sum()
    x = (points - c) * np.sqrt(w)[:, None]
    n = np.linalg.svd(x, full_matrices=False)[2][-1]
    d = float(n @ c)
    return (n, d) if d >= 0 else (-n, -d)


def _check_spread(points: np.ndarray) -> float:
    """s2/s1 of the centred cloud; raises when the samples lie along a line."""
    s = np.linalg.svd(points - points.mean(0), compute_uv=False)
    ratio = float(s[1] / s[0]) if s[0] > 0 else 0.0
    if ratio < MIN_SPREAD_RATIO:
        z = points[:, 2]
        z_lo, z_hi = np.percentile(z, [5, 95])
        if (z_hi - z_lo) < 0.1 * np.median(z):
            raise CalibrationError(
                f"all boards crossing the laser are at one depth (laser points at z = {np.median(z):.2f} m, "
                f"spread {100 * (z_hi - z_lo):.1f} cm; singular-value ratio s2/s1 = {ratio:.3f} < {MIN_SPREAD_RATIO}): "
                "the points fix a line, not a plane. Capture boards crossing the laser line at several distances "
                "between 0.3 and 1.2 m"
            )
        raise CalibrationError(
            f"the laser points are nearly collinear (singular-value ratio s2/s1 = {ratio:.3f} < {MIN_SPREAD_RATIO}): "
            "they fix a line, not a plane. Capture boards crossing the laser at other distances and at the left "
            "and right of the image"
        )
    return ratio


def fit_laser_plane(lines: list[BoardLine], rng_seed: int = 0, ransac_iterations: int = 300, bootstrap: int = 200) -> PlaneFit:
    """Fit the laser plane to the samples of all boards; see the module docstring."""
    lines = [ln for ln in lines if len(ln.points)]
    n_pts = sum(len(ln.points) for ln in lines)
    if n_pts == 0:
        raise CalibrationError(
            "no laser line found on any board: check that the laser fires in the lit frames (lit minus unlit "
            "shows nothing) and capture boards that cross the laser line"
        )
    if n_pts < MIN_POINTS or len(lines) < MIN_BOARDS:
        raise CalibrationError(
            f"too few laser points: {n_pts} on {len(lines)} board(s); need at least {MIN_POINTS} points on "
            f"{MIN_BOARDS} boards. Capture more boards crossing the laser line at different distances"
        )
    pts = np.concatenate([ln.points for ln in lines])
    steps = np.concatenate([ln.row_steps for ln in lines])
    board = np.concatenate([np.full(len(ln.points), i) for i, ln in enumerate(lines)])
    _check_spread(pts)

    rng = np.random.default_rng(rng_seed)
    best, best_count = None, -1
    for _ in range(ransac_iterations):
        idx = rng.choice(n_pts, 3, replace=False)
        n = np.cross(pts[idx[1]] - pts[idx[0]], pts[idx[2]] - pts[idx[0]])
        if np.linalg.norm(n) < 1e-12:
            continue
        n /= np.linalg.norm(n)
        d = n @ pts[idx[0]]
        tol = 0.002 + np.abs(steps @ n)  # 2 mm plus one pixel of peak error
        count = int((np.abs(pts @ n - d) < tol).sum())
        if count > best_count:
            best, best_count = (n, d), count
    n, d = best
    inl = np.abs(pts @ n - d) < 0.002 + np.abs(steps @ n)
    n, d = _weighted_tls(pts[inl], np.ones(inl.sum()))
    for _ in range(10):  # IRLS: per-point sigma from the one-pixel step, Cauchy loss
        sigma = np.abs(steps @ n) + 1e-5
        r = (pts @ n - d) / sigma
        inl = np.abs(r) < 10.0 * max(np.median(np.abs(r)), 0.5)
        w = 1.0 / sigma**2 / (1.0 + (r / (2.385 * max(np.median(np.abs(r)), 0.1))) ** 2)
        n_new, d_new = _weighted_tls(pts[inl], w[inl])
        done = np.linalg.norm(n_new - n) < 1e-10 and abs(d_new - d) < 1e-10
        n, d = n_new, d_new
        if done:
            break
    ratio = _check_spread(pts[inl])
    if d < MIN_PLANE_DISTANCE_M:
        raise CalibrationError(
            f"the fitted laser plane passes {1000 * d:.1f} mm from the camera's optical centre (< {1000 * MIN_PLANE_DISTANCE_M:.0f} mm): "
            "a plane through the centre images every range on one line, so it cannot triangulate. Check that the "
            "laser is mounted off the camera axis (baseline s) and that the lit frames show the laser"
        )
    plane = LaserPlane(tuple((n / np.linalg.norm(n)).tolist()), float(d))
    resid = pts @ np.asarray(plane.normal) - plane.distance

    # bootstrap over boards with the final weights
    normals, offsets = [], []
    nb = len(lines)
    for _ in range(bootstrap):
        pick = rng.integers(0, nb, nb)
        sel = np.concatenate([np.flatnonzero((board == b) & inl) for b in pick])
        if len(sel) < 3 or len(np.unique(board[sel])) < 2:
            continue
        try:
            nn, dd = _weighted_tls(pts[sel], w[sel])
        except np.linalg.LinAlgError:
            continue
        if nn @ n < 0:
            nn, dd = -nn, -dd
        normals.append(math.degrees(math.acos(min(1.0, abs(float(nn @ n))))))
        offsets.append(dd)
    per_board = {ln.name: float(np.sqrt(np.mean(resid[(board == i) & inl] ** 2))) if np.any((board == i) & inl) else float("nan") for i, ln in enumerate(lines)}
    return PlaneFit(
        plane, inl, resid, float(np.sqrt(np.mean(resid[inl] ** 2))),
        float(np.sqrt(np.mean(np.square(normals)))) if normals else float("nan"),
        float(np.std(offsets)) if offsets else float("nan"), per_board, ratio,
    )
