"""Scene renderer: luminance frames of the line laser on a scene, with exact ground truth.

How a frame is made (everything static is computed once per :class:`SceneRenderer`):

1. *Laser curve.* The laser fan (half-angle = fan/2 about the scan x axis, source at the scan
   origin) is cast in its own plane against the scene (``options.ray_samples`` rays); the first
   hit of each ray is a lit point. A lit point is kept if the camera sees it (a 3-D ray from the
   optical centre reaches it unoccluded) and projected with the project's forward camera model
   (``device.model.camera.project_points``, distortion included). Between consecutive samples on
   the same surface, the curve is resampled at every integer image column: that column's true
   laser row (sub-pixel), 3-D point, range and surface are the truth (FrameTruth).
2. *Photometry* (per column, electrons per second summed over the line's rows):
   the line laser spreads ``P`` over the fan angle ``phi``: at range r the surface receives
   ``P cos(i) / (phi r)`` watts per metre of line (irradiance ~ 1/r, thesis eq. 3.46); a
   Lambertian surface of reflectivity rho has radiance rho/pi times that, integrated over the line
   height; the lens (f-number N, transmission T) gives image irradiance pi L / (4 N^2), and one
   pixel row covers z / f_y metres of the surface, so the column collects
   ``T pitch^2 rho P cos(i) f_y / (4 N^2 phi r z)`` watts, times QE * lambda / (h c) electrons/J.
   Off-axis factors (cos^4 falloff, the pixel's footprint growing off axis and with the wall's
   tilt to the ray, distortion's local scale) are left out; the anchoring absorbs their mean.
3. *Line profile.* The illuminated line is a Gaussian in the row direction of sigma
   f_y h / 4 / z (h = [laser] line_height_m as the 1/e^2 full height). Without speckle (or with
   the multiplicative model) it is blurred by a Gaussian of sigma^2 = blur^2 + defocus^2 and
   integrated over each pixel (erf differences) in a band of +-4 sigma rows around the true row.
4. *Speckle* (Dorsch, Haeusler & Herrmann, "Laser triangulation: fundamental uncertainty in
   distance measurement", Appl. Opt. 33, 1994; Goodman, Speckle Phenomena in Optics).
   ``speckle_model="coherent"`` (the default, coherent_line_profiles): per column, the line's
   complex field (amplitude sqrt of the profile, a random phase per surface sample, static per
   scene, pose and seed) is imaged through the lens's coherent pupil (|f| <= 1 / (2 lambda N),
   with a defocus as a quadratic pupil phase), intensity |field|^2, then the incoherent blur and
   the pixel rows. Contrast C < 1 (laser linewidth, surface depth) sums independent patterns.
   Speckle and line are one field, so the centroid's scatter is what the optics allows: for a
   focused lens and a line image at the resolution limit, C lambda N / pi (Dorsch; checked within
   12 % by tests/test_sim_speckle.py). ``"multiplicative"`` (kept for comparison) multiplies the
   profile by a separate static pattern: complex Gaussian noise low-passed to grains of g lambda N
   (g = speckle_grain_factor, 2.44: the Airy diameter), intensity, rescaled to the contrast. It is
   not bounded by the line's own field: in focus it gives a single column 0.47 px of centroid
   scatter at f/2, twice Dorsch's 0.23 px (BENCHMARKS.md "Simulator").
5. *Gloss.* A glossy flat surface (floor or wall, ``gloss`` > 0) mirrors the lit points: the
   camera sees their mirror images (virtual points) where the reflection point lies on the
   mirror, with ``gloss`` times the radiance: a ghost line. Occlusion of the mirrored path is
   not modelled.
6. *Background.* Once per renderer, a ray per 2x2 pixel block (backward projection) is cast
   into the scene; the hit surface's reflectivity and procedural texture under the scene's
   ambient irradiance give ambient electrons per second per pixel (no hit: a 20 % backdrop),
   then the lens (``lens_blur``: the line's blur and defocus of step 3, and the pixel's area),
   as a camera images every point of the scene, not only the laser's.
7. *Rolling shutter.* Row r is exposed during [T - E + r t_line, T + r t_line] (Frame docstring);
   its laser electrons are the column rate times the overlap of that window with the laser's
   pulse windows; ambient electrons are rate x E. Then the sensor (device.sim.sensor). For
   speed the temporal noise comes from a cached table of standard normals (2 frames long, drawn
   once per renderer) read from a random offset per frame: a pixel gets another table entry in
   every frame (unless two offsets coincide), but a frame's spatial pattern is a shifted copy of
   part of an earlier frame's (``noise_table=False`` draws afresh, several times slower).

8. *Flicker* (device/sim/motion.py): the ambient light of a row is its irradiance's mean over
   that row's own exposure window, so the flicker's phase changes from row to row.
9. *Motion* (issue 16, device/sim/motion.py: the sensor on a robot, moving objects). A scene in
   which something moves is rendered per frame instead of from the static caches. The background:
   each row's exposure window is cut into ``n`` equal time slices (so that the image moves at most
   ``RenderOptions.motion_blur_px`` between two: motion blur, as continuous as the pixels resolve
   it, up to ``max_time_slices``: 32 px of motion in an exposure (the operating point's fastest,
   180 deg/s at 1 m/s, moves ~30 px in its 10 ms); beyond that the slices lie further apart. With
   slices 4 px of image motion apart, the default before, a camera's smooth blur came out as a few
   sharp copies: a 4-column stripe texture stayed crisp while the robot turned, and where the
   pitched view moved a horizontal edge across a row, the copies mixed into a bright one-row ridge
   that the unlit neighbours do not show: a phantom line at 0.83 m before a wall at 2.85 m,
   BENCHMARKS.md "Motion"), and in each slice every row is cast from where the sensor was at that
   row's own time (the rolling shutter: each row sees the scene where it was then; translation
   gives depth-dependent parallax), against the objects where they were (a block of rows per object
   position: an object moves < 2 mm in that time); a ray every ``motion_step`` pixels (default
   every pixel, as a sensor samples it: a coarser grid, bilinearly interpolated, is fixed to the
   sensor while the texture moves over it, so a texture's sharp edge changes its shape from frame
   to frame. No background model removes that residue: with the unlit neighbours turned to the lit
   frame it left 13-39 columns > 5 % off per point of `laserpi bench motion` at 4 px, 10-20 at 2
   px, 0-4 at 1 px, BENCHMARKS.md "Motion"). The laser: the time the pulse lights the frame is cut
   into slices likewise; in each the laser curve is cast from the sensor's pose then, with its own
   speckle (speckle decorrelates as the spot moves over the surface: with slices a pixel of image
   motion apart, about twice per grain of the coherent model, 2.44 lambda N = 3.9 um or 1.8 px:
   somewhat more averaging than a camera gets, where slices 4 px apart gave half as much as it
   gets), and lights each row for that row's overlap with the slice. The truth of a column is the
   mean over the slices weighted by that light (the centroid of the smeared line: what a perfect
   pipeline measures), with its time (``FrameTruth.time_ns``); a column lit in less than half of
   that light by a surface has no return. Glossy ghosts are not rendered for a moving scene.

Each effect can be switched off in :class:`RenderOptions`; an effect a scene does not use
(no gloss, no ambient, no pulse, no motion) costs nothing.

Anchoring (device.sim.anchoring; BENCHMARKS.md "Simulator"). The thesis's reference pipeline
(device.vision.reference) at the thesis geometry (thesis-calibrated, 25 mW, 17.4 ms pulse, 40 ms
exposure) on the defaults gives ~0.9 % at 2 m and ~1.1 % at 2.5 m on the 90 % wall: the image's
share of the thesis's ~1.8 % and ~2.4 % (section 6.4.3). The rest is its prototype's
calibration residual (a fixed per-column row error, device.sim.anchoring.THESIS_RESIDUAL_PX,
fitted at 2 m; 2.5 m is then a prediction), which a pipeline scored here with an exact
calibration does not see. The photometry is anchored on its own: with analogue gain 10
(sensor.SIMULATOR_DEFAULT) and indoor ambient 0.5 % of in-band sunlight, the 10 % wall's columns
with a return shrink with range and sunlight gives no output.
- Defaults: coherent speckle, contrast 1 (a rough wall; a multimode diode's coherence length
  still exceeds the wall's roughness), the lens in focus (defocus 0), incoherent blur 1.1 px.
- COHERENT_DEFOCUSED: the other explanation of the thesis's error, without a calibration residual:
  the lens defocused by a 1.2 px (sigma) geometric blur (coherent, so it sets the grain: an M12
  lens focused by eye in visible light is out of focus at 808 nm; the thesis does not report its
  line width), incoherent blur 0.5 px. Its reference error alone is the thesis's. A sensor built
  from this project is focused at 808 nm (README), so the defaults assume focus; the pipeline
  benchmark also reports the defocused set.
`laserpi bench sim --anchor [--defocused]` prints the table; BENCHMARKS.md "Simulator" has it.
"""

from __future__ import annotations

import functools
import math
import zlib
from dataclasses import dataclass, replace
from typing import Sequence

import numpy as np

from ..config import SensorConfig
from ..model.camera import CameraModel, project_points, undistort_robust, pixel_grid
from ..model.scan_frame import scan_frame, to_scan_plane
from ..model.irradiance import band_irradiance_w_m2
from .geometry import Hits, cast, laser_prims, mirror, primitives, texture_factor, value_noise
from .motion import flicker_mean, image_speed_px_s, rotation_z, scene_at, sensor_pose
from .scene import AMBIENT_FRACTION, Floor, Scene, Wall
from .sensor import SIMULATOR_DEFAULT, SensorParams, sensor_frame
from .special import erf
from .truth import FrameTruth

PLANCK_J_S = 6.62607015e-34
LIGHT_M_S = 299792458.0
BACKDROP_REFLECTIVITY = 0.2
SPECKLE_MODELS = ("coherent", "multiplicative")


@dataclass(frozen=True)
class RenderOptions:
    """Switches and knobs of the renderer; every effect can be turned off to isolate it."""

    noise: bool = True  # shot + read noise in the sensor
    speckle: bool = True
    ambient: bool = True  # the scene's ambient light (background image)
    gloss: bool = True  # ghost reflections of glossy surfaces
    texture: bool = True  # procedural reflectivity texture
    rolling_shutter: bool = True  # off: every row is exposed as row 0 (a global shutter)
    background_lens: bool = True  # the background through the lens (step 6); off: point-sampled, a texture's edge a step within a row
    speckle_contrast: float = 1.0  # std/mean of the speckle on the line (1 = fully developed)
    speckle_model: str = "coherent"  # the line's own field through the pupil, or "multiplicative"
    speckle_grain_factor: float = 2.44  # multiplicative model only: grain = factor x lambda x N (2.44: Airy)
    speckle_subsamples: int = 8  # coherent model: field samples per pixel row
    blur_sigma_px: float = 1.1  # incoherent blur (Gaussian sigma) of the line, px (all of it when defocus is 0)
    defocus_sigma_px: float = 0.0  # lens defocus: sigma of its geometric blur, px (a pupil phase when coherent)
    optics_transmission: float = 0.8  # lens x bandpass filter at the laser wavelength (ASSUMPTION)
    ray_samples: int = 16384  # laser rays across the fan
    background_step: int = 2  # background rays every N pixels (texture detail, paid once)
    noise_table: bool = True  # draw noise from a cached table (fast) instead of per frame
    isp_denoise: float = 0.0  # ISP spatial denoise: blend towards a 3x3 Gaussian, 0 (off) .. 1
    isp_sharpen: float = 0.0  # ISP sharpening: unsharp-mask amount (5x5 Gaussian), 0 (off) .. 2
    motion_step: int = 1  # moving scenes: background rays every N pixels, per frame (step 9)
    motion_blur_px: float = 1.0  # moving scenes: the image moves at most this far between two time slices (step 9) ...
    max_time_slices: int = 32  # ... with at most this many slices per exposure (and per pulse)

    def __post_init__(self) -> None:
        if not 0 <= self.speckle_contrast <= 1:
            raise ValueError(f"render: speckle_contrast must be in [0, 1], got {self.speckle_contrast}")
        if self.speckle_model not in SPECKLE_MODELS:
            raise ValueError(f"render: speckle_model must be one of {SPECKLE_MODELS}, got {self.speckle_model!r}")
        if not 4 <= self.speckle_subsamples <= 32:
            raise ValueError(f"render: speckle_subsamples must be in [4, 32], got {self.speckle_subsamples}")
        for name in ("speckle_grain_factor", "optics_transmission"):
            if not getattr(self, name) > 0:
                raise ValueError(f"render: {name} must be positive, got {getattr(self, name)}")
        if not 0 <= self.defocus_sigma_px <= 5:
            raise ValueError(f"render: defocus_sigma_px must be in [0, 5] px, got {self.defocus_sigma_px}")
        if self.blur_sigma_px < 0.3:
            raise ValueError(f"render: blur_sigma_px must be >= 0.3 px (a lens is never sharper), got {self.blur_sigma_px}")
        if not 0 <= self.isp_denoise <= 1 or not 0 <= self.isp_sharpen <= 2:
            raise ValueError(f"render: isp_denoise must be in [0, 1] and isp_sharpen in [0, 2], got "
                             f"{self.isp_denoise}, {self.isp_sharpen}")
        if self.ray_samples < 16 or self.background_step < 1 or self.motion_step < 1:
            raise ValueError("render: ray_samples must be >= 16, background_step and motion_step >= 1")
        if not self.motion_blur_px > 0 or self.max_time_slices < 1:
            raise ValueError(f"render: motion_blur_px must be positive and max_time_slices >= 1, got "
                             f"{self.motion_blur_px}, {self.max_time_slices}")

    def without(self, *effects: str) -> "RenderOptions":
        """These options with the named effects switched off, e.g. ``without('noise', 'speckle')``."""
        return replace(self, **{e: False for e in effects})


# The lens defocused (module docstring, "Anchoring"): fully developed coherent speckle, a 1.2 px
# (sigma) geometric blur as a pupil phase, 0.5 px incoherent; reproduces the thesis's error alone.
COHERENT_DEFOCUSED = RenderOptions(defocus_sigma_px=1.2, blur_sigma_px=0.5)


@dataclass(frozen=True)
class FrameTiming:
    """When a frame was exposed and when the laser was on (CLOCK_MONOTONIC ns).

    ``sensor_timestamp_ns``: T, start of row-0 readout; ``exposure_us``: E; ``pulses_ns``: laser
    on-windows [(on, off), ...] overlapping this frame.
    """

    sensor_timestamp_ns: int
    exposure_us: float
    line_time_ns: float
    pulses_ns: tuple[tuple[int, int], ...] = ()


def row_overlap_s(timing: FrameTiming, height: int, rolling_shutter: bool = True) -> np.ndarray:
    """(height,) seconds each row's exposure window overlaps the laser pulses."""
    r = np.arange(height, dtype=np.float64) * (timing.line_time_ns if rolling_shutter else 0.0)
    end = timing.sensor_timestamp_ns + r
    start = end - timing.exposure_us * 1e3
    total = np.zeros(height)
    for on, off in timing.pulses_ns:
        if off < on:
            raise ValueError(f"pulse window ({on}, {off}) ends before it starts")
        total += np.clip(np.minimum(end, off) - np.maximum(start, on), 0.0, None)
    return total * 1e-9


def ambient_irradiance_w_m2(scene: Scene, cfg: SensorConfig) -> float:
    """In-band ambient irradiance on the scene's surfaces: the scene's own figure, or its fraction
    (AMBIENT_FRACTION) of the AM1.5 solar irradiance through the configured bandpass (thesis 3.4)."""
    if scene.ambient_w_m2 is not None:
        return scene.ambient_w_m2 * scene.ambient_scale
    sun = band_irradiance_w_m2(cfg.laser.wavelength_m * 1e9, cfg.optics.bandpass_width_m * 1e9)
    return AMBIENT_FRACTION[scene.ambient] * sun * scene.ambient_scale


def photons_per_joule(wavelength_m: float) -> float:
    return wavelength_m / (PLANCK_J_S * LIGHT_M_S)


def column_gain(cfg: SensorConfig, sensor: SensorParams, options: RenderOptions) -> float:
    """K of ``electrons/s per column = K rho cos(i) / (r z)`` (module docstring, step 2), e- m^2 / s."""
    o, las = cfg.optics, cfg.laser
    return (options.optics_transmission * o.pixel_pitch_m**2 * las.power_w * cfg.camera.intrinsics.fy
            / (4 * o.f_number**2 * las.fan_angle_rad) * sensor.qe * photons_per_joule(las.wavelength_m))


def ambient_gain(cfg: SensorConfig, sensor: SensorParams, options: RenderOptions) -> float:
    """Electrons/s per pixel per (reflectivity x W/m^2 of ambient irradiance on the surface)."""
    o = cfg.optics
    return (options.optics_transmission * o.pixel_pitch_m**2 / (4 * o.f_number**2) * sensor.qe
            * photons_per_joule(cfg.laser.wavelength_m))


@dataclass(frozen=True)
class _Crossings:
    """The lit curve resampled at integer columns (one entry per column crossing)."""

    col: np.ndarray
    row: np.ndarray
    rate: np.ndarray  # electrons/s summed over the column
    depth: np.ndarray  # camera z, metres
    points: np.ndarray  # (M, 3) camera frame
    surface: np.ndarray


#: Two neighbouring laser samples on different surfaces nearer each other than this share of
#: their depth are one continuous curve: the surfaces meet there (two wall segments in line, a
#: corner). Neighbouring samples on one surface lie ~1.5e-4 of the depth apart (16384 rays over
#: the fan; 6x that at 80 deg incidence); a surface's edge in front of another leaves centimetres.
SEAM_REL = 2e-3


def _resample_columns(u, v, ok, surface, rate, depth, points) -> _Crossings:
    """Interpolate per-sample curve values at every integer column between consecutive samples
    that are both valid and on the same surface, or on surfaces that meet there (SEAM_REL):
    never across a depth jump or an occlusion."""
    with np.errstate(invalid="ignore"):
        meet = np.linalg.norm(points[1:] - points[:-1], axis=1) <= SEAM_REL * np.minimum(depth[:-1], depth[1:])
    pair = ok[:-1] & ok[1:] & ((surface[:-1] == surface[1:]) | meet)
    k = np.nonzero(pair)[0]
    u0, u1 = u[k], u[k + 1]
    lo, hi = np.minimum(u0, u1), np.maximum(u0, u1)
    first = np.ceil(lo)
    count = np.maximum(np.ceil(hi) - first, 0).astype(int)  # integers c with lo <= c < hi
    kk = np.repeat(k, count)
    c = np.repeat(first, count) + (np.arange(count.sum()) - np.repeat(np.cumsum(count) - count, count))
    with np.errstate(invalid="ignore", divide="ignore"):
        w = (c - u[kk]) / (u[kk + 1] - u[kk])
    lerp = lambda a: a[kk] + w * (a[kk + 1] - a[kk])  # noqa: E731
    pts = points[kk] + w[:, None] * (points[kk + 1] - points[kk])
    return _Crossings(c.astype(int), lerp(v), lerp(rate), lerp(depth), pts, surface[kk])


class SceneRenderer:
    """Renders frames of one scene seen by one sensor configuration; caches everything static.

    ``render(timing, rng)`` -> (uint8 image, FrameTruth); ``expected_electrons(timing)`` -> the
    noise-free expected electrons per pixel (float32) that the sensor model turns into a frame.
    ``time_zero_ns``: CLOCK_MONOTONIC of the scene's time zero (motion and flicker, step 8-9).
    """

    def __init__(self, cfg: SensorConfig, scene: Scene, sensor: SensorParams = SIMULATOR_DEFAULT,
                 options: RenderOptions = RenderOptions(), seed: int = 0, time_zero_ns: int = 0):
        self.cfg, self.scene, self.sensor, self.options, self.seed = cfg, scene, sensor, options, seed
        self.time_zero_ns = time_zero_ns
        self.height, self.width = cfg.height, cfg.width
        self.active_height = cfg.active_height or cfg.height
        self.active_width = cfg.active_width or cfg.width
        self.frame = scan_frame(cfg.plane)
        self.camera_scan = -self.frame.rotation @ self.frame.origin  # optical centre in the scan frame
        self._prims = primitives(scene)
        self._tex_seed = seed
        k_col = column_gain(cfg, sensor, options)
        primary, lit = self._laser_curve(k_col)
        self.crossings = primary
        self.truth_template = self._truth(primary)
        ghosts = self._ghosts(lit, k_col) if options.gloss else []
        self._splat = self._splat_table([primary, *ghosts])
        self.ambient_w_m2 = ambient_irradiance_w_m2(scene, cfg)
        lit_by_ambient = options.ambient and self.ambient_w_m2 > 0
        self._ambient = self._ambient_rate() if lit_by_ambient and scene.still else None
        self._moving_rays = self._background_rays(options.motion_step) if lit_by_ambient and not scene.still else None
        self._k_col = k_col
        self._normals = None

    # ------------------------------------------------------------ static geometry
    def _laser_curve(self, k_col: float, pose: tuple[float, float, float] | None = None,
                     prims=None) -> tuple[_Crossings, dict]:
        """The lit curve (step 1); for a moving scene with the sensor at ``pose`` (yaw, x, y) in
        the scene's frame and the scene's primitives ``prims`` at that time."""
        cfg = self.cfg
        prims = self._prims if prims is None else prims
        half = cfg.laser.fan_angle_rad / 2
        theta = np.linspace(-half, half, self.options.ray_samples)
        dirs = np.stack([np.cos(theta), np.sin(theta), np.zeros_like(theta)], axis=-1)
        origin, camera, dirs_w = np.zeros(3), self.camera_scan, dirs
        if pose is not None:
            rot = rotation_z(np.float64(pose[0]))
            origin = np.array([pose[1], pose[2], 0.0])
            camera, dirs_w = origin + rot @ self.camera_scan, dirs @ rot.T
        hits = cast(origin, dirs_w, laser_prims(prims))
        hit = hits.surface >= 0
        p_scan = dirs * np.where(hit, hits.t, 0.0)[:, None]
        cos_i = np.abs(np.sum(hits.normal * dirs_w, axis=-1))
        refl = self._reflectivity(hits)
        lit = {"p_scan": p_scan, "hit": hit, "surface": hits.surface, "r": hits.t, "cos_i": cos_i, "refl": refl}
        # visible from the camera: nothing between the optical centre and the point
        to_p = (p_scan - self.camera_scan) if pose is None else (origin + dirs_w * np.where(hit, hits.t, 0.0)[:, None] - camera)
        seen = cast(camera, to_p, prims)
        visible = hit & (seen.t >= 1 - 1e-7)
        cross = self._project_and_resample(p_scan, visible, hits.surface, k_col * refl * cos_i / np.where(hit, hits.t, 1.0))
        return cross, lit

    def _project_and_resample(self, p_scan, ok, surface, rate_times_z) -> _Crossings:
        p_cam = p_scan @ self.frame.rotation + self.frame.origin
        uv = project_points(p_cam, self.cfg.camera)
        depth = p_cam[:, 2]
        ok = ok & np.all(np.isfinite(uv), axis=-1) & (depth > 0)
        with np.errstate(divide="ignore", invalid="ignore"):
            rate = np.where(ok, rate_times_z / depth, 0.0)
        c = _resample_columns(uv[:, 0], uv[:, 1], ok, surface, rate, depth, p_cam)
        inside = (c.col >= 0) & (c.col < self.active_width) & (c.row >= -0.5) & (c.row <= self.active_height - 0.5)
        return _Crossings(*(getattr(c, f)[inside] for f in ("col", "row", "rate", "depth", "points", "surface")))

    def _reflectivity(self, hits: Hits) -> np.ndarray:
        """Diffuse reflectivity x texture at each hit (BACKDROP_REFLECTIVITY where nothing is hit)."""
        refl = np.full(hits.t.shape, BACKDROP_REFLECTIVITY)
        for i, s in enumerate(self.scene.surfaces):
            m = hits.surface == i
            if not m.any():
                continue
            f = 1.0
            if self.options.texture and s.material.texture != "plain":
                f = texture_factor(s.material.texture, hits.texcoord[m], s.material.texture_scale_m, self._tex_seed + i,
                                   s.material.texture_depth)
            refl[m] = np.minimum(s.material.reflectivity * f, 1.0)
        return refl

    def _ghosts(self, lit: dict, k_col: float) -> list[_Crossings]:
        out = []
        for i, s in enumerate(self.scene.surfaces):
            if not (isinstance(s, (Wall, Floor)) and s.material.gloss > 0):
                continue
            src = lit["hit"] & (lit["surface"] != i)
            virt = mirror(lit["p_scan"], s)
            c = self.camera_scan
            d = virt - c
            if isinstance(s, Floor):
                same_side = (c[2] > s.z) & (lit["p_scan"][:, 2] > s.z)
                with np.errstate(divide="ignore", invalid="ignore"):
                    t = (s.z - c[2]) / d[:, 2]
                on_mirror = same_side & (t > 0) & (t < 1)
            else:
                a, e = np.asarray(s.start), np.asarray(s.end) - np.asarray(s.start)
                nrm = np.array([e[1], -e[0]])
                same_side = np.sign((lit["p_scan"][:, :2] - a) @ nrm) == np.sign((c[:2] - a) @ nrm)
                one = cast(c, d, primitives(Scene("mirror", walls=(s,))))
                on_mirror = same_side & (one.t > 0) & (one.t < 1)
            rate_z = s.material.gloss * k_col * lit["refl"] * lit["cos_i"] / np.where(lit["hit"], lit["r"], 1.0)
            out.append(self._project_and_resample(virt, src & on_mirror, lit["surface"], rate_z))
        return out

    def _truth(self, c: _Crossings) -> FrameTruth:
        w = self.width
        row = np.full(w, np.nan)
        points = np.full((w, 3), np.nan)
        surface = np.full(w, -1, dtype=int)
        depth = np.full(w, np.inf)
        # the nearest visible crossing of each column is its true return
        order = np.lexsort((c.depth, c.col))
        first = np.ones(order.size, dtype=bool)
        first[1:] = c.col[order][1:] != c.col[order][:-1]
        sel = order[first]
        row[c.col[sel]], points[c.col[sel]], surface[c.col[sel]], depth[c.col[sel]] = c.row[sel], c.points[sel], c.surface[sel], c.depth[sel]
        angle, rng_m = to_scan_plane(points, self.frame)
        rng_m = np.where(np.isfinite(row), rng_m, np.inf)
        return FrameTruth(row, rng_m, angle, points, surface, np.zeros(self.height, dtype=bool))

    def _speckle_rng(self, tag: int) -> np.random.Generator:
        """The speckle's random numbers belong to this scene seen from this pose: another scene or
        laser plane (sensor moved) gives an independent pattern, the same ones the same pattern."""
        geometry_key = zlib.crc32(repr((self.scene, self.cfg.plane, self.cfg.camera)).encode())
        return np.random.default_rng([self.seed, geometry_key, tag])

    def _speckle(self) -> np.ndarray:
        """Multiplicative model: static (H, W) speckle field, mean 1, std = contrast."""
        h, w = self.height, self.width
        rng = self._speckle_rng(0x5BEC)
        field = rng.standard_normal((h, w)) + 1j * rng.standard_normal((h, w))
        fy, fx = np.fft.fftfreq(h)[:, None], np.fft.fftfreq(w)[None, :]
        o = self.cfg.optics
        cutoff = min(0.5, o.pixel_pitch_m / (2 * self.options.speckle_grain_factor * self.cfg.laser.wavelength_m * o.f_number))
        amp = np.fft.ifft2(np.fft.fft2(field) * (fx * fx + fy * fy <= cutoff * cutoff))
        inten = np.abs(amp) ** 2
        inten = (inten - inten.mean()) / inten.std()
        return np.clip(1.0 + self.options.speckle_contrast * inten, 0.0, None)

    def _splat_table(self, curves: Sequence[_Crossings],
                     speckle_rng: np.random.Generator | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(flat pixel index, electrons/s, row) of the laser line, duplicates summed; coherent
        speckle from ``speckle_rng`` (default: this scene's, static)."""
        cols = np.concatenate([c.col for c in curves])
        rows = np.concatenate([c.row for c in curves])
        rate = np.concatenate([c.rate for c in curves])
        depth = np.concatenate([c.depth for c in curves])
        if cols.size == 0:
            return np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.float32), np.zeros(0, dtype=np.int64)
        opt = self.options
        line_sigma = self.cfg.camera.intrinsics.fy * self.cfg.laser.line_height_m / 4 / depth
        sigma = np.sqrt(opt.blur_sigma_px**2 + opt.defocus_sigma_px**2 + line_sigma**2)
        half = int(math.ceil(4 * sigma.max())) + 1
        coherent = opt.speckle and opt.speckle_model == "coherent" and opt.speckle_contrast > 0
        if coherent:
            half += int(math.ceil(3 * opt.defocus_sigma_px)) + 2  # the coherent PSF's tails
            o = self.cfg.optics
            r, frac = coherent_line_profiles(
                rows, line_sigma, opt.blur_sigma_px, o.pixel_pitch_m / (2 * self.cfg.laser.wavelength_m * o.f_number),
                opt.speckle_contrast, half, opt.speckle_subsamples,
                speckle_rng if speckle_rng is not None else self._speckle_rng(0xC0E7), opt.defocus_sigma_px)
        else:
            r = np.floor(rows)[:, None] + np.arange(-half, half + 1)[None, :]
            s2 = math.sqrt(2) * sigma[:, None]
            edges = erf((r[:, :1] - 0.5 + np.arange(r.shape[1] + 1)[None, :] - rows[:, None]) / s2)
            frac = 0.5 * np.diff(edges, axis=1)  # each pixel's share: erf at its two edges
        val = rate[:, None] * frac
        r = r.astype(np.int64)
        c = np.broadcast_to(cols[:, None], r.shape)
        keep = (r >= 0) & (r < self.active_height) & (val > 0)
        r, c, val = r[keep], c[keep], val[keep]
        if opt.speckle and opt.speckle_model == "multiplicative":
            val = val * self._speckle()[r, c]
        flat = r * self.width + c
        uniq, inv = np.unique(flat, return_inverse=True)
        summed = np.bincount(inv, weights=val)
        return uniq, summed.astype(np.float32), uniq // self.width

    def _background_rays(self, step: int) -> tuple[np.ndarray, np.ndarray]:
        """Rays every ``step`` pixels of the active area: ((hh, ww, 3) directions in the scan
        frame, (hh, ww) valid)."""
        xy, valid = _pixel_rays(self.cfg.camera, self.active_width, self.active_height, step)
        d_cam = np.concatenate([xy, np.ones_like(xy[..., :1])], axis=-1).reshape(-1, 3)
        return (d_cam @ self.frame.rotation.T).reshape(valid.shape + (3,)), valid

    def _background_reflectivity(self, origin: np.ndarray, d_scan: np.ndarray, prims) -> np.ndarray:
        """Reflectivity seen along rays ``origin + t d_scan`` ((N, 3) or (3,), (N, 3)), backdrop included."""
        hits = cast(origin, d_scan, prims)
        refl = self._reflectivity(hits)
        nohit = hits.surface < 0
        if nohit.any() and self.options.texture:  # backdrop: texture by direction
            az = np.arctan2(d_scan[nohit, 1], d_scan[nohit, 0]) * 40
            d = d_scan[nohit]
            el = d[:, 2] / np.sqrt(np.einsum("ij,ij->i", d, d)) * 40
            refl[nohit] *= 1 + 0.3 * (2 * value_noise(az, el, self.seed + 99) - 1)
        return refl

    def _ambient_rate(self) -> np.ndarray:
        """(H, W) float32 ambient electrons per second per pixel, zero outside the active area,
        through the lens (lens_blur)."""
        step = self.options.background_step
        d_scan, valid = self._background_rays(step)
        hh, ww = valid.shape
        refl = self._background_reflectivity(self.camera_scan, d_scan.reshape(-1, 3), self._prims)
        refl[~valid.ravel()] = 0.0
        rate = (refl * self.ambient_w_m2 * ambient_gain(self.cfg, self.sensor, self.options)).reshape(hh, ww)
        full = np.repeat(np.repeat(rate, step, axis=0), step, axis=1)[: self.active_height, : self.active_width]
        out = np.zeros((self.height, self.width), dtype=np.float32)
        out[: self.active_height, : self.active_width] = lens_blur(full.astype(np.float32), self.options)
        return out

    # ------------------------------------------------------------ per frame
    def expected_electrons(self, timing: FrameTiming) -> tuple[np.ndarray, np.ndarray]:
        """(H, W) float32 expected electrons and the (H,) per-row pulse overlap in seconds."""
        overlap = row_overlap_s(timing, self.height, self.options.rolling_shutter)
        if self._ambient is not None and self.scene.flicker.depth:
            start, end = self._row_windows_s(timing)
            e = self._ambient * (np.float32(timing.exposure_us * 1e-6) * flicker_mean(self.scene.flicker, start, end)
                                 .astype(np.float32))[:, None]
        elif self._ambient is not None:
            e = self._ambient * np.float32(timing.exposure_us * 1e-6)
        else:
            e = np.zeros((self.height, self.width), dtype=np.float32)
        flat, val, rows = self._splat
        if flat.size and overlap.any():
            e.ravel()[flat] += val * overlap[rows].astype(np.float32)
        return e, overlap

    def render(self, timing: FrameTiming, rng: np.random.Generator) -> tuple[np.ndarray, FrameTruth]:
        """One frame (uint8 (H, W)) and its ground truth; deterministic for the rng's state."""
        if self.scene.still:
            e, overlap = self.expected_electrons(timing)
            truth = replace(self.truth_template, lit_rows=overlap > 0)
        else:
            e, overlap, truth = self._moving_frame(timing, np.random.default_rng(rng.integers(2**63)))
        normals = None
        if self.options.noise and self.options.noise_table:
            n = e.size
            if self._normals is None:
                self._normals = np.random.default_rng([self.seed, 0x4015E]).standard_normal(2 * n, dtype=np.float32)
            off = int(rng.integers(0, n))
            normals = self._normals[off: off + n].reshape(e.shape)
        image = sensor_frame(e, rng if self.options.noise else None, self.sensor, normals=normals)
        if self.options.isp_denoise or self.options.isp_sharpen:
            image = isp_filter(image, self.options.isp_denoise, self.options.isp_sharpen)
        return image, truth

    # ------------------------------------------------------------ per frame, moving scenes (step 9)
    def _row_windows_s(self, timing: FrameTiming) -> tuple[np.ndarray, np.ndarray]:
        """(H,) start and end of each row's exposure, seconds after the scene's time zero."""
        lt = timing.line_time_ns if self.options.rolling_shutter else 0.0
        end = (timing.sensor_timestamp_ns - self.time_zero_ns + np.arange(self.height) * lt) * 1e-9
        return end - timing.exposure_us * 1e-6, end

    def _slices(self, span_s: float) -> int:
        """Time slices for a span: the image moves at most motion_blur_px between two."""
        speed = image_speed_px_s(self.scene, self.cfg.camera.intrinsics.fx)
        return int(min(max(math.ceil(speed * span_s / self.options.motion_blur_px), 1), self.options.max_time_slices))

    def _moving_frame(self, timing: FrameTiming, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray, FrameTruth]:
        e = np.zeros((self.height, self.width), dtype=np.float32)
        if self._moving_rays is not None:
            self._moving_background(timing, e)
        overlap = np.zeros(self.height)
        parts = []  # (FrameTruth of a slice, (H,) seconds each row is lit in it, slice time)
        t0, t1 = (timing.sensor_timestamp_ns - timing.exposure_us * 1e3,
                  timing.sensor_timestamp_ns + (self.height - 1) * timing.line_time_ns)
        for on, off in timing.pulses_ns:
            a, b = max(on, t0), min(off, t1)
            if b <= a:
                continue
            n = self._slices((b - a) * 1e-9)
            for k in range(n):
                lo, hi = a + (b - a) * k / n, a + (b - a) * (k + 1) / n
                t_s = ((lo + hi) / 2 - self.time_zero_ns) * 1e-9
                ov = row_overlap_s(replace(timing, pulses_ns=((lo, hi),)), self.height, self.options.rolling_shutter)
                if not ov.any():
                    continue
                # when each row got this slice's light: the middle of its exposure's overlap with the slice
                start, end = self._row_windows_s(timing)
                t_rows = (np.maximum(start, (lo - self.time_zero_ns) * 1e-9) + np.minimum(end, (hi - self.time_zero_ns) * 1e-9)) / 2
                pose = tuple(float(x) for x in sensor_pose(self.scene.motion, t_s))
                cross, _ = self._laser_curve(self._k_col, pose, primitives(scene_at(self.scene, t_s)))
                flat, val, rows = self._splat_table([cross], rng)
                if flat.size:
                    e.ravel()[flat] += val * ov[rows].astype(np.float32)
                overlap += ov
                parts.append((self._truth(cross), ov, t_rows))
        if not parts:  # an unlit frame: where the line would have been, mid-exposure of the middle row
            t_s = ((t0 + t1) / 2 - self.time_zero_ns) * 1e-9
            pose = tuple(float(x) for x in sensor_pose(self.scene.motion, t_s))
            cross, _ = self._laser_curve(self._k_col, pose, primitives(scene_at(self.scene, t_s)))
            parts.append((self._truth(cross), np.ones(self.height), np.full(self.height, t_s)))
        return e, overlap, self._mean_truth(parts, overlap > 0)

    def _moving_background(self, timing: FrameTiming, e: np.ndarray) -> None:
        """Adds the ambient light of a moving scene to ``e`` (step 9)."""
        import cv2

        d_scan, valid = self._moving_rays
        hh, ww = valid.shape
        step = self.options.motion_step
        start, end = self._row_windows_s(timing)
        exposure_s = timing.exposure_us * 1e-6
        n = self._slices(exposure_s)
        gain = self.ambient_w_m2 * ambient_gain(self.cfg, self.sensor, self.options)
        grid_rows = np.minimum(np.arange(hh) * step + (step - 1) // 2, self.height - 1)
        block = 16  # grid rows per position of the moving objects
        h, w = self.active_height, self.active_width
        background = np.zeros((h, w), dtype=np.float32)
        for k in range(n):
            t_row = start[grid_rows] + (k + 0.5) * exposure_s / n
            yaw, x, y = sensor_pose(self.scene.motion, t_row)
            origin = np.stack([x, y, np.zeros_like(x)], -1) + rotation_z(yaw) @ self.camera_scan  # (hh, 3)
            c, s = np.cos(yaw)[:, None], np.sin(yaw)[:, None]  # each grid row's directions turned by its yaw
            d_w = np.stack([c * d_scan[..., 0] - s * d_scan[..., 1], s * d_scan[..., 0] + c * d_scan[..., 1],
                            d_scan[..., 2]], -1)
            refl = np.empty((hh, ww))
            for r0 in range(0, hh, block):
                r1 = min(r0 + block, hh)
                prims = primitives(scene_at(self.scene, float(t_row[(r0 + r1) // 2])))
                o = np.repeat(origin[r0:r1], ww, axis=0)
                refl[r0:r1] = self._background_reflectivity(o, d_w[r0:r1].reshape(-1, 3), prims).reshape(r1 - r0, ww)
            refl[~valid] = 0.0
            full = cv2.resize(refl.astype(np.float32), (ww * step, hh * step), interpolation=cv2.INTER_LINEAR)[:h, :w]
            lo = start + k * exposure_s / n
            light = (exposure_s / n * gain * flicker_mean(self.scene.flicker, lo, lo + exposure_s / n)).astype(np.float32)
            background += full * light[:h, None]
        # the slices' sum through the lens (the blur is linear); the blur mixes each row with
        # rows a few line times (~4 x 19 us) from its exposure window, ~0.35 px of image
        # motion at 180 deg/s: left out
        e[:h, :w] += lens_blur(background, self.options)

    def _mean_truth(self, parts: list, lit_rows: np.ndarray) -> FrameTruth:
        """The truth of a moving frame: each column's mean over the laser's time slices weighted by
        the light each gave the column's line (step 9)."""
        W = self.width
        rows = np.stack([p.row for p, _, _ in parts])  # (S, W)
        present = np.isfinite(rows)
        ref_row = np.where(present, rows, 0.0).sum(axis=0) / np.maximum(present.sum(axis=0), 1)
        ref = np.clip(np.rint(ref_row), 0, self.height - 1).astype(np.intp)
        weight = np.stack([ov[ref] for _, ov, _ in parts])  # (S, W) light of each slice at the column's line
        w_in = np.where(present, weight, 0.0)
        total, lit = weight.sum(axis=0), w_in.sum(axis=0)
        has = (lit > 0) & (lit >= 0.5 * total)
        with np.errstate(invalid="ignore", divide="ignore"):
            wn = w_in / lit
        mean = lambda a: np.sum(np.where(present[..., None] if a.ndim == 3 else present, a, 0.0) *  # noqa: E731
                                (wn[..., None] if a.ndim == 3 else wn), axis=0)
        row = np.where(has, mean(rows), np.nan)
        points = np.where(has[:, None], mean(np.stack([p.points for p, _, _ in parts])), np.nan)
        times = np.stack([t[ref] for _, _, t in parts])  # (S, W)
        time_ns = np.where(has, mean(times) * 1e9 + self.time_zero_ns, np.nan)
        surface = np.stack([p.surface for p, _, _ in parts])[np.argmax(w_in, axis=0), np.arange(W)]
        angle, rng_m = to_scan_plane(points, self.frame)
        # each surface's light-weighted mean range in the column; its nearest and farthest: one
        # surface gives range_m twice, a line that crossed a depth jump both surfaces' ranges
        ranges = np.where(present, np.stack([p.range_m for p, _, _ in parts]), 0.0)
        ids = np.stack([p.surface for p, _, _ in parts])
        span = np.stack([np.full(W, np.inf), np.full(W, -np.inf)], -1)
        for i in np.unique(ids[w_in > 0]):
            on = np.where(ids == i, w_in, 0.0)
            weight_i = on.sum(axis=0)
            with np.errstate(invalid="ignore", divide="ignore"):
                r_i = np.where(weight_i > 0, (on * ranges).sum(axis=0) / weight_i, np.nan)
            span[:, 0], span[:, 1] = np.fmin(span[:, 0], r_i), np.fmax(span[:, 1], r_i)
        return FrameTruth(row, np.where(has, rng_m, np.inf), np.where(has, angle, np.nan), points,
                          np.where(has, surface, -1), lit_rows, time_ns, np.where(has[:, None], span, np.nan))


@functools.lru_cache(maxsize=4)
def _pixel_rays(camera: CameraModel, width: int, height: int, step: int) -> tuple[np.ndarray, np.ndarray]:
    """The normalised camera coordinates ((hh, ww, 2), 0 where not valid) and validity (hh, ww)
    of the pixel centres every ``step`` pixels of a width x height area, read-only. Cached: a
    moving scene's renderer unprojects every pixel (~1.5 M, seconds), and the renderers of one
    camera (each sequence, each test, each sweep point) need the same."""
    hh, ww = -(-height // step), -(-width // step)
    grid = pixel_grid(ww, hh) * step + (step - 1) / 2
    un = undistort_robust(grid.reshape(-1, 2), camera, tol_px=1e-3)
    xy = np.where(un.valid[:, None], un.xy, 0.0).reshape(hh, ww, 2)
    valid = un.valid.reshape(hh, ww)
    xy.flags.writeable = valid.flags.writeable = False
    return xy, valid


def lens_blur(rate: np.ndarray, options: RenderOptions) -> np.ndarray:
    """The background's light through the lens (step 6): its rays are cast at the pixels' centres
    (or every background_step pixels), but a lens images every point of the scene as a spot and a
    pixel integrates over its area, as for the laser line (step 3). So the same incoherent blur and
    defocus (Gaussian sigmas, px), and the pixel's 1-px box as its variance 1/12, as one Gaussian
    (float32 (h, w) in, the same out; ``rate`` itself where ``options.background_lens`` is off).
    A still scene's rays are cast every ``background_step`` pixels and each fills its block before
    the blur, which then acts on blocks: at the default 2 px, about a 1.24 px Gaussian and faint
    block steps (a moving frame's rays are cast every pixel).
    Without it a texture's edge is a step within one pixel row, which no lens draws, and a
    turned frame's resampling leaves residues a camera does not (BENCHMARKS.md "Motion"); the
    option stays for the frames of a renderer that draws them so (the device must hold there too)."""
    import cv2

    if not options.background_lens:
        return rate

    sigma = math.sqrt(options.blur_sigma_px**2 + options.defocus_sigma_px**2 + 1.0 / 12.0)
    return cv2.GaussianBlur(rate, (0, 0), sigma, borderType=cv2.BORDER_REPLICATE)


def speckle_pattern_weights(contrast: float) -> np.ndarray:
    """Weights of K = ceil(1 / C^2) independent fully developed speckle patterns whose incoherent
    sum (weights summing to 1) has contrast C = sqrt(sum w^2): K - 1 equal weights and one larger.
    For C = 1 / sqrt(K) all K are equal (Goodman, Speckle Phenomena in Optics, 3.4: a sum of K
    uncorrelated patterns); other C in (0, 1] are the documented equivalent between two such K."""
    if not 0 < contrast <= 1:
        raise ValueError(f"speckle contrast must be in (0, 1], got {contrast}")
    k = max(1, math.ceil(1 / contrast**2 - 1e-9))
    big = (1 + math.sqrt(max((k - 1) * (k * contrast**2 - 1), 0.0))) / k
    return np.array([big] + [(1 - big) / (k - 1)] * (k - 1)) if k > 1 else np.ones(1)


def coherent_line_profiles(rows: np.ndarray, line_sigma_px: np.ndarray, blur_sigma_px: float,
                           pupil_cutoff_cyc_px: float, contrast: float, half: int, subsamples: int,
                           rng: np.random.Generator, defocus_sigma_px: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """Coherent speckle on the line, column by column (Dorsch, Haeusler & Herrmann 1994; Goodman).

    rows (M,): true line rows (sub-pixel); line_sigma_px (M,): the illuminated line's Gaussian
    intensity sigma on the sensor (geometric image, no blur). Per column: the object field is the
    line's amplitude profile sqrt(I0(y)) times circular complex Gaussian noise (a rough surface:
    random phase per sample, ``subsamples`` per pixel), imaged through a 1-D coherent pupil
    |f| <= ``pupil_cutoff_cyc_px`` (sin u' / lambda = 1 / (2 lambda N), in cycles per pixel), intensity
    |field|^2; contrast < 1 sums the intensities of independent patterns (speckle_pattern_weights).
    Then the lens's defocus blur (Gaussian, intensity), and integration over each pixel row.
    The sample grid is symmetric about the true row, so the expected profile (I0 convolved with the
    intensity line spread function and the blur) is centred on it. Columns are independent (a 1-D
    model): in focus the grain across columns (~lambda N, 0.7 px at f/2) is below a pixel. 2-D
    checks (circular pupil, the field over 4 sub-columns per pixel, not used here for cost; the
    thesis's line at 2 m, f/2): in focus 0.145 px per column (0.16 px here), neighbours correlated
    0.2, a 13-column mean 0.044 px (0.040 px here; 0.040 px in 2-D with a 1.1 px incoherent blur
    after the pupil); with 1.2 px defocus 0.37 px per column (0.57 px here), neighbours correlated
    0.3, a 13-column mean 0.14 px (0.16 px here). So the 1-D model is conservative per column and
    within 10 % for the ~13-column fits the fast pipeline makes (BENCHMARKS.md "Simulator").

    Returns (r, frac), both (M, 2 half + 1): pixel rows round(row) - half .. + half and the
    fraction of the column's expected electrons in each (sums to ~1 in expectation).
    """
    rows = np.asarray(rows, dtype=np.float64)
    line_sigma_px = np.asarray(line_sigma_px, dtype=np.float64)
    if rows.ndim != 1 or line_sigma_px.shape != rows.shape:
        raise ValueError(f"coherent_line_profiles: rows and line_sigma_px must be (M,), got {rows.shape}, {line_sigma_px.shape}")
    s = subsamples
    if not 0 < pupil_cutoff_cyc_px < s / 4:
        raise ValueError(f"coherent_line_profiles: pupil cutoff {pupil_cutoff_cyc_px} cycles/px needs "
                         f"0 < cutoff < subsamples / 4 = {s / 4} (intensity bandwidth below Nyquist)")
    weights = speckle_pattern_weights(contrast)
    n_grid = 2 * (half + 1) * s  # samples over row +- (half + 1) px, every pixel edge of the band inside
    y = (np.arange(n_grid) - (n_grid - 1) / 2) / s  # sample centres relative to the true row
    f = np.fft.fftfreq(n_grid, 1 / s)
    pupil = np.abs(f) <= pupil_cutoff_cyc_px
    if defocus_sigma_px > 0:
        # defocus as the pupil's quadratic phase: the ray through pupil coordinate f / f_c lands
        # at R f / f_c (transverse aberration -phi'(f) / 2 pi), a uniform geometric blur over
        # [-R, R] of sigma R / sqrt(3)
        reach = math.sqrt(3) * defocus_sigma_px
        pupil = pupil * np.exp(-1j * math.pi * reach * f**2 / pupil_cutoff_cyc_px)
    gain = math.sqrt(n_grid / np.abs(pupil).sum())  # sum |h|^2 = 1: the expected energy is kept
    blur_tf = np.exp(-2 * (math.pi * blur_sigma_px * f) ** 2)
    centre = np.round(rows)
    r = centre[:, None] + np.arange(-half, half + 1)[None, :]
    # pixel edges in sample-box units from the grid's first box edge at row - n_grid / (2 s)
    t = (r[:, :1] - 0.5 + np.arange(2 * half + 2)[None, :] - rows[:, None]) * s + n_grid / 2
    frac = np.empty(r.shape)
    chunk = max(1, 2_000_000 // (weights.size * n_grid))
    for a in range(0, rows.size, chunk):
        b = min(a + chunk, rows.size)
        i0 = np.exp(-0.5 * (y[None, :] / np.maximum(line_sigma_px[a:b, None], 1e-3)) ** 2)
        amp = np.sqrt(i0 / i0.sum(axis=1, keepdims=True))
        noise = (rng.standard_normal((b - a, weights.size, n_grid))
                 + 1j * rng.standard_normal((b - a, weights.size, n_grid))) / math.sqrt(2)
        field = np.fft.ifft(np.fft.fft(amp[:, None, :] * noise, axis=-1) * pupil, axis=-1) * gain
        inten = np.einsum("k,mkn->mn", weights, field.real**2 + field.imag**2)
        inten = np.clip(np.fft.ifft(np.fft.fft(inten, axis=-1) * blur_tf, axis=-1).real, 0.0, None)
        cum = np.concatenate([np.zeros((b - a, 1)), np.cumsum(inten, axis=1)], axis=1)
        tt = np.clip(t[a:b], 0, n_grid)
        i = np.minimum(np.floor(tt).astype(int), n_grid - 1)
        at_edge = np.take_along_axis(cum, i, axis=1) + (tt - i) * np.take_along_axis(inten, i, axis=1)
        frac[a:b] = np.diff(at_edge, axis=1)
    return r, frac


def isp_filter(image: np.ndarray, denoise: float, sharpen: float) -> np.ndarray:
    """Optional ISP look on the 8-bit Y plane: spatial denoise, then unsharp-mask sharpening.

    The Pi's ISP does both on its internal data before the Y output; applying them to the 8-bit
    frame is an approximation (one extra rounding). OpenCV's Gaussian blur does the filtering.
    """
    import cv2

    y = image.astype(np.float32)
    if denoise:
        y = (1 - denoise) * y + denoise * cv2.GaussianBlur(y, (3, 3), 0)
    if sharpen:
        y = y + sharpen * (y - cv2.GaussianBlur(y, (5, 5), 0))
    return np.clip(np.rint(y), 0, 255).astype(np.uint8)
