"""`laserpi calibrate`: run on a capture folder, --simulate, and capture with a fake camera."""

import json
import math

import numpy as np
import pytest

from device.calibration.capture import capture_poses, render_progress
from device.calibration.pipeline import save_capture_dir
from device.calibration.simulate import scaled_config, simulate_capture
from device.calibration.target import BoardSpec
from device.camera.base import EndOfRecording
from device.camera.frame import Frame
from device.camera.modes import MODE5
from device.cli import main
from device.config import load_config, load_preset


@pytest.fixture(scope="module")
def capture():
    truth = scaled_config(load_preset("thesis-calibrated"), 0.5)
    poses, shots = simulate_capture(truth, 9, seed=21)
    return truth, poses


def test_run_writes_config_and_report(tmp_path, capture, capsys):
    truth, poses = capture
    save_capture_dir(poses, tmp_path / "set")
    out = tmp_path / "sensor.toml"
    assert main(["calibrate", "run", str(tmp_path / "set"), "--out", str(out), "--json", "--bootstrap", "0"]) == 0
    summary = json.loads(capsys.readouterr().out)
    cfg = load_config(out)
    assert cfg.camera.intrinsics.fx == pytest.approx(truth.camera.intrinsics.fx, rel=0.01)
    assert math.degrees(math.acos(abs(np.dot(cfg.plane.normal, truth.plane.normal)))) < 0.3
    assert summary["views"] == 9 and summary["theta_deg"] > 0
    report = json.loads((tmp_path / "sensor_report" / "report.json").read_text())
    assert set(report) >= {"camera", "views", "laser_plane", "triangulation"}
    assert report["triangulation"]["calibrated"]["theta_deg"] == pytest.approx(summary["theta_deg"])
    assert report["triangulation"]["original"]["s_m"] > 0
    assert all(v["used"] == (v["reason"] is None) for v in report["views"].values())
    for png in ("reprojection.png", "plane_residuals.png", "coverage.png"):
        assert (tmp_path / "sensor_report" / png).stat().st_size > 1000


def test_run_on_a_folder_without_pairs_is_a_clear_error(tmp_path, capsys):
    (tmp_path / "pose_000_unlit.png").write_bytes(b"")
    assert main(["calibrate", "run", str(tmp_path), "--out", str(tmp_path / "s.toml")]) == 1
    assert "no matching pose_000_lit.png" in capsys.readouterr().err
    assert not (tmp_path / "s.toml").exists()


def test_simulate_prints_the_comparison(tmp_path, capsys):
    out = tmp_path / "sim.toml"
    rc = main(["calibrate", "--simulate", "--poses", "10", "--seed", "3", "--scale", "0.5", "--bootstrap", "3", "--out", str(out), "--json"])
    assert rc == 0
    cmp = json.loads(capsys.readouterr().out)
    for key in ("fx_err_pct", "fy_err_pct", "plane_normal_err_deg", "plane_offset_err_mm", "range_err_pct_at_2m"):
        assert key in cmp and math.isfinite(cmp[key])
    assert abs(cmp["fx_err_pct"]) < 1.0
    assert cmp["view_bootstrap_samples"] >= 2 and cmp["view_bootstrap_normal_std_deg"] > 0
    assert load_config(out).post_calibration is not None or cmp["postcal_order"] == [-1, -1]
    assert (tmp_path / "sim_report" / "correction.png").exists()


class FakeCamera:
    """Plays frames from a list, as a camera backend would deliver them."""

    def __init__(self, frames, width, height):
        self.frames, self.width, self.height, self.line_time_ns = list(frames), width, height, MODE5.mode.line_time_ns
        self.started = self.stopped = False

    def start(self):
        self.started = True

    def stop(self):
        self.stopped = True

    def capture(self, timeout_s=1.0):
        if not self.frames:
            raise EndOfRecording("done")
        return self.frames.pop(0)


def _frame(img, seq, lit):
    return Frame(img, seq, seq * 50_000_000, 40000.0, 50000.0, MODE5.mode.line_time_ns, lit)


def test_capture_keeps_still_new_poses_only(capture):
    truth, poses = capture
    frames, seq = [], 0
    plan = [(0, 3), (1, 1), (2, 3), (0, 3)]  # pose 1 only once (moving), pose 0 again (not new)
    for idx, repeats in plan:
        for _ in range(repeats):
            frames += [_frame(poses[idx].lit, seq, True), _frame(poses[idx].unlit, seq + 1, False)]
            seq += 2
    cam = FakeCamera(frames, truth.width, truth.height)
    seen = []
    saved = []
    kept = capture_poses(cam, 5, BoardSpec().pattern_size, on_progress=seen.append, on_pose=saved.append)
    assert len(kept) == 2 and cam.started and cam.stopped and saved == kept
    assert np.array_equal(kept[0].unlit, poses[0].unlit) and np.array_equal(kept[1].lit, poses[2].lit)
    text = render_progress(seen[-1])
    assert text.startswith("[##...] 2/5") and "|" in text
    assert seen[-1].coverage.sum() == 2 * 54


def test_capture_needs_to_know_lit_frames(capture):
    truth, poses = capture
    from device.calibration.intrinsics import CalibrationError

    frames = [_frame(poses[0].lit, 0, None), _frame(poses[0].unlit, 1, None)]
    with pytest.raises(CalibrationError, match="lit-frames"):
        capture_poses(FakeCamera(frames, truth.width, truth.height), 1, BoardSpec().pattern_size)
    kept = capture_poses(FakeCamera(frames * 2, truth.width, truth.height), 1, BoardSpec().pattern_size, lit_parity=0)
    assert len(kept) == 1 and np.array_equal(kept[0].lit, poses[0].lit)
