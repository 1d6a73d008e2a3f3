"""The unlit neighbours turned to the lit frame's yaw (device/vision/yaw.py), on images made
through the calibrated lens model from a texture fixed in (azimuth, elevation): a turn about the
scan frame's z axis moves that texture along the azimuth and nothing else, so the turn found and
the band read back can be checked to the pixel, with no renderer in between."""

import math

import numpy as np
import pytest

from device.config import load_preset
from device.model.camera import pixel_grid, project_points, undistort_robust
from device.model.scan_frame import scan_frame
from device.vision.yaw import COMPOSE_STEP, MAX_TURN_RESIDUE, register, yaw_grid

CFG = load_preset("thesis-calibrated")
FRAME = scan_frame(CFG.plane)
TOP, ROWS = 54, 160  # the fast pipeline's band at the operating point (0.4-3.2 m)
DRAWN = 400  # image rows drawn: the grid's cells of the band's elevations reach row ~350 at the sides
LINE = 60  # levels of the laser line drawn into the lit frame (its peak)


@pytest.fixture(scope="module")
def grid():
    return yaw_grid(CFG.camera, FRAME, CFG.width, CFG.height, TOP, ROWS, math.radians(20))


@pytest.fixture(scope="module")
def rays():
    """(azimuth, elevation) in the scan frame of every pixel of the drawn rows (their own
    derivation: the lens model's undistortion, then the scan frame's rotation)."""
    pixels = pixel_grid(CFG.width, DRAWN)
    un = undistort_robust(pixels.reshape(-1, 2), CFG.camera, tol_px=1e-4)
    assert un.valid.all()
    d = np.concatenate([un.xy, np.ones((len(un.xy), 1))], axis=1) @ FRAME.rotation.T
    az = np.arctan2(d[:, 1], d[:, 0]).reshape(pixels.shape[:2])
    el = np.arctan2(d[:, 2], np.hypot(d[:, 0], d[:, 1])).reshape(pixels.shape[:2])
    return az, el


def texture(az, el, seed=0):
    """A smooth random texture on the sphere of directions, 20-220 levels: a sum of plane waves
    in random directions, 1-4 degrees long (a poster, a door frame seen from 2 m), sharp enough
    to register, smooth enough for bilinear resampling to follow, and periodic in no direction."""
    rng = np.random.default_rng(seed)
    value = np.full(az.shape, 120.0)
    for angle, wavelength, phase in zip(rng.uniform(0, np.pi, 16), rng.uniform(0.017, 0.07, 16), rng.uniform(0, 2 * np.pi, 16)):
        value += 22 * np.sin(2 * np.pi * (np.cos(angle) * az + np.sin(angle) * el) / wavelength + phase)
    return np.clip(value, 20, 220)


def outside_the_neighbour(rays, turn_rad):
    """(width,) True where some band pixel's content is outside a neighbour turned by
    ``turn_rad``: its direction there, azimuth - turn_rad, projects outside the image."""
    az, el = (x[TOP : TOP + ROWS] for x in rays)
    a = az - turn_rad
    d = np.stack([np.cos(el) * np.cos(a), np.cos(el) * np.sin(a), np.sin(el)], axis=-1) @ FRAME.rotation
    xy = project_points(d.reshape(-1, 3), CFG.camera).reshape(ROWS, CFG.width, 2)
    inside = (xy[..., 0] >= 0) & (xy[..., 0] <= CFG.width - 1) & (xy[..., 1] >= 0) & (xy[..., 1] <= CFG.height - 1)
    return ~inside.all(axis=0)


def image(rays, turn_rad=0.0, seed=0):
    """The whole image of the texture with the sensor turned by ``turn_rad`` (to the left, REP 103)
    against the lit frame: a direction at azimuth a then shows what was at a + turn_rad."""
    az, el = rays
    out = np.zeros((CFG.height, CFG.width), np.uint8)
    out[:DRAWN] = np.rint(texture(az + turn_rad, el, seed)).astype(np.uint8)
    return out


@pytest.mark.parametrize("turn_deg", [0.7, -2.2, 4.5, -9.0])  # 14-180 deg/s over the 50 ms frame step
def test_a_turn_is_found_and_its_band_read_back_to_the_pixel(grid, rays, turn_deg):
    lit = image(rays)
    turn = math.radians(turn_deg)
    before, after = image(rays, -turn), image(rays, turn)
    regs = register(grid, lit, (before, after))
    assert regs is not None
    for reg, t in zip(regs, (-turn, turn)):
        assert reg.shift_rad == pytest.approx(t, abs=0.05 * grid.cell_rad)  # to a twentieth of a pixel
        band = lit[TOP : TOP + ROWS].astype(int)
        error = np.abs(reg.band.astype(int) - band)[:, reg.seen]
        assert np.percentile(error, 99) <= 2 and error.mean() < 0.5
        # the columns some band pixel of which shows what is outside the neighbour (the lens
        # model's projection): all of them unseen, on the side the turn brought in, and at most
        # two steps of the composed grid more (it errs on the safe side)
        unseen = ~reg.seen[: CFG.active_width]
        outside = outside_the_neighbour(rays, t)[: CFG.active_width]
        assert outside.any() and not np.any(outside & ~unseen)
        assert np.all(np.nonzero(unseen)[0] < 820 if t < 0 else np.nonzero(unseen)[0] >= 820)
        assert unseen.sum() <= outside.sum() + 2 * COMPOSE_STEP


def test_a_turn_under_half_a_pixel_reads_the_neighbour_as_it_is(grid, rays):
    lit = image(rays)
    neighbours = image(rays, -0.2 * grid.cell_rad), image(rays, 0.2 * grid.cell_rad)
    before = [n.copy() for n in neighbours]
    regs = register(grid, lit, neighbours)
    assert regs is not None
    for reg, neighbour, t in zip(regs, neighbours, (-0.2, 0.2)):
        assert reg.shift_rad == pytest.approx(t * grid.cell_rad, abs=0.05 * grid.cell_rad)
        assert np.array_equal(reg.band, neighbour[TOP : TOP + ROWS]) and reg.seen.all()
        reg.band[:] = 0  # a copy: the caller may write into it
    assert all(np.array_equal(n, b) for n, b in zip(neighbours, before))


def test_no_turn_is_told_in_a_flat_scene(grid):
    flat = np.full((CFG.height, CFG.width), 90, np.uint8)
    assert register(grid, flat, (flat, flat)) is None


def test_a_change_no_turn_explains_is_not_turned(grid, rays):
    """The neighbours show different scenes (as when the robot drives and the parallax spreads the
    scene out from the middle, or the light changes): the best shift leaves most of the change."""
    lit = image(rays, seed=1)
    assert register(grid, lit, (image(rays, seed=2), image(rays, seed=3))) is None
    assert 0 < MAX_TURN_RESIDUE < 1


@pytest.mark.parametrize("top, rows, max_deg", [(-1, 160, 20), (900, 160, 20), (54, 2, 20), (54, 160, 0)])
def test_a_grid_that_means_nothing_is_refused(top, rows, max_deg):
    with pytest.raises(ValueError):
        yaw_grid(CFG.camera, FRAME, CFG.width, CFG.height, top, rows, math.radians(max_deg))


def test_the_pipeline_judges_a_turned_frame_and_rejects_what_no_neighbour_saw(rays):
    """The device's pipeline on a textured scene with a laser line drawn in, the sensor turned
    1 deg before the lit frame and 3 deg after it (a wobble: both neighbours turned the same
    way). The columns whose content neither neighbour saw are REJECTED; the others measure the
    line, where without the turn a 2-3 deg shift of this texture hides much of it."""
    import dataclasses

    from device.vision.fast import FastPipeline
    from device.vision.measurements import ColumnStatus
    from device.vision.pipelines import make_pipeline

    op = CFG.operating_point
    device = make_pipeline("fast-com-track-gated", CFG, op.min_m, op.max_m)
    assert (device.top, device.rows) == (TOP, ROWS)
    line_row = (device.geometry.roi_lo + device.geometry.roi_hi) / 2  # a line in every column, mid-range
    r = np.arange(CFG.height)[:, None]
    lit = np.clip(image(rays) + LINE * np.exp(-((r - line_row[None, :]) ** 2) / 2), 0, 255).astype(np.uint8)
    before, after = image(rays, math.radians(1)), image(rays, math.radians(3))
    lit_rows = np.ones(CFG.height, bool)
    active = slice(0, CFG.active_width)
    meas = device.process(lit, after, lit_rows, other_unlit=before)
    status, valid = meas.status[active], meas.valid[active]
    seen_by_neither = (outside_the_neighbour(rays, math.radians(1)) & outside_the_neighbour(rays, math.radians(3)))[active]
    assert seen_by_neither.sum() >= 10
    assert not valid[seen_by_neither].any() and np.all(status[seen_by_neither] == ColumnStatus.REJECTED)
    inside = np.zeros_like(seen_by_neither)
    inside[100 : CFG.active_width - 100] = True
    unturned = FastPipeline(CFG, dataclasses.replace(device.params, turn_share=math.inf), op.min_m, op.max_m)
    u = unturned.process(lit, after, lit_rows, other_unlit=before).valid[active][inside].mean()
    assert valid[inside].mean() > 0.95 and u < 0.3  # here: 1.0 against 0.10
