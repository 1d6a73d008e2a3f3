import math
from dataclasses import replace

import numpy as np
import pytest

from device.config import load_preset
from device.model.camera import undistort_robust
from device.model.scan_frame import scan_frame
from device.model.triangulation import intersect_plane
from device.sim.render import COHERENT_DEFOCUSED, FrameTiming, RenderOptions, SceneRenderer, column_gain, row_overlap_s
from device.sim.scene import get_scene, wall_scene

CFG = load_preset("thesis-calibrated")
QUIET = RenderOptions().without("noise", "speckle", "ambient")
LINE_NS = CFG.window.mode.line_time_ns


def full_pulse(exposure_us=40000.0, t=10**9):
    """A pulse that covers every row's whole exposure window."""
    return FrameTiming(t, exposure_us, LINE_NS, ((t - int(exposure_us * 1e3) - 1, t + int(CFG.height * LINE_NS) + 1),))


def model_rows(cols, distance, angle_deg):
    """Where the model says the line is: bisect, per column, the row whose back-projected ray meets
    the laser plane on the wall (signed distance of the triangulated point to the wall = 0)."""
    frame = scan_frame(CFG.plane)
    a = math.radians(angle_deg)
    nrm = np.array([math.cos(a), math.sin(a)])

    def f(v):
        un = undistort_robust(np.stack([cols.astype(float), v], axis=-1), CFG.camera)
        p = intersect_plane(un.xy, CFG.plane).points
        q = (p - frame.origin) @ frame.rotation.T
        d = q[:, :2] @ nrm - distance
        return np.where(np.isfinite(d), d, 1e9)  # beyond the plane's horizon: infinitely far

    lo, hi = np.full(cols.shape, 0.0), np.full(cols.shape, 900.0)
    flo = f(lo)
    assert np.all(flo > 0) and np.all(f(hi) < 0)  # the root is bracketed
    for _ in range(60):
        mid = (lo + hi) / 2
        fm = f(mid)
        same = np.sign(fm) == np.sign(flo)
        lo, flo = np.where(same, mid, lo), np.where(same, fm, flo)
        hi = np.where(same, hi, mid)
    return (lo + hi) / 2


@pytest.mark.parametrize("distance,angle", [(2.0, 0.0), (0.6, 30.0), (3.0, -20.0)])
def test_wall_line_row_matches_the_model(distance, angle):
    r = SceneRenderer(CFG, wall_scene(distance, angle), options=QUIET)
    truth = r.truth_template
    cols = np.arange(40, 1600, 37)
    cols = cols[np.isfinite(truth.row[cols])]
    assert cols.size > 30
    expected = model_rows(cols, distance, angle)
    assert np.max(np.abs(truth.row[cols] - expected)) < 0.01
    # and the rendered (noise-free) line's centroid is at the true row
    e, _ = r.expected_electrons(full_pulse())
    rows = np.arange(e.shape[0])[:, None]
    centroid = (e[:, cols] * rows).sum(0) / e[:, cols].sum(0)
    assert np.max(np.abs(centroid - truth.row[cols])) < 0.01
    # truth range: the wall's distance along the wall normal
    frame = scan_frame(CFG.plane)
    q = (truth.points[cols] - frame.origin) @ frame.rotation.T
    n = np.array([math.cos(math.radians(angle)), math.sin(math.radians(angle))])
    assert np.max(np.abs(q[:, :2] @ n - distance)) < 1e-6
    assert np.allclose(truth.range_m[cols], np.hypot(q[:, 0], q[:, 1]))


def test_irradiance_falls_as_the_model_says():
    """Column sum of electrons = K rho cos(i) / (r z) x pulse overlap (render docstring, step 2)."""
    k = column_gain(CFG, SceneRenderer(CFG, get_scene("empty")).sensor, QUIET)
    timing = full_pulse()
    overlap = row_overlap_s(timing, CFG.height)[0]
    sums = {}
    for d in (0.5, 1.0, 2.0, 4.0):
        r = SceneRenderer(CFG, wall_scene(d, 0.0, reflectivity=0.5), options=QUIET)
        e, _ = r.expected_electrons(timing)
        c = 820
        p = r.truth_template.points[c]
        rng_m, z = r.truth_template.range_m[c], p[2]
        ang = r.truth_template.angle_rad[c]
        expected = k * 0.5 * math.cos(ang) / (rng_m * z) * overlap  # wall faces the sensor: cos(i) = cos(angle)
        sums[d] = e[:, c].sum()
        assert sums[d] == pytest.approx(expected, rel=2e-3)
    # surface irradiance ~ 1/r and the pixel footprint ~ 1/z: about 1/d^2 on axis
    assert sums[1.0] / sums[2.0] == pytest.approx(4.0, rel=0.03)
    assert sums[2.0] / sums[4.0] == pytest.approx(4.0, rel=0.03)


def test_pulse_over_rows_200_to_400_lights_exactly_those_rows():
    exposure_us = 50 * LINE_NS / 1e3  # 50 line times
    t = 10**9
    on = t + 199.5 * LINE_NS  # after row 199 has finished exposing
    off = t - exposure_us * 1e3 + 400.5 * LINE_NS  # before row 401 starts
    timing = FrameTiming(t, exposure_us, LINE_NS, ((int(on), int(off)),))
    scene = wall_scene(0.08, 60.0)  # a near, steep wall: the line crosses many rows
    r = SceneRenderer(CFG, scene, options=QUIET)
    img, truth = r.render(timing, np.random.default_rng(0))
    assert np.array_equal(np.nonzero(truth.lit_rows)[0], np.arange(200, 401))
    rows_with_light = np.nonzero(img.max(axis=1) > 0)[0]
    assert rows_with_light.min() >= 200 and rows_with_light.max() <= 400
    true_rows = truth.row[np.isfinite(truth.row)]
    assert true_rows.min() < 150 and true_rows.max() > 450  # the line itself spans more than the pulse
    # the unlit frame of the same scene is dark, the all-rows pulse lights the whole line
    dark, dtruth = r.render(FrameTiming(t, exposure_us, LINE_NS), np.random.default_rng(0))
    assert dark.max() == 0 and not dtruth.lit_rows.any()


def test_deterministic_for_a_seed():
    scene = get_scene("clutter")
    out = []
    for _ in range(2):
        r = SceneRenderer(CFG, scene, seed=3, options=RenderOptions(ray_samples=4096))
        rng = np.random.default_rng(11)
        out.append([r.render(full_pulse(), rng)[0] for _ in range(2)])
    assert np.array_equal(out[0][0], out[1][0]) and np.array_equal(out[0][1], out[1][1])
    assert not np.array_equal(out[0][0], out[0][1])  # noise differs from frame to frame
    other = SceneRenderer(CFG, scene, seed=4, options=RenderOptions(ray_samples=4096)).render(full_pulse(), np.random.default_rng(11))[0]
    assert not np.array_equal(other, out[0][0])


def test_empty_scene_has_no_return_and_clutter_has_depth_jumps():
    r = SceneRenderer(CFG, get_scene("empty"), options=QUIET)
    t = r.truth_template
    assert np.all(np.isnan(t.row)) and np.all(np.isinf(t.range_m)) and np.all(t.surface == -1)
    e, _ = r.expected_electrons(full_pulse())
    assert e.max() == 0
    c = SceneRenderer(CFG, get_scene("clutter"), options=QUIET).truth_template
    ok = np.isfinite(c.range_m)
    assert len(set(c.surface[ok].tolist())) >= 4
    jumps = np.abs(np.diff(c.range_m[ok]))
    assert jumps.max() > 0.5


def test_surfaces_that_meet_make_one_line_without_a_gap():
    """Two wall segments in line (the poster-wall scene's seams) and a corner are one continuous
    laser curve: every column between them has its return and its light (interpolating only
    along one surface left a column at each seam without either), while a depth jump still has
    its empty columns (clutter, above)."""
    from device.sim.scene import scene_from_dict

    ys = np.linspace(-2.0, 2.0, 17)  # a wall in 16 segments (a seam falls between two laser samples'
    # columns one time in a few), and a second wall at a corner
    walls = [{"from": [2.0, a], "to": [2.0, b]} for a, b in zip(ys[:-1], ys[1:])] + [{"from": [2.0, 2.0], "to": [0.5, 3.5]}]
    r = SceneRenderer(CFG, scene_from_dict({"wall": walls}), options=QUIET)
    t = r.truth_template
    has = np.flatnonzero(np.isfinite(t.range_m))
    assert len(set(t.surface[has].tolist())) == 17
    assert np.all(np.diff(has) == 1)  # no column without its return from the first to the last
    e, _ = r.expected_electrons(full_pulse())
    line = e.max(axis=0)
    seams = has[1:][np.diff(t.surface[has]) != 0]
    assert seams.size == 16
    for c in seams:  # as bright as the columns beside it
        assert line[c - 1 : c + 1].min() > 0.8 * min(line[c - 4], line[c + 3])


def test_glossy_floor_makes_a_ghost_line_below_the_real_one():
    scene = get_scene("glossy-floor")
    with_gloss = SceneRenderer(CFG, scene, options=QUIET)
    no_gloss = SceneRenderer(CFG, scene, options=QUIET.without("gloss"))
    e1, _ = with_gloss.expected_electrons(full_pulse())
    e0, _ = no_gloss.expected_electrons(full_pulse())
    c = 820
    row = with_gloss.truth_template.row[c]
    ghost = e1[:, c] - e0[:, c]
    assert ghost.max() > 0 and np.argmax(ghost) > row + 3  # the mirror image lies further down
    assert ghost.sum() == pytest.approx(0.4 * e0[:, c].sum(), rel=0.3)  # gloss 0.4, slightly farther virtual point


def test_sunlight_saturates_the_background_at_a_long_exposure():
    r = SceneRenderer(CFG, get_scene("sunlight"), options=RenderOptions().without("noise"))
    img, _ = r.render(full_pulse(), np.random.default_rng(0))
    truth = r.truth_template
    cols = np.nonzero(np.isfinite(truth.row))[0]
    rows = np.round(truth.row[cols]).astype(int)
    assert np.mean(img[rows, cols] == 255) > 0.9  # the wall is white: nothing left to see the laser in


def test_multiplicative_speckle_is_static_and_has_the_configured_contrast():
    opts = RenderOptions(noise=False, ambient=False, texture=False, speckle=True, speckle_contrast=0.5,
                         speckle_model="multiplicative")
    r = SceneRenderer(CFG, wall_scene(1.0), options=opts)
    flat = SceneRenderer(CFG, wall_scene(1.0), options=opts.without("speckle"))
    e, _ = r.expected_electrons(full_pulse())
    e0, _ = flat.expected_electrons(full_pulse())
    m = e0 > 0.2 * e0.max()
    ratio = e[m] / e0[m]
    assert ratio.mean() == pytest.approx(1.0, abs=0.05)
    assert ratio.std() == pytest.approx(0.5, abs=0.08)
    e2, _ = r.expected_electrons(full_pulse(t=2 * 10**9))
    assert np.array_equal(e, e2)


def test_render_options_validate():
    with pytest.raises(ValueError, match="speckle_contrast"):
        RenderOptions(speckle_contrast=1.5)


def test_any_image_size_renders_with_consistent_truth():
    """A 416x232 camera (mode 5 scaled by 1/4): same geometry, smaller frames."""
    import dataclasses

    from device.model.camera import CameraModel, Intrinsics

    k = CFG.camera.intrinsics
    small = dataclasses.replace(
        CFG, width=416, height=232, active_width=410, active_height=230,
        camera=CameraModel(Intrinsics(k.fx / 4, k.fy / 4, k.cx / 4, k.cy / 4, 0.0, 416, 232), CFG.camera.distortion))
    r = SceneRenderer(small, wall_scene(1.0), options=QUIET)
    img, truth = r.render(full_pulse(), np.random.default_rng(0))
    assert img.shape == (232, 416) and truth.row.shape == (416,) and truth.lit_rows.shape == (232,)
    cols = np.nonzero(np.isfinite(truth.row))[0]
    assert 300 < cols.size <= 410 and cols.max() < 410  # nothing outside the active area
    e, _ = r.expected_electrons(full_pulse())
    assert not e[:, 410:].any() and not e[230:].any()
    rows = np.arange(e.shape[0])[:, None]
    centroid = (e[:, cols] * rows).sum(0) / e[:, cols].sum(0)
    inner = (truth.row[cols] > 6) & (truth.row[cols] < 223)  # the line's band is not cut by the frame edge
    assert np.max(np.abs(centroid - truth.row[cols])[inner]) < 0.01


def test_isp_denoise_lowers_noise_and_sharpening_raises_the_line_peak():
    scene = wall_scene(1.5)
    base = RenderOptions(speckle=False)
    plain = SceneRenderer(CFG, scene, options=base, seed=1)
    denoised = SceneRenderer(CFG, scene, options=RenderOptions(speckle=False, isp_denoise=1.0), seed=1)
    flat = np.s_[600:700, 200:1400]  # floor-less wall scene: backdrop/wall texture region far from the line
    a, _ = plain.render(FrameTiming(10**9, 40000.0, LINE_NS), np.random.default_rng(0))
    b, _ = denoised.render(FrameTiming(10**9, 40000.0, LINE_NS), np.random.default_rng(0))
    assert np.diff(b[flat].astype(float), axis=1).std() < 0.8 * np.diff(a[flat].astype(float), axis=1).std()
    far = wall_scene(3.0, ambient="dark")  # an unsaturated line
    quiet = SceneRenderer(CFG, far, options=RenderOptions(speckle=False, noise=False), seed=1)
    sharp = SceneRenderer(CFG, far, options=RenderOptions(speckle=False, noise=False, isp_sharpen=1.0), seed=1)
    q, truth = quiet.render(full_pulse(), np.random.default_rng(0))
    s, _ = sharp.render(full_pulse(), np.random.default_rng(0))
    c = 820
    assert 20 < q[:, c].max() < 200 and s[:, c].max() > 1.2 * q[:, c].max()
    with pytest.raises(ValueError, match="isp_denoise"):
        RenderOptions(isp_denoise=2.0)


def test_builtin_scenes_do_what_their_names_say():
    fast = RenderOptions(noise=False, speckle=False, ambient=False, texture=False, ray_samples=8192)
    # targets: the 90 % strips return 9x the electrons of the 10 % strips at the same distance
    r = SceneRenderer(CFG, get_scene("targets"), options=fast)
    e, _ = r.expected_electrons(full_pulse())
    t = r.truth_template
    sums = e.sum(axis=0)
    refl = np.array([s.material.reflectivity for s in r.scene.surfaces])
    ok = np.isfinite(t.row) & (np.abs(t.angle_rad) < 0.15)  # near the axis: same range and incidence
    hi = sums[ok & (refl[t.surface] == 0.9)].mean()
    lo = sums[ok & (refl[t.surface] == 0.1)].mean()
    assert hi / lo == pytest.approx(9.0, rel=0.05)
    # far: every return beyond 3.5 m; near: returns closer than 5 cm
    far = SceneRenderer(CFG, get_scene("far"), options=fast).truth_template
    assert np.nanmin(far.range_m[np.isfinite(far.row)]) > 3.5
    near = SceneRenderer(CFG, get_scene("near"), options=fast).truth_template
    assert np.nanmin(near.range_m[np.isfinite(near.row)]) < 0.05


def _centroid_offsets(renderer):
    """Per column: noise-free line centroid (+-10 rows) minus the true row."""
    e, _ = renderer.expected_electrons(full_pulse())
    row = renderer.truth_template.row
    cols = np.nonzero(np.isfinite(row))[0]
    win = np.floor(row[cols]).astype(int)[None, :] + np.arange(-10, 12)[:, None]
    vals = e[win, cols[None, :]].astype(np.float64)
    return (vals * win).sum(0) / vals.sum(0) - row[cols]


@pytest.mark.parametrize("model", ["coherent", "multiplicative"])
def test_speckle_follows_the_scene_not_the_frame(model):
    opts = RenderOptions(noise=False, ambient=False, texture=False, speckle_model=model)
    r = SceneRenderer(CFG, wall_scene(1.0), options=opts, seed=5)
    e1, _ = r.expected_electrons(full_pulse())
    e2, _ = r.expected_electrons(full_pulse(t=2 * 10**9))
    assert np.array_equal(e1, e2)  # static from frame to frame
    a = _centroid_offsets(r)
    b = _centroid_offsets(SceneRenderer(CFG, wall_scene(1.0), options=opts, seed=5))
    moved = _centroid_offsets(SceneRenderer(CFG, wall_scene(1.0005), options=opts, seed=5))  # same rows, new scene
    assert np.array_equal(a, b)
    assert a.std() > 0.1
    n = min(a.size, moved.size)
    assert abs(np.corrcoef(a[:n], moved[:n])[0, 1]) < 0.5


def test_the_background_is_imaged_through_the_lens_as_the_line_is():
    """A texture's edge is drawn as a lens draws it: the background's rays are point samples, so
    the lens's blur and the pixel's area are applied to them (render.py lens_blur: the line's
    blur and defocus, and the pixel's 1/12 px^2), not a step within one row, which no camera
    shows and which a turned frame's resampling turned into residues (BENCHMARKS.md "Motion")."""
    from device.sim.render import lens_blur

    def rise(o):  # 10-90 % rise of a point-sampled step through the lens, px
        col = lens_blur(step, o)[:, 4]
        assert col.sum() == pytest.approx(step[:, 4].sum(), rel=1e-4)
        return np.interp(90.0, col, np.arange(40)) - np.interp(10.0, col, np.arange(40))

    step = np.zeros((40, 8), np.float32)
    step[20:] = 100.0
    opts = RenderOptions()
    # a camera: the lens's Gaussian (1.1 px), then the pixel's box (1/12 px^2): 2.563 sigma; the
    # renderer's point samples through one Gaussian come within 1 % of it, 4 % short without the box
    assert rise(opts) == pytest.approx(2.563 * math.sqrt(opts.blur_sigma_px**2 + 1 / 12), rel=0.02)
    assert rise(COHERENT_DEFOCUSED) > 1.1 * rise(opts)  # the defocus widens it too
    assert lens_blur(step, replace(opts, background_lens=False)) is step  # point-sampled: as cast
    # the poster wall's checker edge under the laser's rows, without noise: the edge spreads over
    # rows (its largest step between two rows at most ~1 / (sigma sqrt(2 pi)) of it), as a lens's does
    cfg = load_preset("thesis-calibrated")
    r = SceneRenderer(cfg, get_scene("poster-wall"), options=opts.without("noise", "speckle"))
    image = r.render(FrameTiming(10**9, 10000.0, cfg.window.mode.line_time_ns), np.random.default_rng(0))[0]
    c = int(np.nonzero(r.truth_template.surface == 1)[0][120])
    profile = image[:, c].astype(float)[:400]
    jumps = np.abs(np.diff(profile))
    edge = profile.max() - profile.min()
    assert edge > 30 and jumps.max() < 0.5 * edge


def test_renderers_of_one_camera_share_its_unprojected_pixels_and_cannot_change_them():
    from device.sim.render import _pixel_rays
    from device.sim.scene import with_motion

    moving = with_motion(get_scene("office"), yaw_rate_deg_s=45)
    a = SceneRenderer(CFG, moving)
    hits = _pixel_rays.cache_info().hits
    b = SceneRenderer(CFG, with_motion(get_scene("person"), yaw_rate_deg_s=45))
    assert _pixel_rays.cache_info().hits == hits + 1  # the second renderer unprojected nothing
    xy, valid = _pixel_rays(CFG.camera, a.active_width, a.active_height, 1)
    with pytest.raises(ValueError, match="read-only"):
        xy[0, 0] = 1.0
    with pytest.raises(ValueError, match="read-only"):
        valid[0, 0] = False
    # each renderer's rays are its own: turned by its own scan frame, the same here
    assert np.array_equal(a._moving_rays[0], b._moving_rays[0]) and a._moving_rays[0] is not b._moving_rays[0]
    # another camera is unprojected again, and sees its pixels elsewhere
    other = replace(CFG, camera=replace(CFG.camera, intrinsics=replace(CFG.camera.intrinsics, fx=CFG.camera.intrinsics.fx * 1.1)))
    misses = _pixel_rays.cache_info().misses
    c = SceneRenderer(other, moving)
    assert _pixel_rays.cache_info().misses == misses + 1
    assert not np.array_equal(c._moving_rays[0], a._moving_rays[0])
