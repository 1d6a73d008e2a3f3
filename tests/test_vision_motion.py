"""The pipeline on a moving robot (issue 16): phantoms from a moved background, columns that
cannot be trusted, the static accuracy with both unlit neighbours, and reprocessing a recording."""

import dataclasses
import json
import math
import re

import numpy as np
import pytest

from device.bench.motion import _no_turn, _pipelines, _process, score, sequence
from device.cli import main
from device.config import load_preset, with_operating_point
from device.sim.render import RenderOptions
from device.sim.scene import get_scene, with_motion
from device.vision.evaluation import FramePair, nearest_true_range, run_pipeline, simulated_pairs
from device.vision.measurements import ColumnStatus
from device.vision.pipelines import make_pipeline

CFG = load_preset("thesis-calibrated")
MIN_M = CFG.operating_point.min_m
#: The operating point these tests' cases were found at: the 9.2 ms exposure before it became 10 ms
#: (a whole period of 100 Hz mains flicker, device/model/flicker.py). The cases are properties of
#: those frames (a phantom a check stops, a target a check meets): at 10 ms these seeds do not all
#: show them, so the tests marked so keep the frames, and the pipeline, they were found on.
CFG_9MS = with_operating_point(CFG, exposure_us=9200.0)
#: The renderer's moving background on a 4 px grid, bilinearly interpolated (its default before
#: issue 16's 1 px frames, device/sim/render.py step 9): the grid is fixed to the sensor, so a
#: texture's sharp edge changes its shape as it moves, a change of the background between the
#: frames that no motion explains. Some checks on a moved background have their cases there only.
#: Its motion blur in time slices 4 px of image motion apart, as it was when they were found
#: (sharp copies; the renderer's default is now 1 px: test_sim_motion.py
#: test_motion_blur_is_a_smear_not_a_few_sharp_copies).
COARSE = RenderOptions(motion_step=4, motion_blur_px=4.0, max_time_slices=12)
#: The background point-sampled, not imaged through the lens (render.py lens_blur): a texture's
#: edge a step within a row, as the renderer drew every background before, and as another
#: renderer's frames may. The checks such edges need have their cases there.
SHARP = RenderOptions(background_lens=False)


@pytest.fixture(scope="module")
def turning_office():
    """The office in 3x the indoor light, the robot turning at 45 deg/s: 2 lit frames."""
    return sequence(CFG, with_motion(get_scene("office"), yaw_rate_deg_s=45, ambient_scale=3), 2, 0)


@pytest.fixture(scope="module")
def still_office():
    """The office in 3x the indoor light, the robot still: 2 lit frames."""
    return sequence(CFG, with_motion(get_scene("office"), ambient_scale=3), 2, 0)


@pytest.fixture(scope="module")
def sharp_office_turning_in_10x_light():
    """90 deg/s in 10x the indoor light (seed 0), the background point-sampled (SHARP): 3 lit
    frames, the cases of two checks of a turned frame."""
    return sequence(CFG, with_motion(get_scene("office"), yaw_rate_deg_s=90, ambient_scale=10), 3, 0, SHARP)


def test_a_moved_background_gives_no_phantoms_and_no_false_no_return(turning_office, still_office):
    pipes = _pipelines(CFG)
    before = score([(_process("fast one-unlit", pipes["fast one-unlit"], p), p.truth) for p in turning_office], MIN_M)
    checks = score([(_process("fast no turn", pipes["fast no turn"], p), p.truth) for p in turning_office], MIN_M)
    now = score([(_process("fast", pipes["fast"], p), p.truth) for p in turning_office], MIN_M)
    still = score([(_process("fast", pipes["fast"], p), p.truth) for p in still_office], MIN_M)
    # the pipeline as it was: many ranges > 5 % off, and "nothing there" on many columns of a wall
    assert before["gross"] > 50 and before["blind_fraction"] > 0.1
    for s in (checks, now):
        assert s["false_returns"] == 0
        assert s["gross"] <= before["gross"] / 5 and s["gross_fraction"] < 0.005
        assert s["sigma_pct"] < before["sigma_pct"]
    # the checks on a moved background alone: a column whose residue could hide a line is
    # REJECTED, never "nothing there"
    assert checks["blind_fraction"] < 0.02
    # the neighbours turned to the lit frame: it is judged as a still one (a dark surface far
    # away gives too weak a line there too), and keeps most of what a still robot measures
    assert now["blind_fraction"] <= still["blind_fraction"] + 0.01
    assert now["valid_fraction"] > 0.9 * still["valid_fraction"] and now["valid_fraction"] > checks["valid_fraction"] + 0.2


def test_a_column_that_cannot_be_trusted_is_rejected_never_no_return(turning_office):
    pipe = _no_turn(make_pipeline("fast-com", CFG, CFG.operating_point.min_m, CFG.operating_point.max_m))
    p = turning_office[1]
    meas = pipe.process(p.lit, p.unlit, p.lit_rows, other_unlit=p.unlit_before)
    rejected = meas.status == ColumnStatus.REJECTED
    assert rejected.sum() > 100 and np.all(np.isnan(meas.range[rejected]))
    has = np.isfinite(p.truth.range_m[meas.column])
    assert np.mean(np.isposinf(meas.range[has])) < 0.02  # a surface is almost never called "nothing there"


@pytest.mark.parametrize("limits_m", [(None, None), (0.1, 10.0)], ids=["configured-band", "evaluate-band"])
@pytest.mark.parametrize("distance,max_sigma_pct", [(2, 0.36), (3, 0.7)])
def test_a_still_wall_is_measured_as_accurately_with_both_neighbours(distance, max_sigma_pct, limits_m):
    # the simulator's 40 ms exposure: a bright background, whose shot noise alone made the
    # neighbours' blocks differ by ~0.9 levels on average; over the 384-row band of evaluate's
    # depth limits (median 157 levels) half of the 2 m wall's columns counted as moved and 22 %
    # lost their lines (valid 0.78 against 1.00) before the bar for the average followed the
    # noise (the configuration's own limits give a 896-row band, median 40 levels, whose
    # average stayed below the old bar)
    pairs = simulated_pairs(CFG, f"wall:distance={distance},reflectivity=0.9", 3, distance - 2, neighbours=True)
    one = [FramePair(p.lit, p.unlit, p.truth, p.lit_rows) for p in pairs]
    s_one, s_both = (run_pipeline(make_pipeline("fast-com", CFG, *limits_m), pp) for pp in (one, pairs))
    assert s_both.range_error_near(distance)[1] < max_sigma_pct
    assert s_both.range_error_near(distance)[1] <= s_one.range_error_near(distance)[1] * 1.05
    assert s_both.summary()["valid_fraction"] >= s_one.summary()["valid_fraction"] - 0.01


def test_a_bright_wall_before_a_dark_backdrop_does_not_count_as_moved():
    # shot noise follows each column's own light: a 1 m wide 90 % wall 2 m ahead, a 3 % wall
    # behind it at 4 m, the simulator's 40 ms exposure. With the noise bar taken over the whole
    # frame (the backdrop's noise) 7 % of the near wall's columns lost their lines with both
    # neighbours (valid 0.93 against 1.00 with one); taken per column, they keep them
    from device.sim.scene import scene_from_dict

    scene = scene_from_dict({"name": "narrow", "wall": [
        {"from": [2.0, -0.5], "to": [2.0, 0.5], "reflectivity": 0.9, "texture": "plain"},
        {"from": [4.0, -20.0], "to": [4.0, 20.0], "reflectivity": 0.03, "texture": "plain"}]})
    pairs = simulated_pairs(CFG, scene, 3, 0, neighbours=True)
    one = [FramePair(p.lit, p.unlit, p.truth, p.lit_rows) for p in pairs]
    s_one, s_both = (run_pipeline(make_pipeline("fast-com", CFG, 0.1, 10.0), pp) for pp in (one, pairs))
    assert s_one.valid_fraction_within(2.5) > 0.99
    assert s_both.valid_fraction_within(2.5) >= s_one.valid_fraction_within(2.5) - 0.015


def test_the_range_gate_meets_the_gross_error_target_on_the_still_office():
    # (CFG_9MS: the frames this case was found on)
    # still office, 3x light: dim lines far away (1 row is 5-8 % of range there), a depth edge
    # bridged by the fit, an outlier beside a shadow gap reporting the fit
    from device.vision.pipelines import DEVICE_VARIANT

    pairs = sequence(CFG_9MS, with_motion(get_scene("office"), ambient_scale=3), 3, 0, SHARP)
    op = CFG_9MS.operating_point
    assert DEVICE_VARIANT == "fast-com-track-gated"  # the device runs the gate
    ungated = make_pipeline("fast-com-track", CFG_9MS, op.min_m, op.max_m)
    off = score([(_process("fast", ungated, p), p.truth) for p in pairs], MIN_M)
    gated = make_pipeline(DEVICE_VARIANT, CFG_9MS, op.min_m, op.max_m)
    assert gated.params.max_range_sigma == 0.015
    on = score([(_process("fast", gated, p), p.truth) for p in pairs], MIN_M)
    assert off["gross_fraction"] > 0.002 and off["false_returns"] > 0  # the gate off: the failure
    assert on["gross_fraction"] <= 0.001 and on["false_returns"] == 0
    assert on["valid_fraction"] > 0.75 and on["sigma_pct"] < off["sigma_pct"]


def test_driving_forward_leaves_no_phantom_line_from_a_moved_edge():
    # (CFG_9MS: the frames this case was found on)
    # 1 m/s towards the office in 3x light: horizontal edges cross the rows between the unlit
    # frames, and each leaves a bright band in the difference that looks like a line at ~0.7 m
    # (the wall is at 2.3-2.5 m). A change a few rows high counts as motion (block by block, not
    # only the column's mean), and the checks on a moved background stop them
    import dataclasses

    from device.vision.pipelines import DEVICE_VARIANT
    from device.vision.fast import FastPipeline

    # (seed 2 of the renderer's coarse frames, COARSE: on its 1 px frames no seed 0-3 shows them;
    # on seed 0's coarse frames the column-mean test alone has caught them since moved_level 0.9)
    pairs = sequence(CFG_9MS, with_motion(get_scene("office"), speed_m_s=1.0, ambient_scale=3), 3, 2, COARSE)
    op = CFG_9MS.operating_point
    device = make_pipeline(DEVICE_VARIANT, CFG_9MS, op.min_m, op.max_m)
    measured = [(_process("fast", device, p), p.truth) for p in pairs]
    now = score(measured, MIN_M)
    # no phantom line (the target beside it: at most 0.1 % gross errors; one column of
    # the side wall at 3 m, where a row is worth 6 % of range, is one row off)
    assert _phantoms(measured) == 0
    assert now["gross_fraction"] <= 0.001 and now["false_returns"] == 0 and now["valid_fraction"] > 0.3
    # two checks stop them, each alone: the block test, and the neighbours' agreement beside
    # moved columns (test_driving_forward_an_edge_that_moved_a_row_beside_moved_columns_is_no_line)
    for off in ({"moved_block_level": math.inf}, {"agree_reach_columns": 0}):
        alone = FastPipeline(CFG_9MS, dataclasses.replace(device.params, **off), op.min_m, op.max_m)
        assert _phantoms([(_process("fast", alone, p), p.truth) for p in pairs]) == 0
    without = FastPipeline(CFG_9MS, dataclasses.replace(device.params, moved_block_level=math.inf, agree_reach_columns=0),
                           op.min_m, op.max_m)
    assert _phantoms([(_process("fast", without, p), p.truth) for p in pairs]) >= 5
    # driving straight is no turn (device/vision/yaw.py's residue test): the neighbours are
    # judged as they are, bit for bit as without the turn
    unturned = [_process("fast", _no_turn(device), p) for p in pairs]
    for (m, _), u in zip(measured, unturned):
        assert np.array_equal(m.status, u.status) and np.array_equal(m.range, u.range, equal_nan=True)


def _device_and_without(off: dict, cfg=CFG):
    import dataclasses

    from device.vision.pipelines import DEVICE_VARIANT
    from device.vision.fast import FastPipeline

    op = cfg.operating_point
    device = make_pipeline(DEVICE_VARIANT, cfg, op.min_m, op.max_m)
    return device, FastPipeline(cfg, dataclasses.replace(device.params, **off), op.min_m, op.max_m)


def test_turning_in_bright_light_keeps_much_of_the_wall(still_office):
    # 90 deg/s in 3x light: each unlit neighbour is turned to the lit frame (device/vision/yaw.py),
    # and the frame is then judged as a still one, the columns only one neighbour saw (the sides)
    # against that one: most of the wall is measured, as at rest. Without the turn, the textured
    # back wall's residue is taken out with the background's trend (its checks, below): ~half
    # of the columns; before either, 3 % of that wall was measured
    pairs = sequence(CFG, with_motion(get_scene("office"), yaw_rate_deg_s=90, ambient_scale=3), 3, 0)
    device, _ = _device_and_without({})
    still = score([(_process("fast", device, p), p.truth) for p in still_office], MIN_M)
    for pipe, share, wall_share in ((device, 0.9 * still["valid_fraction"], 0.6), (_no_turn(device), 0.4, 0.35)):
        measured = [(_process("fast", pipe, p), p.truth) for p in pairs]
        now = score(measured, MIN_M)
        assert now["gross_fraction"] <= 0.001 and now["false_returns"] == 0
        assert now["blind_fraction"] <= still["blind_fraction"] + 0.01
        assert now["valid_fraction"] > share
        wall = sum(int(np.sum(m.valid & (t.surface[m.column] == 0) & np.isfinite(t.range_m[m.column]))) for m, t in measured)
        assert wall / sum(int(np.sum((t.surface == 0) & np.isfinite(t.range_m))) for _, t in measured) > wall_share


def test_a_turned_frame_still_needs_its_lines_to_stand_above_where_the_neighbours_disagree(
        sharp_office_turning_in_10x_light):
    # 90 deg/s in 10x light (seed 0): the turned neighbours agree but for a fraction of a row at
    # sharp horizontal edges, where one's resampling put the edge apart from the other's; there
    # the lit frame shows one-row bright ridges that pass for lines. With the turned background
    # as read back (resample_slack inf, edge_ratio 0: the safeguards test_vision_yaw checks), a
    # line must stand agree_ratio x above that disagreement: without it, 21 columns > 5 % off,
    # with it 9 (7 of them one such ridge, at 0.83 m before the wall at 2.86 m, which the
    # safeguards remove: the device keeps 2, 0.04 %; before the read-back followed the rolling
    # shutter, 18 and under 0.1 %; how many the ridge spans moves with the read-back's last
    # decimals). With the safeguards, the check still keeps the rows a turn smears over a depth
    # edge (the desk before the back wall) out at other points of `laserpi bench motion`
    # (BENCHMARKS.md)
    pairs = sharp_office_turning_in_10x_light
    device, as_read = _device_and_without({"resample_slack": math.inf, "edge_ratio": 0.0})
    _, without = _device_and_without({"resample_slack": math.inf, "edge_ratio": 0.0, "agree_ratio": 0.0})
    gross = {name: score([(_process("fast", pipe, p), p.truth) for p in pairs], MIN_M)
             for name, pipe in (("device", device), ("as read", as_read), ("without", without))}
    assert gross["device"]["gross_fraction"] <= 0.001
    assert gross["without"]["gross"] >= 15 and gross["without"]["gross"] - gross["as read"]["gross"] >= 8


def test_driving_forward_an_edge_that_moved_a_row_beside_moved_columns_is_no_line():
    # 1 m/s towards the office in 3x light (seed 3): a horizontal edge moves down a row a frame,
    # its blocks change by 2 levels between the unlit neighbours (under the bar for one block, 3)
    # and the column's mean by 0.6: the columns count as still, and the edge's residue passed as a
    # line at 0.72 m where the wall is at 2.4 m (7 columns). Beside moved columns a line must
    # stand agree_ratio x above where the neighbours disagree along it
    pairs = sequence(CFG, with_motion(get_scene("office"), speed_m_s=1.0, ambient_scale=3), 3, 3, SHARP)
    device, without = _device_and_without({"agree_reach_columns": 0})
    measured = [(_process("fast", device, p), p.truth) for p in pairs]
    assert _phantoms(measured) == 0 and score(measured, MIN_M)["gross_fraction"] <= 0.001
    assert _phantoms([(_process("fast", without, p), p.truth) for p in pairs]) >= 5


@pytest.mark.parametrize("off,point", [
    ({"lit_ridge_fraction": 0.0}, dict(yaw_rate_deg_s=90, ambient_scale=3, seed=0)),
    ({"moving_min_run": 1}, dict(yaw_rate_deg_s=14, ambient_scale=3, seed=0)),
    ({"texture_ridge_ratio": 0.0}, dict(yaw_rate_deg_s=90, ambient_scale=3, seed=2)),
])
def test_each_check_on_a_moved_background_is_needed(off, point):
    # without each, lines that are not the laser's get through on these frames (more than 0.1 %
    # gross errors); with all, none. Judged without the turn (these checks guard any motion no
    # turn explains: driving, something crossing; the turn makes these frames a still scene's)
    seed = point.pop("seed")
    pairs = sequence(CFG, with_motion(get_scene("office"), **point), 3, seed, SHARP)
    device, without = (_no_turn(p) for p in _device_and_without(off))
    assert score([(_process("fast", device, p), p.truth) for p in pairs], MIN_M)["gross_fraction"] <= 0.001
    assert score([(_process("fast", without, p), p.truth) for p in pairs], MIN_M)["gross"] >= 5


def _phantoms(measured) -> int:
    """Valid ranges nearer than 80 % of the nearest truth: a line that is not the laser's."""
    n = 0
    for meas, truth in measured:
        with np.errstate(invalid="ignore"):
            n += int(np.sum(meas.valid & (meas.range < 0.8 * nearest_true_range(truth, meas.column))))
    return n


def test_evaluate_reprocesses_a_recording_per_image_column(tmp_path, capsys):
    sim = tmp_path / "sim"
    assert main(["simulate", "--scene", "person", "--frames", "5", "--out", str(sim), "--exposure-us", "9200",
                 "--analog-gain", "4", "--yaw-rate-deg-s", "20", "--off", "speckle"]) == 0
    out = tmp_path / "out.npz"
    capsys.readouterr()
    assert main(["evaluate", "--recording", str(sim / "frames.npz"), "--out", str(out), "--truth",
                 str(sim / "truth.npz"), "--json"]) == 0
    result = json.loads(capsys.readouterr().out)
    assert result["variant"] == "fast-com-track-gated" and result["scans"] == 3  # the device's pipeline, lit frames 0, 2, 4
    assert result["columns_with_return"] > 1000 and result["false_return_fraction"] == 0
    z = np.load(out)
    W = CFG.width
    assert z["row"].shape == (3, W) and z["points"].shape == (3, W, 3) and z["status"].shape == (3, W)
    assert list(z["lit_seq"]) == [0, 2, 4]
    ok = z["status"] == ColumnStatus.OK
    assert ok.sum() > 1000 and np.all(np.isfinite(z["points"][ok])) and np.all(np.isnan(z["row"][~ok]))
    truth = np.load(sim / "truth.npz")
    row_err = np.abs(z["row"][ok] - truth["row"][[0, 2, 4]][ok])
    assert np.nanmedian(row_err) < 0.3
    # the truth names the surfaces each column's light fell on (a moving sensor), and evaluate
    # reads them back
    from device.commands.evaluate import _load_truth

    span, has = truth["range_span_m"], np.isfinite(truth["range_m"])
    assert span.shape == (5, W, 2) and np.all(np.isfinite(span[has])) and np.all(np.isnan(span[~has]))
    loaded = _load_truth(str(sim / "truth.npz"), CFG)
    np.testing.assert_array_equal(loaded[2].range_span_m, span[2])
    # the reference processes every other column: the others are marked
    assert main(["evaluate", "--recording", str(sim / "frames.npz"), "--out", str(out), "--pipeline", "reference"]) == 0
    z = np.load(out)
    assert np.all(z["status"][:, 1::2] == 255) and np.any(z["status"][:, ::2] == ColumnStatus.OK)


def test_mains_flicker_at_20_scans_per_second_needs_a_whole_period_of_exposure(tmp_path, capsys):
    """100 Hz lamps (50 Hz mains) at 20 scans/s: frames 25 ms apart are 2.5 flicker periods, so an
    unlit neighbour's rows see the opposite phase of the lit frame's (device/model/flicker.py). A
    9.2 ms exposure keeps 17 % of the lamps' modulation in the difference and lines are lost (and
    evaluate says why); the 10 ms exposure the configuration now asks for cancels it: as many
    lines as without flicker."""
    from device.config import dumps_config, load_preset
    from device.design.report import sensor_at_rate

    at20, _ = sensor_at_rate(load_preset("thesis-calibrated"), 20.0)
    config = tmp_path / "at20.toml"
    config.write_text(dumps_config(at20))
    valid = {}
    for exposure_us, depth in ((9200, 0.0), (9200, 0.4), (10000, 0.0), (10000, 0.4)):
        sim = tmp_path / f"e{exposure_us}-{depth}"
        assert main(["simulate", "--scene", "office", "--config", str(config), "--frames", "5", "--out", str(sim),
                     "--frame-duration-us", "25000", "--exposure-us", str(exposure_us), "--analog-gain", "4",
                     "--ambient-scale", "3", "--flicker-hz", "100", "--flicker-depth", str(depth)]) == 0
        capsys.readouterr()
        assert main(["evaluate", "--recording", str(sim / "frames.npz"), "--config", str(config), "--truth",
                     str(sim / "truth.npz")]) == 0
        out = capsys.readouterr().out
        assert ("100 Hz flicker of mains lighting is not cancelled" in out) == (exposure_us == 9200)
        valid[exposure_us, depth] = float(re.search(r"valid ([0-9.]+) of", out).group(1))
    assert valid[9200, 0.4] < 0.75 * valid[9200, 0.0]
    assert valid[10000, 0.4] == pytest.approx(valid[10000, 0.0], abs=0.01)


def test_evaluate_names_what_is_wrong_with_a_recording(tmp_path, capsys):
    from device.camera.frame import Frame
    from device.camera.replay import save_recording

    small = tmp_path / "small.npz"
    save_recording(small, [Frame(np.zeros((10, 20), np.uint8), i, i * 10**6, 100.0, 1000.0, 10.0, lit=i % 2 == 0)
                           for i in range(4)])
    assert main(["evaluate", "--recording", str(small)]) == 2
    assert "frames are 20x10" in capsys.readouterr().out
    unknown = tmp_path / "unknown.npz"
    save_recording(unknown, [Frame(np.zeros((CFG.height, CFG.width), np.uint8), i, i * 10**6, 100.0, 1000.0, 10.0)
                             for i in range(3)])
    assert main(["evaluate", "--recording", str(unknown)]) == 2
    assert "3 frames have no lit flag" in capsys.readouterr().out
    assert main(["evaluate", "--scene", "wall", "--out", str(tmp_path / "x.npz")]) == 2
    assert "--out and --truth go with --recording" in capsys.readouterr().out
    # what only sets up a simulated scene is refused with a recording, not ignored
    assert main(["evaluate", "--recording", str(unknown), "--frames", "5", "--yaw-rate-deg-s", "90", "--no-lit-rows"]) == 2
    assert "--frames, --no-lit-rows, --yaw-rate-deg-s set up a simulated scene" in capsys.readouterr().out


def test_evaluate_refuses_frames_and_truth_that_do_not_belong_together(tmp_path, capsys):
    """A lit frame exposed 4x as long as its unlit neighbours (the background's change would
    pass for lines), a truth that is not the recording's (an unlit frame's, or two for one
    frame), a truth file numpy cannot read and a seq beyond int64: each refused, naming what is
    wrong, and nothing written."""
    import zipfile

    from device.camera.frame import Frame
    from device.camera.replay import save_recording

    def frames(lit_exposure_us=100.0, seq0=0):
        return [Frame(np.zeros((CFG.height, CFG.width), np.uint8), seq0 + i, 10**9 + i * 10**6,
                      lit_exposure_us if i % 2 == 0 else 100.0, 1000.0, 10.0, lit=i % 2 == 0) for i in range(4)]

    rec, out = tmp_path / "rec.npz", tmp_path / "out.npz"
    save_recording(rec, frames(400.0))
    assert main(["evaluate", "--recording", str(rec), "--out", str(out)]) == 2
    assert "lit frame seq 0 (400 us) and its unlit neighbour seq 1 (100 us) differ in exposure" in capsys.readouterr().out
    save_recording(rec, frames(100.004))  # within half a line (10 ns): the same exposure, as reported
    assert main(["evaluate", "--recording", str(rec), "--out", str(out)]) == 0
    out.unlink()
    save_recording(rec, frames(100.010))  # a line longer: another exposure
    assert main(["evaluate", "--recording", str(rec), "--out", str(out)]) == 2
    assert "differ in exposure" in capsys.readouterr().out
    save_recording(rec, frames(99.996))
    assert main(["evaluate", "--recording", str(rec), "--out", str(out)]) == 0
    out.unlink()
    capsys.readouterr()
    W, H = CFG.width, CFG.height
    nan = np.full((2, W), np.nan)
    arrays = dict(row=nan, range_m=nan, angle_rad=nan, points=np.full((2, W, 3), np.nan), surface=np.full((2, W), -1))
    truth = tmp_path / "truth.npz"
    for seq, lit_rows, message in (([0, 2], np.zeros((2, H), bool), "the truth of frame seq 0 has no lit rows"),
                                   ([2, 2], np.ones((2, H), bool), "frame seq 2 has 2 truths")):
        np.savez(truth, seq=np.array(seq), lit_rows=lit_rows, **arrays)
        assert main(["evaluate", "--recording", str(rec), "--out", str(out), "--truth", str(truth)]) == 2
        assert message in capsys.readouterr().out
    np.savez(truth, seq=np.array([object(), object()]), lit_rows=np.ones((2, H), bool), **arrays)
    assert main(["evaluate", "--recording", str(rec), "--out", str(out), "--truth", str(truth)]) == 2
    assert f"--truth {truth}: not a readable truth .npz of laserpi simulate" in capsys.readouterr().out
    truth.write_text("not an archive")
    assert main(["evaluate", "--recording", str(rec), "--out", str(out), "--truth", str(truth)]) == 2
    assert f"--truth {truth}: not a readable truth .npz of laserpi simulate" in capsys.readouterr().out
    np.save(tmp_path / "truth.npy", np.zeros(3))  # one array, not an archive
    assert main(["evaluate", "--recording", str(rec), "--out", str(out), "--truth", str(tmp_path / "truth.npy")]) == 2
    assert "not a readable truth .npz of laserpi simulate (one ndarray" in capsys.readouterr().out
    np.savez_compressed(truth, seq=np.array([0, 2]), lit_rows=np.ones((2, H), bool), **arrays)
    damaged = bytearray(truth.read_bytes())  # as laserpi simulate writes it, its deflated data broken:
    h = zipfile.ZipFile(truth).infolist()[0].header_offset  # the first member's local header
    data = h + 30 + int.from_bytes(damaged[h + 26 : h + 28], "little") + int.from_bytes(damaged[h + 28 : h + 30], "little")
    damaged[data] = 0xFF  # its first deflate block of the reserved type 3, which zlib refuses (zlib.error)
    truth.write_bytes(bytes(damaged))
    assert main(["evaluate", "--recording", str(rec), "--out", str(out), "--truth", str(truth)]) == 2
    assert f"--truth {truth}: not a readable truth .npz of laserpi simulate" in capsys.readouterr().out
    # a compression method zipfile does not know (NotImplementedError), in the truth and in the recording
    np.savez_compressed(truth, seq=np.array([0, 2]), lit_rows=np.ones((2, H), bool), **arrays)
    for damaged_file, message in ((truth, f"--truth {truth}: not a readable truth .npz"),
                                  (rec, f"{rec}: not a readable .npz recording")):
        damaged = bytearray(damaged_file.read_bytes())
        damaged[damaged.find(b"PK\x01\x02") + 10] = 99  # the central directory's compression method
        damaged_file.write_bytes(bytes(damaged))
        assert main(["evaluate", "--recording", str(rec), "--out", str(out), "--truth", str(truth)]) == 2
        assert message in capsys.readouterr().out
    save_recording(rec, frames())
    save_recording(rec, frames())
    with np.load(rec) as z:
        np.savez(rec, **{k: z[k] for k in z.files if k != "seq"}, seq=np.arange(4, dtype=np.uint64) + np.uint64(2**63))
    assert main(["evaluate", "--recording", str(rec), "--out", str(out)]) == 2
    assert "seq is 9223372036854775808: a count must be a whole number >= 0 and below 2**63" in capsys.readouterr().out
    assert not out.exists()


def test_evaluate_writes_its_results_whole_or_not_at_all(tmp_path, capsys):
    """A refusal leaves no OUT.npz and never an overwritten input; a recording without the
    optional readout_offset_rows is reprocessed with a warning saying what was assumed."""
    from device.camera.frame import Frame
    from device.camera.replay import save_recording

    rec = tmp_path / "rec.npz"
    save_recording(rec, [Frame(np.zeros((CFG.height, CFG.width), np.uint8), i, i * 10**6, 100.0, 1000.0, 10.0,
                               lit=i % 2 == 0) for i in range(4)])
    before = rec.read_bytes()
    out = tmp_path / "out.npz"
    (tmp_path / "dir.npz").mkdir()
    for bad_out, message in ((tmp_path / "out", "the results are an .npz file"), (rec, "is the --recording file"),
                             (tmp_path / "none" / "out.npz", "no directory"), (tmp_path / "dir.npz", "is a directory")):
        assert main(["evaluate", "--recording", str(rec), "--out", str(bad_out)]) == 2
        assert message in capsys.readouterr().out
    assert rec.read_bytes() == before and sorted(p.name for p in tmp_path.iterdir()) == ["dir.npz", "rec.npz"]
    W = CFG.width
    nan = np.full((2, W), np.nan)
    truth = tmp_path / "truth.npz"
    np.savez(truth, seq=np.array([0, 2]), row=nan, range_m=nan[:, :-1], angle_rad=nan, points=np.full((2, W, 3), np.nan),
             surface=np.full((2, W), -1), lit_rows=np.ones((2, CFG.height), bool))
    assert main(["evaluate", "--recording", str(rec), "--out", str(out), "--truth", str(truth)]) == 2
    assert f"range_m has shape (2, {W - 1}), (2, {W}) expected" in capsys.readouterr().out
    assert not out.exists()
    with np.load(rec) as z:
        np.savez(rec, **{k: z[k] for k in z.files if k != "readout_offset_rows"})
    assert main(["evaluate", "--recording", str(rec), "--out", str(out)]) == 0
    assert "warning: the recording has no readout_offset_rows, taken as 0" in capsys.readouterr().out
    with np.load(out) as z:
        assert z["status"].shape == (2, W) and list(z["lit_seq"]) == [0, 2]


@pytest.mark.parametrize("bad", [{"moved_block_level": 0.0}, {"moved_block_ratio": -1.0}, {"moved_mean_ratio": -1.0},
                                 {"turn_share": 0.0},
                                 {"max_turn_deg": 0.0}, {"max_turn_deg": 60.0}, {"agree_ratio": -1.0},
                                 {"agree_reach_columns": -1}, {"agree_share": 0.0}, {"resample_slack": -1.0},
                                 {"edge_ratio": -0.5}, {"mixed_tol": -0.01}, {"mixed_tol": 0.05}, {"mixed_jump": 0.0}])
def test_step_0_refuses_motion_thresholds_that_mean_nothing(bad):
    from device.vision.fast import FastParams

    with pytest.raises(ValueError, match=f"{next(iter(bad))}"):
        FastParams(**bad)


def test_the_range_gate_needs_the_line_fit():
    from device.vision.fast import FastParams

    with pytest.raises(ValueError, match="max_range_sigma needs the line fit"):
        FastParams(smooth_half=0, max_range_sigma=0.015)
    with pytest.raises(ValueError, match="max_range_sigma needs the line fit"):
        make_pipeline("fast-com-raw-gated", CFG)


def test_ridges_tell_a_line_from_an_edge_and_a_dip():
    from device.vision.fast import _ridges

    column = np.full(80, 10, np.int16)
    column[20] += 8  # a ridge one row high
    column[30:33] += 5  # a band 3 rows high
    column[40:] += 20  # an edge: 10 -> 30
    column[60] -= 6  # a dip
    out = _ridges(np.repeat(column[:, None], 3, axis=1), 4)
    assert out.shape == (80, 3) and out.dtype == np.uint8 and np.all(out == out[:, :1])
    assert out[20, 0] == 8 and out[31, 0] == 5 and out[30, 0] == out[32, 0] == 5
    assert np.count_nonzero(out[:, 0]) == 4  # nothing at the edge or the dip, nor in the first and last 4 rows


def test_a_moved_backgrounds_trend_is_taken_out_and_the_line_kept():
    # a line 1.3 px wide on a lit frame whose background differs from the unlit frames' mean by a
    # slow, tall residue (a moved texture, +-25 levels, up to 1.8 levels a row): against the
    # trend-corrected background the difference is the line alone, and the noise side has no
    # dips; a column that did not move keeps the mean
    from device.vision.fast import _moved_backgrounds

    rows, W = 80, 40
    r = np.arange(rows, dtype=float)[:, None]
    c = np.arange(W, dtype=float)[None, :]
    mean = np.clip(60 + 20 * np.sin(c / 7.0) + 0 * r, 0, 255)
    residue = 25 * np.sin(r / 14.0 + c / 11.0)
    line = 30 * np.exp(-0.5 * ((r - 40.3) / 1.3) ** 2)
    lit = np.clip(np.rint(mean + residue + line), 0, 255).astype(np.uint8)
    background = np.rint(mean).astype(np.uint8)
    moved = np.ones(W, bool)
    moved[-4:] = False
    line_bg, noise_bg = _moved_backgrounds(lit, background, moved, 11)
    assert line_bg.dtype == noise_bg.dtype == np.uint8 and line_bg.shape == lit.shape
    # the columns the 5-column smoothing keeps apart from the image's edge and the still columns
    plain = lit[:, 2:-8].astype(int) - background[:, 2:-8]
    diff = lit[:, 2:-8].astype(int) - line_bg[:, 2:-8]
    assert np.abs(plain[:34]).max() >= 20  # against the mean alone the residue is as bright as the line
    assert np.abs(diff[:34]).max() <= 3 and np.abs(diff[47:]).max() <= 3 and diff.min() >= -4
    assert (noise_bg[:, 2:-8].astype(int) - lit[:, 2:-8]).max() <= 6  # no dips beside the line
    # the line is kept (the envelope rises under it by about the slope times its half height),
    # and its centre of mass is less biased than against the mean alone
    assert diff[40].min() >= 0.6 * 30

    def com_bias(d):
        d = np.clip(d[36:45], 0, None).astype(float)
        return np.abs((d * np.arange(36, 45)[:, None]).sum(0) / d.sum(0) - 40.3).max()

    assert com_bias(diff) < com_bias(plain)
    assert np.array_equal(line_bg[:, -4:], background[:, -4:]) and np.array_equal(noise_bg[:, -4:], background[:, -4:])


@pytest.mark.parametrize("bad", [{"trend_rows": 9}, {"moving_min_run": 0}, {"lit_ridge_fraction": -0.1}])
def test_step_0_refuses_a_trend_window_no_taller_than_a_line_and_checks_that_mean_nothing(bad):
    from device.vision.fast import FastParams

    with pytest.raises(ValueError, match=next(iter(bad))):
        FastParams(**bad)


def test_a_saturated_line_on_a_moved_background_is_kept():
    # near a wall the line saturates the lit frame, and its difference counts as full scale (255)
    # however bright the background; the lit frame itself can rise only to 255. Vertical stripes
    # (120 +- 30 levels) moved 3 px each way between the unlit neighbours (a turning robot), the
    # line 400 levels high at 1.3 px sigma: the one-neighbour pipeline measures it, so must the
    # device's (before the fix the lit frame's ridge test rejected every column)
    from device.vision.fast import FastPipeline

    device, _ = _device_and_without({})
    pipe = FastPipeline(CFG, device.params)
    H, W = CFG.height, CFG.width
    rng = np.random.default_rng(1)
    r = np.arange(H, dtype=float)[:, None]
    c = np.arange(W, dtype=float)[None, :]
    y = pipe.top + 60

    def frame(shift, line):
        x = 120 + 30 * np.sin(2 * np.pi * (c + shift) / 23) + line * np.exp(-0.5 * ((r - y) / 1.3) ** 2)
        return np.clip(np.rint(x + rng.standard_normal((H, W))), 0, 255).astype(np.uint8)

    lit, after, before = frame(0, 400), frame(3, 0), frame(-3, 0)
    assert np.mean(lit[y] == 255) > 0.99
    one = pipe.process(lit, after, np.ones(H, bool))
    pipe.reset()
    both = pipe.process(lit, after, np.ones(H, bool), other_unlit=before)
    assert one.valid.sum() > 1000
    assert both.valid.sum() >= 0.95 * one.valid.sum()


def test_too_close_needs_the_return_against_both_neighbours():
    # a wall 4 cm away (below the sensor's minimum range) while turning at 90 deg/s: it is
    # "too close" (-inf) in its columns; a moved edge in the near rows, brighter in the lit frame
    # than in one neighbour only, is not (before: 36-42 such columns a frame here). Beside the
    # wall's ends the turn swept its edge over a few columns during the exposure: the near wall
    # was there for part of it (under half of the line's light: the truth says no return), and
    # those may say "too close"; no column farther away may
    from device.vision.measurements import ColumnStatus

    pairs = sequence(CFG, with_motion(get_scene("near"), yaw_rate_deg_s=90, ambient_scale=3), 2, 0)
    device, _ = _device_and_without({})
    sweep_rad = math.radians(90) * CFG.operating_point.exposure_us * 1e-6  # the turn in an exposure
    angle = device.geometry.column_angle
    for p in pairs:
        meas = _process("fast", device, p)
        truly = nearest_true_range(p.truth, meas.column) < MIN_M
        close = meas.status == ColumnStatus.TOO_CLOSE
        assert np.sum(close & truly) >= 0.95 * truly.sum()
        wall, false = np.flatnonzero(truly), np.flatnonzero(close & ~truly)
        ends = wall[[0, -1]]  # the wall's ends (one wall across the middle of the image)
        assert np.all(np.diff(wall) == 1)
        assert all(np.min(np.abs(angle[ends] - angle[c])) <= sweep_rad for c in false)
        assert score([(meas, p.truth)], MIN_M)["false_too_close"] == false.size


def test_a_person_crossing_before_a_still_robot_is_judged_without_the_agreement_check():
    # 16-17 % of the columns moved, under agree_share: the still wall beside the person keeps
    # its lines as at rest, however strict the check would be. At agree_ratio 6 the check,
    # applied beside the person, takes a few of them (4 columns of these 3 frames with the
    # renderer's continuous motion blur, 12 with its sharp copies before). At the
    # device's ratio it would take none of these either now: the 0-7 columns a frame over
    # seeds 0-4 it took before were fragments of the wall between gated columns, which now
    # continue their run (test_a_line_seen_but_not_measured_continues_its_run_in_a_turned_frame)
    pairs = sequence(CFG, with_motion(get_scene("person"), ambient_scale=3), 3, 2)
    _, device = _device_and_without({"agree_ratio": 6.0})
    _, without = _device_and_without({"agree_ratio": 6.0, "agree_reach_columns": 0})
    _, everywhere = _device_and_without({"agree_ratio": 6.0, "agree_share": 0.05})
    for p in pairs:
        m, w = _process("fast", device, p), _process("fast", without, p)
        assert np.array_equal(m.status, w.status) and np.array_equal(m.range, w.range, equal_nan=True)
    assert sum(int(np.sum(_process("fast", everywhere, p).status != _process("fast", device, p).status))
               for p in pairs) >= 3


def test_a_background_that_moved_by_just_under_a_level_counts_as_moved():
    # (CFG_9MS: the frames this case was found on)
    import dataclasses

    from device.vision.fast import FastPipeline

    # the person crossing while the robot turns at 45 deg/s (seed 1): where nothing is in the
    # laser's plane, the lit frame stands ~2.3 levels above the mean of its unlit neighbours (a
    # moved smooth background, not linear in time), and the one-sided noise level does not see
    # that; its 8-column block changed by 0.95 levels between the neighbours. Counted as moved
    # (moved_level 0.9), its residue's trend is taken out; at 1.0 a faint phantom at 0.96 m stays
    # (the renderer's coarse frames, COARSE: on its 1 px frames no seed 0-3 shows such a pedestal)
    # (without the turn, which makes these frames still ones: the threshold is for motion no turn
    # explains; and without the neighbours' agreement beside moved columns, which stops it too)
    pairs = sequence(CFG_9MS, with_motion(get_scene("person"), yaw_rate_deg_s=45, ambient_scale=3), 3, 1, COARSE)
    device, before = (_no_turn(p) for p in _device_and_without({"moved_level": 1.0}, CFG_9MS))
    device, before = (FastPipeline(CFG_9MS, dataclasses.replace(p.params, agree_reach_columns=0), MIN_M,
                                   CFG_9MS.operating_point.max_m) for p in (device, before))
    assert device.params.moved_level < 0.95
    assert score([(_process("fast", device, p), p.truth) for p in pairs], MIN_M)["false_returns"] == 0
    assert score([(_process("fast", before, p), p.truth) for p in pairs], MIN_M)["false_returns"] >= 3


def test_an_edge_crossing_a_few_blocks_rows_while_turning_counts_as_moved():
    # 90 deg/s in the default light (seed 0): a slanted edge moves 4 rows up a column between the
    # unlit neighbours, and the lit frame's edge lies between theirs, which leaves a bright band
    # two rows high in lit - mean: a phantom line at 0.9 m where the wall is at 2.9 m (3 columns
    # of the third frame). Its blocks changed by 3 levels. The bar for one block is the median
    # block change sensor noise makes, and that was taken between the neighbours, where the
    # turn raised it to 5; within one frame it stays at the floor of 3, and the columns moved
    pairs = sequence(CFG, with_motion(get_scene("office"), yaw_rate_deg_s=90), 3, 0)
    device, _ = _device_and_without({})
    measured = [(_process("fast", device, p), p.truth) for p in pairs]
    assert _phantoms(measured) == 0
    assert score(measured, MIN_M)["gross_fraction"] <= 0.001 and score(measured, MIN_M)["valid_fraction"] > 0.7


def test_a_line_nearer_than_the_range_in_a_moved_column_is_rejected_not_too_close():
    # 0.5 m/s towards the office in 3x light: in one column a moved edge's residue at the near
    # edge of the region of interest (40 rows from the laser's line, the wall at 2.55 m) passed
    # every check on a moved background, and triangulated nearer than the range: "too close"
    # (-inf), a false obstacle. A line there is REJECTED instead; the near rows of columns
    # without a line still tell "too close" (the test above)
    from device.vision.measurements import ColumnStatus

    # (the renderer's coarse frames, COARSE, where a moved edge leaves that residue)
    pairs = sequence(CFG, with_motion(get_scene("office"), speed_m_s=0.5, ambient_scale=3), 3, 0, COARSE)
    device, _ = _device_and_without({})
    measured = [(_process("fast", device, p), p.truth) for p in pairs]
    assert score(measured, MIN_M)["false_too_close"] == 0
    meas = measured[1][0]
    assert meas.status[79] == ColumnStatus.REJECTED and np.isnan(meas.range[79])


def test_a_stripe_aliasing_with_the_frame_step_is_not_too_close(sharp_office_turning_in_10x_light):
    # 90 deg/s in 10x light: a bright stripe in the lit frame's near rows where both neighbours
    # show dark ones (the periodic texture aliases with the 50 ms frame step) brightens the lit
    # frame against both; the neighbours are that bright within the distance the background moves,
    # the laser's return is not; within that distance of the frame's edge, where the stripe may
    # have come in from outside the image, such a return is REJECTED (5 columns here). Judged
    # with the turned background as read back (resample_slack inf): held against it within a
    # row, the lit frame shows a weak line candidate in those columns, which are then not
    # without a line, and step 7 does not look at them
    pairs = sharp_office_turning_in_10x_light
    device, as_read = _device_and_without({"resample_slack": math.inf})
    _, near_only = _device_and_without({"resample_slack": math.inf, "moving_reach_columns": 0})
    for pipe in (device, as_read):
        assert score([(_process("fast", pipe, p), p.truth) for p in pairs], MIN_M)["false_too_close"] == 0
    assert score([(_process("fast", near_only, p), p.truth) for p in pairs], MIN_M)["false_too_close"] >= 15


def test_bench_motion_picks_points_by_labels_that_hold_commas(capsys):
    from device.bench.motion import wanted_points

    assert wanted_points(None) is None
    assert wanted_points("yaw 90, 1x; poster wall, yaw 14 ;still") == {"yaw 90, 1x", "poster wall, yaw 14", "still"}
    for bad in ("yaw 91", ";", "still; yaw 91"):
        with pytest.raises(ValueError, match="unknown sweep point"):
            wanted_points(bad)
    assert main(["bench", "motion", "--points", "yaw 90, 2x"]) == 2
    assert "unknown sweep point(s) yaw 90, 2x; choose from still; yaw 14;" in capsys.readouterr().out


def test_bench_motions_targets_judge_every_scene():
    from device.bench.motion import SWEEP, targets

    def point(label, scene, yaw, ambient, valid, gross=0.0, false=0):
        return {"point": label, "scene": scene, "yaw_deg_s": yaw, "speed_m_s": 0.0, "ambient_x": ambient,
                "fast": {"gross_fraction": gross, "false_returns": false, "false_too_close": 0, "valid_fraction": valid}}

    def sweep(valid=0.95, **changes):  # every point of the sweep, as a whole run has them
        pts = [point(label, scene, yaw, ambient, valid) for label, scene, yaw, _, ambient, _, _ in SWEEP]
        for label, fast in changes.items():
            next(p for p in pts if p["point"] == label)["fast"].update(fast)
        return {"ratio_vs_one_unlit": 1.2, "points": pts}

    gross, valid, speed = targets(sweep(**{"yaw 90, 10x": {"gross_fraction": 0.0005, "valid_fraction": 0.2}}))
    assert gross.startswith("MET: ") and "worst gross 0.05 %" in gross
    assert valid.startswith("MET: ")  # 10x light is not judged for it
    assert speed.startswith("MET")
    valid = targets(sweep(**{"poster wall, yaw 14": {"valid_fraction": 0.6}}))[1]
    assert valid.startswith("NOT MET") and "worst 60.0 %, poster wall, yaw 14" in valid
    assert targets(sweep(still={"false_returns": 1}))[0].startswith("NOT MET")
    # some points run (--points): a target met on them is met on those, and says so
    some = {"ratio_vs_one_unlit": 1.2, "points": [point("still", "office", 0, 3, 0.95)]}
    gross, valid, _ = targets(some)
    assert gross.startswith(f"MET on 1 of its {len(SWEEP)} sweep points (the rest not run): ")
    assert valid.startswith("MET on 1 of its ") and "(the rest not run)" in valid


def test_a_range_of_either_surface_a_line_crossed_during_the_exposure_is_no_gross_error():
    from device.sim.truth import FrameTruth
    from device.vision.evaluation import Score, range_error_rel

    nan, W = np.nan, 7
    truth = FrameTruth(np.array([100.0, 100, 100, 100, 100, 100, nan]), np.array([2.0, 2.3, 2.3, 2.3, 2.3, 2.075, np.inf]),
                       np.zeros(W), np.zeros((W, 3)), np.zeros(W, int), np.zeros(10, bool),
                       range_span_m=np.array([[2.0, 2.0], [2.0, 2.6], [2.0, 2.6], [2.0, 2.6], [2.25, 2.35],
                                              [2.0, 2.15], [nan, nan]]))
    cols = np.arange(W)
    measured = np.array([2.05, 2.59, 2.3, 2.04, 2.5, 2.15, 1.0])
    e = range_error_rel(measured, truth, cols)
    # one surface: against its range; a depth jump crossed (2.0 and 2.6 m; 2.0 and 2.15, 7.5 %
    # apart): against the surface nearer the measurement, 2.59 the far one, 2.04 the near one;
    # the mean (2.3, where nothing is) is no true range, 2.3 there is off both surfaces by > 5 %;
    # a surface that moved 4 % is no jump (2.5: 8.7 % off its mean)
    np.testing.assert_allclose(e[:6], [0.025, -0.01 / 2.6, -0.3 / 2.6, 0.02, 0.2 / 2.3, 0.0], atol=1e-12)
    assert np.isnan(e[6])
    # without the span (a still scene): the range alone
    still = FrameTruth(*(getattr(truth, k) for k in ("row", "range_m", "angle_rad", "points", "surface", "lit_rows")))
    np.testing.assert_allclose(range_error_rel(measured[:2], still, cols[:2]), [0.025, 0.29 / 2.3])
    # bench motion's score and evaluate's count with it: 2.3 and 2.5 are the gross errors, 1.0 a
    # false return; a "too close" in a jump column whose near surface is nearer than the region
    # of interest is true, though the mean is not that near
    from device.vision.measurements import ColumnMeasurements, ColumnStatus

    status = np.full(W, int(ColumnStatus.OK), np.uint8)
    meas = ColumnMeasurements(cols, np.full(W, 100.0), np.zeros(W), measured, np.full(W, 9.0), np.zeros((W, 3)), status)
    s = score([(meas, truth)], MIN_M)
    assert (s["gross"], s["false_returns"], s["valid_fraction"]) == (2, 1, 1.0)
    sc = Score()
    sc.add(meas, truth)
    np.testing.assert_allclose(sc.range_rel_err[0], e[:6], atol=1e-12)
    np.testing.assert_allclose(sc.true_range[0], [2.0, 2.6, 2.6, 2.0, 2.3, 2.15])  # binned by the surface judged against
    assert sc.row_err[0].size == 2  # a jump column has no one true row
    near = dataclasses.replace(truth, range_span_m=np.array([[0.2, 2.6]] * W), range_m=np.full(W, 1.4))
    too_close = dataclasses.replace(meas, range=np.full(W, -np.inf), status=np.full(W, int(ColumnStatus.TOO_CLOSE), np.uint8))
    assert score([(too_close, near)], MIN_M)["false_too_close"] == 0
    assert score([(too_close, dataclasses.replace(near, range_span_m=None))], MIN_M)["false_too_close"] == W


def test_the_neighbours_disagreement_is_measured_as_detection_sees_it():
    # a turned frame's neighbours a and b, a line 10 levels high in every column: it must stand
    # agree_ratio (3) x above their difference as detection's 5 x 3 box (5 columns, 3 rows) sees
    # it along its rows +- half_width (4). A pixel-scale residue (a resampled sharp texture;
    # sensor noise alike) averages out in the box: a checkerboard of +-6, column stripes of +-15
    # (3 in a 5-column box); a coherent difference (something that moved) does not: 4 levels
    # where b is brighter or a is, 6 over two rows 4-5 below the line (4 in the box at row 4)
    from device.vision.measurements import STATUS_U8

    device, _ = _device_and_without({})
    W, n, top = device.cols.size, device.rows, device.top
    r = n // 2
    a = np.full((n, W), 100, np.int16)
    b = a.copy()
    yy, xx = np.mgrid[:n, :W]
    b[:, :400] += np.where((yy + xx) % 2, 6, -6)[:, :400]
    b[:, 400:500] += np.where(xx % 2, 15, -15)[:, 400:500]
    b[:, 600:700] += 4
    b[r + 4 : r + 6, 750:850] += 6
    a[:, 900:1000] += 4
    ok = np.full(W, STATUS_U8[ColumnStatus.OK], np.uint8)
    out = device._disagreed(ok, np.full(W, top + r), np.full(W, 10.0), np.zeros(W, bool),
                            (a.astype(np.uint8), b.astype(np.uint8)), np.ones(W, bool), np.zeros(W, bool),
                            a.astype(np.uint8))
    rejected = out == STATUS_U8[ColumnStatus.REJECTED]
    for kept in (slice(0, 398), slice(402, 498), slice(1010, W)):
        assert not rejected[kept].any()
    for moved in (slice(602, 698), slice(752, 848), slice(902, 998)):
        assert rejected[moved].all()



def test_a_line_seen_but_not_measured_continues_its_run_in_a_turned_frame():
    # in a turned frame what the checks leave must be part of a run of moving_min_run (5)
    # columns: a moved edge's residue passes in fragments. A column whose line was seen but not
    # measured (the range gate: its predicted sigma too large, as on a far wall in bright light)
    # is part of the line all the same, as on a still frame; a gap without a line is not. Seed
    # 0 turning at 14 deg/s in 3x light lost 6 % of the back wall's columns to fragments between
    # gated ones (BENCHMARKS.md "Motion")
    from device.vision.measurements import STATUS_U8

    device, _ = _device_and_without({})
    g = device.geometry
    W, n = device.cols.size, device.rows
    flat = np.full((n, W), 100, np.uint8)
    row = (g.roi_lo + g.roi_hi) / 2.0  # a wall: the middle of each column's region of interest
    status = np.full(W, STATUS_U8[ColumnStatus.OK], np.uint8)
    for c0, gap in ((100, ColumnStatus.REJECTED), (200, ColumnStatus.NO_RETURN), (300, ColumnStatus.REJECTED)):
        status[c0 : c0 + 2] = status[c0 + 5 : c0 + 7] = status[c0 + 10 : c0 + 12] = STATUS_U8[gap]
    row[307:312] += 30.0  # the second fragment at 300 and the seen columns after it: a nearer surface
    seen = status == STATUS_U8[ColumnStatus.REJECTED]
    out = device._disagreed(status, row, np.full(W, 20.0), np.zeros(W, bool), (flat, flat), np.ones(W, bool), seen, flat)
    ok = out == STATUS_U8[ColumnStatus.OK]
    assert ok[102:105].all() and ok[107:110].all()  # 3-column fragments between columns a line was seen in
    assert not ok[202:205].any() and not ok[207:210].any()  # between columns without one
    assert ok[302:305].all()  # on the wall, through the seen columns at 300
    assert not ok[307:310].any()  # the nearer surface: a depth jump from the seen columns on either side
    assert ok[:100].all() and ok[400:].all()


def test_lines_in_run_joins_through_seen_columns_on_one_surface_only():
    from device.vision.fast import _lines_in_run

    ok = np.array([1, 1, 0, 1, 0, 1, 1, 0, 1, 0, 1, 1], bool)
    seen = np.array([0, 0, 1, 0, 0, 0, 0, 1, 0, 1, 0, 0], bool)
    depth = np.array([2.0, 2.0, 2.05, 2.1, np.nan, 2.0, 2.0, 1.0, 1.0, 3.0, np.nan, np.nan])
    # 0-3: through the seen column at 2 (depth steps under 8 %); 4: no line; 5-6; the seen column
    # at 7 is nearer (a jump), so 7-8 stand alone; 9 seen at 3 m; 10-11 ok with no depth: joined
    assert _lines_in_run(ok, seen, depth, 0.08).tolist() == [3, 3, 3, 3, 0, 2, 2, 1, 1, 0, 2, 2]


def test_between_surfaces_is_the_middle_of_a_ramp_between_two_depths():
    from device.vision.fast import between_surfaces

    near, far = np.full(20, 2.33), np.full(20, 2.65)
    ramp = np.r_[far, np.linspace(2.65, 2.33, 16), near]  # a depth edge a turn smeared over 16 columns
    valid = np.ones(ramp.size, bool)
    mixed = between_surfaces(ramp, valid, 8, 0.1, 0.02)
    inside = (ramp < 2.65 / 1.02) & (ramp > 2.33 * 1.02)
    assert mixed.sum() >= 8 and not np.any(mixed & ~inside)  # the middle of the ramp, no column of a surface
    assert mixed[20 + 4 : 20 + 12].all()
    assert not between_surfaces(np.r_[far, near], np.ones(40, bool), 8, 0.1, 0.02).any()  # a sharp edge: none
    assert not between_surfaces(ramp, valid, 8, 0.15, 0.02).any()  # surfaces closer than the jump: none
    assert not between_surfaces(ramp, valid, 0, 0.1, 0.02).any()  # a column alone has no ends
    # invalid columns are neither ends nor judged, whatever depth they hold
    holes = valid.copy()
    holes[:20] = False
    assert np.array_equal(between_surfaces(np.where(holes, ramp, 0.1), holes, 8, 0.1, 0.02), mixed)
    with pytest.raises(ValueError, match="1-D"):
        between_surfaces(ramp[None, :], valid[None, :], 8, 0.1, 0.02)


def test_a_turned_frame_rejects_the_mixture_of_two_surfaces_at_a_depth_edge():
    # 90 deg/s in the default light (seed 2): while a row is exposed the turn sweeps the desk's
    # edge (2.35 m) before the back wall (2.65 m) over ~11 columns; there the line's light comes
    # from both, one line whose range lies between them (2.46-2.51 m): 7 columns > 5 % off either
    # surface without the check, none with it, and the rest of the office measured as before
    pairs = sequence(CFG, with_motion(get_scene("office"), yaw_rate_deg_s=90, ambient_scale=1), 3, 2)
    device, without = _device_and_without({"mixed_jump": math.inf})
    now = score([(_process("fast", device, p), p.truth) for p in pairs], MIN_M)
    before = score([(_process("fast", without, p), p.truth) for p in pairs], MIN_M)
    assert now["gross"] == 0 and now["false_returns"] == 0
    assert before["gross"] >= 5
    assert now["valid_fraction"] > before["valid_fraction"] - 0.02


def test_the_turns_sweep_takes_the_lit_frames_own_exposure():
    from device.camera.frame import Frame
    from device.vision.fast import exposure_share

    op = CFG.operating_point
    image = np.zeros((CFG.height, CFG.width), np.uint8)
    frame = Frame(image, 3, 10**9, 20_000.0, 50_000.0, CFG.window.mode.line_time_ns)
    assert exposure_share(frame, op) == pytest.approx(0.4)  # a recording's ExposureTime / FrameDuration
    assert exposure_share(image, op) == pytest.approx(op.exposure_us * 1e-6 * 2 * op.scan_rate_hz)  # a bare image
