"""The simulator's moving world (issue 16): the sensor's trajectory under the rolling shutter,
moving objects, flicker, and the truth at the time each column was lit."""

import math

import numpy as np
import pytest

from device.config import load_preset
from device.sim.motion import flicker_mean, image_speed_px_s, scene_at, sensor_pose
from device.sim.render import FrameTiming, RenderOptions, SceneRenderer
from device.sim.scene import (Cylinder, Flicker, Material, Motion, Scene, SceneError, get_scene, scene_from_dict,
                              wall_scene, with_motion)

CFG = load_preset("thesis-calibrated")
QUIET = RenderOptions().without("noise", "speckle", "ambient")
LINE_NS = CFG.window.mode.line_time_ns
T0 = 10**9


def pulse_frame(t_ns, exposure_us=40000.0, pulse=None):
    """A frame at T = t_ns; ``pulse`` (on, off) ns, default a 1 ms pulse inside the window where
    every row exposes (all rows lit at one time)."""
    if pulse is None:
        mid = t_ns + int(((CFG.height - 1) * LINE_NS - exposure_us * 1e3) / 2)
        pulse = (mid - 500_000, mid + 500_000)
    return FrameTiming(t_ns, exposure_us, LINE_NS, (pulse,))


def test_the_trajectory_is_the_integral_of_yaw_rate_and_speed():
    m = Motion(math.radians(120), 0.8)
    t = np.linspace(0, 1.5, 3001)
    yaw, x, y = sensor_pose(m, t)
    dt = t[1] - t[0]
    heading = m.yaw_rate_rad_s * (t[:-1] + dt / 2)  # midpoint rule
    assert x[-1] == pytest.approx(np.sum(m.speed_m_s * np.cos(heading) * dt), abs=1e-6)
    assert y[-1] == pytest.approx(np.sum(m.speed_m_s * np.sin(heading) * dt), abs=1e-6)
    assert yaw[-1] == pytest.approx(m.yaw_rate_rad_s * 1.5)
    yaw0, x0, y0 = sensor_pose(Motion(0.0, 0.5), np.array([2.0]))
    assert (yaw0[0], x0[0], y0[0]) == (0.0, 1.0, 0.0)


def test_a_sensor_ahead_of_the_robots_axis_moves_sideways_when_it_turns():
    # 0.1 m ahead of the axis, turning on the spot: on a circle of 0.1 m about the axis (which
    # starts 0.1 m behind the sensor), facing out of it, at 0.1 m x the yaw rate
    d, w = 0.1, math.radians(90)
    t = np.linspace(0, 2.0, 201)
    yaw, x, y = sensor_pose(Motion(w, 0.0, d), t)
    np.testing.assert_allclose(np.hypot(x + d, y), d, atol=1e-12)
    np.testing.assert_allclose(np.arctan2(y, x + d), np.angle(np.exp(1j * yaw)), atol=1e-9)
    speed = np.hypot(np.diff(x), np.diff(y)) / np.diff(t)
    np.testing.assert_allclose(speed, d * w, rtol=1e-3)
    # driving too: the axis follows the unicycle, the sensor d ahead of it along the heading
    m = Motion(w, 0.7, d)
    yaw, x, y = sensor_pose(m, t)
    _, ax, ay = sensor_pose(Motion(w, 0.7), t)
    np.testing.assert_allclose(x, ax - d + d * np.cos(yaw), atol=1e-12)
    np.testing.assert_allclose(y, ay + d * np.sin(yaw), atol=1e-12)


def test_the_image_speed_bound_counts_a_sensor_off_the_robots_axis():
    # the renderer slices an exposure by this bound: a sensor 0.3 m from the axis at 90 deg/s
    # moves 0.47 m/s sideways, seen at 0.5 m as fast as the turn itself
    fx = CFG.camera.intrinsics.fx
    on_axis = image_speed_px_s(with_motion(wall_scene(2.0), yaw_rate_deg_s=90), fx)
    for ahead in (0.3, -0.3):
        off = image_speed_px_s(with_motion(wall_scene(2.0), yaw_rate_deg_s=90, sensor_ahead_m=ahead), fx)
        assert off == pytest.approx(on_axis + fx * math.radians(90) * 0.3 / 0.5)


@pytest.mark.parametrize("ahead_m", [0.3, -0.3])
def test_a_sensor_off_the_robots_axis_sees_the_wall_where_it_is_from_where_it_stands(ahead_m):
    # turning at 90 deg/s 0.3 m ahead of (or behind) the robot's axis: each true point, carried
    # from where the sensor stood at the pulse into the scene's frame, lies on the wall (x = 2 m);
    # a renderer that turned the sensor on the axis would put them ~0.1-0.2 m off
    scene = with_motion(wall_scene(2.0), yaw_rate_deg_s=90, sensor_ahead_m=ahead_m)
    timing = pulse_frame(T0 + 400_000_000)
    _, truth = SceneRenderer(CFG, scene, options=QUIET, time_zero_ns=T0).render(timing, np.random.default_rng(0))
    t_pulse = ((timing.pulses_ns[0][0] + timing.pulses_ns[0][1]) / 2 - T0) * 1e-9
    yaw, x, y = (float(v) for v in sensor_pose(scene.motion, t_pulse))
    ok = np.isfinite(truth.range_m)
    assert ok.sum() > 1000
    wall_x = x + truth.range_m[ok] * np.cos(yaw + truth.angle_rad[ok])
    np.testing.assert_allclose(wall_x, 2.0, atol=0.005)  # the 1 ms pulse's smear
    assert abs(y) > 0.1  # the sensor did move sideways


def test_a_turning_sensor_sees_the_wall_turned_the_other_way_at_the_pulse_time():
    rate = math.radians(90)
    scene = with_motion(wall_scene(2.0), yaw_rate_deg_s=90)
    r = SceneRenderer(CFG, scene, options=QUIET, time_zero_ns=T0)
    timing = pulse_frame(T0 + 200_000_000)
    _, truth = r.render(timing, np.random.default_rng(0))
    t_pulse = (timing.pulses_ns[0][0] + timing.pulses_ns[0][1]) / 2
    turned = math.degrees(rate * (t_pulse - T0) * 1e-9)
    still = SceneRenderer(CFG, wall_scene(2.0, angle_deg=-turned), options=QUIET).truth_template
    both = np.isfinite(truth.range_m) & np.isfinite(still.range_m)
    assert both.sum() > 1000
    # the 1 ms pulse smears the line by 0.09 deg of turn: ranges agree to 0.05 %
    np.testing.assert_allclose(truth.range_m[both], still.range_m[both], rtol=5e-4)
    np.testing.assert_allclose(truth.time_ns[both], t_pulse, atol=1.0)
    # and the still renderer's truth without motion is not that
    assert np.nanmax(np.abs(r.truth_template.range_m[both] - truth.range_m[both])) > 0.1


def test_each_row_is_lit_at_its_own_time_under_the_rolling_shutter():
    """A pulse over every row's whole exposure: a column's light comes at its row's mid-exposure."""
    scene = with_motion(wall_scene(2.0, angle_deg=30), yaw_rate_deg_s=45)
    r = SceneRenderer(CFG, scene, options=QUIET, time_zero_ns=T0)
    t, e_us = T0 + 50_000_000, 9200.0
    timing = pulse_frame(t, e_us, (t - int(e_us * 1e3) - 1, t + int(CFG.height * LINE_NS) + 1))
    _, truth = r.render(timing, np.random.default_rng(0))
    ok = np.isfinite(truth.row)
    rows = truth.row[ok]
    assert np.ptp(rows) > 20  # the line crosses many rows: their times differ by ms
    expected = t - e_us * 1e3 / 2 + rows * LINE_NS
    err = np.abs(truth.time_ns[ok] - expected)
    # the light is cut into time slices (render step 9); where the line leaves the wall during
    # the exposure (the wall's end, the last few columns) a column's slices disagree on its row
    assert np.percentile(err, 99) < 0.05 * e_us * 1e3 and err.max() < 0.5 * e_us * 1e3


def test_translation_moves_near_things_more_than_far_ones():
    """Parallax: two posts at the same angle off the axis (one each side), one near, one far;
    driving forward turns the near one farther off the axis."""
    post = lambda x, y: Cylinder((x, y), 0.05, material=Material(0.9, texture="plain"))  # noqa: E731
    scene = Scene("posts", cylinders=(post(1.0, 0.4), post(3.0, -1.2)), motion=Motion(0.0, 1.0))
    r = SceneRenderer(CFG, scene, options=QUIET, time_zero_ns=T0)
    cols = []
    for dt_ms in (0, 150):
        _, truth = r.render(pulse_frame(T0 + dt_ms * 1_000_000), np.random.default_rng(0))
        cols.append([np.mean(np.nonzero(truth.surface == i)[0]) for i in (0, 1)])
    near_shift, far_shift = abs(cols[1][0] - cols[0][0]), abs(cols[1][1] - cols[0][1])
    assert near_shift > 2 * far_shift > 0


def test_a_person_crosses_and_a_door_swings():
    person = get_scene("person")
    c0, c1 = person.cylinders[0].center, scene_at(person, 0.5).cylinders[0].center
    assert c1 == pytest.approx((c0[0], c0[1] + 0.6))
    door = get_scene("door")
    hinge, end = scene_at(door, 1.0).walls[1].start, scene_at(door, 1.0).walls[1].end
    assert hinge == door.walls[1].start
    assert math.degrees(math.atan2(end[1] - hinge[1], end[0] - hinge[0])) == pytest.approx(90 + 90)
    # the renderer's truth follows the person: where a still scene has it at the pulse's time
    r = SceneRenderer(CFG, person, options=QUIET, time_zero_ns=T0)
    mean_col = []
    for dt_ms in (0, 300):
        timing = pulse_frame(T0 + dt_ms * 1_000_000)
        _, truth = r.render(timing, np.random.default_rng(0))
        mean_col.append(np.mean(np.nonzero(truth.surface == 1)[0]))
    t_pulse = (sum(timing.pulses_ns[0]) / 2 - T0) * 1e-9
    still = SceneRenderer(CFG, Scene("p", walls=person.walls, cylinders=(scene_at(person, t_pulse).cylinders[0],)),
                          options=QUIET).truth_template
    assert mean_col[1] == pytest.approx(np.mean(np.nonzero(still.surface == 1)[0]), abs=1.0)
    assert abs(mean_col[1] - mean_col[0]) > 30


def test_flicker_is_integrated_over_each_rows_exposure():
    f = Flicker(100.0, 0.4)
    start = np.array([0.0, 0.0013, 0.0021])
    for s0 in start:
        t = np.linspace(s0, s0 + 0.0031, 200001)
        assert flicker_mean(f, np.array([s0]), np.array([s0 + 0.0031]))[0] == pytest.approx(
            np.mean(1 + 0.4 * np.sin(2 * np.pi * 100 * t)), abs=1e-5)
    # a still scene: the ambient of each row is its flicker mean (rows differ: the phase moves)
    opts = RenderOptions().without("noise", "speckle", "texture")
    steady = SceneRenderer(CFG, wall_scene(2.0), options=opts, time_zero_ns=T0)
    flick = SceneRenderer(CFG, with_motion(wall_scene(2.0), flicker_hz=100, flicker_depth=0.4), options=opts,
                          time_zero_ns=T0)
    timing = FrameTiming(T0 + 3_000_000, 5000.0, LINE_NS)
    a, _ = steady.expected_electrons(timing)
    b, _ = flick.expected_electrons(timing)
    rows = np.arange(CFG.height)
    end = (timing.sensor_timestamp_ns - T0 + rows * LINE_NS) * 1e-9
    expected = flicker_mean(Flicker(100.0, 0.4), end - 0.005, end)
    seen = a[:, 800] > 0  # the active rows
    assert seen.sum() > 900
    np.testing.assert_allclose(b[seen, 800] / a[seen, 800], expected[seen], rtol=1e-5)
    assert np.ptp(expected) > 0.3


def test_a_moving_background_moves_between_frames_and_a_still_one_does_not():
    scene = get_scene("office")
    opts = RenderOptions().without("noise", "speckle")
    moving = SceneRenderer(CFG, with_motion(scene, yaw_rate_deg_s=60), options=opts, time_zero_ns=T0)
    t1, t2 = FrameTiming(T0, 9200.0, LINE_NS), FrameTiming(T0 + 100_000_000, 9200.0, LINE_NS)
    rng = np.random.default_rng
    a = moving.render(t1, rng(0))[0].astype(float)
    b = moving.render(t2, rng(0))[0].astype(float)
    assert np.mean(np.abs(a - b)) > 0.1 * np.mean(a)
    np.testing.assert_array_equal(a, moving.render(t1, rng(0))[0])  # deterministic
    still = SceneRenderer(CFG, scene, options=opts, time_zero_ns=T0)
    np.testing.assert_array_equal(still.render(t1, rng(0))[0], still.render(t2, rng(0))[0])


def test_motion_blur_is_a_smear_not_a_few_sharp_copies():
    """A camera integrates its exposure continuously: turning at 90 deg/s the poster wall's image
    moves ~9 px in 10 ms, so its sharp edges become ramps of that width (steps of about a ninth of
    the edge per column). Cut into slices 4 px apart (the renderer's default before) the edges
    stayed sharp copies: the largest steps along a row kept two thirds of the still image's; where
    the pitched view moved a horizontal edge across a row, the copies made a one-row ridge that
    passed for a laser line (device/sim/render.py step 9). With the background point-sampled
    (background_lens off), so that what is measured is the slices' smear, not the lens's blur."""
    opts = RenderOptions().without("noise", "speckle", "background_lens")
    scene = with_motion(get_scene("poster-wall"), ambient_scale=10)
    t = FrameTiming(T0 + 50_000_000, 10000.0, LINE_NS)
    still = SceneRenderer(CFG, scene, options=opts, time_zero_ns=T0).render(t, np.random.default_rng(0))[0]
    turning = SceneRenderer(CFG, with_motion(scene, yaw_rate_deg_s=90), options=opts, time_zero_ns=T0)
    # the image moves at most a pixel from one slice to the next
    assert image_speed_px_s(turning.scene, CFG.camera.intrinsics.fx) * 0.01 / turning._slices(0.01) <= 1.0
    moving = turning.render(t, np.random.default_rng(0))[0]

    def steps(image):  # the largest steps along the rows (99.9th percentile)
        return np.percentile(np.abs(np.diff(image.astype(float), axis=1)), 99.9)

    assert steps(still) > 150 and steps(moving) < 0.3 * steps(still)


def test_scene_files_take_motion_flicker_and_texture_contrast():
    doc = {"ambient_scale": 3.0, "flicker_hz": 120.0, "flicker_depth": 0.2,
           "motion": {"yaw_rate_deg_s": 90.0, "speed_m_s": 0.5, "sensor_ahead_m": 0.1},
           "wall": [{"from": [2, -1], "to": [2, 1], "swing_deg_s": 30.0, "texture_depth": 0.9}],
           "cylinder": [{"center": [1, 0], "radius": 0.2, "velocity": [0.0, 1.2]}]}
    s = scene_from_dict(doc)
    assert s.motion == Motion(math.radians(90), 0.5, 0.1) and s.flicker == Flicker(120.0, 0.2) and s.ambient_scale == 3.0
    assert s.walls[0].swing_rad_s == pytest.approx(math.radians(30)) and s.walls[0].material.texture_depth == 0.9
    assert s.cylinders[0].velocity == (0.0, 1.2) and not s.still
    assert get_scene("office").still and not get_scene("person").still and not get_scene("door").still
    for bad, fragment in (({"flicker_depth": 1.5}, "'flicker_depth' = 1.5"), ({"motion": {"yaw": 1}}, "unknown key(s) yaw"),
                          ({"wall": [{"from": [2, -1], "to": [2, 1], "texture_depth": -1}]}, "'texture_depth'")):
        with pytest.raises(SceneError, match=fragment.replace("(", r"\(").replace(")", r"\)")):
            scene_from_dict(bad)
    with pytest.raises(SceneError, match="flicker depth"):
        with_motion(s, flicker_depth=2.0)
    with pytest.raises(SceneError, match="sensor_ahead_m"):
        with_motion(s, sensor_ahead_m=math.inf)
    assert with_motion(s, sensor_ahead_m=0.2).motion == Motion(math.radians(90), 0.5, 0.2)
    # and from the command line (laserpi simulate and evaluate)
    import argparse

    from device.commands.argtypes import add_motion_arguments, scene_with_motion

    parser = argparse.ArgumentParser()
    add_motion_arguments(parser)
    args = parser.parse_args(["--yaw-rate-deg-s", "45", "--sensor-ahead-m", "-0.15"])
    assert scene_with_motion(s, args).motion == Motion(math.radians(45), 0.5, -0.15)


def test_a_column_whose_line_crosses_a_depth_jump_during_the_exposure_keeps_both_ranges():
    """Turning fast past a post before a wall, with a pulse over the whole exposure: the columns
    at the post's edges see the post in some time slices and the wall in others. Their truth's
    range is the light-weighted mean, between the two, where nothing is; its span names both."""
    post = Cylinder((1.0, 0.0), 0.05, material=Material(0.9, texture="plain"))
    wall = wall_scene(2.0)
    scene = Scene("post before a wall", walls=wall.walls, cylinders=(post,), motion=Motion(math.radians(180), 0.0))
    r = SceneRenderer(CFG, scene, options=QUIET, time_zero_ns=T0)
    t, e_us = T0 + 50_000_000, 9200.0
    _, truth = r.render(pulse_frame(t, e_us, (t - int(e_us * 1e3) - 1, t + int(CFG.height * LINE_NS) + 1)),
                        np.random.default_rng(0))
    has = np.isfinite(truth.range_m)
    near, far = truth.range_span_m[has].T
    # (range_m is the range of the mean point, the ends means of ranges: equal to 1e-6 on one surface)
    assert np.all(near <= truth.range_m[has] * (1 + 1e-6)) and np.all(truth.range_m[has] <= far * (1 + 1e-6))
    assert np.all(np.isnan(truth.range_span_m[~has]))
    jump = far > 1.05 * near
    # the post's two edges, as far as the turn swept them: a flat wall's range changes with the
    # turn in each column (by up to 15 % at the image's edges) but it is one surface
    post_cols = np.nonzero(truth.surface == 1)[0]
    assert jump.sum() >= 4 and np.all(np.abs(np.nonzero(has)[0][jump][:, None] - post_cols[None, :]).min(axis=1) < 80)
    # the ends are the post (~0.95 m ahead) and the wall (~2 m), the mean neither
    assert np.all(np.abs(near[jump] - 0.95) < 0.05) and np.all(np.abs(far[jump] - 2.0) < 0.1)
    mean = truth.range_m[has][jump]
    assert np.all((mean > 1.05 * near[jump]) | (mean < far[jump] / 1.05))
    # a still scene's truth has one range per column
    _, still = SceneRenderer(CFG, with_motion(scene, yaw_rate_deg_s=0.0), options=QUIET,
                             time_zero_ns=T0).render(pulse_frame(t), np.random.default_rng(0))
    assert still.range_span_m is None
