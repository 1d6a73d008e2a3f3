"""Per-column geometry (ROI, ray table) and the post-calibration of eq. 6.5 (docs/thesis-notes.md N8)."""

import dataclasses

import numpy as np
import pytest

from device.config import PostCalibration, RangeLimits, load_preset
from device.model.camera import undistort_robust
from device.model.triangulation import RangeStatus, intersect_plane
from device.vision import postcal
from device.vision.geometry import column_geometry

CFG = dataclasses.replace(load_preset("thesis-calibrated"), range=RangeLimits(0.1, 4.0))


def test_table_triangulation_matches_direct_backward_projection():
    g = column_geometry(CFG)
    rng = np.random.default_rng(0)
    rows = rng.uniform(g.top, g.bottom - 1, CFG.width)
    tab = g.triangulate(rows)
    direct = intersect_plane(undistort_robust(np.stack([np.arange(CFG.width, dtype=float), rows], -1), CFG.camera).xy,
                             CFG.plane, 0.1, 4.0)
    ok = (tab.status == RangeStatus.OK) & (direct.status == RangeStatus.OK)
    assert ok.sum() > 500
    np.testing.assert_array_equal(tab.status, direct.status)
    rel = np.abs(tab.depth[ok] - direct.depth[ok]) / direct.depth[ok]
    assert rel.max() < 5e-5  # bound of the linear ray interpolation (0.2 mm at 4 m)
    iz, _ = g.inverse_depth(rows)
    np.testing.assert_allclose(1 / iz[ok], direct.depth[ok], rtol=5e-5)


def test_table_triangulation_is_intersect_plane_on_the_interpolated_ray():
    # the table path writes the ray/plane intersection out; it must give intersect_plane's bits
    # and statuses, also for NaN rows, rows off the table, and depths beyond the limits
    g = column_geometry(CFG, 0.5, 3.0)
    rng = np.random.default_rng(1)
    rows = rng.uniform(g.top - 20, g.bottom + 20, CFG.width)
    rows[rng.random(CFG.width) < 0.1] = np.nan
    tab = g.triangulate(rows)
    n = g.bottom - g.top
    r = rows - g.top
    inside = np.isfinite(r) & (r >= 0) & (r <= n - 1)
    r = np.where(inside, r, 0.0)
    r0 = np.minimum(np.floor(r).astype(int), n - 2)
    t, cols = r - r0, np.arange(CFG.width)
    x = g.xn[r0, cols] * (1 - t) + g.xn[r0 + 1, cols] * t
    y = g.yn[r0, cols] * (1 - t) + g.yn[r0 + 1, cols] * t
    want = intersect_plane(np.stack([np.where(inside, x, np.nan), np.where(inside, y, np.nan)], -1), CFG.plane, 0.5, 3.0)
    assert {int(s) for s in np.unique(tab.status)} >= {RangeStatus.OK, RangeStatus.INVALID_PIXEL, RangeStatus.TOO_CLOSE,
                                                     RangeStatus.TOO_FAR}
    np.testing.assert_array_equal(tab.status, want.status)
    np.testing.assert_array_equal(tab.depth, want.depth)
    np.testing.assert_array_equal(tab.points, want.points)


def test_roi_holds_exactly_the_rows_of_the_range_limits():
    g = column_geometry(CFG, 0.5, 3.0, margin=0)
    for c in (0, 400, 832, 1300, CFG.width - 1):
        rows = np.arange(CFG.height, dtype=float)
        depth = intersect_plane(undistort_robust(np.stack([np.full(CFG.height, float(c)), rows], -1), CFG.camera).xy,
                                CFG.plane).depth
        inside = (depth >= 0.5) & (depth <= 3.0)
        assert np.nonzero(inside)[0].min() == g.roi_lo[c]
        assert np.nonzero(inside)[0].max() + 1 == g.roi_hi[c]
    assert g.near_below  # camera above the plane: nearer is lower in the image


def test_bad_range_limits_are_refused():
    with pytest.raises(ValueError, match="min_m < max_m"):
        column_geometry(CFG, 3.0, 1.0)
    with pytest.raises(ValueError, match="min_m < max_m"):
        column_geometry(CFG, -1.0, 2.0)


def test_thesis_table_converter_gives_the_same_correction():
    post = postcal.from_thesis_mm()
    rng = np.random.default_rng(1)
    x = rng.uniform(-2.0, 2.0, 500)
    z = rng.uniform(0.1, 3.0, 500)
    X, Z = x * 1000, z * 1000  # eq. 6.5 in millimetres, evaluated directly
    raw_mm = sum(p * X**i * Z**j for (i, j), p in postcal.THESIS_TABLE_6_1.items())
    np.testing.assert_allclose(postcal.correction(post, x, z), raw_mm / 1000, rtol=1e-9, atol=1e-12)
    # scaled coordinates stay O(1): no coefficient times monomial near 1e14 as in mm
    assert max(abs(c) for c in post.coefficients) < 1.0
    assert post.z_offset_m == 1.5 and post.z_scale_m == 1.5


def test_apply_moves_points_along_their_ray():
    post = PostCalibration(((0, 0), (0, 1)), (0.01, 0.02), 1.0, 0.0, 1.0)  # z' = z - (0.01 + 0.02 z)
    pts = np.array([[0.5, -0.1, 2.0], [np.nan, np.nan, np.nan]])
    out = postcal.apply(post, pts)
    assert out[0, 2] == pytest.approx(2.0 - 0.05)
    np.testing.assert_allclose(out[0] / out[0, 2], pts[0] / pts[0, 2])
    assert np.all(np.isnan(out[1]))
    np.testing.assert_array_equal(postcal.apply(None, pts[:1]), pts[:1])


def test_fit_recovers_a_polynomial_in_scaled_coordinates():
    rng = np.random.default_rng(2)
    x = rng.uniform(-2, 2, 2000)
    z = rng.uniform(0.2, 3.0, 2000)
    truth = postcal.from_thesis_mm()
    z_true = z - postcal.correction(truth, x, z)  # measured z, and the truth the model says
    fitted = postcal.fit(x, z, z_true, truth.terms)
    np.testing.assert_allclose(postcal.correction(fitted, x, z), postcal.correction(truth, x, z), atol=1e-9)
    z_corr = postcal.apply(fitted, np.stack([x, np.zeros_like(x), z], -1))[:, 2]
    np.testing.assert_allclose(z_corr, z_true, atol=1e-9)
    with pytest.raises(ValueError, match="finite samples"):
        postcal.fit(x[:3], z[:3], z_true[:3], truth.terms)
