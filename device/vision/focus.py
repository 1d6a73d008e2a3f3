"""Focus metrics of the laser line (``laserpi focus``): how wide and how bright the line is across
the image, region by region, and how wide it would be with the lens in focus. Pure math on a lit
and an unlit frame; no I/O.

Width: the line's full width at half maximum across rows in the lit-minus-unlit difference, per
column (the rows around the peak above half of it, the two crossings interpolated linearly),
then the median over the columns of a region. A defocused lens spreads the line over more rows
and lowers its peak; turning the focus ring until the width is smallest and the peak highest
is focusing on the line itself, at 808 nm through the bandpass filter.

In focus the width is set by the optics (:func:`focused_width_px`), Gaussian sigmas added in
quadrature: the laser line's own thickness imaged at the focus distance (``line_height_m`` taken
as its 1/e^2 full width, 4 sigma, as the simulator renders it: f x line height / 4 / distance),
the lens's blur in focus (at best the diffraction limit, the Airy pattern's FWHM 1.03 lambda N at
the laser's wavelength and the f-number; a real M12 lens is worse: the accuracy figures of
BENCHMARKS.md assume the simulator's 1.1 px), and the pixel's own width (a box of 1 px:
variance 1/12).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..config import SensorConfig

#: FWHM of the Airy disk, in units of lambda x N (1.029: Born & Wolf, sec. 8.5.2).
AIRY_FWHM = 1.029
#: FWHM of a Gaussian over its sigma, 2 sqrt(2 ln 2).
GAUSS_FWHM = 2.0 * math.sqrt(2.0 * math.log(2.0))


@dataclass(frozen=True)
class RegionFocus:
    """One column region: columns [first, last), the median line FWHM (rows; NaN: no line)
    and the median peak of the line (grey levels above the unlit frame)."""

    first: int
    last: int
    width_px: float
    peak: float


def diffraction_sigma_px(cfg: SensorConfig) -> float:
    """The diffraction-limited lens blur as a Gaussian sigma, px (Airy FWHM / GAUSS_FWHM)."""
    return AIRY_FWHM * cfg.laser.wavelength_m * cfg.optics.f_number / cfg.optics.pixel_pitch_m / GAUSS_FWHM


def focused_width_px(cfg: SensorConfig, distance_m: float, lens_sigma_px: float | None = None) -> float:
    """The line's FWHM in pixels with the lens in focus on a surface at ``distance_m``, for a
    lens blur of ``lens_sigma_px`` (Gaussian sigma; None: the diffraction limit)."""
    if not distance_m > 0:
        raise ValueError(f"distance must be positive, got {distance_m} m")
    lens = diffraction_sigma_px(cfg) if lens_sigma_px is None else lens_sigma_px
    if not lens > 0:
        raise ValueError(f"lens blur must be positive, got {lens} px")
    line = cfg.camera.intrinsics.fy * cfg.laser.line_height_m / 4 / distance_m
    return GAUSS_FWHM * math.sqrt(lens**2 + line**2 + 1 / 12)


def column_widths(diff: np.ndarray, row_lo: np.ndarray, row_hi: np.ndarray, min_peak: float) -> tuple[np.ndarray, np.ndarray]:
    """Per column: (FWHM in rows, peak) of the line in ``diff`` (lit - unlit, float, (H, W))
    within rows [row_lo, row_hi); NaN width where the peak is below ``min_peak``."""
    h, w = diff.shape
    rows = np.arange(h)[:, None]
    inside = (rows >= row_lo[None, :]) & (rows < row_hi[None, :])
    d = np.where(inside, diff, -np.inf)
    peak_row = np.argmax(d, axis=0)
    cols = np.arange(w)
    peak = d[peak_row, cols]
    width = np.full(w, np.nan)
    for c in np.nonzero(np.isfinite(peak) & (peak >= min_peak))[0]:
        col, p, r, half = d[:, c], peak[c], peak_row[c], peak[c] / 2
        top = r
        while top > 0 and col[top - 1] > half:
            top -= 1
        bottom = r
        while bottom < h - 1 and col[bottom + 1] > half:
            bottom += 1
        # linear interpolation of the half-maximum crossings on each side
        up = top - (col[top] - half) / (col[top] - col[top - 1]) if top > 0 and np.isfinite(col[top - 1]) else top - 0.5
        down = bottom + (col[bottom] - half) / (col[bottom] - col[bottom + 1]) \
            if bottom < h - 1 and np.isfinite(col[bottom + 1]) else bottom + 0.5
        width[c] = down - up
    return width, np.where(np.isfinite(peak), peak, np.nan)


def region_focus(lit: np.ndarray, unlit: np.ndarray, row_lo: np.ndarray, row_hi: np.ndarray, regions: int = 16,
                 min_peak: float = 8.0) -> list[RegionFocus]:
    """The line's width and peak in ``regions`` equal column regions (see the module docstring)."""
    if lit.shape != unlit.shape or lit.ndim != 2:
        raise ValueError(f"lit and unlit frames must be (H, W) of one size, got {lit.shape} and {unlit.shape}")
    if not 1 <= regions <= lit.shape[1]:
        raise ValueError(f"regions must be in 1..{lit.shape[1]}, got {regions}")
    diff = lit.astype(np.float32) - unlit.astype(np.float32)
    width, peak = column_widths(diff, np.asarray(row_lo), np.asarray(row_hi), min_peak)
    edges = np.linspace(0, lit.shape[1], regions + 1).astype(int)
    out = []
    for a, b in zip(edges[:-1], edges[1:]):
        wv, pv = width[a:b], peak[a:b]
        ok = np.isfinite(wv)
        out.append(RegionFocus(int(a), int(b), float(np.median(wv[ok])) if ok.any() else math.nan,
                               float(np.median(pv[ok])) if ok.any() else math.nan))
    return out
