"""Accuracy on simulated frames (device.sim renderer with its anchored defaults: fully developed
speckle C = 1, grain 2.44 lambda N, blur 1.2 px, gain 8, 40 ms, indoor 0.5 %, rolling shutter;
thesis-calibrated geometry, 1664x928). The simulator is anchored so that the thesis's reference
pipeline reproduces the thesis's ~1.9 % at 2 m; at that speckle the issue's absolute targets
(0.1 px, 0.5 % at 2 m) are out of reach within 1 deg (see BENCHMARKS.md), so these tests hold
the fast pipeline to beating the reference on the same frames, and to the hard cases.
Few frame pairs each to stay fast; the benchmark and `laserpi evaluate` use more."""

import numpy as np
import pytest

from device.config import load_preset
from device.vision.evaluation import run_pipeline, simulated_pairs
from device.vision.pipelines import make_pipeline

CFG = load_preset("thesis-calibrated")


@pytest.fixture(scope="module")
def fast():
    return make_pipeline("fast-com", CFG, 0.1, 10.0)


@pytest.fixture(scope="module")
def reference():
    return make_pipeline("reference", CFG)


def test_90pc_wall_at_2m_beats_the_reference(fast, reference):
    pairs = simulated_pairs(CFG, "wall:distance=2,reflectivity=0.9", 2, seed=11)
    s = run_pipeline(fast, pairs)
    ref = run_pipeline(reference, pairs)
    summary = s.summary()
    mean, std = s.range_error_near(2.0)
    assert summary["subpixel_rms_px"] < 0.9 * ref.summary()["subpixel_rms_px"]
    assert std < 0.9 * ref.range_error_near(2.0)[1] and std < 1.8
    assert abs(mean) < 0.3
    assert summary["valid_fraction"] > 0.8


def test_90pc_wall_at_3m_no_worse_than_the_reference(fast, reference):
    pairs = simulated_pairs(CFG, "wall:distance=3,reflectivity=0.9", 2, seed=12)
    s = run_pipeline(fast, pairs)
    mean, std = s.range_error_near(3.0)
    assert std <= run_pipeline(reference, pairs).range_error_near(3.0)[1] and abs(mean) < 0.5


def test_10pc_wall_valid_columns(fast):
    s = run_pipeline(fast, simulated_pairs(CFG, "wall:distance=1.5,reflectivity=0.1", 1, seed=13))
    assert s.valid_fraction_within(2.5) >= 0.9  # issue target: >= 90 % of columns out to 2.5 m


@pytest.mark.parametrize("scene", ["empty", "sunlight"])
def test_no_false_returns(fast, scene):
    pairs = simulated_pairs(CFG, scene, 1, seed=14)
    for p in pairs:
        m = fast.process(p.lit, p.unlit, lit_rows=p.lit_rows)
        truth_rng = p.truth.range_m[m.column]
        finite = np.isfinite(m.range)
        with np.errstate(invalid="ignore"):
            wrong = finite & ~(np.abs(m.range - truth_rng) <= 0.05 * truth_rng)  # no return there, or far off
        assert wrong.mean() < 0.001
        assert not np.isneginf(m.range).any()  # no false "too close" either


@pytest.mark.parametrize("variant", ["fast-com", "fast-blais-rioux"])
def test_glossy_floor_ghost_never_measured(fast, variant):
    pipe = fast if variant == "fast-com" else make_pipeline(variant, CFG, 0.1, 10.0)
    s = run_pipeline(pipe, simulated_pairs(CFG, "glossy-floor", 1, seed=15))
    summary = s.summary()
    assert summary["gross_error_fraction"] < 0.02  # the ghost 47 rows below is not followed
    assert summary["false_return_fraction"] == 0.0
    assert summary["valid_fraction"] > 0.8
