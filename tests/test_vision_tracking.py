"""The tracking fast pipeline (``fast-com-track``): it searches only rows near the previous
frame's line, falls back to a full search in the same frame when the line leaves that band
(a depth jump, a new object in front of the tracked surface, a lost line), and searches the
whole region of interest every ``track_full_every`` frames so that objects appearing where
there was no return are found within that many frames.

Synthetic frames (tests/synth_frames.py) with known line rows; the full-search ``fast-com`` is
the reference for what tracking must reproduce.
"""

import dataclasses

import numpy as np
import pytest

from device.config import RangeLimits, load_preset
from device.vision.fast import FastParams
from device.vision.geometry import column_geometry
from device.vision.measurements import ColumnStatus
from device.vision.pipelines import make_pipeline
from synth_frames import frame_pair, row_for_depth, true_points

CFG = dataclasses.replace(load_preset("thesis-calibrated"), range=RangeLimits(0.1, 4.0))
W = CFG.width


def depth_rows(depth):
    return row_for_depth(CFG, np.asarray(depth, dtype=float))


def true_range(rows):
    return column_geometry(CFG).angle_range(true_points(CFG, rows))[1]


@pytest.fixture()
def pipes():
    return make_pipeline("fast-com", CFG), make_pipeline("fast-com-track", CFG)


def run_both(pipes, frames):
    full, track = pipes
    out = []
    for lit, unlit in frames:
        out.append((full.process(lit, unlit), track.process(lit, unlit), track.searched_rows))
    return out


def test_a_steady_wall_is_tracked_in_a_narrow_band_with_the_same_result(pipes):
    rows = depth_rows(np.full(W, 2.0))
    frames = [frame_pair(CFG, rows, speckle=0.3, seed=s) for s in range(3)]
    full_rows = pipes[0].searched_rows
    res = run_both(pipes, frames)
    roi = res[0][2]
    assert roi[1] - roi[0] >= 300  # first frame: the whole region of interest
    for mf, mt, searched in res[1:]:
        assert searched[1] - searched[0] <= 0.5 * (roi[1] - roi[0])  # tracked: a narrow band
        assert searched[0] <= np.nanmin(rows) and searched[1] > np.nanmax(rows)
        np.testing.assert_array_equal(mt.status, mf.status)
        np.testing.assert_allclose(mt.range, mf.range, rtol=1e-12)
    assert full_rows is None or full_rows == roi


def test_a_depth_jump_and_an_object_in_front_are_found_in_the_same_frame(pipes):
    far = depth_rows(np.full(W, 3.0))
    depth = np.full(W, 3.0)
    depth[500:800] = 0.25  # an object steps in front of the tracked wall, outside the tracked band
    jump = depth_rows(depth)
    near = depth_rows(np.full(W, 1.0))  # then the whole scene jumps nearer
    frames = [frame_pair(CFG, far, seed=0), frame_pair(CFG, far, seed=1), frame_pair(CFG, jump, seed=2),
              frame_pair(CFG, near, seed=3)]
    res = run_both(pipes, frames)
    assert res[1][2][1] <= np.nanmin(jump[500:800])  # frame 2 was tracked, in a band that misses the object
    for (mf, mt, _), rows in zip(res[2:], (jump, near)):
        np.testing.assert_array_equal(mt.status, mf.status)
        np.testing.assert_allclose(mt.range, mf.range, rtol=1e-12)
        ok = mt.valid
        assert ok.mean() > 0.95
        rng = true_range(rows)[mt.column]  # the image's columns
        assert np.max(np.abs(mt.range[ok] - rng[ok]) / rng[ok]) < 0.05  # no point left on the old surface
    assert res[2][1].valid[520:780].all()


def test_a_lost_line_falls_back_to_a_full_search(pipes):
    wall = depth_rows(np.full(W, 2.0))
    nothing = np.full(W, np.nan)
    frames = [frame_pair(CFG, wall, seed=0), frame_pair(CFG, wall, seed=1), frame_pair(CFG, nothing, seed=2),
              frame_pair(CFG, depth_rows(np.full(W, 0.8)), seed=3)]
    res = run_both(pipes, frames)
    mf, mt, searched = res[2]
    assert searched == res[0][2]  # the tracked band lost the line: the whole ROI was searched
    assert np.all(mt.status == ColumnStatus.NO_RETURN) and np.all(np.isposinf(mt.range))
    mf, mt, _ = res[3]  # nothing tracked: a new surface is found at once
    np.testing.assert_array_equal(mt.status, mf.status)
    assert mt.valid.mean() > 0.95


def test_an_object_where_there_was_no_return_is_found_within_the_full_search_period(pipes):
    every = FastParams(track_margin=24).track_full_every
    depth = np.full(W, np.nan)
    depth[:700] = 2.0  # a wall on the left, nothing in range on the right
    left = depth_rows(depth)
    depth2 = depth.copy()
    depth2[1100:1400] = 0.25  # an object appears on the right, outside the tracked band
    both = depth_rows(depth2)
    frames = [frame_pair(CFG, left, seed=s) for s in range(2)] + [frame_pair(CFG, both, seed=10 + s) for s in range(every)]
    res = run_both(pipes, frames)
    assert res[2][2][1] <= np.nanmin(both[1100:1400])  # the frame it appears in is tracked: not seen yet
    seen = [mt.valid[1120:1380].mean() for _, mt, _ in res[2:]]
    first = next((i for i, v in enumerate(seen) if v > 0.95), len(seen))
    assert 0 < first <= every - 2  # frames 0 and 1 were full searches: found within track_full_every frames
    rng = true_range(both)[:CFG.active_width]  # the image's columns, those measured
    for mf, mt, _ in res[2:]:
        ok = mt.valid
        # tracked frames never report a wrong range, only "no return" where they did not look
        assert np.max(np.abs(mt.range[ok] - rng[ok]) / rng[ok]) < 0.05
        assert np.all(mt.valid[:680] == mf.valid[:680])
    mf, mt, _ = res[2 + first]
    np.testing.assert_array_equal(mt.status, mf.status)


@pytest.mark.parametrize("bad", [dict(track_margin=-1), dict(track_full_every=0), dict(track_lost_run=0)])
def test_bad_tracking_parameters_are_named(bad):
    with pytest.raises(ValueError, match="track_"):
        FastParams(**bad)


def test_a_mirror_image_appearing_at_the_band_edge_is_resolved_as_by_a_full_search(pipes):
    rows = depth_rows(np.full(W, 2.0))
    frames = [frame_pair(CFG, rows, amplitude=90.0, speckle=0.3, seed=s) for s in range(2)]
    # a glossy floor's mirror image: farther from the horizon, running alongside the line, and
    # reaching past the tracked band (which ends track_margin rows below the line)
    ghost = (rows + 22.0, 60.0)
    frames += [frame_pair(CFG, rows, amplitude=90.0, speckle=0.3, seed=5 + s, extra_lines=(ghost,)) for s in range(3)]
    res = run_both(pipes, frames)
    roi = res[0][2]
    assert res[1][2] != roi  # tracked before the ghost appears
    assert res[2][2] == roi  # the ghost touches the band's edge: the whole ROI is searched
    assert res[3][2] != roi and res[3][2][1] > np.nanmax(rows) + 22  # then the band covers line and ghost
    for mf, mt, _ in res[2:]:
        np.testing.assert_array_equal(mt.status, mf.status)
        np.testing.assert_allclose(mt.range, mf.range, rtol=1e-12)
        ok = mt.valid
        assert ok.mean() > 0.9
        assert np.max(np.abs(mt.row[ok] - rows[mt.column][ok])) < 1.5  # the line, never the ghost
