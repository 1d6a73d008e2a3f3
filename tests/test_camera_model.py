"""Camera model: forward/backward projection against OpenCV and on hard cases (thesis 3.1)."""

import math

import cv2
import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from device.config import load_preset
from device.model.camera import (
    BrownConrady, CameraModel, Intrinsics, KannalaBrandt, UnprojectStatus, pixel_grid,
    project_normalized, project_points, undistort_fixed, undistort_robust, unproject,
)

THESIS = load_preset("thesis-calibrated").camera
# A strong wide-angle Brown-Conrady lens whose radial profile turns back (k1 < 0, k2 = k3 = 0):
# d r_d / d r = 1 + 3 k1 r^2 = 0 at r = 1/sqrt(-3 k1).
FOLDING = CameraModel(Intrinsics(500.0, 500.0, 832.0, 464.0, 0.0, 1664, 928), BrownConrady(k1=-0.25))
# A 170 deg fisheye (OpenCV cv2.fisheye model): f = 540 px puts the left/right edges near 86 deg
# and the corners past 90 deg, where no normalised coordinate exists.
FISHEYE_170 = CameraModel(Intrinsics(540.0, 540.0, 832.0, 464.0, 0.0, 1664, 928), KannalaBrandt(0.012, -0.004, 0.0008, -0.0001))


def _opencv_undistort(pix, cam):
    crit = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 200, 1e-15)
    fn = getattr(cv2, "undistortPointsIter", None)  # OpenCV 4 name; merged into undistortPoints in 5
    args = (pix.reshape(-1, 1, 2), cam.intrinsics.matrix, cam.distortion.opencv_coefficients(), None, None)
    out = fn(*args, crit) if fn else cv2.undistortPoints(*args, None, crit)
    return out.reshape(-1, 2)


def test_forward_matches_opencv_project_points():
    rng = np.random.default_rng(1)
    pts = rng.uniform([-1.2, -0.8, 0.5], [1.2, 0.8, 3.0], (500, 3))
    ours = project_points(pts, THESIS)
    ref, _ = cv2.projectPoints(pts, np.zeros(3), np.zeros(3), THESIS.intrinsics.matrix, THESIS.distortion.opencv_coefficients())
    np.testing.assert_allclose(ours, ref.reshape(-1, 2), atol=1e-9)


def test_fisheye_forward_matches_opencv():
    rng = np.random.default_rng(2)
    az = rng.uniform(0, 2 * np.pi, 400)
    inc = rng.uniform(0, np.radians(84), 400)
    pts = np.stack([np.sin(inc) * np.cos(az), np.sin(inc) * np.sin(az), np.cos(inc)], -1)
    ours = project_points(pts, FISHEYE_170)
    d = FISHEYE_170.distortion.opencv_coefficients()
    ref, _ = cv2.fisheye.projectPoints(pts.reshape(-1, 1, 3), np.zeros(3), np.zeros(3), FISHEYE_170.intrinsics.matrix, d)
    np.testing.assert_allclose(ours, ref.reshape(-1, 2), atol=1e-8)


def test_robust_backward_matches_opencv_iterative_on_full_grid():
    g = pixel_grid(1664, 928)[::16, ::16].reshape(-1, 2)
    res = undistort_robust(g, THESIS)
    assert res.valid.all()
    np.testing.assert_allclose(res.xy, _opencv_undistort(g, THESIS), atol=1e-9)
    assert res.residual_px.max() < 1e-6


def test_thesis_fixed_iterations_flag_their_own_error():
    g = pixel_grid(1664, 928)[::8, ::8].reshape(-1, 2)
    truth = undistort_robust(g, THESIS).xy
    for iters in (5, 20):
        res = undistort_fixed(g, THESIS, iterations=iters, tol_px=1e-4)
        err_px = np.hypot(*((project_normalized(np.nan_to_num(res.xy), THESIS) - g).T))
        # every point returned valid reprojects within the tolerance, and is close to the truth
        assert np.all(err_px[res.valid] <= 1e-4)
        assert np.all(np.abs(res.xy[res.valid] - truth[res.valid]) < 1e-5)
    # 5 iterations are not enough everywhere on this lens at 1e-4 px: some points are flagged
    assert not undistort_fixed(g, THESIS, iterations=5, tol_px=1e-4).valid.all()


def test_folding_profile_points_beyond_the_fold_are_never_valid():
    fold = FOLDING.distortion.radial_fold()
    assert fold == pytest.approx(1 / math.sqrt(0.75))
    # the distorted radius peaks at the fold; pixels farther out have no preimage at all
    r_max_d = fold * (1 - 0.25 * fold**2)
    g = pixel_grid(1664, 928).reshape(-1, 2)[::7]
    r_d = np.hypot(*((g - [832, 464]) / 500.0).T)
    for res in (undistort_robust(g, FOLDING), undistort_fixed(g, FOLDING, iterations=20), undistort_fixed(g, FOLDING, iterations=5)):
        assert not res.valid[r_d > r_max_d * (1 + 1e-9)].any()
        assert np.all(np.hypot(*res.xy[res.valid].T) < fold)
        assert np.all(res.residual_px[res.valid] <= 0.01)
        assert np.all(np.isnan(res.xy[~res.valid]))
    robust = undistort_robust(g, FOLDING)
    assert robust.valid[r_d < 0.97 * r_max_d].all()


def test_past_the_fold_opencv_returns_a_wrong_point_we_flag_it():
    # r_d = 0.77 lies just outside the largest distorted radius the lens can produce (0.7698):
    # no normalised point maps there. OpenCV's iterative undistortion still returns one.
    pix = np.array([[832 + 500 * 0.77, 464.0]])
    ref = _opencv_undistort(pix, FOLDING)
    assert np.hypot(*(project_normalized(ref, FOLDING) - pix)[0]) > 0.05
    for res in (undistort_robust(pix, FOLDING), undistort_fixed(pix, FOLDING, iterations=20)):
        assert not res.valid[0] and np.isnan(res.xy).all() and res.residual_px[0] > 0.05


def test_near_the_fold_fixed_iteration_stalls_robust_converges():
    pix = np.array([[832 + 500 * 0.765, 464.0]])
    fixed = undistort_fixed(pix, FOLDING, iterations=20)
    robust = undistort_robust(pix, FOLDING)
    assert not fixed.valid[0] and fixed.status[0] == UnprojectStatus.NOT_CONVERGED
    assert robust.valid[0] and robust.residual_px[0] < 1e-6


def test_fisheye_170_corners_are_flagged_or_exact():
    g = pixel_grid(1664, 928)
    corners = np.array([g[0, 0], g[0, -1], g[-1, 0], g[-1, -1], g[464, 0], g[0, 832]])
    res = undistort_robust(corners, FISHEYE_170)
    for ok, st_, xy, px in zip(res.valid, res.status, res.xy, corners):
        if ok:
            np.testing.assert_allclose(project_normalized(xy, FISHEYE_170), px, atol=1e-6)
        else:
            assert st_ in (UnprojectStatus.BEYOND_90_DEG, UnprojectStatus.BEYOND_FOLD)
            assert np.isnan(xy).all()
    # 170 deg lens: the horizontal edge at the centre row is inside 85 deg and must be valid
    assert res.valid[4]
    inc = math.degrees(math.atan(np.hypot(*res.xy[4])))
    assert 60 < inc < 90


def test_float32_input_gives_float64_accuracy():
    g = pixel_grid(1664, 928, dtype=np.float32)[::31, ::29].reshape(-1, 2)
    r32 = undistort_robust(g, THESIS)
    r64 = undistort_robust(g.astype(np.float64), THESIS)
    assert r32.xy.dtype == np.float64
    np.testing.assert_array_equal(r32.xy, r64.xy)


def test_non_finite_pixels_are_invalid_with_reason():
    res = undistort_robust(np.array([[np.nan, 3.0], [np.inf, 0.0], [10.0, 10.0]]), THESIS)
    assert list(res.valid) == [False, False, True]
    assert all(s != UnprojectStatus.OK for s in res.status[:2])


def test_shapes_checked():
    with pytest.raises(ValueError, match=r"\(\.\.\., 2\)"):
        undistort_robust(np.zeros((4, 3)), THESIS)
    with pytest.raises(ValueError, match="method"):
        unproject(np.zeros((1, 2)), THESIS, method="magic")
    with pytest.raises(ValueError, match="fx"):
        Intrinsics(-1.0, 1.0, 0.0, 0.0)


lenses = st.sampled_from([THESIS, FOLDING, FISHEYE_170])


@settings(max_examples=300, deadline=None)
@given(lenses, st.floats(-1.5, 1.5), st.floats(-1.5, 1.5))
def test_roundtrip_within_1e6_px_wherever_converged(cam, x, y):
    xy = np.array([[x, y]])
    pix = project_normalized(xy, cam)
    if not np.all(np.isfinite(pix)):
        return
    res = undistort_robust(pix, cam)
    if res.valid[0]:
        back = project_normalized(res.xy, cam)
        assert np.hypot(*(back - pix)[0]) <= 1e-6
        if isinstance(cam.distortion, BrownConrady) and np.hypot(x, y) < cam.distortion.radial_fold():
            np.testing.assert_allclose(res.xy[0], xy[0], atol=1e-7)
