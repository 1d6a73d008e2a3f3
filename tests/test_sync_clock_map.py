"""Clock mapping: lower-envelope GPIO map, ping fallback, pulse-wise pairing; accuracy vs truth."""

import numpy as np
import pytest

from device.sync.clock_map import (REFIT_EVERY, REFIT_FROM, EdgePairing, GpioClockMap, PingClockMap, Window,
                                   lower_envelope_fit, refit_due)

TICK_HZ = 2e6


def _pairs(rng, n, drift_ppm=100.0, jitter=20e-6, latency=3e-6, outliers=0.0, offset_s=5.0):
    """(ticks, gpio ns, truth function tick -> true Pi ns) for pulses every 50 ms."""
    ticks = np.arange(n) * 100_000 + 1_000_000
    true_s = offset_s + ticks / (TICK_HZ * (1 + drift_ppm * 1e-6))
    late = latency + rng.exponential(jitter, n)
    out = rng.random(n) < outliers
    late[out] += rng.uniform(1e-4, 2e-3, out.sum())
    ns = np.round((true_s + late) * 1e9).astype(np.int64)
    return ticks, ns, lambda t: (offset_s + t / (TICK_HZ * (1 + drift_ppm * 1e-6))) * 1e9


def test_envelope_fit_is_unbiased_and_its_sigma_is_honest():
    rng = np.random.default_rng(3)
    errs, sig = [], []
    for _ in range(300):
        x = np.arange(256) * 0.05 - 12.8
        y = 1e-3 + x * (1 - 50e-6) + rng.exponential(20e-6, x.size)
        f = lower_envelope_fit(x, y)
        errs.append(f.predict(0.1) - (1e-3 + 0.1 * (1 - 50e-6)))
        sig.append(f.sigma(0.1))
    errs, sig = np.array(errs), np.array(sig)
    assert abs(errs.mean()) < 0.5e-6
    assert 0.6 < errs.std() / sig.mean() < 1.4
    assert np.mean(np.abs(errs) < 4 * sig) > 0.99


def test_envelope_fit_of_three_pulses_keeps_its_slope_when_the_block_minima_cluster():
    """Three pulses' rise and fall pairs (8.6 ms wide, 100 ms apart) fall in two blocks of three;
    here the first block's minimum is the second rise and the second block's the second fall,
    8.6 ms apart with 23 us between their latencies (as seed 0 of the sync simulator's ROI rows
    50-150 had it). A line through those two was 2700 ppm off, 830 us at 0.2 s beyond the last
    pair (its sigma said so: 834 us). The block middles, 190 ms apart, give the slope then: 16 ppm,
    5 us there, sigma 113 us (one point's spread over their lever: each middle is one point)."""
    x = np.array([0.0, 0.0086, 0.1, 0.1086, 0.2, 0.2086]) - 0.2086
    late = np.array([40, 42, 2, 25, 45, 40]) * 1e-6
    y = 1e-3 + x * (1 - 100e-6) + late
    f = lower_envelope_fit(x, y, prior_sigma=50e-6)
    at = 0.2
    err = f.predict(at) - (1e-3 + at * (1 - 100e-6))
    assert abs(f.b - (1 - 100e-6)) < 300e-6
    assert abs(err) < 100e-6 and abs(err) < 3 * f.sigma(at)
    # the well-spread minima of many blocks still give the slope (the unbiased fit above)
    x = np.arange(48) * 0.05 - 2.35
    f = lower_envelope_fit(x, 1e-3 + x * (1 - 100e-6) + np.random.default_rng(0).exponential(20e-6, x.size))
    assert f.sxx == pytest.approx(np.sum((x[::3][:16] - x[::3][:16].mean()) ** 2), rel=0.5)


def test_envelope_fit_of_three_pulses_has_an_honest_sigma_where_it_is_placed():
    """Three pulses' pairs, 0.2 s beyond the last, with a jitter 4x the prior (the fit cannot
    measure it from six points): the error stays within 3 sigma 95 % of the time (a block
    middle is one point, so the slope from the middles has one point's spread over their lever;
    taken as a median of three it was 92 %)."""
    rng = np.random.default_rng(0)
    rises = np.arange(3) * 0.1
    x = np.sort(np.r_[rises, rises + 0.0086]) - 0.2086
    z = []
    for _ in range(3000):
        y = x * (1 - 100e-6) + 3e-6 + rng.exponential(200e-6, x.size)
        f = lower_envelope_fit(x, y, prior_sigma=50e-6)
        z.append((f.predict(0.2) - 0.2 * (1 - 100e-6)) / f.sigma(0.2))
    assert np.mean(np.abs(z) < 3) > 0.95


def test_envelope_fit_rejects_bad_shapes():
    with pytest.raises(ValueError, match="at least 2"):
        lower_envelope_fit(np.array([1.0]), np.array([1.0]))
    with pytest.raises(ValueError, match="1-D"):
        lower_envelope_fit(np.zeros((2, 2)), np.zeros((2, 2)))


def test_gpio_map_recovers_offset_and_drift_despite_late_outliers():
    rng = np.random.default_rng(1)
    ticks, ns, truth = _pairs(rng, 400, drift_ppm=-250.0, outliers=0.02)
    m = GpioClockMap(TICK_HZ, gpio_latency_min_s=3e-6, window=256)
    for t, n in zip(ticks, ns):
        m.add(int(t), int(n))
    est = m.estimate()
    assert est.source == "gpio"
    assert est.drift_ppm == pytest.approx(-250.0, abs=2.0)
    nxt = ticks[-1] + 200_000
    err = float(est.mcu_to_pi_ns(nxt)) - truth(nxt)
    assert abs(err) < 3e3  # ns
    assert abs(err) < 5 * float(est.sigma_s(nxt)) * 1e9
    back = float(est.pi_to_mcu_tick(est.mcu_to_pi_ns(nxt)))
    assert back == pytest.approx(nxt, abs=1e-3)


def test_gpio_map_removes_impossible_early_pairs():
    rng = np.random.default_rng(2)
    ticks, ns, truth = _pairs(rng, 200)
    ns = ns.copy()
    ns[[50, 120, 180]] -= 400_000  # 400 us early: not an interrupt latency, a wrong pairing
    m = GpioClockMap(TICK_HZ, window=256)
    for t, n in zip(ticks, ns):
        m.add(int(t), int(n))
    est = m.estimate()
    assert m.rejected == 3
    assert abs(float(est.mcu_to_pi_ns(ticks[-1])) - truth(ticks[-1])) < 3e3


def test_ping_map_is_a_lower_accuracy_fallback_and_its_bounds_hold():
    rng = np.random.default_rng(4)
    up_min, down_min = 0.56e-3, 1.16e-3  # PING and PONG differ in length: the midpoint would be biased
    drift = 80e-6
    maps = {"known minima": PingClockMap(TICK_HZ, up_min, down_min), "unknown": PingClockMap(TICK_HZ)}
    for k in range(256):
        t1 = 1.0 + 0.05 * k
        up = up_min + rng.uniform(0, 1e-3)
        down = down_min + rng.uniform(0, 1e-3)
        tick = int((t1 + up) * TICK_HZ * (1 + drift))
        for m in maps.values():
            m.add(int(t1 * 1e9), tick, int((t1 + up + down) * 1e9))
    probe = int(15.0 * TICK_HZ * (1 + drift))
    for name, m in maps.items():
        est = m.estimate()
        err = float(est.mcu_to_pi_ns(probe)) * 1e-9 - 15.0
        sigma = float(est.sigma_s(probe))
        assert abs(err) < 4 * sigma, name
    assert float(maps["known minima"].estimate().sigma_s(probe)) < 100e-6
    # minima that the link contradicts (a faster exchange) fall back to the whole round trip
    wrong = PingClockMap(TICK_HZ, up_min_s=5e-3, down_min_s=5e-3)
    wrong.add(0, 2000, 3_000_000)
    wrong.add(50_000_000, 102_000, 53_000_000)
    wrong.add(100_000_000, 202_000, 103_000_000)
    assert wrong.contradicted == 3 and float(wrong.estimate().sigma_s(202_000)) > 100e-6
    with pytest.raises(ValueError, match="before it was sent"):
        wrong.add(10, 0, 5)
    with pytest.raises(ValueError, match=">= 0"):
        PingClockMap(TICK_HZ, -1.0)


def test_pairing_ignores_glitches_that_do_not_look_like_the_pulse():
    rng = np.random.default_rng(5)
    ticks, ns, truth = _pairs(rng, 300, jitter=5e-6)
    m = GpioClockMap(TICK_HZ)
    for t, n in zip(ticks[:200], ns[:200]):
        m.add(int(t), int(n))
    est = m.estimate()
    pairing = EdgePairing()
    width = 20_000  # ticks: a 10 ms pulse
    for rise in ticks[200:210]:
        pairing.add_mcu(int(rise), int(rise + width))
        r_ns = int(truth(rise) + 4e3)
        f_ns = int(truth(rise + width) + 4e3)
        pairing.add_gpio(r_ns - 50_000, True)  # a glitch 50 us before the true edge
        pairing.add_gpio(r_ns, True)
        pairing.add_gpio(f_ns, False)
    pairs = pairing.pair(est, now_ns=int(truth(ticks[215])), max_window_s=0.0125)
    assert len(pairs) == 20
    for tick, n in pairs:
        assert 0 < n - truth(tick) < 10e3  # the true edges, never the glitch


def test_gpio_map_window_follows_a_drift_change():
    rng = np.random.default_rng(6)
    m = GpioClockMap(TICK_HZ, window=256)
    ticks = np.arange(1200) * 100_000
    rate = np.where(ticks < 600 * 100_000, 100e-6, 110e-6)  # the oscillator warms up by 10 ppm
    true_s = np.cumsum(np.r_[0.0, np.diff(ticks) / (TICK_HZ * (1 + rate[1:]))])
    for t, s in zip(ticks, true_s):
        m.add(int(t), int(round((s + 3e-6 + rng.exponential(20e-6)) * 1e9)))
    est = m.estimate()
    assert est.drift_ppm == pytest.approx(110.0, abs=1.0)
    nxt = ticks[-1] + 100_000
    truth = (true_s[-1] + 100_000 / (TICK_HZ * (1 + 110e-6))) * 1e9
    assert abs(float(est.mcu_to_pi_ns(nxt)) - truth) < 3e3


def test_a_full_window_refits_at_a_share_of_it_and_the_line_between_refits_stays_honest():
    # below REFIT_FROM every point refits; a full window of 256 every 32nd (REFIT_SHARE), never
    # more rarely than its share, never more often than REFIT_EVERY
    assert all(refit_due(n, 1) for n in range(2, REFIT_FROM))
    assert not refit_due(256, 31) and refit_due(256, 32)
    assert not refit_due(REFIT_FROM, REFIT_EVERY - 1) and refit_due(REFIT_FROM, REFIT_EVERY)
    # between refits the map extrapolates its older line: where the controller places the next
    # pulses (1-3 pulses ahead) it must stay within 5 of its own sigmas of the truth
    rng = np.random.default_rng(7)
    ticks, ns, truth = _pairs(rng, 900, drift_ppm=80.0)
    m = GpioClockMap(TICK_HZ, gpio_latency_min_s=3e-6, window=256)
    fits, misses, checked = set(), 0, 0
    for i, (t, n) in enumerate(zip(ticks, ns)):
        m.add(int(t), int(n))
        est = m.estimate()
        if est is None or i < 300:
            continue
        fits.add(est.ref_tick)
        for ahead in (100_000, 300_000):
            nxt = int(t) + ahead
            err = abs(float(est.mcu_to_pi_ns(nxt)) - truth(nxt))
            misses += err > 5 * float(est.sigma_s(nxt)) * 1e9
            checked += 1
    assert len(fits) == pytest.approx(600 / 32, abs=2)  # the cadence above, not every point
    assert misses <= 0.005 * checked


def test_window_keeps_its_newest_row_through_compaction_masking_and_clearing():
    w = Window(4)
    assert w.last() is None
    for i in range(11):  # past the buffer's end (2 x size): the rows are moved to its front
        w.append(i, 10 * i)
        assert w.last() == (i, 10 * i) and type(w.last()[0]) is int
    assert w.a.tolist() == [7, 8, 9, 10]
    w.keep(np.array([True, True, True, False]))  # the newest row removed: the one before is the newest
    assert w.last() == (9, 90) and w.b.tolist() == [70, 80, 90]
    w.keep(np.zeros(3, bool))
    assert w.last() is None and len(w) == 0
    w.append(1, 2)
    w.clear()
    assert w.last() is None
