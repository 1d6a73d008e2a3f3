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


def test_wall_sweep_frames_correct_a_miscalibrated_plane(tmp_path):
    """Walls rendered with the true sensor (4x the calibration exposure: the 1 mm sheet covers a
    fraction of a pixel at 2 m), measured with a plane 2 mm off: the
    fitted correction removes most of the error."""
    import cv2
    from dataclasses import replace

    from device.calibration.postcal import load_wall_sweep, wall_points
    from device.calibration.simulate import scaled_config
    from device.config import load_preset
    from device.model.triangulation import LaserPlane
    from device.sim.checkerboard import Scene, render_wall

    truth = scaled_config(load_preset("thesis-calibrated"), 0.5)
    wrong = replace(truth, plane=LaserPlane(truth.plane.normal, truth.plane.distance + 0.002))
    rng = np.random.default_rng(0)
    for d in (0.4, 0.6, 0.8, 1.0, 1.3, 1.6, 2.0):
        shot = render_wall(truth.camera, truth.width, truth.height, truth.plane, d, rng, Scene(black=0.8, white=0.8, ambient_e=6000.0, laser_e_at_1m=18000.0))
        cv2.imwrite(str(tmp_path / f"wall_{round(d * 1000)}mm_lit.png"), shot.lit)
        cv2.imwrite(str(tmp_path / f"wall_{round(d * 1000)}mm_unlit.png"), shot.unlit)
    x, z, zt, g = load_wall_sweep(tmp_path, wrong)
    assert len(np.unique(g)) == 7 and len(z) > 7 * 300
    # with the true configuration the measured depth is the wall's
    xt, z_ok, zt_ok = wall_points(cv2.imread(str(tmp_path / "wall_1000mm_lit.png"), 0), cv2.imread(str(tmp_path / "wall_1000mm_unlit.png"), 0), 1.0, truth)
    assert np.median(np.abs(z_ok - zt_ok) / zt_ok) < 0.003
    fit = fit_postcal(x, z, zt, g)
    assert fit.rms_before_m > 0.01  # 2 mm of baseline is ~4 % of range
    assert fit.rms_after_m < 0.3 * fit.rms_before_m
