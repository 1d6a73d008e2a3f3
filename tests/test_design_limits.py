"""Design tool (thesis 3.5, 4.1.3, docs/thesis-notes.md N5) against closed forms and 3-D ground truth."""

import math

import numpy as np
import pytest

from device.config import load_preset
from device.design import limits
from device.model.camera import BrownConrady, CameraModel, Intrinsics, project_points
from device.model.triangulation import LaserPlane, TriangulationParams, plane_from_params

FX = FY = 700.0
CX, CY = 800.0, 400.0
W, H = 1600, 800


def pinhole_geometry(alpha_deg=60.0, s=0.05, rows=H, cy=CY):
    cam = CameraModel(Intrinsics(FX, FY, CX, cy, width=W, height=rows), BrownConrady())
    p = TriangulationParams(math.radians(alpha_deg), math.pi / 2, math.pi / 2, s)
    return limits.RangeGeometry(cam, LaserPlane.from_abc(*plane_from_params(p)), p, W, rows)


def q_closed_form(y_n, alpha_deg, s):
    """Eq. D.43 with beta = 90 deg (principal column, x_n = 0): s (sin a - y cos a) / (sin t + y cos t)."""
    a = math.radians(alpha_deg)
    t = math.pi / 2 - a
    return s * (math.sin(a) - y_n * math.cos(a)) / (math.sin(t) + y_n * math.cos(t))


def row_closed_form(q, alpha_deg, s):
    a = math.radians(alpha_deg)
    t = math.pi / 2 - a
    return CY + FY * (s * math.sin(a) - q * math.sin(t)) / (q * math.cos(t) + s * math.cos(a))


def test_relative_resolution_by_hand():
    # |2.03 - 2| = 0.03, |1.98 - 2| = 0.02 -> 0.02 / 2 = 1 %
    assert limits.relative_resolution(2.0, 1.98, 2.03) == pytest.approx(0.01)
    # a neighbour beyond the horizon or invalid does not count
    assert limits.relative_resolution(2.0, np.inf, 2.05) == pytest.approx(0.025)
    assert limits.relative_resolution(2.0, 1.9, np.nan) == pytest.approx(0.05)
    assert np.isnan(limits.relative_resolution(2.0, np.inf, np.nan))
    assert np.isnan(limits.relative_resolution(np.nan, 1.0, 1.0))
    out = limits.relative_resolution(np.array([[1.0, 2.0]]), np.array([[1.1, 2.2]]), np.array([[0.95, 1.9]]))
    assert out.shape == (1, 2) and out == pytest.approx(np.array([[0.05, 0.05]]))


def test_row_and_resolution_against_the_closed_form():
    g = pinhole_geometry()
    for q in (0.5, 2.0, 3.5):
        v = limits.row_at_range(g, CX, q)
        assert v == pytest.approx(row_closed_form(q, 60.0, 0.05), abs=1e-6)
    table = limits.resolution_table(g, [0.1, 0.5], [2.0, 2.5])
    for i, sigma in enumerate((0.1, 0.5)):
        for j, q in enumerate((2.0, 2.5)):
            y = (row_closed_form(q, 60.0, 0.05) - CY) / FY
            dq = [abs(q_closed_form(y + d * sigma / FY, 60.0, 0.05) - q) for d in (-1, 1)]
            assert table[i, j] == pytest.approx(min(dq) / q, rel=1e-6)


def test_resolution_grows_with_distance_and_subpixel():
    g = pinhole_geometry()
    table = limits.resolution_table(g, [0.1, 0.2, 0.5], [1.0, 2.0, 3.0])
    assert np.all(np.diff(table, axis=0) > 0) and np.all(np.diff(table, axis=1) > 0)
    # first order: resolution proportional to sigma
    assert table[1] / table[0] == pytest.approx(np.full(3, 2.0), rel=0.01)


def test_distance_not_seen_gives_nan_row_and_table_entry():
    g = pinhole_geometry(alpha_deg=55.0)   # horizon above the image: q is bounded
    top = q_closed_form((0 - CY) / FY, 55.0, 0.05)
    assert math.isnan(limits.row_at_range(g, CX, 2 * top))
    assert np.isnan(limits.resolution_table(g, [0.2], [2 * top])).all()


def test_column_limits_bounded_and_unbounded():
    bounded = pinhole_geometry(alpha_deg=55.0)
    col = limits.column_limits(bounded, [CX])
    assert col.q_max[0] == pytest.approx(q_closed_form((0 - CY) / FY, 55.0, 0.05), rel=1e-9)
    assert col.q_min[0] == pytest.approx(q_closed_form((H - 1 - CY) / FY, 55.0, 0.05), rel=1e-9)
    # alpha 62: horizon at y_n = -tan(28 deg), row 400 - 372 = 28, inside the image
    open_ = pinhole_geometry(alpha_deg=62.0)
    horizon_row = CY - FY * math.tan(math.radians(28.0))
    assert 0 < horizon_row < H
    col = limits.column_limits(open_, [0.0, CX, W - 1])
    assert np.all(np.isposinf(col.q_max)) and np.all(np.isfinite(col.q_min))


def test_range_at_pixels_against_3d_ground_truth_with_distortion():
    """Points at known horizontal distance R from the line s, projected through the thesis's
    distorted design camera, come back as q = R (eq. 3.14 is the distance to the line s)."""
    cfg = load_preset("thesis-design")
    g = limits.geometry_from_config(cfg)
    a, s = g.params.alpha, g.params.s
    h = np.array([0.0, -math.cos(a), math.sin(a)])       # horizontal forward, camera frame (y down)
    d = np.array([0.0, math.sin(a), math.cos(a)])        # world down; the laser plane is X . d = s
    rng = np.random.default_rng(3)
    r = rng.uniform(0.1, 3.5, 200)
    az = rng.uniform(-0.8, 0.8, 200)
    pts = (r * np.sin(az))[:, None] * np.array([1.0, 0, 0]) + (r * np.cos(az))[:, None] * h + s * d
    pix = project_points(pts, cfg.camera)
    inside = (pix[:, 0] >= 0) & (pix[:, 0] < g.columns) & (pix[:, 1] >= 0) & (pix[:, 1] < g.rows)
    assert inside.sum() > 100
    q = limits.range_at_pixels(g, pix[inside])
    np.testing.assert_allclose(q, r[inside], rtol=1e-6)


def test_beyond_horizon_is_inf_never_a_number():
    g = pinhole_geometry(alpha_deg=62.0)
    q = limits.range_at_pixels(g, np.array([[CX, 0.0], [CX, H - 1.0]]))
    assert np.isposinf(q[0]) and np.isfinite(q[1])


def test_alpha_sweep_finds_the_thesis_tilt():
    """Figure 4.2 / 4.1.3 on the thesis's design camera: alpha = 58.9 deg in the thesis.

    The optimum is the kink where the top image row's distance meets the 1 % resolution limit,
    so it moves with the row convention and c_y; +/- 0.6 deg covers a couple of rows.
    """
    cfg = load_preset("thesis-design")
    cols = np.r_[np.linspace(0, cfg.active_width - 1, 7), cfg.camera.intrinsics.cx]
    sw = limits.alpha_sweep(cfg.camera, cfg.active_height, cols, np.radians(np.arange(50, 121, 2.0)))
    assert math.degrees(sw.best_alpha) == pytest.approx(58.9, abs=0.6)
    assert 40 < sw.best_usable < 55
    assert sw.q_high.shape == (36, 8) and np.nanmin(sw.q_low) >= 25 * (1 - 1e-9)
    # tilts >= 90 deg have no laser plane in front of the camera: never chosen, even where
    # their raw range is larger (120 deg reaches further than 58.9 deg here)
    assert not sw.feasible[np.degrees(sw.alphas) >= 90].any()
    assert sw.usable[-1] > sw.best_usable
    # s for 2 m follows from the linearity of q in s (thesis: 200 cm / q(s = 1) ~ 5 cm)
    assert limits.baseline_for_range(2.0, sw.best_usable) == pytest.approx(2.0 / sw.best_usable)


def test_alpha_sweep_limit_is_where_resolution_reaches_one_percent():
    g = pinhole_geometry(alpha_deg=60.0, s=1.0)
    sw = limits.alpha_sweep(g.camera, H, [CX], [math.radians(60.0)], refine=False)
    q_hi = sw.q_high[0, 0]
    v = limits.row_at_range(g, CX, q_hi)
    res = limits.resolution_at_pixels(g, np.array([CX, v]), 0.2)
    # the limit is interpolated between rows: within 0.5 % of the 1 % threshold
    assert v > 0 and float(res) == pytest.approx(0.01, rel=5e-3)


def test_bad_design_inputs():
    with pytest.raises(ValueError, match="no usable range"):
        limits.baseline_for_range(2.0, float("nan"))
    with pytest.raises(ValueError, match="sub-pixel"):
        limits.resolution_at_pixels(pinhole_geometry(), np.array([CX, 500.0]), 0.0)
    with pytest.raises(ValueError, match="1-D"):
        limits.resolution_table(pinhole_geometry(), [[0.1]], [2.0])


def test_resolution_table_cross_checked_with_opencv():
    """The calibrated preset's table recomputed independently: OpenCV's iterative undistortion,
    eq. 3.17 for z and eq. 3.14 for q with alpha = 90 deg - atan(1/|b_c|) (beta = 90 deg)."""
    import cv2

    cfg = load_preset("thesis-calibrated")
    g = limits.geometry_from_config(cfg)
    a, b, c = cfg.plane.to_abc()
    alpha = math.pi / 2 - math.atan(1 / abs(b))
    K = cfg.camera.intrinsics.matrix
    D = cfg.camera.distortion.opencv_coefficients()
    u = cfg.camera.intrinsics.cx

    crit = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 200, 1e-14)
    undistort = getattr(cv2, "undistortPointsIter", None)    # OpenCV 4; folded into undistortPoints in 5

    def q_cv(v):
        args = (np.array([[[u, v]]], dtype=np.float64), K, D, None, None)
        xy = (undistort(*args, crit) if undistort else cv2.undistortPoints(*args, None, crit))[0, 0]
        z = c / (1 - a * xy[0] - b * xy[1])
        return z * math.hypot(math.sin(alpha) - xy[1] * math.cos(alpha), xy[0])

    table = limits.resolution_table(g, [0.1, 0.5], [2.0, 3.5])
    for j, q in enumerate((2.0, 3.5)):
        lo, hi = 60.0, 400.0  # q_cv decreases with the row: bisect independently of limits.py
        while hi - lo > 1e-10:
            lo, hi = (lo, 0.5 * (lo + hi)) if q_cv(0.5 * (lo + hi)) < q else (0.5 * (lo + hi), hi)
        v = 0.5 * (lo + hi)
        assert limits.row_at_range(g, u, q) == pytest.approx(v, abs=1e-5)
        for i, sigma in enumerate((0.1, 0.5)):
            expected = min(abs(q_cv(v + sigma) - q), abs(q_cv(v - sigma) - q)) / q
            assert table[i, j] == pytest.approx(expected, rel=1e-5)


def test_plane_behind_the_baseline_is_not_folded_forward():
    """A short focal length sees the laser plane behind the line s (y_n > tan(alpha)); eq. 3.14's
    square root would report those points as small positive distances: they must be NaN."""
    cam = CameraModel(Intrinsics(200.0, 200.0, CX, CY, width=W, height=H), BrownConrady())
    p = TriangulationParams(math.radians(60.0), math.pi / 2, math.pi / 2, 0.05)
    g = limits.RangeGeometry(cam, LaserPlane.from_abc(*plane_from_params(p)), p, W, H)
    behind_row = CY + 200.0 * (math.tan(math.radians(60.0)) + 0.1)
    q = limits.range_at_pixels(g, np.array([[CX, behind_row], [CX, CY]]))
    assert np.isnan(q[0]) and q[1] == pytest.approx(0.05 / math.cos(math.radians(60.0)) * math.sin(math.radians(60.0)))
    col = limits.column_limits(g, [CX])
    assert 0 < col.q_min[0] < 0.01 and np.isposinf(col.q_max[0])
