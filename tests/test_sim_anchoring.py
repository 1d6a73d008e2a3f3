"""The simulator against the thesis's measurements (section 6.4), through the thesis's own pipeline.

At the thesis geometry (thesis-calibrated preset, 25 mW, 17.4 ms pulse, 40 ms exposure, lit and
unlit frames), device.vision.reference on simulated frames must reproduce what the prototype
measured: ~1.8 % range error at 2 m and ~2.4 % at 2.5 m on the 90 % wall indoors (Table 6.3,
6.4.3), no output in sunlight (6.4.1), and the 10 % wall's field of view shrinking at long range
(Figure 6.7). A simulator easier than reality would fail the first two bands from below.
"""

import numpy as np
import pytest

from device.config import load_preset
from device.sim.render import FrameTiming, RenderOptions, SceneRenderer
from device.sim.scene import wall_scene
from device.vision.reference import ReferencePipeline

CFG = load_preset("thesis-calibrated")
T, E_US, LINE_NS = 10**9, 40000.0, 18904.0
CENTRE = int(T + (921 * LINE_NS - E_US * 1e3) / 2)
LIT = FrameTiming(T, E_US, LINE_NS, ((CENTRE - 8_700_000, CENTRE + 8_700_000),))  # 17.4 ms, all rows open
DARK = FrameTiming(T, E_US, LINE_NS)
OPTIONS = RenderOptions(ray_samples=8192, background_step=4)  # photometry unchanged, cheaper setup


def measure(reflectivity, distance, ambient="indoor", pairs=2):
    """(relative range errors of the valid columns of the last pair, number of valid columns)."""
    r = SceneRenderer(CFG, wall_scene(distance, 0.0, reflectivity, ambient=ambient), options=OPTIONS, seed=7)
    pipe = ReferencePipeline(CFG)
    rng = np.random.default_rng(7)
    for _ in range(pairs):  # the thesis's running blend (step 4) sees consecutive pairs
        lit, truth = r.render(LIT, rng)
        unlit, _ = r.render(DARK, rng)
        m = pipe.process(lit, unlit)
    true = truth.range_m[m.column]
    ok = m.valid & np.isfinite(true)
    return (m.range[ok] - true[ok]) / true[ok], int(ok.sum())


@pytest.mark.slow
def test_90_percent_wall_indoors_matches_the_thesis_error():
    e2, n2 = measure(0.9, 2.0)
    e25, n25 = measure(0.9, 2.5)
    assert n2 > 450 and n25 > 450  # nearly the whole 105-110 deg field of view
    assert 1.4 < 100 * e2.std() < 2.3  # thesis: ~1.8 % at 2 m
    assert 1.9 < 100 * e25.std() < 2.9  # thesis: ~2.4 % at 2.5 m
    assert e25.std() > e2.std()
    assert abs(e2.mean()) < 0.005  # no bias: the truth and the pipeline share the camera model


@pytest.mark.slow
def test_no_output_in_sunlight_and_the_dark_wall_field_of_view_shrinks():
    _, n_sun = measure(0.9, 1.5, ambient="sunlight", pairs=1)
    assert n_sun == 0  # thesis 6.4.1: no sensible output outdoors
    _, bright = measure(0.9, 1.5, pairs=1)
    _, dark_near = measure(0.1, 1.5, pairs=1)
    _, dark_far = measure(0.1, 3.0, pairs=1)
    assert dark_near > 0.9 * bright  # the 10 % wall is still seen across the view at 1.5 m
    assert dark_far < 0.7 * dark_near  # and loses its edges beyond ~2.5 m
