"""The fast pipeline's compiled kernel (device/vision/columns/) through its Python binding: its
image passes against the OpenCV operations they fuse, its helpers against plain definitions, and
clear errors for bad arguments (each step on its own, in C: columns/test/test_columns.c). The pipeline's behaviour (targets, hard cases) is tested through FastPipeline
in test_vision_pipelines.py and test_vision_simulated.py; its centre of mass against the general
estimator in test_vision_peaks.py."""

import math

import cv2
import numpy as np
import pytest

from device.vision.fast import SATURATED_LINE_MIN, FastParams
from device.vision.kernel import columns_kernel

K = columns_kernel()
SHAPES = [(1, 3), (2, 3), (3, 7), (5, 5), (16, 4), (37, 101), (128, 1664)]


def _opencv_band(a, b, mask):
    """The OpenCV sequence the kernel's band_difference replaced (d, sm)."""
    d = cv2.subtract(a, b)
    sat = (a == 255) & (d >= SATURATED_LINE_MIN)
    pair = np.zeros_like(sat)
    pair[1:] |= sat[1:] & sat[:-1]
    pair[:-1] |= sat[1:] & sat[:-1]
    d[pair] = 255
    d = cv2.bitwise_and(d, mask)
    return d, cv2.blur(d, (5, 3))


@pytest.mark.parametrize("shape", SHAPES)
def test_band_difference_equals_the_opencv_operations(shape):
    rng = np.random.default_rng(shape[0] * 1000 + shape[1])
    n, W = shape
    for trial in range(4):
        a = rng.integers(0, 256, shape, dtype=np.uint8)
        b = rng.integers(0, 256, shape, dtype=np.uint8)
        if trial >= 2:  # a saturated line over a dim background, and bright unlit pixels that must not count
            a = (a // 4).astype(np.uint8)
            a[rng.random(shape) < 0.3] = 255
            b[rng.random(shape) < 0.1] = 250
        mask = np.where(rng.random(shape) < 0.8, 255, 0).astype(np.uint8)
        pad = 4
        padded = np.full((n + 2 * pad, W), 77, np.uint8)  # the pad rows are the caller's: left alone
        sm = np.empty(shape, np.uint8)
        K.band_difference(a, b, mask, padded, pad, sm, SATURATED_LINE_MIN)
        want_d, want_sm = _opencv_band(a, b, mask)
        np.testing.assert_array_equal(padded[pad : pad + n], want_d)
        np.testing.assert_array_equal(sm, want_sm)
        assert (padded[:pad] == 77).all() and (padded[pad + n :] == 77).all()


@pytest.mark.parametrize("shape", SHAPES)
def test_noise_level_equals_the_opencv_operations(shape):
    rng = np.random.default_rng(shape[0] + 7 * shape[1])
    a = rng.integers(0, 256, shape, dtype=np.uint8)
    b = rng.integers(0, 256, shape, dtype=np.uint8)
    out = np.empty(shape[1])
    K.noise_level(a, b, out)
    np.testing.assert_array_equal(out, cv2.blur(cv2.subtract(b, a), (5, 3)).max(axis=0))


def _opencv_moved(a, b, unlit, p):
    """The OpenCV and numpy sequence the kernel's moved replaced (FastPipeline._moved before it,
    for a multiple of 8 columns: INTER_AREA's blocks are 8 columns wide only then)."""
    W, n = a.shape[1], a.shape[0] // 8
    blocks = lambda rows: cv2.resize(rows, (-(-W // 8), n), interpolation=cv2.INTER_AREA)  # noqa: E731
    diff = cv2.absdiff(blocks(a[: 8 * n : 2]), blocks(b[: 8 * n : 2]))
    change = cv2.reduce(diff, 0, cv2.REDUCE_SUM, dtype=cv2.CV_32S)[0]
    local = cv2.reduce(diff, 0, cv2.REDUCE_MAX)[0]
    mean_level, block_level = p.moved_level * n, p.moved_block_level
    if change.max() > mean_level or local.max() >= block_level:
        upper, lower = (blocks(unlit[r : 8 * n : 4].astype(np.float32)) for r in (0, 2))
        block_level = max(block_level, p.moved_block_ratio * float(np.median(np.abs(np.rint(upper) - np.rint(lower)))))
        within = np.abs(upper - lower).T
        within = np.concatenate([within[:1], within, within[-1:]])
        noise = np.median(np.concatenate([within[:-2], within[1:-1], within[2:]], axis=1), axis=1)
        mean_level = np.maximum(mean_level, p.moved_mean_ratio * n * noise)
    return np.repeat((change > mean_level) | (local >= block_level), 8)[:W]


def _kernel_moved(a, b, unlit, p):
    out = np.empty(a.shape[1], bool)
    K.moved(a, b, unlit, (p.moved_level, p.moved_block_level, p.moved_block_ratio, p.moved_mean_ratio), out)
    return out


def _moving_bands(rng, rows, W, light, shift):
    """Two unlit neighbours of a textured band under sensor noise (``light``: its standard
    deviation in levels), the second's texture moved ``shift`` columns, and the first's own band."""
    texture = cv2.GaussianBlur(rng.uniform(20, 200, (rows, W + 16)), (0, 0), 3)
    noisy = lambda t: np.clip(np.rint(t + rng.normal(0, light, t.shape)), 0, 255).astype(np.uint8)  # noqa: E731
    a = noisy(texture[:, 8 : 8 + W])
    return a, noisy(texture[:, 8 - shift : 8 - shift + W]), a


@pytest.mark.parametrize("rows, W", [(8, 8), (16, 16), (24, 40), (48, 208), (160, 1664), (168, 1640)])
def test_moved_equals_the_opencv_operations(rows, W):
    rng = np.random.default_rng(rows * 7 + W)
    p = FastParams()
    for light, shift in ((0.0, 0), (0.7, 0), (2.0, 0), (4.0, 0), (1.0, 1), (1.0, 5), (3.0, 2)):
        a, b, unlit = _moving_bands(rng, rows, W, light, shift)
        want = _opencv_moved(a, b, unlit, p)
        np.testing.assert_array_equal(_kernel_moved(a, b, unlit, p), want, err_msg=f"light {light}, shift {shift}")
    # whole-band random bytes: every bar reached, many ties in the rounding; the unlit band its own
    for trial in range(3):
        a, b, u = (rng.integers(0, 256 if trial else 2, (rows, W), dtype=np.uint8) for _ in range(3))
        np.testing.assert_array_equal(_kernel_moved(a, b, u, p), _opencv_moved(a, b, u, p))
    # other bars: each of them deciding somewhere
    for params in (FastParams(moved_level=0.2), FastParams(moved_block_level=1.0, moved_block_ratio=0.5),
                   FastParams(moved_mean_ratio=4.0), FastParams(moved_block_ratio=0.0, moved_mean_ratio=0.0)):
        a, b, unlit = _moving_bands(rng, rows, W, 1.5, 1)
        np.testing.assert_array_equal(_kernel_moved(a, b, unlit, params), _opencv_moved(a, b, unlit, params))


def test_moved_takes_non_finite_bars_as_the_opencv_operations_did():
    # np.maximum propagates a NaN mean bar (no column moves by it); Python's max() keeps the block
    # bar where an infinite ratio meets a noise median of 0 (inf x 0 is NaN); infinite bars move nothing
    from types import SimpleNamespace

    rng = np.random.default_rng(11)
    moving = _moving_bands(rng, 96, 416, 1.0, 5)
    a, b, _ = _moving_bands(rng, 96, 416, 0.0, 2)
    flat_unlit = np.full_like(a, 80)
    base = dict(moved_level=0.9, moved_block_level=3.0, moved_block_ratio=5.0, moved_mean_ratio=1.5)
    for change, bands in (({"moved_level": math.nan}, moving), ({"moved_block_ratio": math.inf}, (a, b, flat_unlit)),
                          ({"moved_level": math.inf}, moving), ({"moved_block_level": math.inf}, moving),
                          ({"moved_mean_ratio": math.inf}, moving)):
        p = SimpleNamespace(**{**base, **change})
        want = _opencv_moved(*bands, p)
        np.testing.assert_array_equal(_kernel_moved(*bands, p), want, err_msg=str(change))
        assert 0 < want.sum() < want.size or change == {"moved_block_level": math.inf}, change


def test_fast_params_refuse_a_moved_level_that_is_not_a_level():
    for level in (math.nan, -0.1):
        with pytest.raises(ValueError, match="need moved_level >= 0"):
            FastParams(moved_level=level)


def test_moved_does_not_count_sensor_noise_as_motion_and_finds_a_moved_texture():
    rng = np.random.default_rng(3)
    p, no_noise_bars = FastParams(), FastParams(moved_block_ratio=0.0, moved_mean_ratio=0.0)
    for light in (4.0, 6.0):  # a still band in bright light: its noise alone passes the fixed bars
        a, b, unlit = _moving_bands(rng, 160, 1664, light, 0)
        assert _kernel_moved(a, b, unlit, no_noise_bars).mean() > 0.2
        assert _kernel_moved(a, b, unlit, p).mean() < 0.02
    a, b, unlit = _moving_bands(rng, 160, 1664, 2.0, 5)  # the texture moved 5 columns
    assert _kernel_moved(a, b, unlit, p).mean() > 0.9


def _moved_by_its_definition(a, b, unlit, p):
    """columns_moved as columns.h states it, for any width, in numpy (the groups' sums and the
    rounding in float64, exact for these sizes)."""
    rows, W = a.shape
    n, starts = rows // 8, np.arange(0, W, 8)
    k = np.minimum(8, W - starts)  # the columns of each group

    def sums(x, offsets):  # (n, groups): the group's columns of the block's rows at these offsets
        return np.add.reduceat(sum(x[r : 8 * n : 8].astype(np.int64) for r in offsets), starts, axis=1)

    d = np.abs(np.rint(sums(a, (0, 2, 4, 6)) / (4 * k)) - np.rint(sums(b, (0, 2, 4, 6)) / (4 * k)))
    change, local = d.sum(axis=0), d.max(axis=0)
    level, block_level = p.moved_level * n, p.moved_block_level
    if not ((change > level).any() or (local >= block_level).any()):
        return np.zeros(W, bool)
    upper, lower = sums(unlit, (0, 4)), sums(unlit, (2, 6))
    block_level = max(block_level, p.moved_block_ratio * np.median(np.abs(np.rint(upper / (2 * k)) - np.rint(lower / (2 * k)))))
    sixteenths = np.rint(8 * np.abs(upper - lower) / k)
    G = starts.size
    bar = np.empty(G, np.float32)
    for g in range(G):
        window = sixteenths[:, [max(g - 1, 0), g, min(g + 1, G - 1)]]
        noise = np.float32(np.median(window) / 16)
        bar[g] = max(np.float32(level), np.float32(p.moved_mean_ratio * n) * noise)
    return np.repeat((change > bar) | (local >= block_level), 8)[:W]


@pytest.mark.parametrize("W", [19, 1642, 1650, 1664])
def test_moved_is_its_definition_for_any_width(W):
    rng = np.random.default_rng(W)
    for light, shift in ((0.7, 0), (4.0, 0), (1.0, 5), (3.0, 2)):
        a, b, unlit = _moving_bands(rng, 96, W, light, shift)
        want = _moved_by_its_definition(a, b, unlit, FastParams())
        np.testing.assert_array_equal(_kernel_moved(a, b, unlit, FastParams()), want, err_msg=f"{light}, {shift}")
        if W % 8 == 0:
            np.testing.assert_array_equal(want, _opencv_moved(a, b, unlit, FastParams()))


def test_moved_groups_a_width_not_divisible_by_8_by_its_own_columns():
    # the last group is the 3 columns left: a change there moves those columns, not the group before
    rows, W = 16, 19
    a = np.full((rows, W), 100, np.uint8)
    b = a.copy()
    b[:, 16:] = 130
    out = _kernel_moved(a, b, a, FastParams())
    np.testing.assert_array_equal(out, np.arange(W) >= 16)
    b = a.copy()
    b[:, 8:16] = 130
    np.testing.assert_array_equal(_kernel_moved(a, b, a, FastParams()), (np.arange(W) >= 8) & (np.arange(W) < 16))


def test_moved_refuses_a_band_of_fewer_than_8_rows():
    a = np.zeros((7, 16), np.uint8)
    with pytest.raises(ValueError, match="moved: need >= 8 rows and >= 1 column, got 7 rows x 16 columns"):
        _kernel_moved(a, a, a, FastParams())
    with pytest.raises(ValueError, match="unlit has length 8 along axis 1, expected 16"):
        K.moved(np.zeros((8, 16), np.uint8), np.zeros((8, 16), np.uint8), np.zeros((8, 8), np.uint8),
                (0.9, 3.0, 5.0, 1.5), np.empty(16, bool))


def test_box_mean_rounds_as_opencv_for_every_sum():
    # the middle row's 5x3 boxes centred on every fifth column take every sum 0..3825 once
    sums = np.arange(0, 15 * 255 + 1)
    img = np.zeros((3, 5 * sums.size), np.uint8)
    for i, s in enumerate(sums):
        q, r = divmod(int(s), 15)
        block = np.full(15, q, np.uint8)
        block[:r] += 1
        img[:, 5 * i : 5 * i + 5] = block.reshape(3, 5)
    np.testing.assert_array_equal(cv2.boxFilter(img, cv2.CV_32S, (5, 3), normalize=False)[1, 2::5], sums)
    out = np.empty(img.shape[1])
    K.noise_level(np.zeros_like(img), img, out)  # unlit - lit = img; the largest over the rows
    np.testing.assert_array_equal(out, cv2.blur(img, (5, 3)).max(axis=0))


def test_constants_shared_with_python_agree():
    from device.vision.fast import BLOCK_ROWS
    from device.vision.measurements import ColumnStatus

    for name in ("OK", "NO_RETURN", "UNLIT", "REJECTED"):
        assert getattr(K, f"STATUS_{name}") == ColumnStatus[name]
    assert K.BLOCK_ROWS == BLOCK_ROWS


def test_run_length():
    mask = np.array([1, 1, 0, 1, 0, 0, 1, 1, 1], bool)
    out = np.empty(mask.size, np.intp)
    K.run_length(mask, out)
    np.testing.assert_array_equal(out, [2, 2, 0, 1, 0, 0, 3, 3, 3])


def _spans_numpy(mask, join):
    """_spans' definition in numpy (the device's own before the kernel took it)."""
    runs = np.flatnonzero(np.diff(np.concatenate(([False], mask, [False])).astype(np.int8))).reshape(-1, 2)
    if len(runs) < 2:
        return runs
    apart = np.flatnonzero(runs[1:, 0] - runs[:-1, 1] >= join)
    return np.stack([np.concatenate(([runs[0, 0]], runs[apart + 1, 0])),
                     np.concatenate((runs[apart, 1], [runs[-1, 1]]))], axis=1)


@pytest.mark.parametrize("seed", range(30))
def test_spans_join_runs_closer_than_join(seed):
    from device.vision.fast import _spans

    rng = np.random.default_rng(seed)
    n = int(rng.integers(0, 3000))
    mask = rng.random(n) < rng.choice([0.0, 0.01, 0.3, 0.9, 1.0])
    join = int(rng.choice([0, 1, 2, 64]))
    got = _spans(mask, join)
    assert got.dtype == np.intp and got.shape[1:] == (2,)
    np.testing.assert_array_equal(got, _spans_numpy(mask, join).reshape(-1, 2))


def test_spans_refuses_too_small_an_output():
    with pytest.raises(ValueError, match="out holds 1 spans, a mask of 4 can have 2"):
        K.spans(np.array([1, 0, 1, 0], bool), 1, np.empty((1, 2), np.intp))


def _near_rows_opencv(lit, unlit, mask, r0, r1, c0, c1):
    """Step 7's near rows as the OpenCV sequence the device ran before the kernel took them."""
    la, ua, m = lit[r0:r1:2, c0:c1], unlit[r0:r1:2, c0:c1], mask[:, c0:c1]
    u = cv2.bitwise_and(ua, m)
    return (cv2.bitwise_and(cv2.subtract(la, ua), m).max(axis=0), cv2.bitwise_and(cv2.subtract(ua, la), m).max(axis=0),
            np.minimum(u[:-1], u[1:]).max(axis=0, initial=0))


@pytest.mark.parametrize("seed", range(20))
def test_near_rows_is_the_opencv_sequence(seed):
    """Random frames, masks of whole rows nearer than the range (255 from a column's own row on,
    0 above), one to hundreds of near rows, odd and even counts, spans at the image's edges."""
    rng = np.random.default_rng(seed)
    H, W = int(rng.integers(2, 300)), int(rng.integers(1, 200))
    lit, unlit = (rng.integers(0, 256, (H, W)).astype(np.uint8) for _ in range(2))
    if seed % 4 == 0:
        unlit[rng.random((H, W)) < 0.2] = 255  # saturated pixels: pairs of them
    r0 = int(rng.integers(0, H - 1))
    r1 = int(rng.integers(r0 + 1, H + 1))
    rows = np.arange(r0, r1, 2)
    mask = np.where(rows[:, None] >= rng.integers(r0, r1 + 1, W)[None, :], 255, 0).astype(np.uint8)
    c0 = int(rng.integers(0, W))
    c1 = int(rng.integers(c0 + 1, W + 1))
    got = tuple(np.empty(c1 - c0, np.uint8) for _ in range(3))
    K.near_rows(lit, unlit, mask, (r0, r1, 2), (c0, c1), *got)
    for g, want in zip(got, _near_rows_opencv(lit, unlit, mask, r0, r1, c0, c1)):
        np.testing.assert_array_equal(g, want)


def test_near_rows_names_bad_arguments():
    f = np.zeros((10, 8), np.uint8)
    out = tuple(np.empty(4, np.uint8) for _ in range(3))
    with pytest.raises(ValueError, match="mask has length 4 along axis 0, expected 5"):
        K.near_rows(f, f, np.zeros((4, 8), np.uint8), (0, 10, 2), (0, 4), *out)
    with pytest.raises(ValueError, match="need 0 <= r0 < r1 <= H"):
        K.near_rows(f, f, np.zeros((1, 8), np.uint8), (10, 11, 2), (0, 4), *out)
    with pytest.raises(ValueError, match="step must be >= 1"):
        K.near_rows(f, f, np.zeros((5, 8), np.uint8), (0, 10, 0), (0, 4), *out)
    with pytest.raises(ValueError, match="got rows 10-9223372036854775807 of 10"):  # not a mask's size overflowing
        K.near_rows(f, f, np.zeros((5, 8), np.uint8), (10, 2**63 - 1, 2**62), (0, 4), *out)
    one_row = tuple(np.empty(4, np.uint8) for _ in range(3))
    K.near_rows(f, f, np.zeros((1, 8), np.uint8), (0, 10, 2**62), (0, 4), *one_row)  # one row: r0
    with pytest.raises(ValueError, match="above has length 4 along axis 0, expected 2"):
        K.near_rows(f, f, np.zeros((5, 8), np.uint8), (0, 10, 2), (6, 8), *out)
    shared = np.empty(4, np.uint8)
    with pytest.raises(ValueError, match="above shares memory with below"):
        K.near_rows(f, f, np.zeros((5, 8), np.uint8), (0, 10, 2), (0, 4), shared, shared, out[2])
    with pytest.raises(ValueError, match="pair shares memory with lit"):
        K.near_rows(f, f, np.zeros((5, 8), np.uint8), (0, 10, 2), (0, 4), *out[:2], f[0, :4])


def test_scan_plane_rounds_each_operation_as_stated():
    """columns_scan_plane against its definition with every product and sum rounded (numpy's
    elementwise ufuncs), libm's atan2 (math.atan2, as the kernel's C) and hypot, and within
    an ulp or two of to_scan_plane (whose matmul goes through BLAS, fused multiply-adds
    included); NaN points stay NaN."""
    import math

    from device.config import load_preset
    from device.model.scan_frame import to_scan_plane
    from device.vision.geometry import column_geometry

    g = column_geometry(load_preset("thesis-calibrated"))
    rng = np.random.default_rng(0)
    p = rng.normal(0, 2, (5000, 3))
    p[::17] = np.nan
    angle, r = g.angle_range(p)
    R, o = g.scan.rotation, g.scan.origin
    d = p - o
    q0 = (d[:, 0] * R[0, 0] + d[:, 1] * R[0, 1]) + d[:, 2] * R[0, 2]
    q1 = (d[:, 0] * R[1, 0] + d[:, 1] * R[1, 1]) + d[:, 2] * R[1, 2]
    np.testing.assert_array_equal(angle, [math.atan2(b, a) for a, b in zip(q0, q1)])
    np.testing.assert_allclose(r, np.hypot(q0, q1), rtol=2.3e-16, atol=0)
    want_angle, want_r = to_scan_plane(p, g.scan)
    np.testing.assert_allclose(angle, want_angle, rtol=1e-14, atol=1e-15)
    np.testing.assert_allclose(r, want_r, rtol=1e-14)
    assert np.isnan(angle[::17]).all() and np.isnan(r[::17]).all()
    assert g.angle_range(p.reshape(50, 100, 3))[0].shape == (50, 100)
    with pytest.raises(ValueError, match="points must have shape"):
        g.angle_range(np.zeros((4, 2)))


def _candidates(sm, sep=5, pad=4):
    """The kernel's candidates (k, s) for a smoothed difference that is also the difference."""
    n, W = sm.shape
    padded = np.zeros((n + 2 * pad, W), np.uint8)
    padded[pad : pad + n] = sm
    k, s = np.empty(2 * W, np.intp), np.empty(2 * W)
    K.candidates(sm, padded, pad, sep, k, s)
    return k, s


def test_candidates_find_the_largest_and_a_separated_second_peak():
    n, W = 64, 6
    sm = np.zeros((n, W), np.uint8)
    sm[20, :] = 50  # the line
    sm[22, :] = 40  # its own flank: too close to be a second line
    sm[45, :] = 30  # a ghost
    k, s = _candidates(sm)
    np.testing.assert_array_equal(k[:W], 20)
    np.testing.assert_array_equal(k[W:], 45)
    np.testing.assert_array_equal(s, [50] * W + [30] * W)


@pytest.mark.parametrize("call, message", [
    (lambda: K.noise_level(np.zeros((4, 8)), np.zeros((4, 8), np.uint8), np.empty(8)), "lit has dtype"),
    (lambda: K.noise_level(np.zeros((4, 8), np.uint8), np.zeros((4, 9), np.uint8), np.empty(8)), "unlit has length 9"),
    (lambda: K.noise_level(np.zeros((4, 8), np.uint8)[:, ::2], np.zeros((4, 4), np.uint8), np.empty(4)), "C-contiguous"),
    (lambda: K.noise_level(np.zeros((4, 8), np.uint8), np.zeros((4, 8), np.uint8), np.empty(8)[:4].view()),
     "out has length 4"),
    (lambda: K.run_length(np.zeros(5, bool), np.empty(5, np.int8)), "out has dtype"),
    (lambda: K.candidates(np.zeros((0, 4), np.uint8), np.zeros((8, 4), np.uint8), 4, 5, np.empty(8, np.intp),
                          np.empty(8)), "need 1 to 65535 rows (got 0)"),
    (lambda: K.candidates(np.zeros((16, 4), np.uint8), np.zeros((24, 4), np.uint8), 4, 8, np.empty(8, np.intp),
                          np.empty(8)), "sep >= 0 and 2 sep + 1 <= 16"),
    (lambda: K.refine_com(np.zeros((20, 4), np.uint8), 4, np.zeros(1, np.intp), np.array([4]), np.zeros(1, np.intp),
                          np.ones(1, np.intp), 4, *_refine_outputs(1)), "column 4"),
    (lambda: K.refine_com(np.zeros((20, 4), np.uint8), 1, np.zeros(1, np.intp), np.zeros(1, np.intp),
                          np.zeros(1, np.intp), np.ones(1, np.intp), 4, *_refine_outputs(1)), "pad >= max(half_width, 2)"),
    (lambda: K.triangulate(np.zeros(1), np.array([5]), np.zeros((2, 4)), np.zeros((2, 4)), 0, (0.0, 1.0, 0.0, 1.0),
                           (0.0, 1.0, 1e-9), (0, 1, 2, 3, 4), np.empty((1, 3)), np.empty(1), np.empty(1, np.uint8)),
     "column 5 outside the table's 4 columns"),
    (lambda: K.triangulate(np.zeros(2), np.zeros(2, np.intp), np.zeros((2, 4)), np.zeros((3, 4)), 0,
                           (0.0, 1.0, 0.0, 1.0), (0.0, 1.0, 1e-9), (0, 1, 2, 3, 4), np.empty((2, 3)), np.empty(2),
                           np.empty(2, np.uint8)), "yn has length 3 along axis 0"),
])
def test_bad_arguments_are_named(call, message):
    with pytest.raises(ValueError, match=message.replace("(", r"\(").replace(")", r"\)").replace("+", r"\+")):
        call()


def _refine_outputs(m):
    return np.empty(m), np.empty(m), np.empty(m, np.intp), np.empty(m, bool), np.empty(m, bool), np.empty(m)


def test_refine_com_reads_only_its_buffers_on_empty_and_edge_columns():
    # an empty interval, a candidate outside it, and a line cut by the interval's end: no
    # estimate (NaN), no read outside the padded image (pad = half_width)
    n, W, pad = 10, 3, 4
    padded = np.zeros((n + 2 * pad, W), np.uint8)
    padded[pad + 8 : pad + 10, 2] = 100
    k = np.array([3, 12, 9], np.intp)
    lo, hi = np.array([5, 0, 0], np.intp), np.array([5, 10, 10], np.intp)
    out = _refine_outputs(3)
    K.refine_com(padded, pad, k, np.arange(3), lo, hi, 4, *out)
    row, peak, argmax, valid = out[:4]
    assert not valid.any() and np.isnan(row).all()
    np.testing.assert_array_equal(argmax, [-1, -1, 9])
    assert np.isnan(peak[:2]).all() and peak[2] == 100


def test_fast_params_reject_a_window_wider_than_the_candidate_blocks_allow():
    with pytest.raises(ValueError, match="half_width must be <= 6"):
        FastParams(half_width=7)


def test_candidates_in_a_band_whose_last_block_is_partial():
    n, W = 21, 3  # one whole block and 5 rows
    sm = np.zeros((n, W), np.uint8)
    sm[19, :] = 60
    sm[4, 1] = 20
    k, s = _candidates(sm)
    np.testing.assert_array_equal(k[:W], 19)
    assert k[W + 1] == 4 and s[W + 1] == 20
    assert (s[[W, W + 2]] == 0).all()  # nothing else: no second candidate


def test_no_second_candidate_on_the_flank_of_a_line_near_the_band_top():
    # only the line (row 3) and its flanks: the rows within sep of it are not candidates, and
    # with nothing else the second candidate is empty (0), not the line's own flank
    n, W = 32, 2
    sm = np.zeros((n, W), np.uint8)
    sm[1:6, :] = [[40], [80], [90], [80], [40]]
    k, s = _candidates(sm)
    np.testing.assert_array_equal(k[:W], 3)
    np.testing.assert_array_equal(s[W:], 0)


def _resolve(W=8, status_dtype=np.uint8, idx=()):
    """The kernel's resolve on a straight line at band row 5 in every column (band from image
    row 100, 1/z table of 20 rows from image row 90), second candidates in columns ``idx``."""
    k, s = np.full(2 * W, 5, np.intp), np.full(2 * W, 50.0)
    first = (np.full(W, 5.0), np.full(W, 50.0), np.ones(W, bool), np.ones(W))
    m = len(idx)
    second = (np.array(idx, np.intp), np.full(m, 5.0), np.full(m, 50.0), np.ones(m, bool), np.ones(m))
    inv_depth = np.tile(np.linspace(0.1, 0.3, 20)[:, None], (1, W))
    params = (0.1, 0.5, 2.5, 0.08, 3.0, 3.0, 0.015, 5, 0, 4, 3)
    out = (np.empty(W, bool), np.empty(W), np.empty(W), np.empty(W, status_dtype))
    seen = K.resolve((k, s), np.full(W, 10.0), np.zeros(W), first, second, (inv_depth, 90), (100, 0, 16), params, out)
    return seen, out


def test_resolve_takes_its_arguments_grouped_as_the_kernels_structs():
    seen, (found, row, peak, status) = _resolve()
    assert seen == (5, 5) and found.all() and (row == 105.0).all() and (status == K.STATUS_OK).all()
    with pytest.raises(ValueError, match="status has dtype"):
        _resolve(status_dtype=np.int8)
    with pytest.raises(ValueError, match=r"idx2 must be increasing columns in \[0, 8\)"):
        _resolve(idx=(3, 3))


def _scan_rays_numpy(angle, rng, quality, row, grid):
    """scan_rays' definition in numpy: resample_scan over the columns in angle_order, bridging
    bridged_gap, and quality and row of the measured column each ray with a finite range came
    from (of the two it was interpolated between, the one nearer in angle)."""
    from device.model.scan_frame import angle_order, resample_scan
    from device.vision.measurements import bridged_gap

    order = angle_order(angle)
    out = resample_scan(angle, rng, grid, bridged_gap(angle[order], grid), order=order)
    ok = order[np.isfinite(rng[order])]  # the measured columns in increasing angle, as resample_scan takes them
    a, q, r = angle[ok], quality[ok], row[ok]
    measured = np.isfinite(out)
    if not a.size:
        return out, np.zeros(grid.size, np.uint8), np.full(grid.size, np.nan)
    k = np.searchsorted(a, grid)
    lo, hi = np.clip(k - 1, 0, a.size - 1), np.clip(k, 0, a.size - 1)
    nearest = np.where(np.abs(grid - a[lo]) <= np.abs(a[hi] - grid), lo, hi)
    return out, np.where(measured, np.clip(np.rint(q[nearest]), 0, 255), 0).astype(np.uint8), np.where(measured, r[nearest], np.nan)


def _kernel_scan_rays(angle, r, quality, row, grid):
    m = grid.size
    out, q, rows = np.empty(m), np.empty(m, np.uint8), np.empty(m)
    K.scan_rays(angle, r, quality, row, grid, 3.0, 0.05, out, q, rows)
    return out, q, rows


@pytest.mark.parametrize("seed", range(60))
def test_scan_rays_equals_resample_scan_and_the_nearest_columns(seed):
    """Random columns, a camera's order (angle falling with the column) but for inversions, equal
    angles (a stable order: which of two columns at one angle is taken decides the range), a few
    columns or thousands (the angle order's merges and the median's selection at every size)."""
    rng = np.random.default_rng(seed)
    n = int(rng.choice([1, 2, 3, 4, int(rng.integers(5, 300)), int(rng.integers(1000, 4000))]))
    m = int(rng.integers(2, 400))
    grid = np.linspace(-1.0, 1.0, m)
    angle = np.sort(rng.uniform(-1.2, 1.2, n))[::-1].copy()
    angle += rng.normal(0, 0.002, n) * (rng.random(n) < rng.choice([0.0, 0.3, 1.0]))  # out of order near depth jumps
    if seed % 3 == 0:
        angle = np.round(angle, 2)  # many equal angles
    angle[rng.random(n) < 0.05] = np.nan
    angle[rng.random(n) < 0.01] = np.inf
    r = np.where(rng.random(n) < 0.5, 2.0, rng.choice([1.0, 2.0, 3.5], n)) * rng.uniform(0.97, 1.03, n)
    codes = rng.random(n)
    r[codes < 0.15] = np.inf
    r[(codes >= 0.15) & (codes < 0.2)] = -np.inf
    r[(codes >= 0.2) & (codes < 0.25)] = np.nan
    quality = rng.uniform(-5, 300, n)
    row = rng.uniform(0, 900, n)
    if not np.isfinite(angle).any():
        angle[0] = 0.0
    got = _kernel_scan_rays(angle, r, quality, row, grid)
    want = _scan_rays_numpy(angle, r, quality, row, grid)
    for g, expected in zip(got, want):
        assert g.dtype == expected.dtype
        np.testing.assert_array_equal(g, expected)


def test_scan_rays_takes_equal_angles_in_column_order():
    """Columns 1 and 2 share an angle, with different ranges: the stable order takes column 1
    first (numpy's argsort kind="stable"), so the ray just above the angle interpolates from
    column 2, the one just below from column 1."""
    angle = np.array([0.2, 0.1, 0.1, 0.0])
    r = np.array([2.0, 2.0, 2.02, 2.02])
    grid = np.array([0.0, 0.0999, 0.1001, 0.2])
    out, _, rows = _kernel_scan_rays(angle, r, np.ones(4), np.arange(4.0), grid)
    assert rows.tolist() == [3.0, 1.0, 2.0, 0.0]
    np.testing.assert_array_equal(out, _scan_rays_numpy(angle, r, np.ones(4), np.arange(4.0), grid)[0])


def test_scan_rays_bridges_three_median_spacings():
    """Columns 0.01 rad apart with a hole of 0.025 rad (bridged: within three spacings) and one of
    0.035 rad (not): the median spacing, not the mean (0.0167), sets the gap."""
    angle = np.array([0.0, 0.01, 0.02, 0.045, 0.055, 0.09, 0.10])
    grid = np.array([0.035, 0.0725, 0.095])  # 0.0725: beyond half a gap from either side
    out, _, _ = _kernel_scan_rays(angle, np.full(7, 2.0), np.ones(7), np.zeros(7), grid)
    assert out[0] == 2.0 and out[1] == np.inf and out[2] == 2.0


def test_a_ray_with_a_range_has_the_row_and_quality_of_a_measured_column():
    """Ray 5 lies on column 5, whose line was REJECTED (NaN); its range is interpolated between
    columns 4 and 6, and its row and quality are theirs (the nearer in angle), so it has a time.
    Before, they were column 5's: no row (no time, the host fell back to the scan's line) and
    quality 0 (dropped by a host's min_quality)."""
    angle = np.linspace(0.1, -0.1, 11)  # a camera's columns: angle falls with the column
    r = np.full(11, 2.0)
    r[5] = np.nan
    quality = np.arange(11) * 10.0
    row = 100.0 + np.arange(11)
    row[5] = np.nan
    grid = np.linspace(-0.1, 0.1, 11)  # ray i at column 10 - i
    grid[5] += 0.001  # a little nearer column 4
    out, q, rows = _kernel_scan_rays(angle, r, quality, row, grid)
    assert np.isfinite(out).all() and np.isfinite(rows).all()
    assert (rows[5], q[5]) == (104.0, 40)
    np.testing.assert_array_equal(rows[:5], row[:5:-1][:5])


def test_scan_rays_names_bad_arguments():
    a = np.zeros(3)
    with pytest.raises(ValueError, match="no column has a finite angle"):
        K.scan_rays(np.full(3, np.nan), a, a, a, np.linspace(0, 1, 4), 3.0, 0.05, np.empty(4), np.empty(4, np.uint8),
                    np.empty(4))
    with pytest.raises(ValueError, match="gap_spacings >= 0"):
        K.scan_rays(a, a, a, a, np.linspace(0, 1, 4), np.nan, 0.05, np.empty(4), np.empty(4, np.uint8), np.empty(4))
    with pytest.raises(ValueError, match="m >= 2"):
        K.scan_rays(a, a, a, a, np.zeros(1), 3.0, 0.05, np.empty(1), np.empty(1, np.uint8), np.empty(1))


def test_resolve_refuses_a_range_gate_that_is_not_positive():
    from device.vision.fast import FastParams

    with pytest.raises(ValueError, match="max_range_sigma > 0"):
        FastParams(max_range_sigma=0.0)
