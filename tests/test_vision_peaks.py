"""Column peak finding against synthetic line profiles with known centres (thesis 6.1.2 step 6)."""

import numpy as np
import pytest

from device.vision.peaks import ESTIMATORS, column_peaks, subpixel_offset

H, W = 48, 300


def gaussian_image(centres, sigma=1.5, amp=200.0, height=H, background=0.0):
    r = np.arange(height)[:, None]
    return amp * np.exp(-((r - np.asarray(centres)[None, :]) ** 2) / (2 * sigma**2)) + background


def test_gaussian_estimator_returns_the_exact_offset_not_half_of_it():
    # three samples of a Gaussian centred 0.3 px below the middle one
    f = lambda x: 80.0 * np.exp(-((x - 0.3) ** 2) / (2 * 1.3**2))
    delta, ok = subpixel_offset(f(-1.0), f(0.0), f(1.0), "gaussian")
    assert ok and delta == pytest.approx(0.3, abs=1e-12)  # the halving bug would give 0.15


@pytest.mark.parametrize("sigma", [0.8, 1.2, 2.0, 2.6])
def test_gaussian_estimator_is_exact_on_gaussian_lines(sigma):
    centres = 24 + np.linspace(-0.5, 0.5, W)
    p = column_peaks(gaussian_image(centres, sigma), "gaussian")
    assert p.valid.all()
    np.testing.assert_allclose(p.row, centres, atol=1e-9)


@pytest.mark.parametrize(
    "estimator, bound", [("com", 0.04), ("parabolic", 0.08), ("blais-rioux", 0.02), ("gaussian", 1e-9)]
)
@pytest.mark.parametrize("sigma", [0.8, 1.0, 1.5, 2.0])
def test_every_estimator_within_its_known_bias(estimator, bound, sigma):
    centres = 20.25 + np.linspace(-0.5, 0.5, W) + np.linspace(0, 4, W)  # sloped line, all phases
    p = column_peaks(gaussian_image(centres, sigma), estimator)
    assert p.valid.all()
    err = np.abs(p.row - centres)
    assert err.max() < bound
    # and not trivially: each estimator tracks the sub-pixel phase (integer rounding errs 0.5)
    assert err.max() < 0.25 * np.abs(np.rint(centres) - centres).max()


def test_parabolic_bias_pulls_towards_the_pixel_centre():
    centres = np.full(W, 24.3)
    p = column_peaks(gaussian_image(centres, 1.0), "parabolic")
    assert np.all(p.row < 24.3) and np.all(p.row > 24.0)


def test_background_is_subtracted_before_the_estimate():
    centres = np.full(W, 24.3)
    img = gaussian_image(centres, 1.2, background=30.0)
    wrong = column_peaks(img, "gaussian")
    right = column_peaks(img, "gaussian", background=30.0)
    np.testing.assert_allclose(right.row, 24.3, atol=1e-9)
    assert np.all(np.abs(wrong.row - 24.3) > 0.003)  # a pedestal biases the log fit
    np.testing.assert_allclose(right.peak, column_peaks(gaussian_image(centres, 1.2), "gaussian").peak)


@pytest.mark.parametrize("estimator", ESTIMATORS)
def test_saturated_flat_top_gives_the_centre(estimator):
    centres = 24 + np.linspace(-0.5, 0.5, W)
    img = np.minimum(gaussian_image(centres, 1.5, amp=600.0), 255.0)  # 3-5 saturated rows
    p = column_peaks(np.rint(img).astype(np.uint8), estimator)
    assert p.plateau.mean() > 0.9
    assert p.valid.all()
    assert np.max(np.abs(p.row - centres)) < 0.15


@pytest.mark.parametrize("estimator", ESTIMATORS)
def test_line_cut_by_the_image_edge_is_invalid_not_biased(estimator):
    p = column_peaks(gaussian_image(np.full(W, 0.6), 1.5), estimator)
    assert not p.valid.any() or np.max(np.abs(p.row[p.valid] - 0.6)) < 0.1
    p = column_peaks(gaussian_image(np.full(W, 5.4), 1.5), estimator)
    assert p.valid.all() and np.max(np.abs(p.row - 5.4)) < 0.05


def test_com_refuses_a_line_cut_by_the_edge():
    p = column_peaks(gaussian_image(np.full(W, 0.6), 1.5), "com")
    assert not p.valid.any() and np.all(np.isnan(p.row))


def test_per_column_interval_ignores_brighter_light_outside():
    centres = 30 + np.linspace(-3, 3, W)
    img = gaussian_image(centres, 1.3) + gaussian_image(np.full(W, 8.0), 1.3, amp=250.0)
    lo = np.floor(centres - 8).astype(int)
    hi = np.ceil(centres + 8).astype(int)
    p = column_peaks(img, "gaussian", row_lo=lo, row_hi=hi)
    assert p.valid.all()
    np.testing.assert_allclose(p.row, centres, atol=0.01)
    assert np.all(np.abs(column_peaks(img, "gaussian").row - 8.0) < 0.01)  # without: the distractor


def test_min_peak_rejects_noise_and_empty_intervals():
    rng = np.random.default_rng(1)
    img = rng.uniform(0, 8, (H, W))
    p = column_peaks(img, "com", min_peak=10)
    assert not p.valid.any() and np.all(np.isnan(p.row))
    p = column_peaks(gaussian_image(np.full(W, 20.0)), "com", row_lo=np.full(W, 10), row_hi=np.full(W, 10))
    assert not p.valid.any() and np.all(p.argmax == -1)


def test_speckle_noise_com_beats_three_point_estimators():
    rng = np.random.default_rng(2)
    centres = 24 + rng.uniform(-0.5, 0.5, 4000)
    clean = gaussian_image(centres, 1.6, amp=150.0)
    speckle = rng.gamma(1 / 0.3**2, 0.3**2, clean.shape)  # contrast 0.3, mean 1
    img = clean * speckle
    rms = {e: np.sqrt(np.nanmean((column_peaks(img, e).row - centres) ** 2)) for e in ("com", "parabolic")}
    assert rms["com"] < rms["parabolic"]
    assert 0.02 < rms["com"] < 0.3


def test_bad_arguments_are_named():
    img = np.zeros((H, W))
    with pytest.raises(ValueError, match="estimator"):
        column_peaks(img, "median")
    with pytest.raises(ValueError, match="row_lo"):
        column_peaks(img, row_lo=np.zeros(W - 1))
    with pytest.raises(ValueError, match="height, width"):
        column_peaks(np.zeros(5))
    with pytest.raises(ValueError, match="pedestal"):
        column_peaks(img, pedestal=1.0)


def test_two_lines_in_one_window_show_as_wide_spread():
    single = column_peaks(gaussian_image(np.full(W, 24.0), 1.2), "com")
    double = column_peaks(gaussian_image(np.full(W, 22.5), 1.2) + gaussian_image(np.full(W, 25.5), 1.2), "com")
    assert np.all(single.spread < 1.3)
    assert np.all(double.spread > 1.5 * single.spread)


def test_padded_centre_of_mass_is_identical_to_refine_peaks():
    # random 8-bit profiles with lines, flat saturated tops, lines cut by per-column intervals
    # and by the image edge, empty intervals and candidates outside their interval
    from device.vision.peaks import refine_com_padded, refine_peaks

    rng = np.random.default_rng(3)
    centres = rng.uniform(-2, H + 2, W)
    img = gaussian_image(centres, sigma=rng.uniform(0.8, 2.5, W), amp=rng.uniform(5, 400, W))
    img = np.clip(img + rng.normal(0, 3, (H, W)), 0, 255).astype(np.uint8)
    lo = rng.integers(0, H // 2, W)
    hi = np.where(rng.random(W) < 0.05, lo, rng.integers(H // 2, H + 1, W))
    rows = np.arange(H)[:, None]
    img[(rows < lo) | (rows >= hi)] = 0  # zeros outside each column's interval, as the contract says
    k = np.where(rng.random(W) < 0.1, rng.integers(0, H, W), np.argmax(img, axis=0))
    pad = 4
    padded = np.zeros((H + 2 * pad, W), np.uint8)
    padded[pad:-pad] = img
    for cols in (np.arange(W), np.sort(rng.choice(W, 40, replace=False))):
        want = refine_peaks(img[:, cols], k[cols], "com", lo[cols], hi[cols], 1.0, 0.0, 4, 0.0, 255)
        got = refine_com_padded(padded, pad, k[cols], cols, lo[cols], hi[cols], 4)
        assert got.plateau.any() and got.valid.any() and not got.valid.all()
        for name in ("row", "peak", "argmax", "valid", "plateau", "spread"):
            np.testing.assert_array_equal(getattr(got, name), getattr(want, name), err_msg=name)


@pytest.mark.parametrize("estimator", ESTIMATORS)
@pytest.mark.parametrize("half_width", [1, 2, 4, 6])
def test_refinement_reads_no_row_past_the_estimators_reach(estimator, half_width):
    # distinct values (no flat top, whose walk reads on): rows further than rows_read() from the
    # maximum, changed at random, change nothing
    from device.vision.peaks import refine_peaks, rows_read

    rng = np.random.default_rng(7)
    k = np.full(W, H // 2)
    img = gaussian_image(k + rng.uniform(-0.5, 0.5, W), sigma=rng.uniform(0.8, 2.0, W)) + rng.uniform(0, 3, (H, W))
    reach = rows_read(estimator, half_width)
    far = np.abs(np.arange(H) - H // 2) > reach
    other = img.copy()
    other[far] = rng.uniform(0, 400, (far.sum(), W))
    want = refine_peaks(img, k, estimator, half_width=half_width)
    got = refine_peaks(other, k, estimator, half_width=half_width)
    assert want.valid.any()
    for name in ("row", "peak", "argmax", "valid", "plateau", "spread"):
        np.testing.assert_array_equal(getattr(got, name), getattr(want, name), err_msg=name)


@pytest.mark.parametrize("estimator, half_width", [("blais-rioux", 1), ("com", 5), ("gaussian", 1)])
def test_the_reach_is_not_larger_than_needed(estimator, half_width):
    # the row rows_read() away from the maximum matters: the derivative filter's outer sample,
    # the centre-of-mass window's edge, the flat-top test's second sample
    from device.vision.peaks import refine_peaks, rows_read

    reach = rows_read(estimator, half_width)
    col = np.array([0, 0, 0, 0, 10, 40, 80, 100, 100, 30, 5, 0, 0, 0, 0, 0], float)  # maximum at row 7
    k = np.array([7])
    changed = col.copy()
    changed[7 + reach] = 100.0 if estimator == "gaussian" else col[7 + reach] + 20.0
    a = refine_peaks(col[:, None], k, estimator, half_width=half_width)
    b = refine_peaks(changed[:, None], k, estimator, half_width=half_width)
    assert (a.row[0], a.plateau[0]) != (b.row[0], b.plateau[0]) or a.valid[0] != b.valid[0]


@pytest.mark.parametrize("estimator", ESTIMATORS)
@pytest.mark.parametrize("half_width", [1, 2, 4])
def test_fast_pipeline_pads_by_the_estimators_reach(estimator, half_width):
    from device.config import load_preset
    from device.vision.fast import FastParams, FastPipeline
    from device.vision.peaks import rows_read

    pipe = FastPipeline(load_preset("thesis-calibrated"), FastParams(estimator=estimator, half_width=half_width), 0.4, 3.2)
    assert pipe._pad == rows_read(estimator, half_width) >= half_width
    assert pipe._padded(pipe.rows).shape[0] == pipe.rows + 2 * rows_read(estimator, half_width)
