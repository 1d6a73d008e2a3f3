"""Triangulation models and plane conversions (thesis 3.2, D.1-D.2), including hard cases."""

import math
import warnings

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from device.model.triangulation import (
    DegeneratePlaneError, LaserPlane, PlaneConditioningWarning, RangeStatus, TriangulationParams,
    check_conditioning, ideal_depth, ideal_range, intersect_plane, params_from_plane, plane_from_params,
    spot_range,
)

DESIGN = TriangulationParams(alpha=math.radians(58.9), beta=math.radians(90), psi=math.radians(90), s=0.055)
CALIBRATED = LaserPlane.from_abc(0.03099, -1.62720, 0.09405262)


def test_design_plane_matches_thesis_ideal_plane():
    a, b, c = plane_from_params(DESIGN)
    # section 4.2.2 quotes the ideal plane as (0, 1.6, 106.5 mm); b is negative in the OpenCV frame
    assert a == pytest.approx(0.0, abs=1e-12)
    assert b == pytest.approx(-1.0 / math.tan(math.radians(31.1)))
    assert abs(b) == pytest.approx(1.6, abs=0.06)
    assert c * 1000 == pytest.approx(106.5, abs=0.05)


def test_plane_model_equals_ideal_model_including_roll():
    rng = np.random.default_rng(3)
    xy = rng.uniform([-1.0, -0.5], [1.0, 0.6], (2000, 2))
    for psi_deg in (90.0, 87.0, 93.5):
        p = TriangulationParams(DESIGN.alpha, DESIGN.beta, math.radians(psi_deg), DESIGN.s)
        tri = intersect_plane(xy, LaserPlane.from_abc(*plane_from_params(p)))
        z_ideal = ideal_depth(xy, p)
        ok = tri.status == RangeStatus.OK
        assert ok.sum() > 1000
        np.testing.assert_allclose(tri.depth[ok], z_ideal[ok], rtol=1e-12)
        assert np.all(np.isnan(z_ideal[~ok]))


@settings(max_examples=200, deadline=None)
@given(st.floats(40, 85), st.floats(60, 120), st.floats(70, 110), st.floats(0.01, 0.2))
def test_params_plane_roundtrip(alpha_deg, beta_deg, psi_deg, s):
    p = TriangulationParams(math.radians(alpha_deg), math.radians(beta_deg), math.radians(psi_deg), s)
    if not 0.05 < p.theta < math.pi / 2:  # b < 0 branch, laser axis crossing in front
        return
    back = params_from_plane(*plane_from_params(p), beta=p.beta)
    for f in ("alpha", "beta", "psi", "s"):
        assert getattr(back, f) == pytest.approx(getattr(p, f), rel=1e-9, abs=1e-12)


def test_spot_laser_special_case_D43():
    # a spot laser ignores x_n and psi (D.41): the line model at x_n = 0 must equal D.43
    y = np.linspace(-0.5, 0.5, 101)
    q_line = ideal_range(np.stack([np.zeros_like(y), y], -1), DESIGN)
    np.testing.assert_allclose(q_line, spot_range(y, DESIGN), rtol=1e-12)


def test_konolige_special_case_D60():
    # alpha = 90 deg, beta = 90 deg: theta = 0 ... the Konolige geometry has the laser parallel to
    # the optical axis; D.56-D.60 give q = s f / x_p with x_p the pixel offset from the ray parallel
    # to the laser. Take beta slightly off 90 so theta > 0, and compare D.47 with D.56.
    s, f = 0.05, 600.0
    p = TriangulationParams(alpha=math.radians(90), beta=math.radians(80), psi=math.radians(90), s=s)
    y_n = np.linspace(0.0, 0.4, 50)
    q = spot_range(y_n, p)  # D.47 at alpha = 90 deg
    r = y_n * f
    x_p = f * math.tan(p.theta) + r  # D.55: pixel offset from the ray parallel to the laser
    np.testing.assert_allclose(q, s * f * math.sin(p.beta) / (x_p * math.cos(p.theta)), rtol=1e-12)


def test_horizon_and_limits_never_return_a_distance():
    horizon_y = -1.0 / 1.6272 - 0.03099 * 0.0  # denominator 1 - b y_n = 0 at x_n = 0
    xy = np.array([[0.0, horizon_y], [0.0, horizon_y - 0.1], [0.0, horizon_y + 1e-13], [np.nan, 0.0], [0.0, 0.5], [0.0, -0.6], [0.0, 5.0]])
    tri = intersect_plane(xy, CALIBRATED, min_depth=0.02, max_depth=1.0)
    assert list(tri.status[:4]) == [RangeStatus.BEYOND_HORIZON] * 3 + [RangeStatus.INVALID_PIXEL]
    assert list(tri.status[4:]) == [RangeStatus.OK, RangeStatus.TOO_FAR, RangeStatus.TOO_CLOSE]
    assert np.isnan(tri.depth[[0, 1, 2, 3, 5, 6]]).all() and np.isnan(tri.points[[0, 1, 2, 3, 5, 6]]).all()
    # a point just inside the horizon is far but finite and on the plane
    near = intersect_plane(np.array([[0.0, horizon_y + 1e-6]]), CALIBRATED)
    assert near.status[0] == RangeStatus.OK and near.depth[0] > 1e3
    n, d = np.array(CALIBRATED.normal), CALIBRATED.distance
    assert n @ near.points[0] == pytest.approx(d, rel=1e-9)


def test_degenerate_planes_raise_clear_errors():
    with pytest.raises(DegeneratePlaneError, match="positive"):
        LaserPlane.from_abc(0.0, -1.6, 0.0)
    with pytest.raises(DegeneratePlaneError, match="baseline"):
        LaserPlane((0.0, 1.0, 0.0), 0.0)
    with pytest.raises(DegeneratePlaneError, match="b_c = 0"):
        params_from_plane(0.0, 0.0, 0.1, math.pi / 2)
    with pytest.raises(DegeneratePlaneError, match="parallel"):
        LaserPlane((0.0, 1.0, 0.0), 0.05).to_abc()
    with pytest.raises(DegeneratePlaneError, match="theta"):
        plane_from_params(TriangulationParams(math.radians(100), math.radians(90), math.radians(90), 0.05))


@pytest.mark.parametrize("b, expect", [(-1e-4, "perpendicular"), (-1e4, "parallel"), (-1.6272, None)])
def test_conditioning_warnings_for_b_to_zero_and_infinity(b, expect):
    plane = LaserPlane.from_abc(0.0, b, 0.094 if abs(b) < 1e3 else 0.094 * abs(b))
    with warnings.catch_warnings(record=True) as w:
        warnings.simplefilter("always")
        reasons = check_conditioning(plane)
    if expect is None:
        assert reasons == [] and not w
    else:
        assert len(reasons) == 1 and expect in reasons[0]
        assert issubclass(w[0].category, PlaneConditioningWarning)


def test_plane_parallel_to_axis_triangulates_without_abc():
    # |b_c| -> inf: the Hessian form keeps working; y = 0.05 m below the axis
    plane = LaserPlane((0.0, 1.0, 0.0), 0.05)
    tri = intersect_plane(np.array([[0.0, 0.05], [0.1, 0.025], [0.0, 0.0], [0.0, -0.1]]), plane)
    np.testing.assert_allclose(tri.depth[:2], [1.0, 2.0])
    assert list(tri.status[2:]) == [RangeStatus.BEYOND_HORIZON] * 2


def test_shape_checked():
    with pytest.raises(ValueError, match=r"\(\.\.\., 2\)"):
        intersect_plane(np.zeros(3), CALIBRATED)
