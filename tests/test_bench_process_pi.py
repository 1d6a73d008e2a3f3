"""`laserpi bench process --stats FILE`: the real CPU figure of a running serve (a Pi user's
measurement), from its stats file; the simulated mode's estimate stays labelled an estimate."""

import json
import threading
import time

import pytest

from device.bench.process import cost_per_scan, measure_running
from device.cli import main


def snapshot(t, scans, process_s, camera_s, pipeline_s, laser_s):
    return {"monotonic_s": t, "cpu_process_s": process_s, "cpu_sim_hardware_s": 0.0, "cpu_sim_gpio_s": 0.0,
            "source": {"scans_made": scans, "cpu_camera_s": camera_s, "cpu_pipeline_s": pipeline_s, "cpu_laser_s": laser_s}}


def test_on_a_pi_the_camera_capture_is_the_devices_own_cost():
    a, b = snapshot(0.0, 0, 1.0, 0.5, 0.2, 0.1), snapshot(10.0, 100, 5.0, 1.5, 1.2, 0.6)
    real = cost_per_scan(a, b, simulated=False)
    assert real["device_ms_per_scan"] == 40.0 and real["scan_rate_hz"] == 10.0  # 4 s CPU over 100 scans
    assert real["sensor_scan_rate_hz"] == 10.0 and real["simulation_behind_pct"] == 0.0  # no simulation to lag
    assert real["other_ms_per_scan"] == 40.0 - 10.0 - 5.0  # capture included in "other"
    assert cost_per_scan(a, b)["device_ms_per_scan"] == 30.0  # simulated: rendering is not the device's


def test_it_reads_a_running_serves_stats_file(tmp_path, capsys):
    stats = tmp_path / "stats.json"
    stats.write_text(json.dumps(snapshot(0.0, 0, 1.0, 0.5, 0.2, 0.1)))

    def later():
        time.sleep(0.1)
        stats.write_text(json.dumps(snapshot(2.0, 20, 1.6, 0.6, 0.4, 0.2)))

    threading.Thread(target=later).start()
    r = measure_running(stats, 0.4)
    assert r["scans"] == 20 and abs(r["device_ms_per_scan"] - 30.0) < 1e-9
    assert main(["bench", "process", "--stats", str(tmp_path / "none.json"), "--seconds", "0.01"]) == 2
    assert "no stats file" in capsys.readouterr().out
    assert main(["bench", "process", "--stats", str(stats), "--seconds", "0.01"]) == 2  # no scans in between
    assert "no scans" in capsys.readouterr().out
    with pytest.raises(SystemExit) as exit_:  # a span of no time measures nothing
        main(["bench", "process", "--stats", str(stats), "--seconds", "0"])
    assert exit_.value.code == 2 and "--seconds: must be a finite positive number" in capsys.readouterr().err
