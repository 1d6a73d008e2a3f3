"""Post-calibration fit (thesis 6.3): order by cross-validation, well conditioned, clear errors."""

import numpy as np
import pytest

from device.calibration.intrinsics import CalibrationError
from device.calibration.postcal import fit_postcal, terms_for
from device.vision.postcal import correction, from_thesis_mm


def _sweep(err_fn, noise_m=0.002, seed=0):
    rng = np.random.default_rng(seed)
    walls = np.arange(0.3, 3.01, 0.1)
    x = np.concatenate([np.linspace(-1.2 * d, 1.2 * d, 60) for d in walls])
    zt = np.concatenate([np.full(60, d) for d in walls])
    groups = np.concatenate([np.full(60, i) for i in range(len(walls))])
    z = zt.copy()
    for _ in range(60):  # the correction is a function of the measured z: solve z = zt + err(x, z)
        z = zt + err_fn(x, z)
    z = z + rng.normal(0, noise_m, len(zt))
    return x, z, zt, groups


def test_thesis_terms_are_the_2_4_family():
    assert set(terms_for(2, 4)) == {(0, 0), (1, 0), (0, 1), (2, 0), (1, 1), (0, 2), (2, 1), (1, 2), (0, 3), (2, 2), (1, 3), (0, 4)}


def test_recovers_the_thesis_correction_from_a_noisy_sweep():
    thesis = from_thesis_mm()
    x, z, zt, g = _sweep(lambda x, zt: correction(thesis, x, zt))
    fit = fit_postcal(x, z, zt, g)
    assert fit.post is not None and fit.z_order >= 2
    assert fit.rms_before_m > 0.005
    assert fit.rms_after_m < 0.0025  # down to the 2 mm noise
    assert fit.cv_rmse_m[f"{fit.x_order},{fit.z_order}"] < fit.cv_rmse_m["none"]


def test_a_linear_error_picks_a_low_order():
    x, z, zt, g = _sweep(lambda x, zt: 0.01 + 0.02 * (zt - 1.5), noise_m=0.001)
    fit = fit_postcal(x, z, zt, g)
    assert fit.z_order <= 2 and fit.x_order == 0
    assert fit.rms_after_m < 0.0012


def test_no_error_gives_no_correction():
    x, z, zt, g = _sweep(lambda x, zt: 0.0 * x, noise_m=0.001)
    fit = fit_postcal(x, z, zt, g)
    assert fit.post is None or fit.rms_after_m <= fit.rms_before_m


def test_too_few_walls_is_a_clear_error():
    x, z, zt, g = _sweep(lambda x, zt: 0.0 * x)
    keep = g < 2
    with pytest.raises(CalibrationError, match="3 or more distances"):
        fit_postcal(x[keep], z[keep], zt[keep], g[keep])
