"""The simulator against the thesis's measurements (section 6.4), through the thesis's own pipeline.

At the thesis geometry (thesis-calibrated preset, 25 mW, 17.4 ms pulse, 40 ms exposure, lit and
unlit frames), device.vision.reference on simulated frames must reproduce what the prototype
measured: ~1.8 % range error at 2 m and ~2.4 % at 2.5 m on the 90 % wall indoors (Table 6.3,
6.4.3), no output in sunlight (6.4.1), and the 10 % wall's field of view shrinking at long range
(Figure 6.7).

Two explanations of the thesis's error are checked (device/sim/render.py, "Anchoring"): the
defaults (lens in focus) plus the thesis prototype's calibration residual
(device.sim.anchoring, fitted at 2 m, so 2.5 m is a prediction), and COHERENT_DEFOCUSED alone.
The image's share alone must stay below the thesis's figure (a residual cannot be negative) and
must not be trivially small (the speckle floor of Dorsch et al.).
"""

from dataclasses import replace

import numpy as np
import pytest

from device.bench.sim import measure_wall
from device.sim.anchoring import relative_range_per_row, with_thesis_residual
from device.sim.render import COHERENT_DEFOCUSED, RenderOptions

# photometry unchanged, cheaper setup
OPTIONS = {"focused": RenderOptions(ray_samples=8192, background_step=4),
           "defocused": replace(COHERENT_DEFOCUSED, ray_samples=8192, background_step=4)}


def measure(reflectivity, distance, ambient="indoor", pairs=2, model="focused"):
    return measure_wall(reflectivity, distance, ambient, pairs=pairs, seed=7, options=OPTIONS[model])


@pytest.mark.slow
def test_focused_defaults_plus_the_thesis_calibration_residual_match_the_thesis_error():
    e2, n2, s2 = measure(0.9, 2.0)
    e25, n25, s25 = measure(0.9, 2.5)
    assert n2 > 750 and n25 > 750  # nearly the whole field of view (820 columns processed)
    assert 0.6 < 100 * e2.std() < 1.5  # the image's share: under the thesis's 1.8 %, above the speckle floor
    assert 100 * e25.std() < 2.0
    assert 1.5 < 100 * with_thesis_residual(e2, s2) < 2.3  # thesis: ~1.8 % at 2 m (fitted here)
    assert 1.9 < 100 * with_thesis_residual(e25, s25) < 2.9  # thesis: ~2.4 % at 2.5 m (predicted)
    assert e25.std() > e2.std()
    assert abs(e2.mean()) < 0.005  # no bias: the truth and the pipeline share the camera model


@pytest.mark.slow
def test_the_defocused_lens_alone_matches_the_thesis_error():
    e2, n2, _ = measure(0.9, 2.0, model="defocused")
    e25, n25, _ = measure(0.9, 2.5, model="defocused")
    assert n2 > 750 and n25 > 750
    assert 1.5 < 100 * e2.std() < 2.3
    assert 1.9 < 100 * e25.std() < 2.9


@pytest.mark.slow
@pytest.mark.parametrize("model", sorted(OPTIONS))
def test_no_output_in_sunlight_and_the_dark_wall_field_of_view_shrinks(model):
    _, n_sun, _ = measure(0.9, 1.5, ambient="sunlight", pairs=1, model=model)
    assert n_sun == 0  # thesis 6.4.1: no sensible output outdoors
    _, bright, _ = measure(0.9, 1.5, pairs=1, model=model)
    _, dark_near, _ = measure(0.1, 1.5, pairs=1, model=model)
    _, dark_far, _ = measure(0.1, 3.0, pairs=1, model=model)
    assert dark_near > 0.85 * bright  # the 10 % wall is still seen across most of the view at 1.5 m
    assert dark_far < 0.7 * dark_near  # and loses its (farther, oblique) edges at long range


def test_the_residual_adds_in_quadrature_with_each_columns_sensitivity():
    rng = np.random.default_rng(0)
    e = rng.normal(0.0, 0.01, 5000)
    s = np.full(5000, 0.05)  # 5 % of range per row
    assert with_thesis_residual(e, s, 0.0) == pytest.approx(e.std())
    assert with_thesis_residual(e, s, 0.2) == pytest.approx(np.hypot(e.std(), 0.01))
    # a column twice as sensitive counts four times in the variance
    s2 = np.where(np.arange(5000) % 2 == 0, 0.05, 0.1)
    assert with_thesis_residual(np.zeros(5000), s2, 1.0) == pytest.approx(np.sqrt((0.05**2 + 0.1**2) / 2))


def test_the_residual_refuses_bad_input():
    with pytest.raises(ValueError, match="equal length"):
        with_thesis_residual(np.zeros(3), np.zeros(4))
    with pytest.raises(ValueError, match="finite"):
        with_thesis_residual(np.array([0.0, np.nan]), np.ones(2))
    with pytest.raises(ValueError, match="residual_px"):
        with_thesis_residual(np.zeros(3), np.ones(3), -0.1)
    with pytest.raises(ValueError, match="shapes differ"):
        relative_range_per_row(np.ones(3), np.ones(2))
    # a column beyond the horizon (1/z = 0) has no finite sensitivity, and says so with inf
    assert np.isinf(relative_range_per_row(np.array([0.0]), np.array([0.1]))[0])
