"""`laserpi demo` and `laserpi soak`: the verdict logic, and short real runs."""

from __future__ import annotations

import json
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest

from device.commands.demo import scan_errors
from device.commands.soak import rss_growth_mb, verdict
from device.sim.scene_truth import scene_truth

ROOT = Path(__file__).resolve().parents[1]


def test_rss_growth_fits_the_second_half_only():
    t = np.arange(20.0)
    warmup_then_flat = np.where(t < 10, 50e6 + 2e6 * t, 70e6)
    assert rss_growth_mb(t, warmup_then_flat) == pytest.approx(0.0, abs=1e-9)
    leak = 50e6 + 1e6 * t  # 1 MB per sample
    assert rss_growth_mb(t, leak) == pytest.approx(9.0)
    with pytest.raises(ValueError):
        rss_growth_mb(t, leak[:-1])


def test_verdict_passes_counted_gaps_and_fails_leaks_and_uncounted_losses():
    t = np.arange(10.0)
    flat = np.full(10, 40e6)
    assert verdict(10, 100, 3, 2, 1, 0, t, flat, 5.0).verdict == "PASS"
    lost = verdict(10, 100, 3, 1, 0, 0, t, flat, 5.0)
    assert lost.verdict == "FAIL" and lost.lost_uncounted == 2
    assert verdict(10, 100, 0, 0, 0, 1, t, flat, 5.0).verdict == "FAIL"  # a corrupt frame
    leak = verdict(10, 100, 0, 0, 0, 0, t, 40e6 + 2e6 * t, 5.0)
    assert leak.verdict == "FAIL" and not leak.memory_steady


def test_scan_errors_against_the_scene_truth():
    wall = scene_truth("wall", 2.0)
    a = np.linspace(-0.5, 0.5, 101)
    truth = wall.ranges(a)
    np.testing.assert_allclose(truth, 2.0 / np.cos(a), rtol=1e-9)
    measured = truth * 1.01
    measured[:10] = np.nan
    valid, compared, mean, std = scan_errors(measured, truth)
    assert (valid, compared) == (91, 91) and mean == pytest.approx(0.01) and std == pytest.approx(0.0, abs=1e-12)
    assert np.isinf(wall.ranges(np.array([1.45])))  # past the end of the 20 m wide wall
    room = scene_truth("room", 2.0)
    r = room.ranges(np.linspace(-3.1, 3.1, 50))
    assert np.isfinite(r).all() and (r > 0).all()  # a closed room: every ray hits a wall


def test_soak_short_run_on_the_mock(tmp_path):
    out = subprocess.run([sys.executable, "-m", "device.cli", "soak", "--mock", "--minutes", "0.05", "--sample-s", "0.5",
                          "--json", "--log", str(tmp_path / "serve.log")], cwd=ROOT, capture_output=True, text=True,
                         timeout=60)
    result = json.loads(out.stdout.strip().splitlines()[-1])
    assert out.returncode == 0, out.stdout + out.stderr
    assert result["verdict"] == "PASS" and result["scans"] >= 20 and result["lost_uncounted"] == 0


@pytest.mark.parametrize("command", ["demo", "soak"])
def test_a_bad_scene_is_named_before_anything_starts(command, tmp_path, capsys):
    from device.cli import main

    log = tmp_path / "serve.log"
    assert main([command, "--scene", "wal", "--log", str(log)]) == 2
    assert capsys.readouterr().out.startswith(f"laserpi {command}: unknown scene 'wal'; choose from: ")
    assert not log.exists()  # no device process was started


def test_serve_that_does_not_come_up_is_reported_with_its_reason(tmp_path):
    from device.service.child import start_serve

    with pytest.raises(RuntimeError) as exc:
        start_serve(tmp_path / "laserpi", ["--simulate", "--scene", "wal"])
    assert str(exc.value).startswith("laserpi serve did not come up (exit 2): laserpi serve: unknown scene 'wal'; ")
    assert not (tmp_path / "laserpi").exists()


@pytest.mark.parametrize("command", ["demo", "soak"])
def test_demo_and_soak_relay_a_device_process_that_did_not_come_up(command, tmp_path, monkeypatch, capsys):
    from device.cli import main
    from device.service import child

    def fails(*_, **__):
        raise RuntimeError("laserpi serve did not come up (exit 2): laserpi serve: no firmware")

    monkeypatch.setattr(child, "start_serve", fails)
    assert main([command, "--log", str(tmp_path / "serve.log")]) == 1
    assert capsys.readouterr().out.splitlines()[-1] == (f"laserpi {command}: laserpi serve did not come up (exit 2): "
                                                        "laserpi serve: no firmware")


def test_bench_process_subtracts_the_simulation_from_the_process_cpu():
    from device.bench.process import cost_per_scan

    a = {"monotonic_s": 10.0, "cpu_process_s": 5.0, "cpu_sim_hardware_s": 1.0, "cpu_sim_gpio_s": 0.02, "sim_lag_s": 0.3,
         "source": {"scans_made": 100, "cpu_camera_s": 2.0, "cpu_pipeline_s": 0.5, "cpu_laser_s": 0.1}}
    b = {"monotonic_s": 20.0, "cpu_process_s": 9.0, "cpu_sim_hardware_s": 1.5, "cpu_sim_gpio_s": 0.07, "sim_lag_s": 0.8,
         "source": {"scans_made": 200, "cpu_camera_s": 3.5, "cpu_pipeline_s": 1.2, "cpu_laser_s": 0.2}}
    r = cost_per_scan(a, b)
    assert r["scan_rate_hz"] == pytest.approx(10.0)
    # the simulated sensor's time fell 0.5 s behind in those 10 s: its 100 scans took 9.5 s of it
    assert r["sensor_scan_rate_hz"] == pytest.approx(100 / 9.5) and r["simulation_behind_pct"] == pytest.approx(5.0)
    assert r["process_ms_per_scan"] == pytest.approx(40.0)
    assert r["simulation_ms_per_scan"] == pytest.approx(20.0)  # 1.5 s render + 0.5 s hardware over 100 scans
    assert r["device_ms_per_scan"] == pytest.approx(20.0)
    # the laser step's 0.1 s less the 0.05 s it spent in the simulated GPIO queue
    assert r["pipeline_ms_per_scan"] == pytest.approx(7.0) and r["laser_sync_ms_per_scan"] == pytest.approx(0.5)
    assert r["other_ms_per_scan"] == pytest.approx(12.5)
    with pytest.raises(ValueError, match="no scans"):
        cost_per_scan(a, a)


def test_bench_process_measures_the_heartbeat_threads_wait_that_simulation_leaves_out():
    # a Pi's heartbeat thread wakes every HEARTBEAT_S (SyncedLaser._heartbeat_loop); the probe
    # does that wait and reports its own CPU, its span and its wake-ups, and ends when stopped
    from device.bench.process import heartbeat_wait_cpu

    stop, out = threading.Event(), []
    t = threading.Thread(target=lambda: out.append(heartbeat_wait_cpu(stop, 0.01)))
    t.start()
    time.sleep(0.3)
    stop.set()
    t.join(1.0)
    assert not t.is_alive()
    cpu_s, wall_s, wakeups = out[0]
    assert 0.3 <= wall_s < 0.6 and 0 <= cpu_s < wall_s
    assert 5 <= wakeups <= wall_s / 0.01 + 1  # a timed wait's wake-ups, not a busy loop's
