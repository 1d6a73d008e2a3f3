import json
import sys
import subprocess

import numpy as np

from device.camera.replay import ReplayCamera
from device.cli import main


def test_simulate_writes_frames_truth_and_metadata(tmp_path):
    out = tmp_path / "run"
    rc = main(["simulate", "--scene", "wall:distance=1.5,angle=20", "--frames", "3", "--seed", "2", "--out", str(out), "--png"])
    assert rc == 0
    meta = json.loads((out / "metadata.json").read_text())
    assert meta["frames"] == 3 and meta["lit"] == [True, False, True] and meta["simulated"] is True
    truth = np.load(out / "truth.npz")
    assert truth["row"].shape == (3, 1664) and truth["lit_rows"].shape == (3, 928)
    assert np.nanmin(truth["range_m"]) > 1.4
    cam = ReplayCamera(out / "frames.npz")
    frames = [cam.capture() for _ in range(3)]
    assert [f.lit for f in frames] == [True, False, True]
    # the lit frame is brighter than the dark frame where the truth puts the line
    cols = np.nonzero(np.isfinite(truth["row"][0]))[0]
    rows = np.round(truth["row"][0][cols]).astype(int)
    assert np.median(frames[0].image[rows, cols].astype(int) - frames[1].image[rows, cols]) > 10
    assert (out / "scene.png").stat().st_size > 1000


def test_simulate_bad_scene_is_a_clear_error(tmp_path, capsys):
    rc = main(["simulate", "--scene", "kitchen", "--out", str(tmp_path / "x")])
    assert rc == 2
    assert "unknown scene 'kitchen'" in capsys.readouterr().out
    assert not (tmp_path / "x").exists()  # nothing half written


def test_simulate_runs_as_a_module(tmp_path):
    r = subprocess.run([sys.executable, "-m", "device.cli", "simulate", "--scene", "empty", "--frames", "2",
                        "--off", "noise", "--out", str(tmp_path / "e")], capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    assert "0 columns with a return" in r.stdout


def test_simulate_makes_only_frames_the_sensor_mode_can_and_evaluate_takes_them(tmp_path, capsys):
    """The mode reads all its rows and blanking (1232 + 32 lines, 23.9 ms: device/camera/modes.py);
    a shorter --frame-duration-us made frames evaluate then refused as unreadable in their frame."""
    from device.config import load_preset

    mode = load_preset("thesis-calibrated").window.mode
    shortest_us = mode.min_frame_duration_s * 1e6
    assert main(["simulate", "--scene", "empty", "--frames", "2", "--frame-duration-us", "19000", "--exposure-us", "5000",
                 "--out", str(tmp_path / "short")]) == 2
    assert f"shorter than the sensor mode {mode.name}'s shortest frame, {shortest_us:.0f} us" in capsys.readouterr().out
    assert not (tmp_path / "short").exists()
    out = tmp_path / "fastest"
    assert main(["simulate", "--scene", "wall", "--frames", "4", "--frame-duration-us", f"{shortest_us + 1:.0f}",
                 "--exposure-us", "5000", "--out", str(out)]) == 0
    capsys.readouterr()
    assert main(["evaluate", "--recording", str(out / "frames.npz"), "--out", str(tmp_path / "o.npz")]) == 0
    assert "2 scan(s)" in capsys.readouterr().out
