"""A lit frame and its unlit neighbours (device/scan/pairing.py), and when a scan's rays were
measured (device/scan/timing.py)."""

import numpy as np
import pytest

from device.camera.frame import Frame
from device.scan.pairing import NeighbourPairing
from device.scan.timing import column_times_ns, scan_timing

IMG = np.zeros((4, 4), np.uint8)


def frame(seq, t_ns=0, exposure_us=1000.0, line_ns=20000.0):
    return Frame(IMG, seq, t_ns, exposure_us, 50000.0, line_ns)


def run(flags, seqs=None):
    """(lit, unlit, other) seqs of every Neighbours, pushing frames with these lit flags."""
    pairing, out = NeighbourPairing(), []
    for s, lit in zip(seqs or range(len(flags)), flags):
        n = pairing.push(frame(s), lit)
        out += [n] if n else []
    last = pairing.flush()
    out += [last] if last else []
    return [(n.lit.seq, n.unlit.seq, n.other_unlit.seq if n.other_unlit else None) for n in out]


def test_each_lit_frame_gets_the_unlit_frames_after_and_before_it():
    assert run([False, True, False, True, False]) == [(1, 2, 0), (3, 4, 2)]
    # the stream starts lit: the first lit frame has no unlit frame before it
    assert run([True, False, True, False]) == [(0, 1, None), (2, 3, 1)]
    # the stream ends on a lit frame: it is paired with the frame before it when flushed
    assert run([False, True, False, True]) == [(1, 2, 0), (3, 2, None)]


def test_gaps_and_lit_neighbours_break_the_pairing():
    # frame 3 was dropped: lit 2 has only the frame before it; lit 4 only the one after it
    assert run([False, False, True, True, False], seqs=[0, 1, 2, 4, 5]) == [(2, 1, None), (4, 5, None)]
    # two lit frames in a row (a re-synchronised laser): each pairs with its unlit neighbour
    assert run([False, True, True, False]) == [(1, 0, None), (2, 3, None)]
    assert run([True, True]) == []
    pairing = NeighbourPairing()
    pairing.push(frame(0), False)
    pairing.push(frame(1), True)
    pairing.reset()
    assert pairing.push(frame(2), False) is None


def test_a_columns_time_is_its_rows_mid_exposure():
    f = frame(0, t_ns=10**9, exposure_us=9200.0, line_ns=18904.0)
    rows = np.array([0.0, 100.5, np.nan])
    t = column_times_ns(f, rows)
    assert t[0] == pytest.approx(10**9 - 4.6e6)
    assert t[1] == pytest.approx(10**9 - 4.6e6 + 100.5 * 18904.0)
    assert np.isnan(t[2])


def test_scan_timing_is_exact_for_rays_on_a_line_and_reports_the_residual_otherwise():
    i = np.arange(200.0)
    times = 5e8 + 1234.0 * i
    times[::7] = np.nan  # rays without a return
    s = scan_timing(times, fallback_ns=0.0)
    assert (s.first_ray_ns, s.ray_interval_ns) == (500_000_000, 1234)
    assert s.residual_ns < 1.0
    bent = 5e8 + 1e6 * ((i - 100) / 100) ** 2  # a wall seen obliquely: rows curve across the scan
    s = scan_timing(bent, fallback_ns=0.0)
    assert s.residual_ns == pytest.approx(np.max(np.abs(bent - (s.first_ray_ns + s.ray_interval_ns * i))), abs=1.0)
    assert s.residual_ns > 1e5
    none = scan_timing(np.full(10, np.nan), fallback_ns=7.6e8)
    assert (none.first_ray_ns, none.ray_interval_ns) == (760_000_000, 0)


def _scan_timing_numpy(times_ns, fallback_ns):
    """scan_timing's definition as numpy states it (the device's own before the kernel took it)."""
    t = np.asarray(times_ns, dtype=np.float64)
    i = np.nonzero(np.isfinite(t))[0]
    if i.size < 2:
        return int(round(fallback_ns)), 0, 0.0
    x, y = i - i.mean(), t[i] - t[i].mean()
    slope = round(float(np.dot(x, y) / np.dot(x, x)))
    first = float(np.mean(t[i] - slope * i))
    return int(round(first)), int(slope), float(np.max(np.abs(t[i] - (first + slope * i))))


@pytest.mark.parametrize("seed", range(20))
def test_scan_timing_is_its_least_squares_definition(seed):
    """Rays' times as a scan has them (a line of a few us per ray, bent and stepped by the rows,
    rays without a time), on a clock that has run for an hour: the same line as numpy's."""
    rng = np.random.default_rng(seed)
    n = int(rng.integers(2, 2000))
    i = np.arange(n)
    t = 3.6e12 + rng.uniform(-5e3, 5e3) * i + rng.normal(0, 3e4, n) + 2e5 * (i > n // 2)
    t[rng.random(n) < rng.choice([0.0, 0.3, 0.95])] = np.nan
    t[rng.random(n) < 0.01] = np.inf  # not a time either
    s = scan_timing(t, fallback_ns=1.5e12)
    first, interval, residual = _scan_timing_numpy(t, 1.5e12)
    assert (s.first_ray_ns, s.ray_interval_ns) == (first, interval)
    assert s.residual_ns == pytest.approx(residual, rel=1e-9, abs=1e-3)


def test_scan_timing_keeps_every_ns_on_a_clock_that_ran_for_weeks():
    """CLOCK_MONOTONIC at 30 days is 2.6e15 ns: a sum of 1640 such times (4e18) keeps no digit
    below ~500 ns, so a mean taken that way is off by a fraction of that. The kernel sums relative
    to the first ray's time: rays exactly on a line come out exact, residual 0."""
    i = np.arange(1640)
    t0 = 2_592_000 * 10**9 + 123_456_789
    times = (t0 + 1718 * i).astype(np.float64)
    s = scan_timing(times, fallback_ns=0.0)
    assert (s.first_ray_ns, s.ray_interval_ns, s.residual_ns) == (t0, 1718, 0.0)


def test_scan_timing_names_a_fallback_that_is_no_time():
    with pytest.raises(ValueError, match="fallback_ns"):
        scan_timing(np.full(3, np.nan), fallback_ns=float("nan"))


def test_a_scans_rays_are_timed_from_the_rows_their_line_was_found_in():
    from device.config import load_preset
    from device.scan.pipeline import ScanPipeline
    from device.vision.evaluation import simulated_pairs
    from device.vision.pipelines import make_pipeline

    cfg = load_preset("thesis-calibrated")
    pair = simulated_pairs(cfg, "wall:distance=2,angle=20", 1, neighbours=True)[0]
    line_ns, t = cfg.window.mode.line_time_ns, 10**9
    frames = [Frame(img, seq, t + (seq - 1) * 50_000_000, 40000.0, 50000.0, line_ns)
              for seq, img in ((0, pair.unlit_before.image), (1, pair.lit.image), (2, pair.unlit.image))]
    pipe = make_pipeline("fast-com", cfg)
    scan = ScanPipeline(pipe, 400)
    rays = scan(frames[1], frames[2], frames[0])
    meas = pipe.process(pair.lit, pair.unlit, other_unlit=pair.unlit_before)
    ok = meas.valid
    times = column_times_ns(frames[1], meas.row[ok])
    # the rays' times span the columns' own times, and ray 0 is not the frame's SensorTimestamp
    first, last = rays.first_ray_ns, rays.first_ray_ns + 399 * rays.ray_interval_ns
    assert min(first, last) >= times.min() - 2e5 and max(first, last) <= times.max() + 2e5
    assert abs(first - t) > 1e6 and rays.ray_interval_ns != 0
    assert np.isfinite(rays.ranges).sum() > 300
