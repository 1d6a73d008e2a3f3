"""Background irradiance, eq. 3.46 with docs/thesis-notes.md N9, against the thesis's section 4.1.4 figures."""

import math

import numpy as np
import pytest

from device.model import irradiance as ir

FAN = math.radians(120)
HEIGHT = 4e-3
P_LASER = 25e-3


def test_shipped_spectrum_is_the_g173_global_column():
    wl, e = ir.solar_spectrum()
    assert wl[0] == 600 and wl[-1] == 1100 and np.all(np.diff(wl) == 1)
    # spot values of ASTM G173-03 global tilt (W m^-2 nm^-1)
    assert e[wl == 808][0] == pytest.approx(1.0106, abs=0.2)
    assert np.all(e >= 0)


def test_band_integration_against_a_plain_sum():
    wl, e = ir.solar_spectrum()
    # on whole-nm band edges and a 1 nm grid, trapezoid = sum minus half the end samples
    m = (wl >= 783) & (wl <= 833)
    expected = e[m].sum() - 0.5 * (e[m][0] + e[m][-1])
    assert ir.band_irradiance_w_m2(808, 50) == pytest.approx(expected, rel=1e-12)
    # band edges between samples are interpolated: the integral is continuous in the width
    assert ir.band_irradiance_w_m2(808, 50.2) == pytest.approx(expected, rel=0.01)
    assert ir.band_irradiance_w_m2(808, 50.2) > expected


def test_thesis_background_for_808nm_50nm_filter():
    """Thesis 4.1.4: ~5.1 mW/cm^2. Quoted to two figures, so +/-0.1 mW/cm^2 (2 %)."""
    e = ir.band_irradiance_w_m2(808, 50)
    assert e / 10 == pytest.approx(5.1, abs=0.1)    # W/m^2 -> mW/cm^2


def test_thesis_detection_distance_at_one_percent():
    """Figure 4.4: the return drops below 1 % of the background beyond ~350 cm.

    Our 5.08 mW/cm^2 gives 355 cm; the thesis reads '~350' off a plot with its own (rounded)
    5.1 mW/cm^2, so 3 % covers the reading and the rounding.
    """
    e = ir.band_irradiance_w_m2(808, 50)
    x = ir.background_limited_distance_m(P_LASER, e, 0.01, FAN, HEIGHT)
    assert x == pytest.approx(3.50, rel=0.03)
    # by hand, docs/thesis-notes.md N9 units: 25 mW / (0.01 * E mW/cm^2 * 2 tan 60 * 0.4 cm) in cm
    assert x * 100 == pytest.approx(25 / (0.01 * (e / 10) * 2 * math.tan(math.radians(60)) * 0.4), rel=1e-12)


def test_thesis_fraction_at_one_metre():
    """Figure 4.4 caption: ~3.25 % at 100 cm.

    Eq. 3.46 makes pp * x constant, so the thesis's two readings (1 % at 350 cm -> 3.5 % at
    100 cm; and 3.25 %) disagree with each other by 7.7 %: no single background satisfies
    both. We match 3.25 % within 10 % and assert the exact 1/x law that the equation implies.
    """
    e = ir.band_irradiance_w_m2(808, 50)
    pp = ir.return_to_background(np.array([1.0, 3.5]), P_LASER, e, FAN, HEIGHT)
    assert pp[0] == pytest.approx(0.0325, rel=0.10)
    assert pp[0] * 1.0 == pytest.approx(pp[1] * 3.5, rel=1e-12)


def test_indoor_fraction_gives_the_thesis_five_percent():
    """4.1.4: indoors (20 % of outdoor) the return at the outdoor 1 % distance is ~5 %."""
    e = ir.band_irradiance_w_m2(808, 50)
    x1 = ir.background_limited_distance_m(P_LASER, e, 0.01, FAN, HEIGHT)
    pp = ir.return_to_background(x1, P_LASER, ir.INDOOR_FRACTION * e, FAN, HEIGHT)
    assert float(pp) == pytest.approx(0.05, rel=1e-12)


def test_return_ratio_is_the_inverse_of_the_distance():
    e = ir.band_irradiance_w_m2(808, 50)
    for pp in (0.01, 0.1, 1.0):
        x = ir.background_limited_distance_m(P_LASER, e, pp, FAN, HEIGHT)
        assert float(ir.return_to_background(x, P_LASER, e, FAN, HEIGHT)) == pytest.approx(pp, rel=1e-12)
    out = ir.return_to_background(np.array([[0.0, -1.0], [2.0, 4.0]]), P_LASER, e, FAN, HEIGHT)
    assert out.shape == (2, 2) and np.isnan(out[0]).all() and out[1, 0] == pytest.approx(2 * out[1, 1])


@pytest.mark.parametrize("call, match", [
    (lambda: ir.band_irradiance_w_m2(1090, 50), "leaves the shipped solar spectrum"),
    (lambda: ir.band_irradiance_w_m2(808, 0), "positive width"),
    (lambda: ir.background_limited_distance_m(P_LASER, 50.0, 0.0, FAN, HEIGHT), "fraction"),
    (lambda: ir.background_limited_distance_m(P_LASER, 50.0, 1.5, FAN, HEIGHT), "fraction"),
    (lambda: ir.background_limited_distance_m(P_LASER, 0.0, 0.01, FAN, HEIGHT), "positive"),
    (lambda: ir.background_limited_distance_m(P_LASER, 50.0, 0.01, math.pi, HEIGHT), "fan"),
])
def test_bad_inputs(call, match):
    with pytest.raises(ValueError, match=match):
        call()
