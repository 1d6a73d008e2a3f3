import numpy as np
import pytest

from device.sim.sensor import IMX219_MODE5, SensorParams, sensor_frame


def test_noise_free_levels_follow_gain_and_black_level():
    p = SensorParams(analog_gain=2.0)
    e = np.array([[0.0, p.e_per_y * 10, p.e_per_y * 100, 1e9]])
    y = sensor_frame(e, None, p)
    assert y.dtype == np.uint8 and y.shape == (1, 4)
    assert y.tolist() == [[0, 10, 100, 255]]  # black maps to 0, saturation to 255


def test_saturation_at_full_well_even_with_high_digital_gain_off():
    p = SensorParams()
    y = sensor_frame(np.array([[p.full_well_e * 0.5, p.full_well_e * 3]]), None, p)
    assert abs(int(y[0, 0]) - 128) <= 1 and y[0, 1] == 255


def test_noise_statistics_match_shot_plus_read_noise():
    p = SensorParams(analog_gain=8.0, read_noise_e=4.0)
    mean_e = 50.0 * p.e_per_y  # well inside the range
    e = np.full((400, 400), mean_e)
    y = sensor_frame(e, np.random.default_rng(1), p).astype(float)
    expected_sigma_y = np.sqrt(mean_e + p.read_noise_e**2) / p.e_per_y
    assert abs(y.mean() - 50.0) < 0.1
    assert abs(y.std() / np.sqrt(expected_sigma_y**2 + 1 / 12) - 1) < 0.03


def test_deterministic_for_a_seed_and_normals_table_equivalent():
    e = np.full((20, 30), 2000.0)
    a = sensor_frame(e, np.random.default_rng(5))
    b = sensor_frame(e, np.random.default_rng(5))
    c = sensor_frame(e, None, normals=np.random.default_rng(5).standard_normal(e.shape, dtype=np.float32))
    assert np.array_equal(a, b) and np.array_equal(a, c)


@pytest.mark.parametrize("bad", [np.array([[-1.0]]), np.array([[np.nan]]), np.zeros((2, 2, 2))])
def test_bad_input_is_an_error(bad):
    with pytest.raises(ValueError):
        sensor_frame(bad, None, IMX219_MODE5)


def test_bad_params_name_the_field():
    with pytest.raises(ValueError, match="analog_gain"):
        SensorParams(analog_gain=20.0)
    with pytest.raises(ValueError, match="qe"):
        SensorParams(qe=0.0)


def test_erf_matches_math_erf():
    import math

    import numpy as np

    from device.sim.special import erf

    x = np.linspace(-6, 6, 2001)
    ref = np.array([math.erf(v) for v in x])
    assert np.max(np.abs(erf(x) - ref)) < 1.6e-7
    assert np.array_equal(erf(-x), -erf(x)) and np.all(np.diff(erf(x)) >= 0)
