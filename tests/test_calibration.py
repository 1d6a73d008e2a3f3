"""Calibration against simulated ground truth: accuracy targets and every degenerate capture set.

The 20-pose target check renders at half resolution (832x464, focal lengths halved) to keep the
suite fast; `laserpi calibrate --simulate --poses 20` runs it at full resolution."""

import math

import numpy as np
import pytest

from device.calibration.intrinsics import CalibrationError, detect_corners
from device.calibration.pipeline import calibrate, triangulation_table
from device.calibration.metrics import compare
from device.calibration.plane import BoardLine, fit_laser_plane
from device.calibration.simulate import scaled_config, simulate_capture
from device.calibration.target import BoardSpec
from device.config import load_preset
from device.model.camera import BrownConrady
from device.sim.checkerboard import Scene, generate_poses

SCALE = 0.5


@pytest.fixture(scope="module")
def truth():
    return scaled_config(load_preset("thesis-calibrated"), SCALE)


@pytest.fixture(scope="module")
def twenty(truth):
    poses, shots = simulate_capture(truth, 20, seed=7)
    return calibrate(poses, truth), shots


@pytest.mark.slow
def test_twenty_poses_meet_the_targets(truth, twenty):
    result, _ = twenty
    cmp = compare(truth, result.config)
    assert abs(cmp["fx_err_pct"]) < 0.5 and abs(cmp["fy_err_pct"]) < 0.5
    assert abs(cmp["cx_err_px"]) < 2 / (1 / SCALE) and abs(cmp["cy_err_px"]) < 2 / (1 / SCALE)  # 2 full-res px
    assert cmp["plane_normal_err_deg"] < 0.1
    assert abs(cmp["plane_offset_err_mm"]) < 0.5
    assert cmp["range_err_pct_at_2m"] <= 1.0  # RMS over the scan
    assert cmp["range_err_centre_pct_at_2m"] <= 1.0
    assert cmp["range_err_max_pct_at_2m"] <= 3.0  # frame corners, half resolution
    fit = result.plane_fit
    assert 0 < fit.rms_m < 0.002 and fit.inliers.mean() > 0.9


def test_view_bootstrap_uncertainty_covers_the_true_error(truth, twenty):
    """The board bootstrap misses the intrinsics' shared error; the view bootstrap includes it."""
    from device.calibration.pipeline import bootstrap_views

    result, _ = twenty
    cmp = compare(truth, result.config)
    boot = bootstrap_views(result, BoardSpec(), samples=10, seed=1)
    assert boot.samples >= 8
    assert cmp["plane_normal_err_deg"] < 4 * boot.normal_std_deg
    assert abs(cmp["fx_err_pct"]) / 100 * truth.camera.intrinsics.fx < 4 * boot.fx_std_px
    assert boot.normal_std_deg > result.plane_fit.normal_std_deg


def test_triangulation_table_matches_truth(truth, twenty):
    result, _ = twenty
    table = triangulation_table(result)
    from device.model.triangulation import params_from_plane

    p = params_from_plane(*truth.plane.to_abc(), truth.beta_rad)
    assert table["theta_deg"] == pytest.approx(math.degrees(p.theta), abs=0.1)
    assert table["psi_deg"] == pytest.approx(math.degrees(p.psi), abs=0.2)
    assert table["s_m"] == pytest.approx(p.s, abs=5e-4)


def test_laser_points_lie_on_the_true_plane(truth, twenty):
    result, _ = twenty
    n, d = np.asarray(truth.plane.normal), truth.plane.distance
    pts = np.concatenate([ln.points for ln in result.lines if len(ln.points)])
    assert len(pts) > 1000
    assert np.sqrt(np.mean((pts @ n - d) ** 2)) < 0.001


def test_distortion_model_keeps_what_the_lens_has(twenty):
    result, _ = twenty
    # the true lens has all five coefficients clearly non-zero except p2 (0.00025)
    assert isinstance(result.config.camera.distortion, BrownConrady)
    assert {"k1", "k2", "k3"} <= set(result.intrinsics.kept)
    assert result.intrinsics.rms_px < 0.2


def test_unneeded_coefficients_are_dropped(truth):
    """A lens without tangential distortion or k3: the evidence rule drops them (thesis 4.1.2)."""
    from dataclasses import replace

    lens = BrownConrady(k1=-0.04, k2=0.004)  # radial only, no fold inside the frame
    plain = replace(truth, camera=replace(truth.camera, distortion=lens))
    poses, _ = simulate_capture(plain, 14, seed=3)
    result = calibrate(poses, plain)
    assert "k3" not in result.intrinsics.kept and {"k1", "k2"} <= set(result.intrinsics.kept)
    assert result.intrinsics.selection[0]["kept"] == ["k1", "k2", "p1p2", "k3"]
    assert result.config.camera.distortion.k3 == 0.0
    assert abs(compare(plain, result.config)["fx_err_pct"]) < 0.5


# ---------------------------------------------------------------- failure modes
def test_all_boards_at_one_depth(truth):
    spec = BoardSpec()
    cam, w, h = truth.camera, truth.width, truth.height
    laser = generate_poses(cam, w, h, truth.plane, 5, seed=11, depth_range=(0.9, 0.9), laser_fraction=1.0, max_tilt_rad=0.0, face_camera=False)
    other = generate_poses(cam, w, h, truth.plane, 6, seed=12, laser_fraction=0.0)
    lit_poses, _ = simulate_capture(truth, 0, 11, poses=laser)
    dark_poses, _ = simulate_capture(truth, 0, 12, scene=Scene(laser_on=False), poses=other)
    poses = [p.__class__(f"pose_{i:03d}", p.lit, p.unlit) for i, p in enumerate(lit_poses + dark_poses)]
    with pytest.raises(CalibrationError, match="one depth.*several distances"):
        calibrate(poses, truth, spec)


def test_no_laser_on_any_board(truth):
    poses, _ = simulate_capture(truth, 5, seed=5, scene=Scene(laser_on=False))
    with pytest.raises(CalibrationError, match="no laser line found on any board"):
        calibrate(poses, truth)


def test_too_few_corners(truth):
    poses, _ = simulate_capture(truth, 3, seed=5)
    with pytest.raises(CalibrationError, match="too few corners.*need at least 4 views"):
        calibrate(poses, truth)


def test_blurred_frames(truth):
    poses, _ = simulate_capture(truth, 4, seed=5, motion_blur_px=4.0)
    with pytest.raises(CalibrationError, match="blurred"):
        calibrate(poses, truth)


def test_a_board_partly_out_of_view_is_dropped_with_a_reason(truth, twenty):
    from device.sim.checkerboard import BoardPose

    _, shots = twenty
    good = shots[0].pose
    shift = np.array([0.6 * good.translation[2], 0.0, 0.0])  # slide the board off the right edge
    out = BoardPose(good.rotation, good.translation + shift)
    poses, _ = simulate_capture(truth, 0, 9, poses=[out])
    det = detect_corners(poses[0].unlit, BoardSpec().pattern_size, "pose_out")
    assert det.corners is None
    assert "partly out of view" in det.reason and "right" in det.reason


def test_view_reasons_reach_the_result(truth, twenty):
    result, _ = twenty
    for det in result.detections:
        assert (det.corners is None) == (det.reason is not None)
        assert (det.name in result.intrinsics.poses) == (det.corners is not None)


# ---------------------------------------------------------------- plane fit on synthetic points
def _lines(points_per_board):
    return [BoardLine(f"b{i}", np.zeros((len(p), 2)), p, np.tile([0.0, 1e-3, 0.0], (len(p), 1))) for i, p in enumerate(points_per_board)]


def test_plane_through_the_optical_centre():
    rng = np.random.default_rng(0)
    boards = []
    for z in (0.4, 0.7, 1.0, 1.3):
        x = rng.uniform(-0.3, 0.3, 100)
        boards.append(np.stack([x, -0.5 * np.full(100, z), np.full(100, z)], -1) + rng.normal(0, 1e-5, (100, 3)))
    with pytest.raises(CalibrationError, match="optical centre"):
        fit_laser_plane(_lines(boards))


def test_nearly_collinear_points_at_many_depths():
    t = np.linspace(0, 1, 300)
    line = np.stack([0.3 * t, -0.2 - 0.3 * t, 0.3 + t], -1) + np.random.default_rng(1).normal(0, 1e-5, (300, 3))
    with pytest.raises(CalibrationError, match="nearly collinear"):
        fit_laser_plane(_lines([line[:100], line[100:200], line[200:]]))


def test_too_few_laser_points():
    pts = np.array([[0.0, -0.1, 0.5], [0.1, -0.1, 0.5], [0.0, -0.2, 0.6]])
    with pytest.raises(CalibrationError, match="too few laser points"):
        fit_laser_plane(_lines([pts, pts + 0.01, pts + 0.02]))


def test_plane_fit_recovers_a_known_plane_with_outliers():
    rng = np.random.default_rng(2)
    n = np.array([0.02, 0.85, 0.53])
    n /= np.linalg.norm(n)
    d = 0.05
    boards = []
    for z in (0.4, 0.6, 0.8, 1.0, 1.2):
        x = rng.uniform(-0.3, 0.3, 200)
        y = (d - n[0] * x - n[2] * z) / n[1]
        p = np.stack([x, y, np.full(200, z)], -1) + rng.normal(0, 2e-4, (200, 3))
        p[:10] += rng.normal(0, 0.05, (10, 3))  # outliers
        boards.append(p)
    fit = fit_laser_plane(_lines(boards))
    assert math.degrees(math.acos(min(1, abs(np.dot(fit.plane.normal, n))))) < 0.05
    assert fit.plane.distance == pytest.approx(d, abs=2e-4)
    assert fit.inliers.sum() < 1000 and fit.inliers.sum() >= 950


def test_a_fisheye_lens_gets_the_fisheye_model(truth):
    from dataclasses import replace

    from device.model.camera import CameraModel, KannalaBrandt

    k = truth.camera.intrinsics
    fisheye = replace(truth, camera=CameraModel(replace(k, fx=230.0, fy=230.0), KannalaBrandt(0.05, -0.02, 0.003, 0.0)))
    poses, _ = simulate_capture(fisheye, 12, seed=4)
    result = calibrate(poses, fisheye)
    assert isinstance(result.config.camera.distortion, KannalaBrandt)
    cmp = compare(fisheye, result.config)
    assert abs(cmp["fx_err_pct"]) < 0.5 and abs(cmp["cy_err_px"]) < 1.0
    assert cmp["plane_normal_err_deg"] < 0.3
    # Brown-Conrady was tried and lost on held-out corners
    assert result.intrinsics.selection[-1]["model"] == "kannala-brandt"


def test_extracted_line_matches_the_true_laser_segment(truth, twenty):
    """The line pixels found on each board, intersected with the *true* board plane, lie on the
    renderer's true laser segment: bias < 0.1 rows, scatter < 0.3 rows."""
    from device.calibration.plane import line_points

    result, shots = twenty
    checked = 0
    for ln in result.lines:
        shot = shots[int(ln.name.split("_")[1])]
        if len(ln.points) < 20:
            continue
        assert len(shot.laser_points) > 1, f"{ln.name}: line found on a board the laser does not cross"
        on_true = line_points(ln.name, ln.pixels, truth.camera, shot.pose.rotation, shot.pose.translation)
        a, b = shot.laser_points[0], shot.laser_points[-1]
        u = (b - a) / np.linalg.norm(b - a)
        rel = on_true.points - a
        perp = rel - (rel @ u)[:, None] * u
        rows = np.einsum("ij,ij->i", perp, on_true.row_steps) / np.einsum("ij,ij->i", on_true.row_steps, on_true.row_steps)
        assert abs(np.median(rows)) < 0.1 and np.std(rows) < 0.3, (ln.name, np.median(rows), np.std(rows))
        checked += 1
    assert checked >= 8


def test_poses_are_deterministic_by_seed_and_cover_the_frame(truth):
    from device.model.camera import project_points

    cam, w, h = truth.camera, truth.width, truth.height
    a = generate_poses(cam, w, h, truth.plane, 12, seed=5)
    b = generate_poses(cam, w, h, truth.plane, 12, seed=5)
    c = generate_poses(cam, w, h, truth.plane, 12, seed=6)
    assert all(np.array_equal(p.translation, q.translation) and np.array_equal(p.rotation, q.rotation) for p, q in zip(a, b))
    assert not np.allclose(a[0].translation, c[0].translation)
    depths = [p.translation[2] for p in a]
    assert min(depths) < 0.5 and max(depths) > 1.0
    centres = np.array([project_points(p.to_camera(BoardSpec().outline().mean(0)), cam) for p in a])
    assert centres[:, 0].min() < w / 3 and centres[:, 0].max() > 2 * w / 3 and centres[:, 1].max() > h / 2


def test_detected_corners_match_the_rendered_truth(truth, twenty):
    """Anti-aliased rendering and sub-pixel detection agree with the true projection."""
    from device.model.camera import project_points

    result, shots = twenty
    errs = []
    for det in result.detections:
        if det.corners is not None:
            shot = shots[int(det.name.split("_")[1])]
            true_px = project_points(shot.pose.to_camera(BoardSpec().object_points()), truth.camera)
            errs.append(np.linalg.norm(det.corners - true_px, axis=1))
    errs = np.concatenate(errs)
    assert len(errs) >= 15 * 54
    assert np.sqrt(np.mean(errs**2)) < 0.15 and errs.max() < 0.6
