"""The unlit neighbours turned to the lit frame's yaw (issue 16, fast pipeline step 0).

When the robot turns, the scene moves across the image between the unlit frame before the lit
one and the one after it, and their mean is not the lit frame's background: a textured wall
leaves its texture in the difference. A pure rotation about the scan frame's z axis (the robot's
yaw) moves every ray's azimuth by the same angle and keeps its elevation, whatever the depth:
in a grid of (elevation, azimuth) cells a turn is a shift along the azimuth (thesis eq. 3.1-3.4
for the lens, device/model/scan_frame.py for the scan frame). So each neighbour is resampled on
that grid (every SEARCH_ROW_STEP-th row of cells), the shift that matches it to the lit frame is
found there (the best normalised correlation on block means COARSE times coarser, then at full
resolution near it, to a fraction of a cell by the peak's parabola; the laser line is a few rows
of the lit frame and moves nothing), and the neighbour is read back into the lit frame's pixels
through the lens model, shifted by it: the map is composed on every COMPOSE_STEP-th row and
column of the band and spread to the others by linear interpolation (the displacement a turn
makes changes slowly across the image). Each neighbour gets its own shift, so a yaw rate that
changes between the frames is followed. A texture periodic along the azimuth (tiles, shelves, a
checkerboard) matches itself a whole period away nearly as well as at the turn: of such aliases
the smallest turn is tried first (ALIAS_SCORE), the right one while the turn between two frames
is under half the period; beyond that it is a wrong one, which leaves the rows the rolling
shutter read later unexplained (below), the pipeline refuses it, and the next is tried
(MAX_ALIASES). Where none is taken the checks on a moved background judge the frame: they
reject lines there, never guess them.

What a rotation about the camera does not explain stays: the parallax of driving forward,
something moving in the scene, a texture coming in from outside the image
(:attr:`Registered.seen` says which columns have their whole band inside the neighbour). Two
such parallaxes come with every turn of a real robot: it turns about its own axis, so a sensor
mounted d ahead of it also moves sideways by d x the turn (at d = 0.1 m and 90 deg/s, 8 mm per
50 ms: ~2 px at 2.5 m, ~5 px at 1 m); and the scan frame's z axis is the robot's yaw axis only
if the laser plane is level. The simulator models the first (``sensor_ahead_m``; ``laserpi bench
motion``'s points "0.1 m ahead", with surfaces 1.5-3 m away: the office turning at 90 deg/s
keeps 1-2 points less of its columns than on the axis, the person crossing as many), not the
second; near objects keep a residue and count as moved. Where the neighbours, turned, still differ
by most of what they differed (MAX_TURN_RESIDUE: driving straight), no turn is returned at all;
step 0 judges the registered neighbours as it judges the raw ones.

The rolling shutter: the three frames read their rows at the same times after their starts (the
line time is the mode's line length over its pixel rate, and frames follow at the frame length:
device/camera/modes.py, from the kernel's driver raspberrypi/linux drivers/media/i2c/imx219.c,
which no frame of a running mode changes at the device's frame lengths: libcamera lengthens the
line only beyond the mode's longest frame, ~1.2 s for the IMX219, CamHelper::getBlanking), so the yaw between a row of the lit frame and the
same row of a neighbour is the same for every row at a constant yaw rate. But a turn does not
keep a ray in its row: the camera looks down at the laser plane through a wide lens, and a ray
the turn moves sideways lands rows higher or lower in the neighbour (at the operating point's
band, 3-6 rows at the median and 7-16 at the 90th percentile for 2.25-4.5 deg, 13 and 56 for 9
deg). That row was read that many line times later or earlier, while the sensor went on
turning: at 180 deg/s, 56 rows of 18.9 us are 0.19 deg, two pixels. So the read-back turns each
ray by the shift times (1 + rows it moved x ``readout_share``, one row's readout as a share of
the time between the frames; registrations), the rows it moved taken from the plain shift's map (the
correction moves them by a fraction of a row more). The search itself finds the shift at the
mean move of the rows it matched (-0.7 to +1.7 rows at 4.5 deg, -0.3 to +4.5 at 9 deg: up to
0.17 % of the shift, 0.15 px at 180 deg/s), which is divided out first. A yaw rate that
changes leaves the rows' turns unequal: by the acceleration x the readout between them x the 50
ms between the frames; over the band at the operating point (160 rows, 3 ms) at 3 rad/s^2, 0.03
deg, a quarter of a cell.

What it costs (BENCHMARKS.md "Motion"): ~4-5 ms per turning lit frame here in the pipeline for
both neighbours (the three grid reads and the searches ~2 ms, each read-back ~1.2 ms), ~1 ms
where no turn is found (driving), only when step 0 finds ``turn_share`` of the columns moved.
The grid is built once per pipeline (~0.1 s here).

Pure arrays and OpenCV, no I/O: the grid is built from the configuration's lens and laser plane.
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np

from ..model.camera import CameraModel, pixel_grid, project_points, undistort_robust
from ..model.scan_frame import ScanFrame

#: Coarse search: the grids are reduced this many times along both axes first.
COARSE = 4
#: The fine search looks this many cells either side of the coarse shift.
FINE_REACH = COARSE
#: A neighbour shifted by less than this (cells) is read as it is: a turn that small (a robot
#: starting or ending one) moves nothing by a pixel, and resampling would only blur it.
MIN_SHIFT = 0.5
#: The turn found must leave at most this share of how the two neighbours differ (registrations).
MAX_TURN_RESIDUE = 0.7
#: ... and each neighbour's grid must correlate with the lit frame's at least this well at its
#: best coarse shift (0.86-0.998 over the frames of ``laserpi bench motion``; a turn beyond the
#: searched range gave ~0.5 at a wrong shift).
MIN_PEAK = 0.7
#: Peaks of the coarse correlation within this of the best are aliases the frames cannot tell
#: apart: a texture periodic along the azimuth (tiles, shelves, a checkerboard) matches itself
#: shifted by a whole period nearly as well as at the turn, and which alias scores a few
#: thousandths higher is chance (the image's ends, noise, the rolling shutter). The smallest
#: turn among them is tried first: the right one while the turn between two frames is under half
#: the texture's period. On the frames of ``laserpi bench motion`` (84 registrations: seeds 0-1,
#: 14-180 deg/s, the poster wall, the person, driving) the best peak stands 0.21 or more above
#: the next; a checkerboard of 0.15 m squares at 2 m, turning at 90 deg/s, put its aliases
#: within 0.024 of each other, and the one a period further scored highest.
ALIAS_SCORE = 0.05
#: At most this many aliases are tried, smallest turn first, where the caller refuses one
#: (registrations): each costs a fine search and a read-back (~2-3 ms here).
MAX_ALIASES = 3
#: Where a map has no pixel (NaN: a ray outside the image), this coordinate instead: cv2.remap
#: reads its border value there on every platform (a NaN coordinate's conversion is undefined).
OUTSIDE = -1e4
#: Elevation rows of the grid the search reads: every this-many-th (the turn shifts along the
#: azimuth only; the rows between add little to the match and cost their share).
SEARCH_ROW_STEP = 4
#: The band's map into a neighbour is composed on every this-many-th row and column and spread
#: to the others by linear interpolation (the displacement a turn makes changes slowly).
COMPOSE_STEP = 5


class NoTurnToSearch(ValueError):
    """This lens and band leave no turn to search: no pixel of the band has a ray, or its grid is
    too small (a configuration's property, not a caller's mistake: the pipeline goes on without
    the turn)."""


@dataclass(frozen=True)
class YawGrid:
    """An (elevation, azimuth) grid over a band of image rows, and the maps a turn needs.

    ``search_map``: (n_search, n_azimuth, 2) float32 image (x, y) of every SEARCH_ROW_STEP-th
    elevation row's cells, where the shift is searched (OUTSIDE where a ray is not in the
    image); ``to_image``: (n_elevation, n_azimuth, 2) float32 image (x, y) of every cell's ray,
    NaN where it is not in the image. ``top``: the band's first image row; ``max_shift``: the
    largest shift searched, in cells (``max_yaw_rad``, or a quarter of the grid's width where
    that is less: the lens's widest searchable turn); ``cell_rad``: the azimuth step.
    ``compose_pixels``: (n_rows, n_columns, 2) float32 pixels (x, y) of every COMPOSE_STEP-th row
    and column of the band, where ``cv2.resize`` samples an image
    COMPOSE_STEP times coarser, so that its linear interpolation spreads what is composed there
    to every pixel, and ``compose_cells`` their (azimuth, elevation) cells, NaN where a pixel
    has no ray; ``compose_bracket``: (2, width) the composed columns either side of each image
    column (the nearest one twice beyond the first and the last); ``band_pixels``: (rows,
    width, 2) float32 pixels (x, y) of the band; ``image_size``: the image's (width, height)."""

    search_map: np.ndarray
    to_image: np.ndarray
    top: int
    rows: int
    max_shift: int
    cell_rad: float
    compose_cells: np.ndarray
    compose_pixels: np.ndarray
    compose_bracket: np.ndarray
    band_pixels: np.ndarray
    image_size: tuple[int, int]


@dataclass(frozen=True)
class Registered:
    """A neighbour read into the lit frame's band: ``band`` (rows, width) uint8; ``seen`` (width,)
    bool, the columns whose every band pixel came from inside the neighbour; ``shift_rad`` the
    yaw found between them: the neighbour's minus the lit frame's (REP 103: positive when the
    sensor turned left from the lit frame to the neighbour, so that a direction of the lit frame
    lies that much further right, at an azimuth that much smaller, in the neighbour)."""

    band: np.ndarray
    seen: np.ndarray
    shift_rad: float


def yaw_grid(camera: CameraModel, frame: ScanFrame, width: int, height: int, top: int, rows: int,
             max_yaw_rad: float) -> YawGrid:
    """The grid for image rows [top, top + rows) of a ``width`` x ``height`` image, searched up to
    ``max_yaw_rad`` of turn between a neighbour and the lit frame. Cells are as wide as a pixel at
    the image centre (1 / fx rad; fy for the elevation)."""
    if not (0 <= top and rows >= COMPOSE_STEP and top + rows <= height and width >= COMPOSE_STEP):
        raise ValueError(f"band rows [{top}, {top + rows}) not inside an image {height} rows high, or fewer than "
                         f"{COMPOSE_STEP} rows")
    if not max_yaw_rad > 0:
        raise ValueError(f"max_yaw_rad must be positive, got {max_yaw_rad}")
    k = camera.intrinsics
    # the band's rays span the azimuths and elevations of its border's: the lens model maps
    # pixels to rays one to one and smoothly, so neither angle has an extreme inside the band
    x, y = np.arange(width, dtype=float), np.arange(top, top + rows, dtype=float)
    border = np.concatenate([np.stack([x, np.full(width, y[0])], 1), np.stack([x, np.full(width, y[-1])], 1),
                             np.stack([np.zeros(rows), y], 1), np.stack([np.full(rows, width - 1.0), y], 1)])
    azimuth, elevation, ok = _directions(border, camera, frame)
    if not ok.any():
        raise NoTurnToSearch("no pixel of the band has a ray (lens model)")
    step_az, step_el = 1.0 / k.fx, 1.0 / k.fy
    az0, az1 = float(azimuth[ok].min()), float(azimuth[ok].max())
    el0, el1 = float(elevation[ok].min()), float(elevation[ok].max())
    n_az = int(math.ceil((az1 - az0) / step_az)) + 1
    n_el = int(math.ceil((el1 - el0) / step_el)) + 1
    # azimuth falls from the image's left to its right (REP 103: y to the left): cell j's azimuth
    # is az1 - j step, so that cells run the way the image's columns do
    a = az1 - np.arange(n_az) * step_az
    e = el0 + np.arange(n_el) * step_el
    ca, sa = np.cos(a)[None, :], np.sin(a)[None, :]
    ce, se = np.cos(e)[:, None], np.sin(e)[:, None]
    rays = np.stack([ce * ca, ce * sa, np.broadcast_to(se, (n_el, n_az))], axis=-1) @ frame.rotation
    with np.errstate(invalid="ignore"):
        xy = project_points(rays.reshape(-1, 3), camera).reshape(n_el, n_az, 2)
        inside = (rays[..., 2] > 0) & np.all(np.isfinite(xy), axis=-1)
        inside &= (xy[..., 0] >= 0) & (xy[..., 0] <= width - 1) & (xy[..., 1] >= 0) & (xy[..., 1] <= height - 1)
    to_image = np.where(inside[..., None], xy, np.nan).astype(np.float32)
    # the pixels cv2.resize samples when it enlarges (n_rows, n_columns) COMPOSE_STEP times to the band
    n_rows, n_columns = rows // COMPOSE_STEP, width // COMPOSE_STEP
    column = (np.arange(n_columns) + 0.5) * (width / n_columns) - 0.5
    compose = np.stack(np.meshgrid(column, top + (np.arange(n_rows) + 0.5) * (rows / n_rows) - 0.5), axis=-1)
    az, el, valid = _directions(compose.reshape(-1, 2), camera, frame)
    cells = np.stack([(az1 - az) / step_az, (el - el0) / step_el], axis=-1)
    cells = np.where(valid[:, None], cells, np.nan).reshape(n_rows, n_columns, 2).astype(np.float32)
    below = np.clip(np.searchsorted(column, np.arange(width), side="right") - 1, 0, n_columns - 1)
    bracket = np.stack([below, np.where(np.arange(width) < column[0], 0, np.minimum(below + 1, n_columns - 1))])
    search = np.ascontiguousarray(to_image[::SEARCH_ROW_STEP])
    search[~np.isfinite(search)] = OUTSIDE
    # the search slides the middle half of the grid's width along it at most
    max_shift = min(int(math.ceil(max_yaw_rad / step_az)), (n_az - 1) // 4)
    if max_shift <= FINE_REACH + 1 or len(search) < COARSE:
        raise NoTurnToSearch(f"the band's grid ({len(search)} x {n_az} cells) is too small to search a turn in")
    band = pixel_grid(width, rows, np.float32)
    band[..., 1] += top
    return YawGrid(search, to_image, top, rows, max_shift, step_az, cells, compose.astype(np.float32), bracket, band,
                   (width, height))


def _directions(pixels: np.ndarray, camera: CameraModel, frame: ScanFrame):
    """(azimuth, elevation, valid) in the scan frame of the rays of ``pixels`` (N, 2)."""
    un = undistort_robust(pixels, camera, tol_px=1e-3)
    d_scan = np.concatenate([un.xy, np.ones_like(un.xy[:, :1])], axis=1) @ frame.rotation.T
    return (np.arctan2(d_scan[:, 1], d_scan[:, 0]), np.arctan2(d_scan[:, 2], np.hypot(d_scan[:, 0], d_scan[:, 1])),
            un.valid)


def registrations(grid: YawGrid, lit: np.ndarray, neighbours, readout_shares=None) -> Iterator[list[Registered]]:
    """Each of ``neighbours`` (whole uint8 images) read into the band of ``lit`` under the turn
    that matches it (a copy of its own band where that is under MIN_SHIFT cells), each ray turned
    ``readout_shares`` (one per neighbour: one row's readout time over the time from the lit frame
    to that neighbour, negative for one before it; None: 0, a global shutter) of the turn more per
    row the turn moved it down (the rolling shutter, module docstring); one such list per alias of
    the turn (ALIAS_SCORE), the smallest turn first, up to MAX_ALIASES: a caller takes the first
    it accepts (beyond half a periodic texture's period the smallest alias is a wrong one, which
    leaves the rows the rolling shutter turned further unexplained). Nothing where no turn can be
    told (no texture: a flat or dark scene) or a turn does not explain how the neighbours differ:
    turned, they still differ by more than MAX_TURN_RESIDUE of what they did (driving straight:
    the parallax spreads the scene out from the middle, which a best shift matches only a little:
    on the frames of ``laserpi bench motion``, seeds 0-4, 0.81-0.89 of the difference stays at
    0.5-1 m/s, 0.05-0.18 turning at 14-180 deg/s, 0.14-0.25 with a person crossing too, 0.36-0.42
    turning at 180 deg/s and driving at 1 m/s in 10x light). That test is made on the coarse
    shifts, before the fine search. The grids and the search are made at the first request, each
    read-back at its own."""
    import cv2

    on = lambda x: cv2.remap(x, grid.search_map, None, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT).astype(np.float32)  # noqa: E731
    a, *grids = (on(x) for x in (lit, *neighbours))
    h, w = a.shape[0] // COARSE, a.shape[1] // COARSE  # >= 1: yaw_grid refuses a smaller grid
    small_a, *smalls = (cv2.resize(x[: h * COARSE, : w * COARSE], (w, h), interpolation=cv2.INTER_AREA)
                        for x in (a, *grids))
    aliases = [_coarse_shifts(small_a, small_b, grid.max_shift // COARSE) for small_b in smalls]
    if not all(aliases):
        return
    for rank in range(min(MAX_ALIASES, max(map(len, aliases)))):
        coarse = [s[min(rank, len(s) - 1)] for s in aliases]  # a neighbour with fewer keeps its last
        if _residue(smalls, coarse) > MAX_TURN_RESIDUE:
            continue
        shifts = [_fine_shift(a, b, round(s * COARSE), grid.max_shift) for b, s in zip(grids, coarse)]
        if all(s is not None for s in shifts):
            yield _read_back(grid, neighbours, shifts, readout_shares)


def _read_back(grid: YawGrid, neighbours, shifts, readout_shares) -> list[Registered]:
    """Each of ``neighbours`` read into the band under its turn ``shifts`` (cells; registrations)."""
    import cv2

    out = []
    for neighbour, shift, share in zip(neighbours, shifts, readout_shares or (0.0,) * len(neighbours)):
        if abs(shift) < MIN_SHIFT:
            out.append(Registered(neighbour[grid.top : grid.top + grid.rows].copy(), np.ones(neighbour.shape[1], bool),
                                  shift * grid.cell_rad))
            continue
        if share:  # the search matched rows that moved by their mean, read that much later
            shift /= 1.0 + share * _mean_rows_moved(grid, shift)
        # where each band pixel's ray lies in the neighbour: composed on every COMPOSE_STEP-th
        # row and column, and its displacement, which changes slowly, spread to the others
        source = _composed(grid, np.full(grid.compose_cells.shape[:2], shift, np.float32))
        if share:  # the rolling shutter: the rows each ray moved, read that much later
            moved_rows = np.nan_to_num(source[..., 1] - grid.compose_pixels[..., 1])
            source = _composed(grid, (shift * (1.0 + share * moved_rows)).astype(np.float32))
        cv2.patchNaNs(source, OUTSIDE)  # and what it spreads to reads outside too
        rows, width = grid.band_pixels.shape[:2]
        at = cv2.add(cv2.resize(source - grid.compose_pixels, (width, rows), interpolation=cv2.INTER_LINEAR),
                     grid.band_pixels)
        seen = _seen(grid, source, at)
        band = cv2.remap(neighbour, at, None, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT)
        out.append(Registered(band, seen, shift * grid.cell_rad))
    return out


def _mean_rows_moved(grid: YawGrid, shift: float) -> float:
    """The mean of the rows a turn of ``shift`` cells moves the rays the fine search matched (its
    template: the search rows' cells ``max_shift`` in from each side, _fine_shift), in the
    image: the rolling shutter's share of the shift it found (module docstring)."""
    m, n, k = grid.max_shift, grid.search_map.shape[1], int(round(shift))
    here, there = grid.search_map[:, m : n - m, 1], grid.search_map[:, m + k : n - m + k, 1]
    inside = (here > OUTSIDE / 2) & (there > OUTSIDE / 2)
    return float(np.mean((there - here)[inside])) if inside.any() else 0.0


def _composed(grid: YawGrid, shift: np.ndarray) -> np.ndarray:
    """(n_rows, n_columns, 2) the neighbour's pixel (x, y) of every composed band pixel's ray
    turned by ``shift`` (cells, per composed pixel); NaN where it has none in the image."""
    import cv2

    m = grid.compose_cells.copy()
    m[..., 0] += shift
    cv2.patchNaNs(m, OUTSIDE)
    return cv2.remap(grid.to_image, m, None, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=math.nan)


def _seen(grid: YawGrid, source: np.ndarray, at: np.ndarray) -> np.ndarray:
    """(width,) the columns whose every band pixel's place ``at`` (rows, width, 2) lies inside the
    neighbour. Between composed rows and columns a place is bilinear in the pixel's row and
    column (the spread displacement and the pixel's own coordinates), so it is inside a cell of
    them where their composed places (``source``) are; where the spreading holds the
    displacement (the band's first and last rows and columns up to the first composed one) it is
    bilinear too, with corners on the band's first or last row or column: those are tested."""
    import cv2

    lo, hi = (0.0, 0.0), (grid.image_size[0] - 1.0, grid.image_size[1] - 1.0)
    composed = cv2.reduce(cv2.inRange(source, lo, hi), 0, cv2.REDUCE_MIN)[0] > 0
    seen = composed[grid.compose_bracket].all(axis=0)
    seen &= cv2.reduce(cv2.inRange(np.ascontiguousarray(at[[0, -1]]), lo, hi), 0, cv2.REDUCE_MIN)[0] > 0
    for edge in (slice(0, 1), slice(at.shape[1] - 1, at.shape[1])):
        seen[edge] &= cv2.inRange(np.ascontiguousarray(at[:, edge]), lo, hi).min() > 0
    return seen


def _residue(grids, shifts) -> float:
    """The mean |difference| of two neighbours' grids (COARSE times reduced), each shifted by its
    turn (``shifts``, in their cells), as a share of it unshifted."""
    import cv2

    b0, b1 = grids
    h, w = b0.shape
    turned = [cv2.warpAffine(b, np.float32([[1, 0, s], [0, 1, 0]]), (w, h), flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP,
                             borderMode=cv2.BORDER_CONSTANT, borderValue=math.nan) for b, s in zip(grids, shifts)]
    # over the cells inside the image in both, turned and not (0: a cell outside the image, as
    # the search grid reads it; a black pixel counts as one, which only narrows the cells compared)
    ok = np.isfinite(turned[0]) & np.isfinite(turned[1]) & (b0 > 0) & (b1 > 0) & (turned[0] > 0) & (turned[1] > 0)
    raw = float(np.mean(np.abs(b0 - b1)[ok])) if ok.any() else 0.0
    return float(np.mean(np.abs(turned[0] - turned[1])[ok])) / raw if raw > 0 else math.inf


def _coarse_shifts(small_a: np.ndarray, small_b: np.ndarray, reach: int) -> list[float]:
    """The shifts s (cells of these grids, to a fraction of one) with small_b[:, j + s] ~
    small_a[:, j]: the best normalised correlation of ``small_a``'s middle (``reach`` cells in from
    each side) along ``small_b`` and its aliases (ALIAS_SCORE, none under MIN_PEAK), smallest
    first, each at its peak's parabola; none where it has no peak (a flat grid), a weak one (under
    MIN_PEAK) or one at the end of the searched range (it may lie beyond)."""
    import cv2

    c = small_a.shape[1]
    score = cv2.matchTemplate(small_b, small_a[:, reach : c - reach], cv2.TM_CCOEFF_NORMED)[0]
    if not np.all(np.isfinite(score)) or np.ptp(score) <= 0:
        return []
    best = int(np.argmax(score))
    if score[best] < MIN_PEAK or not 0 < best < score.size - 1:
        return []
    inner = score[1:-1]  # local maxima (the first of a plateau) no lower than the bar
    bar = max(MIN_PEAK, float(score[best]) - ALIAS_SCORE)
    peaks = 1 + np.flatnonzero((inner > score[:-2]) & (inner >= score[2:]) & (inner >= bar))
    return [int(k) - reach + _parabola(score[k - 1 : k + 2]) for k in sorted(peaks, key=lambda k: abs(int(k) - reach))]


def _fine_shift(a: np.ndarray, b: np.ndarray, k0: int, max_shift: int) -> float | None:
    """The shift s (cells, to a fraction of one) with b[:, j + s] ~ a[:, j] within FINE_REACH
    cells of ``k0`` (the coarse one): the best normalised correlation of ``a``'s middle
    (``max_shift`` cells in from each side) along ``b``, the peak's parabola; None where the best
    is at the window's edge (the coarse peak was not this one)."""
    import cv2

    n, m = a.shape[1], max_shift
    k0 = int(np.clip(k0, -(m - FINE_REACH - 1), m - FINE_REACH - 1))
    fine = cv2.matchTemplate(b[:, m + k0 - FINE_REACH - 1 : n - m + k0 + FINE_REACH + 1], a[:, m : n - m],
                             cv2.TM_CCOEFF_NORMED)[0]
    if not np.all(np.isfinite(fine)):
        return None
    i = int(np.argmax(fine))
    if i == 0 or i == fine.size - 1:
        return None
    return k0 - FINE_REACH - 1 + i + _parabola(fine[i - 1 : i + 2])


def _parabola(y: np.ndarray) -> float:
    """Where the parabola through three samples (at -1, 0, 1) peaks, 0 where it has no maximum."""
    y0, y1, y2 = (float(v) for v in y)
    curvature = y0 - 2 * y1 + y2
    return 0.5 * (y0 - y2) / curvature if curvature < 0 else 0.0
