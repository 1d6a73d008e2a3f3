"""GPIO edge source against libgpiod v2's documented API (mocked), and pulse placement."""

import subprocess
import sys
import json
import types

import numpy as np
import pytest

from device.camera.modes import MODE5
from device.sync.clock_map import ClockEstimate, LineFit
from device.sync.placement import (THESIS_PULSE_S, check_separation, class1_power_w, pulse_budget,
                                   roi_exposure_window, window_to_ticks)

LT = MODE5.mode.line_time_s


def _fake_gpiod(mocker, events):
    gpiod = types.ModuleType("gpiod")
    line = types.ModuleType("gpiod.line")
    line.Edge = types.SimpleNamespace(BOTH="both")
    line.Clock = types.SimpleNamespace(MONOTONIC="monotonic")
    gpiod.line = line
    gpiod.EdgeEvent = types.SimpleNamespace(Type=types.SimpleNamespace(RISING_EDGE="rise", FALLING_EDGE="fall"))
    gpiod.LineSettings = mocker.Mock(name="LineSettings", side_effect=lambda **kw: ("settings", kw))
    request = mocker.Mock(name="request")
    request.wait_edge_events.return_value = True
    request.read_edge_events.return_value = events
    gpiod.request_lines = mocker.Mock(name="request_lines", return_value=request)
    mocker.patch.dict(sys.modules, {"gpiod": gpiod, "gpiod.line": line})
    return gpiod, request


def _event(ns, kind, seqno):
    return types.SimpleNamespace(timestamp_ns=ns, event_type=kind, line_seqno=seqno, line_offset=17)


def test_gpio_edge_source_requests_both_edges_on_monotonic_and_reads_events(mocker):
    from device.sync.gpio_edges import GpioEdgeSource

    gpiod, request = _fake_gpiod(mocker, [_event(1000, "rise", 1), _event(9000, "fall", 2), _event(20000, "rise", 5)])
    with GpioEdgeSource("/dev/gpiochip0", 17) as src:
        gpiod.LineSettings.assert_called_once_with(edge_detection="both", event_clock="monotonic")
        args, kwargs = gpiod.request_lines.call_args
        assert args == ("/dev/gpiochip0",) and kwargs["consumer"] == "laserpi-sync"
        assert list(kwargs["config"]) == [17]
        assert src.read(0.01) == [(1000, True), (9000, False), (20000, True)]
        request.wait_edge_events.assert_called_with(0.01)
        assert src.lost_events == 2  # seqno 3 and 4 never arrived
        request.wait_edge_events.return_value = False
        assert src.read() == []
    request.release.assert_called_once()


def test_gpio_edge_source_without_gpiod_says_what_to_install(mocker):
    from device.sync.gpio_edges import GpioEdgeSource

    mocker.patch.dict(sys.modules, {"gpiod": None})
    with pytest.raises(RuntimeError, match="laserpi\\[pi\\]"):
        GpioEdgeSource("/dev/gpiochip0", 17)
    with pytest.raises(ValueError, match="offset"):
        GpioEdgeSource("/dev/gpiochip0", -1)


def test_roi_window_is_the_exposure_of_exactly_those_rows():
    s, e = roi_exposure_window(1.0, 0.005, LT, 200, 400)
    assert s == pytest.approx(1.0 - 0.005 + 200 * LT) and e == pytest.approx(1.0 + 400 * LT)
    # per-frame ROI rows broadcast
    s, e = roi_exposure_window(np.array([1.0, 2.0]), 0.005, LT, np.array([100, 150]), np.array([500, 600]))
    assert np.allclose(e - s, 0.005 + np.array([400, 450]) * LT)
    with pytest.raises(ValueError, match="ROI rows"):
        roi_exposure_window(1.0, 0.005, LT, 400, 200)
    with pytest.raises(ValueError, match="positive"):
        roi_exposure_window(1.0, 0.0, LT, 200, 400)


def test_separation_check_names_the_problem():
    check_separation(0.05, 0.005, LT, 300, 700, guard_s=10e-6)
    with pytest.raises(ValueError, match="does not fit"):
        check_separation(0.03, 0.02, LT, 0, 900)


def test_window_to_ticks_never_covers_less_than_asked():
    fit = LineFit(a=0.0, b=1 / (1 + 100e-6), x_mean=0.0, sxx=1.0, n_points=8, point_sigma=1e-6)
    est = ClockEstimate("gpio", ref_tick=0, ref_ns=0, tick_hz=2e6, fit=fit, n_samples=100)
    start_ns, end_ns = 1e9 + 0.3e3, 1e9 + 12.5617e6
    t0, w = window_to_ticks(start_ns, end_ns, est, 5e-6)
    assert est.mcu_to_pi_ns(t0) <= start_ns - 5e3
    assert est.mcu_to_pi_ns(t0 + w) >= end_ns + 5e3
    assert est.mcu_to_pi_ns(t0 + w) - est.mcu_to_pi_ns(t0) < end_ns - start_ns + 10e3 + 1.1e3
    with pytest.raises(ValueError):
        window_to_ticks(end_ns, start_ns, est, 0.0)


def test_pulse_budget_and_class1_power_against_the_thesis_pulse():
    b = pulse_budget(0.005, LT, 300, 700, 0.05, (True, False), guard_s=10e-6)
    assert b.pulse_s == pytest.approx(0.005 + 400 * LT + 20e-6)
    assert b.pulse_rate_hz == 10.0 and b.duty == pytest.approx(b.pulse_s * 10)
    assert b.thesis_pulse_s == THESIS_PULSE_S and b.width_ratio > 1.3
    ours, thesis = class1_power_w(b.pulse_s, 10.0), class1_power_w(THESIS_PULSE_S, 10.0)
    assert ours > thesis  # a shorter pulse is allowed more peak power
    with pytest.raises(ValueError, match="pattern"):
        pulse_budget(0.005, LT, 300, 700, 0.05, (False,))


def test_sync_sim_cli_json_and_side_by_side_report():
    out = subprocess.run([sys.executable, "-m", "device.cli", "sync-sim", "--seconds", "20", "--drift-ppm", "100",
                          "--gpio-jitter-us", "20", "--seed", "3", "--json"], capture_output=True, text=True, check=True)
    m = json.loads(out.stdout)
    for key in ("lock_frames", "p99_error_us", "max_error_us", "pulse_us", "frames_partly_unlit_after_lock"):
        assert key in m
    assert m["controller"] == "ours" and m["lock_frames"] <= 10
    text = subprocess.run([sys.executable, "-m", "device.cli", "sync-sim", "--seconds", "10"],
                          capture_output=True, text=True, check=True).stdout
    assert "ours (closed loop)" in text and "thesis (Alg. 1 + P)" in text and "17.4 ms" in text
    bad = subprocess.run([sys.executable, "-m", "device.cli", "sync-sim", "--roi-rows", "700", "300"],
                         capture_output=True, text=True)
    assert bad.returncode == 2 and "--roi-rows" in bad.stderr
