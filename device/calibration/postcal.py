"""Post-calibration of the depth from a wall sweep (thesis section 6.3), order by cross-validation.

The thesis fitted a "2-4" polynomial (x up to 2nd order, total order 4: the 12 terms of eq. 6.5)
chosen by experiment. Here the family is ``i <= x_order, i + j <= z_order`` and the pair is chosen
by k-fold cross-validation (folds by wall distance when the sweep says which wall a point
belongs to, so a held-out fold is a distance never seen by the fit). The fit itself is
:func:`device.vision.postcal.fit`, in centred and scaled coordinates (docs/thesis-notes.md N8).

Input: points ``(x, z_measured, z_true)`` in metres, camera frame - from frames of a flat wall at
known distances (:func:`load_wall_sweep`: ``wall_<mm>mm_lit.png`` / ``_unlit.png`` pairs), or
from a reference scanner's readings of the same wall (:func:`load_sweep_csv`).
"""

from __future__ import annotations

import csv
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..config import PostCalibration, SensorConfig
from ..model.camera import undistort_robust
from ..model.scan_frame import scan_frame
from ..model.triangulation import RangeStatus, intersect_plane
from ..vision.peaks import column_peaks
from ..vision.postcal import correction, fit
from .intrinsics import CalibrationError

#: Fewest samples per fitted term, and the fewest points for any correction.
MIN_SAMPLES_PER_TERM = 5


def terms_for(x_order: int, z_order: int) -> tuple[tuple[int, int], ...]:
    """Monomials X^i Z^j with i <= x_order and i + j <= z_order (eq. 6.5 is x_order 2, z_order 4)."""
    return tuple((i, t - i) for t in range(z_order + 1) for i in range(min(t, x_order) + 1))


@dataclass
class PostcalFit:
    post: PostCalibration | None  # None: no polynomial beats leaving z as it is
    x_order: int
    z_order: int
    cv_rmse_m: dict[str, float]  # "x_order,z_order" -> held-out RMS error; "none" for no correction
    rms_before_m: float
    rms_after_m: float


def _folds(n: int, groups: np.ndarray | None, k: int, seed: int) -> np.ndarray:
    if groups is not None:
        uniq = np.unique(groups)
        order = np.random.default_rng(seed).permutation(len(uniq))
        fold_of = {g: order[i] % k for i, g in enumerate(uniq)}
        return np.array([fold_of[g] for g in groups])
    return np.random.default_rng(seed).permutation(n) % k


def fit_postcal(
    x: np.ndarray, z_measured: np.ndarray, z_true: np.ndarray, groups: np.ndarray | None = None,
    max_x_order: int = 2, max_z_order: int = 5, folds: int = 5, seed: int = 0,
) -> PostcalFit:
    """Choose (x_order, z_order) by cross-validated RMS of z_true - corrected z, then fit on all."""
    x, z, zt = (np.asarray(a, dtype=np.float64).ravel() for a in (x, z_measured, z_true))
    if not (x.shape == z.shape == zt.shape):
        raise ValueError(f"x, z_measured and z_true must have one length, got {x.shape}, {z.shape}, {zt.shape}")
    ok = np.isfinite(x) & np.isfinite(z) & np.isfinite(zt)
    x, z, zt = x[ok], z[ok], zt[ok]
    g = None if groups is None else np.asarray(groups).ravel()[ok]
    if len(z) < 3 * MIN_SAMPLES_PER_TERM:
        raise CalibrationError(f"post-calibration needs at least {3 * MIN_SAMPLES_PER_TERM} wall points, got {len(z)}; record the wall at more distances")
    n_groups = len(np.unique(g)) if g is not None else len(z)
    k = max(2, min(folds, n_groups))
    if g is not None and n_groups < 3:
        raise CalibrationError(f"post-calibration needs walls at 3 or more distances, got {n_groups}; record a sweep (e.g. every 10 cm)")
    fold = _folds(len(z), g, k, seed)
    # scaling from all data, so every fold fits in the same well-conditioned coordinates
    xs = max(float(np.max(np.abs(x))), 1e-3)
    z0, zs = float((z.max() + z.min()) / 2), max(float((z.max() - z.min()) / 2), 1e-3)

    cv = {"none": float(np.sqrt(np.mean((z - zt) ** 2)))}
    best = ("none", cv["none"], None)
    for zo in range(0, max_z_order + 1):
        for xo in range(0, min(max_x_order, zo) + 1):
            terms = terms_for(xo, zo)
            if len(z) < MIN_SAMPLES_PER_TERM * len(terms):
                continue
            sq = []
            for f in range(k):
                tr, te = fold != f, fold == f
                if tr.sum() < MIN_SAMPLES_PER_TERM * len(terms) or not te.any():
                    continue
                post = fit(x[tr], z[tr], zt[tr], terms, xs, z0, zs)
                sq.append((z[te] - correction(post, x[te], z[te]) - zt[te]) ** 2)
            if not sq:
                continue
            rmse = float(np.sqrt(np.mean(np.concatenate(sq))))
            cv[f"{xo},{zo}"] = rmse
            if rmse < best[1] * 0.99:  # a more complex model must win by at least 1 %
                best = (f"{xo},{zo}", rmse, (xo, zo))
    if best[2] is None:
        return PostcalFit(None, -1, -1, cv, cv["none"], cv["none"])
    xo, zo = best[2]
    post = fit(x, z, zt, terms_for(xo, zo), xs, z0, zs)
    after = float(np.sqrt(np.mean((z - correction(post, x, z) - zt) ** 2)))
    return PostcalFit(post, xo, zo, cv, cv["none"], after)


def load_sweep_csv(path: str | Path) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray | None]:
    """A wall sweep as CSV with a header: x_m, z_measured_m, z_true_m and optionally wall (a
    distance-set label used to fold the cross-validation)."""
    path = Path(path)
    try:
        with path.open() as fh:
            rows = list(csv.DictReader(fh))
    except FileNotFoundError:
        raise CalibrationError(f"{path}: no such wall-sweep file") from None
    need = {"x_m", "z_measured_m", "z_true_m"}
    if not rows or not need <= set(rows[0]):
        raise CalibrationError(f"{path}: a wall sweep needs a header with {', '.join(sorted(need))} (and optionally wall)")
    try:
        cols = {k: np.array([float(r[k]) for r in rows]) for k in need}
    except ValueError as exc:
        raise CalibrationError(f"{path}: non-numeric value ({exc})") from None
    groups = np.array([r["wall"] for r in rows]) if "wall" in rows[0] else None
    return cols["x_m"], cols["z_measured_m"], cols["z_true_m"], groups


def wall_points(lit: np.ndarray, unlit: np.ndarray, distance_m: float, config: SensorConfig, snr: float = 6.0):
    """(x, z_measured, z_true) of one frame pair of a flat wall ``distance_m`` ahead.

    The wall is perpendicular to the scan's forward axis (device.model.scan_frame) of ``config``;
    each laser pixel (one per column, :func:`device.vision.peaks.column_peaks` on lit - unlit) is
    triangulated with ``config``, and its true depth is where the same ray meets the wall."""
    if lit.shape != unlit.shape:
        raise ValueError(f"lit {lit.shape} and unlit {unlit.shape} frames differ in size")
    diff = lit.astype(np.float64) - unlit.astype(np.float64)
    noise = 1.4826 * float(np.median(np.abs(diff - np.median(diff)))) + 0.5  # at least a quantisation step
    peaks = column_peaks(diff, estimator="gaussian", min_peak=snr * noise)
    cols = np.flatnonzero(peaks.valid)
    px = np.stack([cols.astype(np.float64), peaks.row[cols]], axis=-1)
    un = undistort_robust(px, config.camera)
    tri = intersect_plane(un.xy, config.plane)
    fr = scan_frame(config.plane)
    forward = fr.rotation[0]
    rays = np.concatenate([un.xy, np.ones((len(px), 1))], axis=-1)
    with np.errstate(invalid="ignore", divide="ignore"):
        z_true = (distance_m + forward @ fr.origin) / (rays @ forward)
    ok = un.valid & (tri.status == RangeStatus.OK) & np.isfinite(z_true) & (z_true > 0)
    return tri.points[ok, 0], tri.points[ok, 2], z_true[ok]


def load_wall_sweep(folder: str | Path, config: SensorConfig):
    """A wall sweep folder: ``wall_<distance in mm>_lit.png`` / ``wall_<distance>_unlit.png`` pairs
    -> (x, z_measured, z_true, wall index) for :func:`fit_postcal`."""
    import cv2

    folder = Path(folder)
    out = []
    pairs = []
    for unlit_path in folder.glob("wall_*_unlit.png"):
        tag = unlit_path.name[len("wall_"): -len("_unlit.png")]
        if not tag.endswith("mm") or not tag[:-2].isdigit():
            raise CalibrationError(f"{unlit_path.name}: name walls wall_<distance>mm_unlit.png, e.g. wall_1500mm_unlit.png")
        pairs.append((int(tag[:-2]), tag, unlit_path))
    for i, (_, tag, unlit_path) in enumerate(sorted(pairs)):
        lit_path = folder / f"wall_{tag}_lit.png"
        lit, unlit = cv2.imread(str(lit_path), cv2.IMREAD_GRAYSCALE), cv2.imread(str(unlit_path), cv2.IMREAD_GRAYSCALE)
        if lit is None or unlit is None:
            raise CalibrationError(f"{folder}: cannot read the pair for wall_{tag}")
        x, z, zt = wall_points(lit, unlit, int(tag[:-2]) / 1000.0, config)
        out.append(np.stack([x, z, zt, np.full(len(x), i)], axis=-1))
    if not out:
        raise CalibrationError(f"{folder}: no wall_<distance>mm_lit.png / _unlit.png pairs")
    data = np.concatenate(out)
    return data[:, 0], data[:, 1], data[:, 2], data[:, 3].astype(int)
