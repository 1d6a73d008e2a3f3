"""The simulator against the thesis's measurements (section 6.4), through the thesis's own pipeline.

At the thesis geometry (thesis-calibrated preset, 25 mW, 17.4 ms pulse, 40 ms exposure, lit and
unlit frames), device.vision.reference on simulated frames must reproduce what the prototype
measured: ~1.8 % range error at 2 m and ~2.4 % at 2.5 m on the 90 % wall indoors (Table 6.3,
6.4.3), no output in sunlight (6.4.1), and the 10 % wall's field of view shrinking at long range
(Figure 6.7). A simulator easier than reality would fail the first two bands from below. Checked for both
anchored sets: the default (multiplicative speckle) and COHERENT_ANCHORED (coherent speckle with
the lens defocused); the coherent model in focus does not reach the thesis's error (~0.95 % at
2 m, BENCHMARKS.md "Simulator").
"""

import pytest

from device.bench.sim import measure_wall
from dataclasses import replace

from device.sim.render import COHERENT_ANCHORED, RenderOptions

# photometry unchanged, cheaper setup; the default (multiplicative speckle) and the coherent set
OPTIONS = {"multiplicative": RenderOptions(ray_samples=8192, background_step=4),
           "coherent": replace(COHERENT_ANCHORED, ray_samples=8192, background_step=4)}
MODELS = pytest.mark.parametrize("model", sorted(OPTIONS))


def measure(reflectivity, distance, ambient="indoor", pairs=2, model="multiplicative"):
    return measure_wall(reflectivity, distance, ambient, pairs=pairs, seed=7, options=OPTIONS[model])


@pytest.mark.slow
@MODELS
def test_90_percent_wall_indoors_matches_the_thesis_error(model):
    e2, n2 = measure(0.9, 2.0, model=model)
    e25, n25 = measure(0.9, 2.5, model=model)
    assert n2 > 750 and n25 > 750  # nearly the whole field of view (820 columns processed)
    assert 1.5 < 100 * e2.std() < 2.3  # thesis: ~1.8 % at 2 m
    assert 1.9 < 100 * e25.std() < 2.9  # thesis: ~2.4 % at 2.5 m
    assert e25.std() > e2.std()
    assert abs(e2.mean()) < 0.005  # no bias: the truth and the pipeline share the camera model


@pytest.mark.slow
@MODELS
def test_no_output_in_sunlight_and_the_dark_wall_field_of_view_shrinks(model):
    _, n_sun = measure(0.9, 1.5, ambient="sunlight", pairs=1, model=model)
    assert n_sun == 0  # thesis 6.4.1: no sensible output outdoors
    _, bright = measure(0.9, 1.5, pairs=1, model=model)
    _, dark_near = measure(0.1, 1.5, pairs=1, model=model)
    _, dark_far = measure(0.1, 3.0, pairs=1, model=model)
    assert dark_near > 0.85 * bright  # the 10 % wall is still seen across most of the view at 1.5 m
    assert dark_far < 0.7 * dark_near  # and loses its (farther, oblique) edges at long range
