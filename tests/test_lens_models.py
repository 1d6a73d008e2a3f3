"""The lens models' table (device.model.camera.LENS_MODELS): every row complete and consistent
with OpenCV, and a model that is not in the table an error everywhere, never another model."""

import dataclasses
import tomllib
from types import SimpleNamespace

import numpy as np
import pytest

from device.config import ConfigError, config_from_dict, dumps_config, load_preset, save_config
from device.model.camera import (
    LENS_MODELS, BrownConrady, CameraModel, Intrinsics, KannalaBrandt, LensModel, distort, lens_model,
    lens_model_named, project_normalized, project_points, undistort_fixed, undistort_robust,
)

K = Intrinsics(600.0, 590.0, 810.0, 420.0, 0.0, 1664, 928)
#: One lens of every model, each coefficient non-zero and different from the others, so that a
#: wrong OpenCV order shows up as a wrong projection.
SAMPLES = {
    "brown-conrady": BrownConrady(k1=-0.05, k2=0.012, k3=-0.002, p1=0.0011, p2=-0.0017),
    "kannala-brandt": KannalaBrandt(0.012, -0.004, 0.0008, -0.0001),
}
FUNCTIONS = ("distort", "project", "undistort_fixed", "undistort_robust", "beyond_fold", "newton_error",
             "opencv_project", "opencv_undistort")


@dataclasses.dataclass(frozen=True)
class Division:
    """A lens model that is not in the table."""

    k1: float = -0.1


UNKNOWN = CameraModel(K, Division())


def _rays(n: int, max_deg: float, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    az, inc = rng.uniform(0, 2 * np.pi, n), np.radians(rng.uniform(0, max_deg, n))
    return np.stack([np.sin(inc) * np.cos(az), np.sin(inc) * np.sin(az), np.cos(inc)], -1) * rng.uniform(0.5, 3, (n, 1))


def test_every_model_has_a_sample_here():
    assert set(SAMPLES) == set(LENS_MODELS)


@pytest.mark.parametrize("name", sorted(LENS_MODELS))
def test_a_row_is_complete(name):
    m = LENS_MODELS[name]
    assert m.name == name and lens_model_named(name) is m
    assert dataclasses.is_dataclass(m.distortion) and m.distortion.__dataclass_params__.frozen
    names = tuple(f.name for f in dataclasses.fields(m.distortion))
    assert m.coefficient_names == names and len(names) >= 1
    assert sorted(m.opencv_order) == sorted(names) and len(set(m.opencv_order)) == len(names)
    for fn in FUNCTIONS:
        assert callable(getattr(m, fn)), fn
    assert lens_model(m.distortion()) is m and isinstance(SAMPLES[name], m.distortion)
    assert {f.name for f in dataclasses.fields(LensModel)} - {"name", "distortion", "opencv_order"} == set(FUNCTIONS)


@pytest.mark.parametrize("name", sorted(LENS_MODELS))
def test_opencv_order_round_trips_and_matches_opencv_forward(name):
    m, dist = LENS_MODELS[name], SAMPLES[name]
    cam = CameraModel(K, dist)
    assert m.from_opencv(dist.opencv_coefficients()) == dist
    assert dist.opencv_coefficients().tolist() == [getattr(dist, n) for n in m.opencv_order]
    pts = _rays(500, 60, 1)
    ours = project_points(pts, cam)
    ref = m.opencv_project(pts, np.zeros(3), np.zeros(3), K.matrix, dist.opencv_coefficients())
    np.testing.assert_allclose(ours, ref, atol=1e-8)
    # the normalised-coordinate forward agrees with the 3-D one
    np.testing.assert_allclose(project_normalized(pts[:, :2] / pts[:, 2:], cam), ours, atol=1e-9)


@pytest.mark.parametrize("name", sorted(LENS_MODELS))
def test_backward_inverts_forward_and_matches_opencv_backward(name):
    import cv2

    m, dist = LENS_MODELS[name], SAMPLES[name]
    cam = CameraModel(K, dist)
    pts = _rays(500, 55, 2)
    pix = project_points(pts, cam)
    truth = pts[:, :2] / pts[:, 2:]
    for res in (undistort_robust(pix, cam), undistort_fixed(pix, cam, iterations=50, tol_px=1e-6)):
        assert res.valid.all()
        np.testing.assert_allclose(res.xy, truth, atol=1e-8)
    crit = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 200, 1e-15)
    np.testing.assert_allclose(m.opencv_undistort(pix, K.matrix, dist.opencv_coefficients(), crit), truth, atol=1e-8)


# ---------------------------------------------------------------- an unknown model is an error everywhere
@pytest.mark.parametrize("call", [
    lambda: lens_model(Division()),
    lambda: lens_model_named("division"),
    lambda: distort(np.zeros((3, 2)), Division()),
    lambda: project_points(np.ones((3, 3)), UNKNOWN),
    lambda: project_normalized(np.zeros((3, 2)), UNKNOWN),
    lambda: undistort_fixed(np.full((3, 2), 400.0), UNKNOWN),
    lambda: undistort_robust(np.full((3, 2), 400.0), UNKNOWN),
], ids=["lens_model", "lens_model_named", "distort", "project_points", "project_normalized", "undistort_fixed",
        "undistort_robust"])
def test_camera_functions_refuse_an_unknown_model(call):
    with pytest.raises(ValueError, match="lens model"):
        call()


def test_config_load_refuses_an_unknown_model():
    from device.config import PRESET_DIR

    doc = tomllib.loads((PRESET_DIR / "thesis-calibrated.toml").read_text())
    doc["camera"]["model"] = "division"
    with pytest.raises(ConfigError, match=r"\[camera\].*model must be one of 'brown-conrady', 'kannala-brandt'"):
        config_from_dict(doc, "sensor.toml")


def test_config_save_refuses_an_unknown_model(tmp_path):
    cfg = dataclasses.replace(load_preset("thesis-calibrated"), camera=UNKNOWN)
    with pytest.raises(ValueError, match="unknown lens model Division"):
        dumps_config(cfg)
    with pytest.raises(ValueError, match="unknown lens model Division"):
        save_config(cfg, tmp_path / "s.toml")
    assert not (tmp_path / "s.toml").exists()


def test_calibration_report_refuses_an_unknown_model():
    from device.calibration.report import report_dict

    result = SimpleNamespace(intrinsics=None, plane_fit=None, config=dataclasses.replace(load_preset("thesis-calibrated"), camera=UNKNOWN))
    with pytest.raises(ValueError, match="unknown lens model Division"):
        report_dict(result)


def test_calibration_refuses_an_unknown_model():
    from device.calibration.intrinsics import _fit, calibrate_intrinsics, refit
    from device.sim.checkerboard import BoardSpec

    obj = BoardSpec().object_points()
    corners = [np.zeros((len(obj), 2))] * 4
    with pytest.raises(ValueError, match="unknown lens model Division"):
        refit(corners, obj, (1664, 928), UNKNOWN, ("k1",))
    with pytest.raises(ValueError, match="no OpenCV calibration for lens model 'division'"):
        _fit([obj] * 4, corners, (1664, 928), "division", ("k1",))
    with pytest.raises(ValueError, match="model must be"):
        calibrate_intrinsics([SimpleNamespace(corners=c, name=str(i)) for i, c in enumerate(corners)], obj, (1664, 928), "division")


def test_bench_refuses_an_unknown_model():
    from device.bench.model import _opencv

    with pytest.raises(ValueError, match="unknown lens model Division"):
        _opencv(UNKNOWN, 5)
