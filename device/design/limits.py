"""Limit estimation of a line-laser sensor design (thesis sections 3.5, 4.1.3, 4.1.5, 4.2.3).

Everything here evaluates only the pixels it needs: one image column (or a sample of columns)
and the rows of that column, never the full pixel grid. Distances are SI (metres); ``q`` is the
object distance perpendicular to the baseline s (eq. 3.14), computed on the laser plane of the
configuration (eq. 3.17) with the camera tilt alpha derived from the plane (section 3.2.2).

Resolution (docs/thesis-notes.md N5): for sub-pixel accuracy sigma at row v of a column,
``min(|q(v + sigma) - q(v)|, |q(v - sigma) - q(v)|) / q(v)``; "the resolution at distance q"
is that value at the row where the model gives q(v) = q on the column through the principal
point; ``min(q)`` is the smallest distance that column's rows can see.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from device.model.camera import CameraModel, undistort_robust
from device.model.triangulation import (LaserPlane, RangeStatus, TriangulationParams, ideal_range,
                                        intersect_plane, params_from_plane)


@dataclass(frozen=True)
class RangeGeometry:
    """What limit estimation needs of a sensor: its camera, laser plane and usable image size.

    ``params`` are the triangulation parameters derived from the plane (section 3.2.2); their
    alpha turns depth into the distance q of eq. 3.14. ``columns``/``rows`` is the active image.
    """

    camera: CameraModel
    plane: LaserPlane
    params: TriangulationParams
    columns: int
    rows: int

    @property
    def principal_column(self) -> float:
        return self.camera.intrinsics.cx


def geometry_from_config(cfg) -> RangeGeometry:
    """RangeGeometry of a :class:`device.config.SensorConfig` (active image area if given)."""
    a, b, c = cfg.plane.to_abc()
    return RangeGeometry(
        camera=cfg.camera, plane=cfg.plane, params=params_from_plane(a, b, c, cfg.beta_rad),
        columns=cfg.active_width or cfg.width, rows=cfg.active_height or cfg.height)


def range_at_pixels(geom: RangeGeometry, pixels: np.ndarray) -> np.ndarray:
    """Distance q (m) seen at ``pixels`` (..., 2) = (u, v); +inf at or beyond the plane's horizon,
    NaN where the backward projection is not valid (robust solver, flagged points)."""
    un = undistort_robust(pixels, geom.camera)
    tri = intersect_plane(un.xy, geom.plane)
    q = _forward_range(un.xy, geom.params)
    q = np.where(tri.status == RangeStatus.BEYOND_HORIZON, np.inf, q)
    return np.where(un.valid, q, np.nan)


def _forward_range(xy: np.ndarray, params: TriangulationParams) -> np.ndarray:
    """Eq. 3.14 for points in front of the baseline line s; NaN behind it (docs/thesis-notes.md N17).

    A wide lens can see the laser plane behind the line s (q_y = z (sin a - y_n cos a) < 0);
    the square root of eq. 3.14 would fold those points forward into small positive distances.
    """
    with np.errstate(invalid="ignore"):
        ahead = math.sin(params.alpha) - xy[..., 1] * math.cos(params.alpha) > 0
    return np.where(ahead, ideal_range(xy, params), np.nan)


def _column_pixels(column: float | np.ndarray, rows: np.ndarray) -> np.ndarray:
    """Pixels (C, R, 2) of the given columns (C,) at the given rows (R,)."""
    u, v = np.meshgrid(np.atleast_1d(np.asarray(column, dtype=float)), np.asarray(rows, dtype=float), indexing="ij")
    return np.stack([u, v], axis=-1)


def relative_resolution(q: np.ndarray, q_before: np.ndarray, q_after: np.ndarray) -> np.ndarray:
    """docs/thesis-notes.md N5: min(|q(v+sigma) - q(v)|, |q(v-sigma) - q(v)|) / q(v), elementwise.

    A neighbour beyond the horizon (inf) or invalid (NaN) does not count; NaN if neither counts
    or q itself is not a finite positive distance.
    """
    q, q_before, q_after = np.broadcast_arrays(*(np.asarray(a, dtype=float) for a in (q, q_before, q_after)))
    with np.errstate(invalid="ignore"):
        steps = np.stack([np.abs(q_after - q), np.abs(q_before - q)])
    steps = np.where(np.isfinite(steps), steps, np.nan)
    good = np.isfinite(q) & (q > 0) & np.any(np.isfinite(steps), axis=0)
    with np.errstate(invalid="ignore", divide="ignore"):
        smallest = np.fmin(steps[0], steps[1])
        return np.where(good, smallest / np.where(good, q, 1.0), np.nan)


def resolution_at_pixels(geom: RangeGeometry, pixels: np.ndarray, subpixel: float) -> np.ndarray:
    """Relative resolution (docs/thesis-notes.md N5) at ``pixels`` (..., 2) for sub-pixel accuracy ``subpixel``."""
    if not (math.isfinite(subpixel) and subpixel > 0):
        raise ValueError(f"sub-pixel accuracy must be positive, got {subpixel!r}")
    pixels = np.asarray(pixels, dtype=float)
    shift = np.array([0.0, subpixel])
    return relative_resolution(range_at_pixels(geom, pixels), range_at_pixels(geom, pixels - shift),
                               range_at_pixels(geom, pixels + shift))


@dataclass(frozen=True)
class ColumnLimits:
    """Per-column distance limits (m): ``q_max`` is +inf where the horizon is inside the column."""

    columns: np.ndarray
    q_min: np.ndarray
    q_max: np.ndarray


def column_limits(geom: RangeGeometry, columns: np.ndarray | float) -> ColumnLimits:
    """Smallest and largest distance each column's rows can see (thesis 3.5 step 5).

    Only the listed columns are back-projected, every row of each. NaN if a column sees nothing.
    """
    columns = np.atleast_1d(np.asarray(columns, dtype=float))
    q = range_at_pixels(geom, _column_pixels(columns, np.arange(geom.rows)))
    seen = ~np.isnan(q)
    any_seen = seen.any(axis=1)
    q_min = np.where(any_seen, np.where(seen, q, np.inf).min(axis=1), np.nan)
    q_max = np.where(any_seen, np.where(seen, q, -np.inf).max(axis=1), np.nan)
    return ColumnLimits(columns, q_min, q_max)


def row_at_range(geom: RangeGeometry, column: float, q_m: float) -> float:
    """Fractional row v where the model gives q(v) = ``q_m`` on ``column``; NaN if not seen.

    Brackets the crossing between whole rows, then bisects on the continuous row to 1e-9 px. Where q(v) is not monotonic and ``q_m`` is crossed more than
    once, the crossing nearest the horizon (smallest v) is returned.
    """
    rows = np.arange(geom.rows, dtype=float)
    q = range_at_pixels(geom, _column_pixels(column, rows))[0]
    with np.errstate(invalid="ignore"):
        g = q - q_m
        cross = np.nonzero(np.isfinite(g[:-1]) & np.isfinite(g[1:]) & (np.sign(g[:-1]) != np.sign(g[1:])))[0]
    exact = np.nonzero(g == 0)[0]
    if exact.size and (not cross.size or exact[0] <= cross[0]):
        return float(rows[exact[0]])
    if not cross.size:
        return math.nan
    i = int(cross[0])

    def f(v: float) -> float:
        return float(range_at_pixels(geom, np.array([column, v]))) - q_m

    return _bisect(f, rows[i], rows[i + 1], xtol=1e-9)


def _bisect(f, lo: float, hi: float, xtol: float) -> float:
    """Root of f in [lo, hi] where f changes sign. Plain bisection: a bracketed root one pixel
    wide needs ~30 halvings, not a SciPy dependency."""
    f_lo = f(lo)
    while hi - lo > xtol:
        mid = 0.5 * (lo + hi)
        f_mid = f(mid)
        if f_mid == 0:
            return mid
        if (f_mid < 0) == (f_lo < 0):
            lo, f_lo = mid, f_mid
        else:
            hi = mid
    return 0.5 * (lo + hi)


def _golden_max(f, lo: float, hi: float, xtol: float) -> tuple[float, float]:
    """(x, f(x)) maximising a unimodal f on [lo, hi] by golden-section search (no SciPy needed)."""
    g = (math.sqrt(5) - 1) / 2
    a, b = lo, hi
    c, d = b - g * (b - a), a + g * (b - a)
    fc, fd = f(c), f(d)
    while b - a > xtol:
        if fc > fd:
            b, d, fd = d, c, fc
            c = b - g * (b - a)
            fc = f(c)
        else:
            a, c, fc = c, d, fd
            d = a + g * (b - a)
            fd = f(d)
    x = 0.5 * (a + b)
    return x, f(x)


def resolution_table(geom: RangeGeometry, subpixels, ranges_m, column: float | None = None) -> np.ndarray:
    """Relative resolution (S, D) for each sub-pixel accuracy and distance (Tables 4.5, 4.10).

    Evaluated on ``column`` (default: the principal point's, docs/thesis-notes.md N5); NaN where that column
    never sees the distance.
    """
    column = geom.principal_column if column is None else float(column)
    subpixels = np.asarray(subpixels, dtype=float)
    ranges_m = np.asarray(ranges_m, dtype=float)
    if subpixels.ndim != 1 or ranges_m.ndim != 1:
        raise ValueError("subpixels and ranges_m must be 1-D sequences")
    table = np.full((subpixels.size, ranges_m.size), np.nan)
    for j, q_m in enumerate(ranges_m):
        v = row_at_range(geom, column, q_m)
        if math.isfinite(v):
            pixels = np.stack([np.full(subpixels.size, column), np.full(subpixels.size, v)], axis=-1)
            table[:, j] = [resolution_at_pixels(geom, px, s) for px, s in zip(pixels, subpixels)]
    return table


# ---------------------------------------------------------------- camera tilt sweep (Fig. 4.2)
@dataclass(frozen=True)
class AlphaSweep:
    """Figure 4.2: per tilt alpha and column, the distances (in units of s) with resolution below
    ``max_resolution`` and q > ``min_range_over_s``.

    ``q_low``/``q_high`` (A, C); NaN where no row of that column qualifies. ``usable`` (A,) is
    the smallest ``q_high`` over the columns (the range the whole field of view reaches), NaN if
    some column has no qualifying row. ``feasible`` (A,) marks the tilts whose laser axis crosses
    the optical axis in front of the camera (theta = pi - alpha - beta in (0, pi)): only those
    have a laser plane z = a x + b y + c with c > 0 that the sensor can calibrate and use
    (eq. 3.16-3.17). ``best_alpha`` maximises ``usable`` over the feasible tilts.
    """

    alphas: np.ndarray
    columns: np.ndarray
    q_low: np.ndarray
    q_high: np.ndarray
    usable: np.ndarray
    feasible: np.ndarray
    best_alpha: float
    best_usable: float


def _qualifying_extent(q: np.ndarray, res: np.ndarray, max_res: float, min_q: float) -> tuple[np.ndarray, np.ndarray]:
    """Smallest and largest q along the last axis (rows) with res <= max_res and q >= min_q.

    Besides the rows themselves, the points between two rows where a constraint changes sign
    are included, interpolating 1/q (linear in y_n for a pinhole, and 0 at the horizon) and the
    resolution linearly; so the result moves smoothly with the design instead of in row steps.
    """
    with np.errstate(invalid="ignore", divide="ignore"):
        inv_q = np.where(np.isposinf(q), 0.0, 1.0 / q)
        ok = (res <= max_res) & (q >= min_q) & np.isfinite(q)
        best_hi = np.where(ok, q, -np.inf).max(axis=-1)
        best_lo = np.where(ok, q, np.inf).min(axis=-1)
        for g in (max_res - res, 1.0 / min_q - inv_q):      # each >= 0 where its constraint holds
            g0, g1 = g[..., :-1], g[..., 1:]
            flip = np.isfinite(g0) & np.isfinite(g1) & (np.sign(g0) != np.sign(g1))
            t = np.where(flip, g0 / np.where(flip, g0 - g1, 1.0), np.nan)
            iq = inv_q[..., :-1] + t * (inv_q[..., 1:] - inv_q[..., :-1])
            rt = res[..., :-1] + t * (res[..., 1:] - res[..., :-1])
            qt = 1.0 / iq
            good = flip & (iq > 0) & (rt <= max_res * (1 + 1e-9)) & (qt >= min_q * (1 - 1e-9))
            best_hi = np.maximum(best_hi, np.where(good, qt, -np.inf).max(axis=-1))
            best_lo = np.minimum(best_lo, np.where(good, qt, np.inf).min(axis=-1))
    return np.where(np.isfinite(best_lo), best_lo, np.nan), np.where(np.isfinite(best_hi), best_hi, np.nan)


def alpha_sweep(camera: CameraModel, rows: int, columns, alphas_rad, subpixel: float = 0.2,
                max_resolution: float = 0.01, min_range_over_s: float = 25.0,
                beta: float = math.pi / 2, psi: float = math.pi / 2, refine: bool = True) -> AlphaSweep:
    """Sweep the camera tilt alpha with the ideal model at s = 1 (thesis 4.1.3, Figure 4.2).

    q scales with s (eq. 4.1) and the relative resolution does not, so all distances are in
    units of s. The listed columns are back-projected once at rows v and v +/- ``subpixel``
    (the camera does not change with alpha); each alpha then costs only eq. 3.12-3.14.
    With ``refine`` the best alpha is refined between its grid neighbours (bounded Brent).
    """
    columns = np.atleast_1d(np.asarray(columns, dtype=float))
    alphas = np.atleast_1d(np.asarray(alphas_rad, dtype=float))
    if not (math.isfinite(subpixel) and subpixel > 0):
        raise ValueError(f"sub-pixel accuracy must be positive, got {subpixel!r}")
    pixels = _column_pixels(columns, np.arange(rows))
    shift = np.array([0.0, subpixel])
    xys = [undistort_robust(pixels + d, camera).xy for d in (0 * shift, -shift, shift)]

    def extent(alpha: float) -> tuple[np.ndarray, np.ndarray]:
        p = TriangulationParams(alpha=alpha, beta=beta, psi=psi, s=1.0)
        q, q_before, q_after = (_forward_range(xy, p) for xy in xys)
        return _qualifying_extent(q, relative_resolution(q, q_before, q_after), max_resolution, min_range_over_s)

    def usable(q_high: np.ndarray) -> float:
        return float(np.min(q_high)) if np.all(np.isfinite(q_high)) else math.nan

    def is_feasible(alpha):
        theta = math.pi - np.asarray(alpha) - beta
        return (theta > 0) & (theta < math.pi)

    lows, highs = zip(*(extent(a) for a in alphas))
    q_low, q_high = np.array(lows), np.array(highs)
    merit = np.array([usable(h) for h in q_high])
    feasible = is_feasible(alphas)
    candidates = np.where(feasible & np.isfinite(merit), merit, -np.inf)
    if not np.any(np.isfinite(candidates)):
        return AlphaSweep(alphas, columns, q_low, q_high, merit, feasible, math.nan, math.nan)
    k = int(np.argmax(candidates))
    best_alpha, best = float(alphas[k]), float(merit[k])
    if refine and alphas.size > 1:
        lo, hi = alphas[max(k - 1, 0)], alphas[min(k + 1, alphas.size - 1)]
        x, fx = _golden_max(lambda a: float(np.nan_to_num(usable(extent(a)[1]), nan=0.0)) if is_feasible(a) else 0.0,
                            float(lo), float(hi), math.radians(1e-3))
        if fx > best:
            best_alpha, best = float(x), float(fx)
    return AlphaSweep(alphas, columns, q_low, q_high, merit, feasible, best_alpha, best)


def baseline_for_range(target_m: float, range_over_s: float) -> float:
    """Baseline s (m) for which a design reaching ``range_over_s`` (q/s) reaches ``target_m``.

    q is linear in s (eq. 4.1), so s = target / (q/s); thesis 4.1.3: 200 cm / q(s = 1 cm).
    """
    if not (math.isfinite(range_over_s) and range_over_s > 0):
        raise ValueError(f"the design has no usable range (q/s = {range_over_s!r}): no baseline reaches the target")
    if not (math.isfinite(target_m) and target_m > 0):
        raise ValueError(f"target range must be positive, got {target_m!r}")
    return target_m / range_over_s
