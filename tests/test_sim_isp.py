"""The simulated ISP options (device/sim/isp.py, SensorParams.isp): LaserPi's linear full-range Y
by default, and the Raspberry Pi ISP's default transfer on request."""

import numpy as np
import pytest

from device.sim.isp import GAMMA_CURVE, isp_default_y
from device.sim.sensor import SensorParams, sensor_frame


def test_the_default_isp_is_limited_range_and_gamma_encoded():
    ramp = np.tile(np.linspace(0.0, 255.0, 256, dtype=np.float32), (8, 1))
    y = isp_default_y(ramp)
    assert y.dtype == np.uint8 and y.min() == 16 and y.max() == 235  # Rec709 limited range
    assert np.all(np.diff(y[4].astype(int)) >= 0)  # monotone on a smooth ramp
    # mid-grey linear 64/255 comes out at the tuning curve's value for 16448/65535, not 64
    expected = 16 + 219 * np.interp(64 * 65535 / 255, GAMMA_CURVE[:, 0], GAMMA_CURVE[:, 1]) / 65535
    assert abs(int(y[4, 64]) - expected) <= 1 and expected > 16 + 219 * 64 / 255 + 50


def test_the_default_isp_sharpens_an_edge_and_smooths_flat_noise():
    edge = np.full((32, 32), 40.0, np.float32)
    edge[:, 16:] = 160.0
    y = isp_default_y(edge).astype(int)
    flat_left, flat_right = y[16, 4], y[16, 28]
    assert y[16, 15] < flat_left and y[16, 16] > flat_right  # overshoot on both sides of the edge
    rng = np.random.default_rng(0)
    noisy = (100.0 + rng.normal(0, 1.0, (64, 64))).astype(np.float32)
    assert isp_default_y(noisy)[8:-8, 8:-8].std() < isp_default_y(np.full_like(noisy, 100.0)).std() + 1.0


def test_the_sensor_model_keeps_its_linear_default_and_takes_the_option():
    e = np.full((16, 16), 2000.0)
    linear = sensor_frame(e, None, SensorParams())
    default = sensor_frame(e, None, SensorParams(isp="default"))
    assert SensorParams().isp == "linear"
    assert linear.min() == linear.max() and default.min() == default.max()
    p = SensorParams()
    level = (np.rint(2000.0 / p.e_per_dn + p.black_level_dn) - p.black_level_dn) * 255 / (p.max_dn - p.black_level_dn)
    assert linear[0, 0] == round(level) == 28
    gamma = 16 + 219 * np.interp(level * 65535 / 255, GAMMA_CURVE[:, 0], GAMMA_CURVE[:, 1]) / 65535
    assert abs(int(default[0, 0]) - gamma) <= 1 and default[0, 0] > 90  # gamma lifts the dark end
    with pytest.raises(ValueError, match="isp must be"):
        SensorParams(isp="raw")
    with pytest.raises(ValueError, match=r"\(H, W\)"):
        isp_default_y(np.zeros(5, np.float32))
