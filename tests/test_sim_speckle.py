"""The coherent speckle model against the physics (Dorsch, Haeusler & Herrmann, Appl. Opt. 33, 1994).

Dorsch et al.: the speckle-limited uncertainty of a spot image's centroid is
delta_x' = C lambda / (2 pi sin u'), sin u' = 1 / (2 N), i.e. C lambda N / pi, for a focused
system whose spot image is speckled with contrast C (a spot about the size of the resolution
cell; a smaller one images as a single, partly developed grain, a defocused one with larger
grains). Checked here on the renderer's noise-free line, ideal centroid over the whole profile.
"""

import math
from dataclasses import replace

import numpy as np
import pytest

from device.bench.sim import centroid_scatter_px, dorsch_config
from device.config import load_preset
from device.sim.render import COHERENT_DEFOCUSED, RenderOptions, coherent_line_profiles, speckle_pattern_weights

CFG = load_preset("thesis-calibrated")
LAMBDA, PITCH = CFG.laser.wavelength_m, CFG.optics.pixel_pitch_m
QUIET = replace(COHERENT_DEFOCUSED, noise=False, ambient=False, texture=False, ray_samples=8192)


@pytest.mark.parametrize("contrast", [1.0, 0.6])
def test_focused_centroid_scatter_follows_dorsch_and_scales_with_the_f_number(contrast):
    opts = replace(QUIET, speckle_contrast=contrast, defocus_sigma_px=0.0)
    std = {}
    for n in (1.4, 2.0, 2.8):
        err = centroid_scatter_px(dorsch_config(CFG, n), opts, seeds=(1, 2))
        dorsch_px = contrast * LAMBDA * n / math.pi / PITCH
        assert err.std() == pytest.approx(dorsch_px, rel=0.25), f"f/{n}"
        assert abs(err.mean()) < 0.01  # unbiased: the truth is the line's mean centroid
        std[n] = err.std()
    assert std[2.8] / std[1.4] == pytest.approx(2.0, rel=0.15)  # delta x' ~ N


def test_speckle_off_or_no_contrast_leaves_no_scatter():
    for opts in (QUIET.without("speckle"), replace(QUIET, speckle_contrast=0.0)):
        assert np.abs(centroid_scatter_px(CFG, opts, seeds=(1,))).max() < 0.01


def test_defocus_makes_larger_grains_and_more_scatter_than_focus():
    focused = centroid_scatter_px(CFG, replace(QUIET, defocus_sigma_px=0.0), seeds=(1,)).std()
    defocused = centroid_scatter_px(CFG, QUIET, seeds=(1,)).std()  # the anchored 1.2 px defocus
    assert defocused > 2 * focused


def test_focused_coherent_speckle_scatters_less_than_the_multiplicative_model():
    """The finding behind the coherent model: a separate multiplicative pattern over-states it."""
    mult = replace(QUIET, speckle_model="multiplicative", defocus_sigma_px=0.0, blur_sigma_px=1.1)
    coherent = replace(QUIET, defocus_sigma_px=0.0, blur_sigma_px=1.1)
    dorsch_px = LAMBDA * 2.0 / math.pi / PITCH
    assert centroid_scatter_px(CFG, mult, seeds=(1,)).std() > 1.6 * dorsch_px
    assert centroid_scatter_px(CFG, coherent, seeds=(1,)).std() < dorsch_px


def test_coherent_profiles_are_unbiased_and_keep_the_energy():
    rng = np.random.default_rng(0)
    rows = 100 + rng.uniform(-0.5, 0.5, 30000)
    line_sigma = np.full(rows.size, 0.3)
    cutoff = PITCH / (2 * LAMBDA * 2.0)
    r, frac = coherent_line_profiles(rows, line_sigma, 0.5, cutoff, 1.0, 12, 8, np.random.default_rng(1),
                                     defocus_sigma_px=1.2)
    assert r.shape == frac.shape == (rows.size, 25)
    centroid = (r * frac).sum(1) / frac.sum(1)
    assert centroid.std() > 0.3  # speckled
    assert abs((centroid - rows).mean()) < 0.01  # and unbiased on average
    assert frac.sum(1).mean() == pytest.approx(1.0, abs=0.02)  # the expected energy is kept


def test_partial_contrast_scales_the_pixel_fluctuations():
    """Contrast C sums independent patterns: every pixel's fluctuation scales by C."""
    rows = np.full(20000, 50.0)
    sig = np.full(rows.size, 0.3)
    cut = PITCH / (2 * LAMBDA * 2.0)
    spread = {c: coherent_line_profiles(rows, sig, 0.5, cut, c, 6, 8, np.random.default_rng(2))[1].std(0)
              for c in (1.0, 0.5, 0.3)}
    centre = slice(5, 8)
    for c in (0.5, 0.3):
        assert np.mean(spread[c][centre] / spread[1.0][centre]) == pytest.approx(c, rel=0.08)


@pytest.mark.parametrize("contrast", [1.0, 0.7, 0.5, 0.33, 0.1])
def test_pattern_weights_give_the_contrast(contrast):
    w = speckle_pattern_weights(contrast)
    assert w.sum() == pytest.approx(1.0)
    assert np.all(w > 0)
    assert math.sqrt((w**2).sum()) == pytest.approx(contrast)


def test_bad_speckle_arguments_are_named():
    with pytest.raises(ValueError, match="contrast"):
        speckle_pattern_weights(0.0)
    with pytest.raises(ValueError, match="speckle_model"):
        RenderOptions(speckle_model="gamma")
    with pytest.raises(ValueError, match="defocus_sigma_px"):
        RenderOptions(defocus_sigma_px=-1.0)
    with pytest.raises(ValueError, match="cutoff"):
        coherent_line_profiles(np.zeros(3), np.ones(3), 0.5, 3.0, 1.0, 4, 8, np.random.default_rng(0))
    with pytest.raises(ValueError, match=r"\(M,\)"):
        coherent_line_profiles(np.zeros(3), np.ones(2), 0.5, 0.5, 1.0, 4, 8, np.random.default_rng(0))
