"""Scan frame (REP 103) and resampling onto the LaserScan angle grid."""

import math

import numpy as np
import pytest

from device.config import load_preset
from device.model.scan_frame import angle_order, resample_scan, scan_frame, to_scan_plane, uniform_angles
from device.model.triangulation import LaserPlane


def test_frame_axes_and_wall_distance():
    plane = load_preset("thesis-calibrated").plane
    f = scan_frame(plane)
    np.testing.assert_allclose(f.rotation @ f.rotation.T, np.eye(3), atol=1e-12)
    assert np.linalg.det(f.rotation) == pytest.approx(1.0)
    assert f.rotation[2] @ [0, -1, 0] > 0  # z up = towards the top of the image
    assert f.rotation[1] @ [-1, 0, 0] > 0.99  # y left = camera -x
    # points on the plane straight ahead at 2 m forward and 1 m to the left
    p = f.origin + 2.0 * f.rotation[0] + 1.0 * f.rotation[1]
    ang, rng = to_scan_plane(p[None], f)
    assert rng[0] == pytest.approx(math.hypot(2, 1)) and ang[0] == pytest.approx(math.atan2(1, 2))


def test_degenerate_frames():
    with pytest.raises(ValueError, match="perpendicular"):
        scan_frame(LaserPlane((0.0, 0.0, 1.0), 0.05))
    with pytest.raises(ValueError, match="vertical"):
        scan_frame(LaserPlane((1.0, 0.0, 0.0), 0.05))


def test_resample_interpolates_surfaces_but_not_across_jumps():
    grid = uniform_angles(-0.5, 0.5, 101)
    a = np.linspace(-0.5, 0.5, 300)
    r = np.where(a < 0, 1.0, 3.0)  # a depth jump at 0 rad
    out = resample_scan(a, r, grid, max_gap=0.02)
    assert np.all((np.abs(out - 1.0) < 1e-12) | (np.abs(out - 3.0) < 1e-12))  # no phantom ranges
    assert np.all(out[grid < -0.01] == 1.0) and np.all(out[grid > 0.01] == 3.0)


def test_resample_gaps_and_codes():
    grid = uniform_angles(-0.5, 0.5, 11)
    out = resample_scan(np.array([-0.5, -0.4, 0.2, 0.3]), np.array([2.0, 2.0, -np.inf, np.nan]), grid, max_gap=0.15)
    assert out[0] == 2.0 and out[1] == 2.0
    assert np.isposinf(out[5])  # nothing measured near 0 rad: no return
    assert np.isneginf(out[7]) and np.isnan(out[8])  # REP 117 codes kept in their cells


def test_codes_sharing_a_cell_the_first_that_says_more_than_no_return_wins():
    grid = np.linspace(-1.0, 1.0, 3)  # cells at -1, 0, 1
    a = np.array([0.01, -0.01, 0.02, 0.98, 1.01])
    r = np.array([np.inf, np.nan, -np.inf, -np.inf, np.nan])
    out = resample_scan(a, r, grid, max_gap=0.1)
    assert np.isposinf(out[0]) and np.isnan(out[1]) and np.isneginf(out[2])
    measured = resample_scan(np.array([0.0, 0.01]), np.array([2.0, np.nan]), grid, max_gap=0.1)
    assert measured[1] == 2.0, "a measured range in the cell wins over a code"


def test_angle_order_skips_non_finite_angles_and_keeps_equal_ones_in_column_order():
    angles = np.array([0.3, np.nan, 0.1, 0.2, 0.1, np.inf, -0.4, 0.2])
    assert angle_order(angles).tolist() == [6, 2, 4, 3, 7, 0]
    # many equal angles (an unstable sort reorders them): each angle's columns in column order
    many = np.round(np.random.default_rng(0).uniform(-0.5, 0.5, 200), 1)
    order = angle_order(many)
    assert np.all(np.diff(many[order]) >= 0)
    assert all(np.all(np.diff(order[many[order] == v]) > 0) for v in np.unique(many))
