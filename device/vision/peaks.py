"""Column-wise laser-line peak finding with selectable sub-pixel estimators (thesis 6.1.2 steps 5-6).

For every image column the brightest row inside ``[row_lo, row_hi)`` is found (one vectorised
argmax), then refined to a sub-pixel row by one of these estimators, all on the samples around
the integer maximum ``f(k)`` after subtracting ``background``:

* ``"com"`` - centre of mass over ``k +- half_width`` with a pedestal: weights
  ``max(f - t, 0)`` with ``t = pedestal * peak``. The pedestal removes the noise floor and the
  tails that the window would cut asymmetrically (Fisher & Naidu 1996, "centre of mass").
* ``"gaussian"`` - 3-point Gaussian fit (exact for a Gaussian profile)::

      delta = 0.5 * (ln f(k-1) - ln f(k+1)) / (ln f(k-1) - 2 ln f(k) + ln f(k+1))

  A widely copied MATLAB implementation returns half of this offset; the tests check the
  exact offset against Gaussian profiles with known centres.
* ``"parabolic"`` - 3-point parabola, same formula on f instead of ln f (biased towards the
  integer pixel for Gaussian lines; kept as the cheapest baseline).
* ``"blais-rioux"`` - 4th-order derivative filter ``g(i) = f(i-2) + f(i-1) - f(i+1) - f(i+2)``
  and linear interpolation of its zero crossing next to the maximum (Blais & Rioux 1986).

A flat top (a saturated line: the maximum repeated on three or more rows) is handled for every
estimator: the argmax returns the plateau's first row, so such columns get the plateau's centre
refined by the centre of mass instead. Columns whose estimator needs samples outside the
search interval or the image are returned invalid, never extrapolated.

Written with numpy rather than OpenCV: OpenCV has no column argmax with sub-pixel refinement,
and ``cv2.minMaxLoc`` works on a whole image, not per column.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .kernel import columns_kernel


@dataclass(frozen=True)
class Estimator:
    """One sub-pixel estimator of :data:`ESTIMATORS`. ``reach``: rows each side of the integer
    maximum its own formula reads. The centre of mass reads its window, ``half_width`` rows each
    side, which every estimator reads anyway (the spread, the flat-top refinement), so its own
    reach is 0; :func:`rows_read` adds the window and the flat-top test."""

    reach: int


#: The sub-pixel estimators by name (the module docstring describes each).
ESTIMATORS = {
    "com": Estimator(reach=0),
    "gaussian": Estimator(reach=1),  # f(k-1), f(k), f(k+1)
    "parabolic": Estimator(reach=1),
    "blais-rioux": Estimator(reach=3),  # g(k-1..k+1), each from f(i-2..i+2)
}
#: Rows after the maximum that the flat-top test reads (two more equal samples), for every estimator.
PLATEAU_PROBE = 2
#: Rows looked ahead per step when walking along a flat top (a saturated line is a few rows high).
PLATEAU_STEP = 8


def rows_read(estimator: str, half_width: int) -> int:
    """Rows each side of a candidate that :func:`refine_peaks` reads with ``estimator`` (besides a
    flat top's walk): its reach, the centre-of-mass window and the flat-top test. An image padded
    with this many zero rows above and below needs no clamping (device.vision.fast)."""
    return max(ESTIMATORS[estimator].reach, half_width, PLATEAU_PROBE)


@dataclass(frozen=True)
class ColumnPeaks:
    """Per-column result of :func:`column_peaks`, every array of shape (W,).

    ``row``: sub-pixel row of the line centre (pixel-centre convention: row k is at k.0), NaN where
    not valid. ``peak``: value at the integer maximum after background subtraction.
    ``argmax``: integer row of the maximum (-1 where the interval is empty). ``valid``: the peak is
    at least ``min_peak`` and the estimator had all its samples. ``plateau``: the maximum was
    repeated on at least three rows (flat or saturated top). ``spread``: RMS width (rows) of the
    pedestal-subtracted profile in the centre-of-mass window, whatever the estimator; two lines
    merged in one window (a depth jump, a ghost) show up as a wide spread.
    """

    row: np.ndarray
    peak: np.ndarray
    argmax: np.ndarray
    valid: np.ndarray
    plateau: np.ndarray
    spread: np.ndarray


def clamp(x, lo, hi):
    """np.clip without its per-call overhead (tens of microseconds on small arrays)."""
    return np.minimum(np.maximum(x, lo), hi)


def _limits(value, default: int, width: int, height: int, name: str) -> np.ndarray:
    if value is None:
        return np.full(width, default, dtype=np.intp)
    arr = np.asarray(value)
    if arr.ndim == 0:
        arr = np.full(width, int(arr), dtype=np.intp)
    if arr.shape != (width,):
        raise ValueError(f"{name} must be a scalar or shape ({width},), got {arr.shape}")
    return clamp(arr.astype(np.intp), 0, height)


def subpixel_offset(fm: np.ndarray, f0: np.ndarray, fp: np.ndarray, estimator: str) -> tuple[np.ndarray, np.ndarray]:
    """Offset of the peak from the middle sample for the 3-point estimators; returns (delta, ok).

    ``ok`` is False where the formula does not apply (non-positive samples for the Gaussian, or
    a middle sample that is not a maximum, i.e. a non-negative curvature).
    """
    fm, f0, fp = (np.asarray(a, dtype=np.float64) for a in (fm, f0, fp))
    if estimator == "gaussian":
        ok = (fm > 0) & (f0 > 0) & (fp > 0)
        with np.errstate(divide="ignore", invalid="ignore"):
            lm, l0, lp = np.log(np.where(ok, fm, 1.0)), np.log(np.where(ok, f0, 1.0)), np.log(np.where(ok, fp, 1.0))
        fm, f0, fp = lm, l0, lp
    elif estimator == "parabolic":
        ok = np.ones(f0.shape, dtype=bool)
    else:
        raise ValueError(f"subpixel_offset handles 'gaussian' and 'parabolic', got {estimator!r}")
    curv = fm - 2.0 * f0 + fp
    ok &= curv < 0
    with np.errstate(divide="ignore", invalid="ignore"):
        delta = np.where(ok, 0.5 * (fm - fp) / np.where(ok, curv, -1.0), 0.0)
    ok &= np.abs(delta) <= 1.0
    return delta, ok


def _check_args(image, estimator: str, half_width: int, pedestal: float) -> np.ndarray:
    if estimator not in ESTIMATORS:
        raise ValueError(f"unknown estimator {estimator!r}; choose from {', '.join(ESTIMATORS)}")
    img = np.asarray(image)
    if img.ndim != 2:
        raise ValueError(f"image must be (height, width), got shape {img.shape}")
    if half_width < 1:
        raise ValueError(f"half_width must be >= 1, got {half_width}")
    if not 0.0 <= pedestal < 1.0:
        raise ValueError(f"pedestal must be in [0, 1), got {pedestal}")
    return img


def column_peaks(
    image: np.ndarray,
    estimator: str = "com",
    row_lo=None,
    row_hi=None,
    min_peak: float = 10.0,
    background=0.0,
    half_width: int = 4,
    pedestal: float = 0.1,
) -> ColumnPeaks:
    """Find the laser line in every column of ``image`` (H, W) and refine it to sub-pixel.

    ``row_lo``/``row_hi``: search interval [lo, hi) per column (scalar or (W,) ints; default the
    whole column). ``background``: subtracted before estimating (scalar or (W,)).
    ``min_peak``: smallest background-subtracted maximum that counts as a line.
    ``half_width``/``pedestal``: window and relative threshold of the centre of mass (and of the
    plateau refinement of every estimator).
    """
    img = _check_args(image, estimator, half_width, pedestal)
    height, width = img.shape
    lo = _limits(row_lo, 0, width, height, "row_lo")
    hi = _limits(row_hi, height, width, height, "row_hi")
    top, bottom = int(lo.min()), int(hi.max())
    if bottom <= top:
        k = np.full(width, -1)
    else:
        band = img[top:bottom]
        if np.any(lo > top) or np.any(hi < bottom):
            rows = np.arange(top, bottom)[:, None]
            band = np.where((rows >= lo) & (rows < hi), band, 0)
        k = np.argmax(band, axis=0) + top
    return refine_peaks(img, k, estimator, lo, hi, min_peak, background, half_width, pedestal)


def refine_peaks(
    image: np.ndarray,
    argmax: np.ndarray,
    estimator: str = "com",
    row_lo=None,
    row_hi=None,
    min_peak: float = 10.0,
    background=0.0,
    half_width: int = 4,
    pedestal: float = 0.1,
    plateau_min: float = 0.0,
) -> ColumnPeaks:
    """Sub-pixel refinement of given integer peak rows ``argmax`` (W,) (-1: none), same options
    as :func:`column_peaks`; use it when the candidates come from elsewhere (a second peak).
    ``plateau_min``: only maxima at least this high count as a flat top (e.g. 255: saturation)."""
    img = _check_args(image, estimator, half_width, pedestal)
    height, width = img.shape
    lo = _limits(row_lo, 0, width, height, "row_lo")
    hi = _limits(row_hi, height, width, height, "row_hi")
    k = np.asarray(argmax, dtype=np.intp)
    if k.shape != (width,):
        raise ValueError(f"argmax must have shape ({width},), got {k.shape}")
    bg = np.broadcast_to(np.asarray(background, dtype=np.float64), (width,))
    cols = np.arange(width)
    empty = (hi <= lo) | (k < lo) | (k >= hi)
    k = np.where(empty, -1, k)
    # one gather of every sample the estimator needs: rows k-reach..k+reach (fewer, larger
    # numpy calls than one gather per offset)
    reach = rows_read(estimator, half_width)
    kk = np.maximum(k, 0)
    r = kk[None, :] + np.arange(-reach, reach + 1)[:, None]
    inside = (r >= lo) & (r < hi)
    raw = img[clamp(r, 0, height - 1), cols].astype(np.float64)
    vals = raw - bg
    f0 = np.where(empty, np.nan, vals[reach])

    def sample(offset: int) -> tuple[np.ndarray, np.ndarray]:
        ins = inside[reach + offset] & ~empty
        return np.where(ins, vals[reach + offset], np.nan), ins

    fp1, in_p1 = sample(1)
    fp2, in_p2 = sample(2)
    plateau = in_p1 & in_p2 & (fp1 == f0) & (fp2 == f0) & (f0 >= plateau_min)
    valid = (f0 >= min_peak) & ~empty

    win = slice(reach - half_width, reach + half_width + 1)
    com_row, com_ok, spread = _centre_of_mass(img, kk, raw[win], inside[win], f0, bg, lo, hi, half_width, pedestal)
    if estimator == "com":
        row, ok = com_row, com_ok
    elif estimator in ("gaussian", "parabolic"):
        fm1, in_m1 = sample(-1)
        delta, ok = subpixel_offset(fm1, f0, fp1, estimator)
        ok &= in_m1 & in_p1
        row = k + delta
    else:
        row, ok = _blais_rioux(sample, k, f0)

    if plateau.any():
        # flat top: centre of the plateau, refined by the centre of mass over it
        idx = np.nonzero(plateau & valid)[0]
        if idx.size:
            prow, pok = _plateau_centre(img, k[idx], f0[idx], bg[idx], lo[idx], hi[idx], idx, half_width, pedestal)
            row[idx], ok[idx] = prow, pok
    valid &= ok & np.isfinite(row)
    return ColumnPeaks(np.where(valid, row, np.nan), f0, k, valid, plateau, spread)


def refine_com_padded(padded: np.ndarray, pad: int, argmax: np.ndarray, cols: np.ndarray, row_lo: np.ndarray,
                      row_hi: np.ndarray, half_width: int = 4) -> ColumnPeaks:
    """:func:`refine_peaks` with ``estimator="com"``, ``pedestal=0``, ``background=0``,
    ``min_peak=1`` and ``plateau_min=255`` for columns ``cols`` of a uint8 image that is stored
    as ``padded[pad:-pad]`` with ``pad >= rows_read("com", half_width)`` zero rows above and below it and
    zeros outside each column's rows ``[row_lo, row_hi)`` (given per column of ``cols``, within
    the image): identical results, much cheaper. With those zeros the window needs no clamping
    or masking, and the moments of 8-bit samples are exact integers. Computed by the compiled
    kernel (:func:`device.vision.kernel.columns_kernel`), one pass per column. Used by the fast pipeline (thesis
    6.1.2 step 6, improved)."""
    n = len(argmax)
    row, peak, spread = np.empty(n), np.empty(n), np.empty(n)
    k, valid, plateau = np.empty(n, np.intp), np.empty(n, bool), np.empty(n, bool)
    columns_kernel().refine_com(padded, pad, np.ascontiguousarray(argmax, np.intp), np.ascontiguousarray(cols, np.intp),
                                np.ascontiguousarray(row_lo, np.intp), np.ascontiguousarray(row_hi, np.intp),
                                half_width, row, peak, k, valid, plateau, spread)
    return ColumnPeaks(row, peak, k, valid, plateau, spread)


def _centre_of_mass(img, k, vals, inside, f0, bg, lo, hi, half, pedestal):
    """Centre of mass of the window ``vals`` (2 half + 1, n) of rows k-half..k+half (``inside``:
    the row lies in [lo, hi)) above ``bg + pedestal * f0``; returns (row, ok, spread)."""
    cols = np.arange(img.shape[1])
    offs = np.arange(-half, half + 1, dtype=np.float64)
    t = bg + pedestal * f0
    w = np.where(inside, np.maximum(vals - t, 0.0), 0.0)
    # the three moments in one matrix product: sum w, sum w o, sum w o^2
    s, s1, s2 = np.stack([np.ones_like(offs), offs, offs * offs]) @ w
    with np.errstate(invalid="ignore", divide="ignore"):
        delta = s1 / s
        spread = np.sqrt(np.maximum(s2 / s - delta * delta, 0.0))
    return k + delta, (s > 0) & ~_cut_with_weight(img, cols, k, half, lo, hi, t), spread


def _cut_with_weight(img, cols, centre, span, lo, hi, threshold):
    """The window centre +- span is cut by the interval/image edge while the last sample inside
    is still above the threshold: the line continues past the edge, its centre is unmeasurable."""
    top, bottom = clamp(lo, 0, img.shape[0] - 1), clamp(hi - 1, 0, img.shape[0] - 1)
    cut_top = (centre - span < lo) & (img[top, cols] > threshold)
    cut_bottom = (centre + span >= hi) & (img[bottom, cols] > threshold)
    return cut_top | cut_bottom


def _blais_rioux(sample, k, f0):
    f = {o: sample(o) for o in (-3, -2, -1, 1, 2, 3)}
    f[0] = (f0, np.ones_like(f0, dtype=bool))
    ok = np.all([f[o][1] for o in f], axis=0)
    g = {i: f[i - 2][0] + f[i - 1][0] - f[i + 1][0] - f[i + 2][0] for i in (-1, 0, 1)}
    # g < 0 left of the peak (rising f), > 0 right of it: the centre is its upward zero crossing
    right = g[0] < 0  # crossing between k and k+1
    ga, gb = np.where(right, g[0], g[-1]), np.where(right, g[1], g[0])
    base = np.where(right, k, k - 1).astype(np.float64)
    rise = gb - ga
    ok &= (ga <= 0) & (gb >= 0) & (rise > 0)
    with np.errstate(invalid="ignore", divide="ignore"):
        row = base + np.where(ok, -ga / np.where(ok, rise, 1.0), 0.0)
    return row, ok


def _plateau_centre(img, k, f0, bg, lo, hi, cols, half, pedestal):
    """Centre of mass over a window centred on the middle of a run of equal maxima."""
    height = img.shape[0]
    end = k.copy()
    active = np.ones(k.shape, dtype=bool)
    ahead = np.arange(1, PLATEAU_STEP + 1)[:, None]
    while active.any():  # walk to the end of each plateau, PLATEAU_STEP rows per gather
        ia = np.nonzero(active)[0]
        r = end[ia] + ahead
        vals = img[np.minimum(r, height - 1), cols[ia]].astype(np.float64) - bg[ia]
        same = (r < hi[ia]) & (r < height) & (vals == f0[ia])
        whole = same.all(axis=0)
        end[ia] += np.where(whole, PLATEAU_STEP, np.argmin(same, axis=0))  # leading equal rows
        active[ia] = whole
    mid = np.floor((k + end) / 2.0).astype(np.intp)
    span = (end - k) // 2 + half
    offs = np.arange(-int(span.max()), int(span.max()) + 1)[:, None]
    r = mid[None, :] + offs
    inside = (r >= lo[None, :]) & (r < hi[None, :]) & (np.abs(offs) <= span[None, :])
    vals = img[clamp(r, 0, height - 1), cols[None, :]].astype(np.float64)
    t = bg + pedestal * f0
    w = np.where(inside, np.maximum(vals - t[None, :], 0.0), 0.0)
    s = w.sum(axis=0)
    ok = (s > 0) & ~_cut_with_weight(img, cols, mid, span, lo, hi, t)
    with np.errstate(invalid="ignore", divide="ignore"):
        return mid + (w * offs).sum(axis=0) / s, ok
