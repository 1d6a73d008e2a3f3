"""The fast, accurate pipeline (issue 7): region of interest, vectorised peaks, line fit across
neighbouring columns, ghost rejection, table triangulation (thesis 6.1 and 6.3, improved).

Per frame pair:

1. Difference ``lit - unlit`` (saturating, uint8) only over the rows where the laser can land
   for the configured depth limits, per column (:mod:`device.vision.geometry`); the negative
   part ``unlit - lit`` gives each column's noise level and reveals a pulse that lit the wrong
   frame.
2. Two candidate peaks per column: the maximum, and the maximum at least ``half_width + 1``
   rows away from it, both found through 16-row block maxima (contiguous reductions, much
   faster than a strided argmax over the whole band). Each is refined by the selected
   sub-pixel estimator (:func:`device.vision.peaks.refine_peaks`).
3. Detection, on the difference smoothed over 5 columns x 3 rows (speckle and noise averaged):
   peak >= max(min_peak, noise_ratio x the column's largest smoothed negative difference),
   a profile no wider than a single line, and part of a run of >= ``min_run`` continuous columns
   (a noise peak is alone; a line is not).
4. Several peaks in a column (a glossy floor's mirror image, multipath, an occlusion edge): by
   consistency with neighbouring columns and geometry, never by brightness alone. A mirror image
   in a floor below the laser plane, or a secondary reflection off it, always appears farther
   from the horizon than the line that causes it and runs alongside it; the nearer line of an
   occlusion edge continues alone on its side. See :meth:`FastPipeline._choose`.
5. Speckle: the row of each column is replaced by a local linear fit over ``2 smooth_half + 1``
   columns, only within a run of columns whose rows are continuous (no depth jump: the 5-column
   running medians of adjacent columns differ by less than the row step of a ``jump_rel`` depth
   change, at least 1 px, and their raw rows by less than ``jump_factor`` times that), so no
   point is ever pulled towards another surface. A column far from its median (an outlier) is
   left out of the fit and reports the fit; gaps of up to ``max_gap`` columns without a
   measurement inside a run (dark speckle grains) are filled between their neighbours (quality
   0). The fit weights each column by its line's amplitude (dark speckle grains scatter most).
   A column whose own peak is dim next to its smoothed one (a dark grain: down to
   ``dim_peak_fraction``) counts only between bright columns of the same run (at least
   ``own_peak_fraction``), never at a run's end, where the smoothed detector also sees the line
   of the neighbours past a depth jump. A line seen but not measurable is REJECTED (NaN), never
   "no return". The effective angular resolution is the fit window
   (:attr:`FastPipeline.resolution_deg`).
6. Triangulation by the per-column ray table, post-calibration (ERRATA 8), scan angle/range.
Tracking (``track_margin`` > 0, variant ``fast-com-track``): steps 1-5 search only the rows of
the previous frame's line and runs of second candidates (e.g. a floor's mirror image) +-
``track_margin`` (one rectangle of whole blocks over all columns; the noise level is still taken
over the whole band, so thresholds do not change). If ``track_lost_run``
adjacent columns that had a line lose it (a depth jump, an object stepping in front of the
tracked surface, the line gone), or the line or a ghost touches the band's edge, the same frame is
searched again over the whole region of interest; and every
``track_full_every``-th frame is a full search, so an object appearing outside the band in
columns that had no line is found within ``track_full_every`` - 1 frames (0.4 s at 10 Hz with
the default 5). Steps 6-7 are unchanged.

7. Nearer than the region of interest: the rows on the near side of it are not searched for a
   line, but their per-column maximum difference (one cheap reduction) is: a column with no
   line in range and a strong return there reports "too close" (-inf), never "no return".
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..config import SensorConfig
from .geometry import column_geometry
from .measurements import ColumnMeasurements, ColumnStatus, finish, luminance
from .peaks import ESTIMATORS, clamp, refine_com_padded, refine_peaks

BLOCK_ROWS = 16
#: Smallest difference at a saturated lit pixel for it to count as part of a saturated line.
SATURATED_LINE_MIN = 24
#: Box (columns, rows) that smooths the difference image for detection only.
DETECT_KERNEL = (5, 3)


@dataclass(frozen=True)
class FastParams:
    estimator: str = "com"
    half_width: int = 4  # centre-of-mass window (rows each side)
    pedestal: float = 0.0  # centre-of-mass threshold, fraction of the peak (0: best under speckle)
    min_peak: float = 3.0  # smallest line amplitude in the smoothed difference, 8-bit levels
    noise_ratio: float = 1.5  # smoothed peak must exceed this x the column's largest smoothed negative difference
    max_spread_px: float = 2.5  # RMS width above which a profile is two lines, not one
    min_run: int = 5  # continuous columns for a detection to count
    smooth_half: int = 6  # local line fit over 2 smooth_half + 1 columns (0: off)
    jump_rel: float = 0.08  # relative depth step that separates surfaces (on the running median)
    jump_factor: float = 3.0  # adjacent raw rows may differ by this x the jump step (speckle)
    support_half: int = 4  # neighbour columns consulted to pick among candidates
    max_gap: int = 3  # columns without a measurement filled inside a continuous run (line fit on)
    own_peak_fraction: float = 0.5  # a column's own peak must reach this x its smoothed peak to end a run (depth jumps)
    dim_peak_fraction: float = 0.1  # ... and this inside a run, between columns that reach own_peak_fraction (dark speckle grains)
    track_margin: int = 0  # rows searched each side of the previous frame's line (0: whole ROI every frame)
    track_full_every: int = 5  # with tracking: a full search at least every this many frames (new objects)
    track_lost_run: int = 10  # with tracking: this many adjacent columns losing their line force a full search

    def __post_init__(self) -> None:
        if self.estimator not in ESTIMATORS:
            raise ValueError(f"unknown estimator {self.estimator!r}; choose from {', '.join(ESTIMATORS)}")
        for name in ("half_width", "min_run", "support_half"):
            if getattr(self, name) < 1:
                raise ValueError(f"{name} must be >= 1, got {getattr(self, name)}")
        if self.track_margin < 0 or self.track_full_every < 1 or self.track_lost_run < 1:
            raise ValueError(f"need track_margin >= 0, track_full_every >= 1, track_lost_run >= 1, got "
                             f"{self.track_margin}, {self.track_full_every}, {self.track_lost_run}")
        if self.smooth_half < 0:
            raise ValueError(f"smooth_half must be >= 0, got {self.smooth_half}")
        if not (0 < self.jump_rel < 1 and self.min_peak > 0):
            raise ValueError(f"need 0 < jump_rel < 1 and min_peak > 0, got {self.jump_rel}, {self.min_peak}")
        if not 0 < self.dim_peak_fraction <= self.own_peak_fraction <= 1:
            raise ValueError(f"need 0 < dim_peak_fraction <= own_peak_fraction <= 1, got "
                             f"{self.dim_peak_fraction}, {self.own_peak_fraction}")


@dataclass(frozen=True)
class _Track:
    """What a tracking fast pipeline keeps from the previous frame pair."""

    found: np.ndarray  # (W,) columns that had a line
    first_row: int  # band rows [first_row, last_row] held a detected candidate (line or ghost)
    last_row: int
    since_full: int  # frames since the last full search


class FastPipeline:
    """``FastPipeline(config, FastParams(...), min_m, max_m).process(lit, unlit, lit_rows=None)``."""

    def __init__(self, config: SensorConfig, params: FastParams = FastParams(),
                 min_m: float | None = None, max_m: float | None = None):
        self.config = config
        self.params = params
        g = self.geometry = column_geometry(config, min_m, max_m)
        self.name = f"fast-{params.estimator}" + ("" if params.smooth_half else "-raw") + ("-track" if params.track_margin else "")
        self._track: _Track | None = None
        #: image rows [start, stop) searched for the line in the last frame pair (tracking narrows them)
        self.searched_rows: tuple[int, int] | None = None
        self.top = int(g.roi_lo.min())
        n = max(int(g.roi_hi.max()) - self.top, 1)
        self.rows = int(math.ceil(n / BLOCK_ROWS) * BLOCK_ROWS)  # band height, whole blocks
        self.top = max(min(self.top, config.height - self.rows), 0)
        self.rows = min(self.rows, config.height - self.top)
        self.lo = (g.roi_lo - self.top).astype(np.intp)
        self.hi = np.minimum(g.roi_hi - self.top, self.rows).astype(np.intp)
        r = np.arange(self.rows)[:, None]
        self.mask = np.where((r >= self.lo) & (r < self.hi), 255, 0).astype(np.uint8)
        # rows nearer than the region of interest, per column (for the too-close check)
        H = config.height
        if g.near_below:
            self.near_top, self.near_bottom = int(min(g.roi_hi.min(), H)), H
            rn = np.arange(self.near_top, H)[:, None]
            near = rn >= g.roi_hi[None, :]
        else:
            self.near_top, self.near_bottom = 0, int(g.roi_lo.max())
            rn = np.arange(0, self.near_bottom)[:, None]
            near = rn < g.roi_lo[None, :]
        self.near_mask = np.where(near, 255, 0).astype(np.uint8)[::2].copy()
        self.cols = np.arange(config.width)
        nb = self.rows // BLOCK_ROWS
        self._block_rows = np.arange(BLOCK_ROWS)[None, :]
        self._in_block_keys = ((BLOCK_ROWS - 1) - np.arange(self.rows) % BLOCK_ROWS).astype(np.uint16)[:, None]
        block_key = np.arange(1 << 12, dtype=np.uint32)  # value << 4 | (15 - row in block)
        self._global_keys = ((block_key >> 4) << 16) | (block_key & (BLOCK_ROWS - 1))
        self._block_keys = (0xFFF0 - BLOCK_ROWS * np.arange(nb, dtype=np.uint32))[:, None]
        self._cols2 = np.concatenate([self.cols, self.cols])
        h = params.support_half
        offs = np.array([o for o in range(-h, h + 1) if o != 0])
        self._choose_offsets = (offs + h)[:, None]  # neighbours in columns padded by h
        self._choose_tol = (1.0 + 0.5 * np.abs(offs))[None, None, :, None]
        self._pad = max(params.half_width, 3)  # zero rows around the difference: every estimator's reach
        # image-sized temporaries kept between frame pairs (a search uses their first rows): one
        # allocated per frame costs page faults whenever the allocator returns it to the system
        W = config.width
        self._padded_buf = np.zeros((self.rows + 2 * self._pad, W), np.uint8)
        self._sm_buf = np.zeros((self.rows, W), np.uint8)
        self._key_buf = np.zeros((self.rows, W), np.uint16)
        self._neg_buf = np.zeros((self.rows, W), np.uint8)
        self._neg_blur_buf = np.zeros((self.rows, W), np.uint8)
        spacing = np.abs(np.diff(g.column_angle))
        self.column_spacing_rad = float(np.median(spacing[np.isfinite(spacing)]))

    @property
    def resolution_deg(self) -> float:
        """Effective angular resolution: the width of the column window one range depends on."""
        return math.degrees((2 * self.params.smooth_half + 1) * self.column_spacing_rad)

    # ---------------------------------------------------------------- steps
    def reset(self) -> None:
        """Forget the tracked line (the next frame pair gets a full search)."""
        self._track = None

    def process(self, lit, unlit, lit_rows: np.ndarray | None = None) -> ColumnMeasurements:
        import cv2

        shape = (self.config.height, self.config.width)
        lum_lit, lum_unlit = luminance(lit, "lit", shape), luminance(unlit, "unlit", shape)
        p = self.params
        band = self._tracking_band()
        if band is None:
            found, row, peak, status, seen = self._search(lum_lit, lum_unlit, 0, self.rows)
        else:
            found, row, peak, status, seen = self._search(lum_lit, lum_unlit, *band)
            lost = self._track.found & ~found
            edge = p.half_width + 1
            if (np.any(_run_length(lost) >= p.track_lost_run)
                    or (band[0] > 0 and seen[0] < band[0] + edge) or (band[1] < self.rows and seen[1] >= band[1] - edge)):
                # the line left the band in some columns (a depth jump, a new object in front of
                # the tracked surface, a lost line), or a candidate touches the band's edge (it
                # may continue outside): search the whole region of interest now
                found, row, peak, status, seen = self._search(lum_lit, lum_unlit, 0, self.rows)
                band = None
        t0, t1 = band or (0, self.rows)
        self.searched_rows = (self.top + t0, self.top + t1)
        if p.track_margin:
            tr = self._track
            self._track = _Track(found.copy(), *seen, 0 if band is None or tr is None else tr.since_full + 1)
        W = self.cols.size
        # too close: only columns in runs of >= min_run without a return can become a run of
        # "too close" ones (none: a wall fills every column; scattered dark speckle grains)
        empty = _run_length(status == ColumnStatus.NO_RETURN) >= p.min_run
        cols = np.nonzero(empty)[0]
        if self.near_bottom > self.near_top and cols.size:
            # every other row: a line is at least two rows high
            c0, c1 = int(cols[0]), int(cols[-1]) + 1
            la = lum_lit[self.near_top : self.near_bottom : 2, c0:c1]
            ua = lum_unlit[self.near_top : self.near_bottom : 2, c0:c1]
            mask = self.near_mask[:, c0:c1]
            near = cv2.bitwise_and(cv2.subtract(la, ua), mask).max(axis=0)
            near_noise = cv2.bitwise_and(cv2.subtract(ua, la), mask).max(axis=0)
            # stricter than in range (twice the noise ratio): a false "too close" stops a robot
            close = np.zeros(W, bool)
            close[c0:c1] = near >= np.maximum(2 * p.min_peak, 2 * p.noise_ratio * near_noise)
            close &= empty
            if close.any():
                status[_run_length(close) >= p.min_run] = ColumnStatus.TOO_CLOSE
        if lit_rows is not None:
            status = self._unlit(status, row, np.asarray(lit_rows, dtype=bool))
        found = status == ColumnStatus.OK
        row = np.where(found, row, np.nan)
        return finish(self.geometry, self.cols, row, np.where(found, peak, 0.0), status, self.geometry.triangulate(row),
                      self.config.post_calibration)

    def _tracking_band(self) -> tuple[int, int] | None:
        """Rows [t0, t1) of the band (whole blocks) to search this frame: the previous frame's
        line +- ``track_margin`` rows; None for a full search (tracking off, nothing tracked, or
        ``track_full_every`` frames since the last full search, so new objects are found)."""
        p, tr = self.params, self._track
        if not p.track_margin or tr is None or tr.since_full + 1 >= p.track_full_every or not tr.found.any():
            return None
        t0 = max(tr.first_row - p.track_margin, 0) // BLOCK_ROWS * BLOCK_ROWS
        t1 = min(-(-(tr.last_row + p.track_margin + 1) // BLOCK_ROWS) * BLOCK_ROWS, self.rows)
        return None if t1 - t0 >= self.rows else (t0, t1)

    def _search(self, lum_lit: np.ndarray, lum_unlit: np.ndarray, t0: int, t1: int):
        """Find the line in rows [t0, t1) of the band (whole blocks): steps 1-5 of the module
        docstring. Returns (found, row, peak, status, seen): rows in image coordinates, ``seen``
        the first and last band row of the line or a run of second candidates (a ghost; (t1, -1)
        if none), from which tracking sizes the next frame's band."""
        import cv2

        a = lum_lit[self.top + t0 : self.top + t1]
        b = lum_unlit[self.top + t0 : self.top + t1]
        p = self.params
        W = self.cols.size
        lo, hi = clamp(self.lo - t0, 0, t1 - t0), clamp(self.hi - t0, 0, t1 - t0)
        # the difference goes into a buffer with zero rows above and below (sub-pixel windows
        # at the band's edges need no clamping)
        n, pad = t1 - t0, self._pad
        padded = self._padded(n)
        # a saturated lit pixel that the laser clearly brightened is "at least full scale": flat
        # top at 255, so the estimators' plateau handling finds its centre whatever the unlit
        # frame's noise (a bright background that merely touches 255 is left alone: the pixel must
        # be brightened by the laser and one of its vertical neighbours too)
        d = cv2.subtract(a, b, dst=padded[pad : pad + n])
        # only the rows that hold a saturated pixel (usually a few: the line's)
        full = np.nonzero(a.max(axis=1) == 255)[0]
        if full.size >= 2:
            r0, r1 = int(full[0]), int(full[-1]) + 1
            d_s = d[r0:r1]
            sat = cv2.bitwise_and(cv2.compare(a[r0:r1], 255, cv2.CMP_EQ), cv2.compare(d_s, SATURATED_LINE_MIN, cv2.CMP_GE))
            pair = cv2.bitwise_and(sat[1:], sat[:-1])  # both rows of a vertical pair, in place
            cv2.max(d_s[1:], pair, dst=d_s[1:])
            cv2.max(d_s[:-1], pair, dst=d_s[:-1])
        cv2.bitwise_and(d, self.mask[t0:t1], dst=d)
        # detection on a copy smoothed along the line (5 columns) and across it (3 rows): it
        # averages speckle and noise; the sub-pixel estimate still uses the unsmoothed difference
        sm = cv2.blur(d, DETECT_KERNEL, dst=self._sm_buf[:n])
        # noise: the largest smoothed negative difference over the whole band, also when tracking
        # (a maximum over fewer rows would be lower: more, and dimmer, detections). The ROI mask is
        # left out: the band's rows are as noisy as the column's own interval, and it saves a pass
        fa, fb = lum_lit[self.top : self.top + self.rows], lum_unlit[self.top : self.top + self.rows]
        neg = cv2.subtract(fb, fa, dst=self._neg_buf)
        noise = cv2.blur(neg, DETECT_KERNEL, dst=self._neg_blur_buf).max(axis=0).astype(np.float64)
        k = self._candidates(sm, padded)  # (2W,): first candidates, then second ones
        s = sm.reshape(-1).take(k * W + self._cols2).astype(np.float64)
        k1, k2, s1, s2 = k[:W], k[W:], s[:W], s[W:]
        thr = np.maximum(p.min_peak, p.noise_ratio * noise)
        c1 = self._refine(padded, k1, self.cols, lo, hi)
        # detection is decided before the estimator's own validity, so that a line whose sub-pixel
        # estimate fails is reported as such and never replaced by the other candidate (a ghost);
        # the column itself must carry the line, not only its smoothed neighbours (depth jumps)
        det1 = (s1 >= thr) & (c1.peak >= p.dim_peak_fraction * s1) & (c1.spread <= p.max_spread_px)
        r1 = np.where(c1.valid, c1.row, k1)
        # second candidates: refined only where they are strong enough to matter (few columns)
        det2 = np.zeros(W, bool)
        idx = np.nonzero(s2 >= thr)[0]
        if idx.size:
            r2, v2, ok2 = np.full(W, np.nan), np.zeros(W), np.zeros(W, bool)
            c2 = self._refine(padded, k2[idx], idx, lo[idx], hi[idx])
            det2[idx] = (c2.peak >= p.dim_peak_fraction * s2[idx]) & (c2.spread <= p.max_spread_px)
            r2[idx], v2[idx], ok2[idx] = np.where(c2.valid, c2.row, k2[idx]), c2.peak, c2.valid
        two = bool(det2.any())
        if two:
            pick2 = self._choose(r1 + t0, r2 + t0, det1, det2)
            row = np.where(pick2, r2, r1)
            peak = np.where(pick2, v2, c1.peak)
            measured = np.where(pick2, ok2, c1.valid)
        else:  # the usual case when tracking a single line: no second candidate anywhere
            row, peak, measured = r1, c1.peak, c1.valid
        found = det1 | det2
        failed = found & ~measured  # a line is there, its sub-pixel estimate is not
        found &= measured
        row = row + (self.top + t0)
        segment, outlier = self._segments(row, found)
        # a dim column (a dark speckle grain: its own peak below own_peak_fraction of the smoothed
        # one) counts only between bright columns of its run, never at a run's end: past the end
        # of a surface (a depth jump) the smoothed detector still sees the neighbours' line
        bright = found & (peak >= p.own_peak_fraction * (np.where(pick2, s2, s1) if two else s1))
        found &= _inside_bright(segment, bright)
        # a run needs min_run columns that agree with it (outliers do not count)
        found &= np.bincount(segment, weights=found & ~outlier).take(segment) >= p.min_run
        status = np.where(found, np.uint8(ColumnStatus.OK), np.uint8(ColumnStatus.NO_RETURN))
        # a line seen by the smoothed detector but not measurable in the column (too wide, a
        # failed estimate, only in the neighbours): invalid, never "no return"
        status[~found & ((s1 >= thr) | failed)] = ColumnStatus.REJECTED
        if p.smooth_half:
            # outliers take the line fit of their run (the fit is what every column reports)
            row = _local_line_fit(row, np.where(found & ~outlier, np.maximum(peak, 1.0), 0.0), found, segment,
                                  p.smooth_half)
            row, filled = _fill_gaps(row, found, p.max_gap, status != ColumnStatus.NO_RETURN)
            status[filled] = ColumnStatus.OK
            peak = np.where(filled, 0.0, peak)
            found |= filled
        else:
            status[found & outlier] = ColumnStatus.REJECTED
            found &= ~outlier
        # the pulse lit the "unlit" frame in this column (out of sync)
        status[(noise >= np.maximum(p.min_peak, 2.0 * s1)) & ~found] = ColumnStatus.UNLIT
        # rows of the line and of runs of second candidates (a mirror image runs alongside the
        # line; a lone second candidate is noise)
        cand = row[found] - self.top
        if two:
            cand = np.concatenate([cand, (k2 + t0)[_run_length(det2) >= p.min_run]])
        seen = (int(math.floor(cand.min())), int(math.ceil(cand.max()))) if cand.size else (t1, -1)
        return found, row, peak, status, seen

    def _padded(self, n: int) -> np.ndarray:
        """A (n + 2 pad, W) uint8 buffer whose first and last ``pad`` rows are zero."""
        buf = self._padded_buf[: n + 2 * self._pad]
        buf[n + self._pad :] = 0  # a previous, taller search may have written there
        return buf

    def _refine(self, padded: np.ndarray, k: np.ndarray, cols: np.ndarray, lo: np.ndarray, hi: np.ndarray):
        """Sub-pixel rows of candidates ``k`` in columns ``cols`` of the difference stored in
        ``padded`` (:meth:`_padded`), by the configured estimator."""
        p = self.params
        if p.estimator == "com" and p.pedestal == 0:
            return refine_com_padded(padded, self._pad, k, cols, lo, hi, p.half_width)
        d = padded[self._pad : padded.shape[0] - self._pad]
        return refine_peaks(d if cols is self.cols else d[:, cols], k, p.estimator, lo, hi, 1.0, 0.0, p.half_width,
                            p.pedestal, 255)

    def _candidates(self, sm: np.ndarray, padded: np.ndarray) -> np.ndarray:
        """Rows (band coordinates, (2W,): first candidates, then second ones) of the largest and
        the second, separated, peak per column of the smoothed difference ``sm``: the largest
        outside the 16-row blocks within ``half_width + 1`` rows of the first, or, if those are
        all zero, in the first block (at least that far from the first). Each is moved to the
        largest of the difference (stored in ``padded``, :meth:`_padded`) at k-1, k, k+1 (the
        smoothed peak can sit a row off the unsmoothed one)."""
        nb = sm.shape[0] // BLOCK_ROWS
        W = self.cols.size
        # keys value << 4 | (15 - row in block): one contiguous max per block gives the block's
        # maximum and the first row holding it (no strided argmax, no per-column gather); then as
        # keys value << 16 | (0xFFFF - row) (a table lookup), one max over blocks gives the first
        # row of the column's maximum
        key = self._key_buf[: nb * BLOCK_ROWS]
        np.copyto(key, sm[: nb * BLOCK_ROWS])  # a plain cast, then in place: cheaper than a casting shift
        key <<= 4
        key |= self._in_block_keys[: nb * BLOCK_ROWS]
        g = self._global_keys.take(key.reshape(nb, BLOCK_ROWS, -1).max(axis=1))  # (nb, W)
        g += self._block_keys[:nb]
        k1 = 0xFFFF - (g.max(axis=0) & 0xFFFF).astype(np.intp)
        # blocks within sep rows of the first peak (at most two: 2 sep + 1 <= BLOCK_ROWS) drop out
        sep = self.params.half_width + 1
        b_lo = np.maximum((k1 - sep) // BLOCK_ROWS, 0)
        b_hi = np.minimum((k1 + sep) // BLOCK_ROWS, nb - 1)
        flat = g.reshape(-1)
        flat[b_lo * W + self.cols] = 0
        flat[b_hi * W + self.cols] = 0
        m2 = g.max(axis=0)
        k2 = 0xFFFF - (m2 & 0xFFFF).astype(np.intp)
        zero = np.nonzero(m2 <= 0xFFFF)[0]
        if zero.size:
            # nothing but zeros left: the first block, at least sep rows from the first peak
            k2[zero] = 0
            odd = zero[b_lo[zero] == 0]
            if odd.size:
                inner = sm[:BLOCK_ROWS, odd].T.copy()  # (n, BLOCK_ROWS)
                inner[np.abs(self._block_rows - k1[odd][:, None]) <= sep] = 0
                k2[odd] = np.argmax(inner, axis=1)
        # local maximum of d around both (the first of equals, as argmax over k-1, k, k+1); the
        # zero rows around the band stand in for clamping (a zero row above row 0 can only win
        # when row 0 ties it, and then row 0 is the answer)
        k = np.concatenate([k1, k2])
        base = (k + self._pad) * W + self._cols2
        d = padded.reshape(-1)
        vm, v0, vp = d.take(base - W), d.take(base), d.take(base + W)
        return np.maximum(np.where((vm >= v0) & (vm >= vp), k - 1, np.where(v0 >= vp, k, k + 1)), 0)

    def _choose(self, r1, r2, det1, det2) -> np.ndarray:
        """Where to take the second candidate, for columns with two detected lines.

        ``support``: neighbour columns (+-support_half) with a candidate that agrees with it;
        ``alone``: those of them whose only detection agrees with it. A mirror image (glossy
        floor) runs alongside the line that causes it, so it is rarely alone; the nearer line of
        an occlusion edge (two real surfaces overlapping over a few columns) continues alone on
        its side. So: the nearer candidate wins when it is alone in at least half the
        neighbours (a real edge: the nearer surface is the one that matters), else the farther
        one (nearer the horizon) unless it is backed less than half as well as the other.
        """
        h = self.params.support_half
        W = r1.size
        pick2 = det2 & ~det1
        idx = np.nonzero(det1 & det2)[0]
        if idx.size:
            # candidates and "single" padded by h columns of none on each side: neighbours need
            # no bounds checks
            cand = np.full((2, W + 2 * h), np.nan)
            cand[0, h:-h] = np.where(det1, r1, np.nan)
            cand[1, h:-h] = np.where(det2, r2, np.nan)
            single = np.zeros(W + 2 * h, bool)
            single[h:-h] = det1 != det2
            own = cand[:, idx + h]  # (2, n)
            j = idx + self._choose_offsets  # (2h, n) neighbour columns, padded coordinates
            nb = cand.take(j, axis=1)  # (2, 2h, n)
            with np.errstate(invalid="ignore"):
                agree = (np.abs(own[:, None, None, :] - nb[None]) <= self._choose_tol).any(axis=1)  # (2, 2h, n)
            support = agree.sum(axis=1)
            alone = (agree & single.take(j)[None]).sum(axis=1)
            # which candidate is farther: smaller inverse depth (nearer the horizon)
            iz = self.geometry.inverse_depth(own.ravel() + self.top, np.concatenate([idx, idx]))[0]
            iz = np.where(np.isnan(iz), np.inf, iz).reshape(2, -1)
            far2 = iz[1] < iz[0]
            near_alone = np.where(far2, alone[0], alone[1]) >= h
            take_far = np.where(far2, 2 * support[1] >= support[0], 2 * support[0] >= support[1])
            pick2[idx] = np.where(near_alone, ~far2, np.where(take_far, far2, ~far2))
        return pick2

    def _segments(self, row: np.ndarray, found: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Label of the continuous surface run of each column (a column without a line is a run
        of its own), and the columns that disagree with their run (speckle outliers).

        Continuity is judged on a 5-column running median, which keeps depth jumps sharp but
        ignores single-column outliers: adjacent medians must differ by less than the row step of
        a ``jump_rel`` relative depth change (at least 1 px); a column more than that step from
        its median is an outlier.
        """
        p = self.params
        med = _running_median(row, found)
        iz, slope = self.geometry.inverse_depth(med)
        with np.errstate(invalid="ignore", divide="ignore"):
            step = np.abs(p.jump_rel * iz / slope)  # rows for a jump_rel change of depth
        step = np.where(np.isfinite(step), np.maximum(step, 1.0), 1.0)
        lim = np.minimum(step[1:], step[:-1])
        with np.errstate(invalid="ignore"):
            outlier = found & ~(np.abs(row - med) <= step)
            near = (np.abs(np.diff(row)) <= p.jump_factor * lim) | outlier[1:] | outlier[:-1]
            cont = found[1:] & found[:-1] & (np.abs(np.diff(med)) <= lim) & near
        start = np.empty(row.size, bool)
        start[0] = True
        np.logical_not(cont, out=start[1:])
        return np.cumsum(start), outlier

    def _unlit(self, status: np.ndarray, row: np.ndarray, lit_rows: np.ndarray) -> np.ndarray:
        H = self.config.height
        if lit_rows.shape != (H,):
            raise ValueError(f"lit_rows must have shape ({H},), got {lit_rows.shape}")
        if lit_rows.all():
            return status  # the usual case: the pulse lit every row
        dark = np.concatenate([[0], np.cumsum(~lit_rows)])
        lo, hi = self.lo + self.top, self.hi + self.top
        roi_dark = dark[hi] - dark[lo] > 0
        status = status.copy()
        status[(status == ColumnStatus.NO_RETURN) & roi_dark] = ColumnStatus.UNLIT
        ok = status == ColumnStatus.OK
        r = np.where(ok, np.rint(row), 0).astype(np.intp)
        w = self.params.half_width
        near_dark = dark[clamp(r + w + 1, 0, H)] - dark[clamp(r - w, 0, H)] > 0
        status[ok & near_dark] = ColumnStatus.UNLIT
        return status


def _last_true(mask: np.ndarray) -> np.ndarray:
    """Index of the last True element at or before each element (-1 if none)."""
    return np.maximum.accumulate(np.where(mask, np.arange(mask.size), -1))


def _next_true(mask: np.ndarray) -> np.ndarray:
    """Index of the next True element at or after each element (``mask.size`` if none)."""
    return np.minimum.accumulate(np.where(mask, np.arange(mask.size), mask.size)[::-1])[::-1]


def _inside_bright(label: np.ndarray, bright: np.ndarray) -> np.ndarray:
    """Columns with a bright column of the same run (equal consecutive labels) at or before them
    and at or after them."""
    W = label.size
    last, nxt = _last_true(bright), _next_true(bright)
    return ((last >= 0) & (nxt < W) & (label.take(np.maximum(last, 0)) == label)
            & (label.take(np.minimum(nxt, W - 1)) == label))


def _fill_gaps(row: np.ndarray, found: np.ndarray, max_gap: int, seen: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Fill runs of at most ``max_gap`` columns without a measurement (a dark speckle grain)
    between two measured columns of the same surface: linear in the row between them. Only
    where the two ends agree (|row difference| <= 1 + 0.5 x their distance in columns) and, for
    gaps where no line was seen at all (``seen`` False everywhere), only single columns.
    Returns the new rows and the mask of filled columns."""
    W = row.size
    left, right = _last_true(found), _next_true(found)
    gap = np.nonzero(~found & (left >= 0) & (right < W) & (right - left <= max_gap + 1))[0]
    filled = np.zeros(W, bool)
    if not gap.size:
        return row, filled
    lg, rg = left[gap], right[gap]
    span = rg - lg
    rl, rr = row[lg], row[rg]
    ok = (np.abs(rr - rl) <= 1.0 + 0.5 * span) & (seen[gap] | (span == 2))
    row = row.copy()
    row[gap[ok]] = rl[ok] + (rr[ok] - rl[ok]) * ((gap[ok] - lg[ok]) / span[ok])
    filled[gap[ok]] = True
    return row, filled


def _running_median(x: np.ndarray, found: np.ndarray) -> np.ndarray:
    """Median of the ``found`` values of x within +-2 of each element (NaN where not found).

    Where all five are found (most columns of a surface) the median-of-5 selection network gives
    it in 10 elementwise np.minimum/np.maximum over whole arrays; only the columns next to a
    missing one sort their window (missing as +inf, so last) and average the middle one or two
    of the found values."""
    W = x.size
    pad = np.full(W + 4, np.inf)
    pad[2:-2] = np.where(found, x, np.inf)
    a, b, e, c, d = (pad[i : i + W] for i in range(5))
    f = np.maximum(np.minimum(a, b), np.minimum(c, d))
    hi_ab, hi_cd = np.maximum(a, b), np.maximum(c, d)
    g = np.minimum(hi_ab, hi_cd)
    med = np.maximum(np.minimum(e, f), np.minimum(np.maximum(e, f), g))
    # a window with a missing value has +inf for its largest
    part = np.nonzero(found & (np.maximum(np.maximum(hi_ab, hi_cd), e) == np.inf))[0]
    if part.size:
        win = np.sort(pad[part[:, None] + np.arange(5)], axis=1)
        m, rows = np.isfinite(win).sum(axis=1), np.arange(part.size)
        med[part] = 0.5 * (win[rows, (m - 1) // 2] + win[rows, m // 2])
    return np.where(found, med, np.nan)


def _run_length(mask: np.ndarray) -> np.ndarray:
    """Length of the run of consecutive True elements that each element belongs to (0 if False)."""
    start = np.empty(mask.size, bool)
    start[0] = True
    np.logical_not(mask[1:] & mask[:-1], out=start[1:])
    label = np.cumsum(start)  # a False element is a run of its own, of weight 0
    return np.bincount(label, weights=mask).take(label)


def _local_line_fit(row: np.ndarray, weight: np.ndarray, inrun: np.ndarray, label: np.ndarray, half: int) -> np.ndarray:
    """Weighted least-squares line through the (finite) rows of the columns with ``weight`` > 0
    within +-half of each ``inrun`` column that belong to the same run (equal consecutive
    labels), evaluated at the column. Windowed sums by cumsum; every column of a run gets a
    value, weighted or not. The caller weights by the line's amplitude: under coherent speckle a
    dark column sits near a dark grain, where the field's phase varies fastest and the centroid
    scatters most (on the simulator's 90 % walls weighting by amplitude lowers the range error
    at 3 m from ~0.85 % to ~0.65 % against equal weights)."""
    W = row.size
    x = np.arange(W, dtype=np.float64)
    # window limits clipped to the run: runs are contiguous column ranges
    idx = np.arange(W)
    new = np.empty(W, bool)  # first column of a run
    new[0] = True
    np.not_equal(label[1:], label[:-1], out=new[1:])
    end = np.empty(W, bool)  # last column of a run
    end[-1] = True
    end[:-1] = new[1:]
    lo = np.maximum(idx - half, _last_true(new))  # new[0] and end[-1] are set: never -1 or W
    hi = np.minimum(idx + half, _next_true(end)) + 1
    # the five windowed sums from one cumulative sum over a (W, 5) array (row
    # gathers of 5 contiguous sums: much cheaper than fancy indexing along the second axis)
    terms = np.zeros((W + 1, 5))
    t = terms[1:]
    t[:, 0], t[:, 1], t[:, 2], t[:, 3] = 1.0, x, x * x, row
    np.multiply(x, row, out=t[:, 4])
    np.multiply(t, weight[:, None], out=t)
    np.cumsum(t, axis=0, out=t)
    sw, swx, swxx, swy, swxy = (terms.take(hi, axis=0) - terms.take(lo, axis=0)).T
    s0 = sw
    sx = swx - x * s0  # sums of (x - x_c) with x_c the column itself
    sxx = swxx - 2 * x * swx + x * x * s0
    sy = swy
    sxy = swxy - x * sy
    det = s0 * sxx - sx * sx
    with np.errstate(invalid="ignore", divide="ignore"):
        intercept = np.where(det > 1e-9, (sxx * sy - sx * sxy) / det, sy / s0)
    return np.where(inrun & (s0 > 0), intercept, row)
