"""The fast, accurate pipeline (issue 7): region of interest, vectorised peaks, line fit across
neighbouring columns, ghost rejection, table triangulation (thesis 6.1 and 6.3, improved).

Per frame pair (or triple):

0. Both unlit neighbours (issue 16; ``process(..., other_unlit=...)``, as the device pairs
   frames, device/scan/pairing.py). When the robot turns or drives, or something moves, the
   background of the lit frame is not that of the unlit frame 50 ms away: a textured background
   leaves bright edges in the difference, which became phantom ranges. With the unlit frames
   before and after the lit one, the band's background is their mean (the lit frame lies half
   way between them in time: a smooth motion's residue is second order, and mains flicker,
   whose 100/120 Hz period divides the 50 ms frame period, cancels in it). A column whose two
   neighbours differ (their 8-column x 4-row block means, every other row: the mean |difference|
   above ``moved_level`` and ``moved_mean_ratio`` times the median block difference sensor noise
   makes in its columns (shot noise grows with the light), or one block's above
   ``moved_block_level`` and ``moved_block_ratio`` times the frame's median (both measured
   within one unlit frame, where motion does not inflate them): an edge a few rows high that
   moved, as a horizontal edge crosses the rows when the robot drives forward; sensor noise
   alone stays below) moved. In a moved column the residue a moved texture leaves in
   ``lit - mean`` varies slowly along the column, except at its horizontal edges, while the laser
   line is a few rows high: the residue's trend along the column (its morphological opening over
   ``trend_rows`` rows, the largest envelope from below of what is at least that tall) joins the
   background the line is measured against, and the closing of that trend the one the noise
   level is measured against (narrow dark dips, the counterpart of narrow bright ridges that
   are not a line; the closing of the residue itself would bridge to the line). A line found
   there is kept only if it stands ``moving_noise_ratio`` times above the noise level (step 1) of
   the columns within ``moving_noise_columns`` (16; a moved feature leaves its residue where it
   was), ``lit_ridge_fraction`` of its smoothed peak above the lit frame's own rows
   ``half_width`` above and below it (the laser adds a ridge to the lit frame whatever the
   background did; a band of residue where an edge of the unlit frames moved against the lit
   one's is not a ridge there) and ``texture_ridge_ratio`` times the ridges of the unlit frames
   within ``moving_reach_columns`` and ``half_width`` rows (a narrow ridge of the texture itself,
   a bright stripe's corner above a moved edge, is in them too, where the background moved it),
   is no wider than ``moving_max_spread_px``, has dark flanks
   ``flank_rows`` above and below (moved texture is a band, aliased periodic texture a plateau,
   the laser a narrow line), and what is left after these checks is part of a run of
   ``moving_min_run`` continuous columns (a moved edge's residue passes in fragments); otherwise
   it is REJECTED (NaN), never a guess. And any column whose noise level in the residue (before
   the trend is taken out) exceeds ``blind_noise`` cannot claim "no return" (+inf: free space to a
   robot): REJECTED. A still scene's output differs from the one-neighbour pipeline by the
   lower noise of the mean background, and where sensor noise alone makes a column count as
   moved (16-32 columns a frame on a 90 % wall at a 40 ms exposure) by these checks there
   (BENCHMARKS.md "Motion"); ``process(lit, unlit)``
   without ``other_unlit`` is the pipeline as before, bit for bit. The too-close check (step 7)
   needs the return to brighten the lit frame against both neighbours, and in a moved column against
   the brightest of them within ``moving_reach_columns`` (a bright stripe of a periodic texture that
   aliases with the frame step is in the lit frame, and in neither neighbour at that column); within
   that distance of the image's edge, where the texture may have come in from outside it, such a
   return is REJECTED.

   When the robot turns, a quarter (``turn_share``) of the columns or more moved: each unlit
   neighbour is then turned to the lit frame first (device/vision/yaw.py: a yaw is a shift of
   the azimuth, found against the lit frame and read back through the lens model, up to
   ``max_turn_deg``, each ray where its row of the neighbour was read under the rolling shutter,
   from the Frames' timing: :func:`readout_shares`), and kept where a turn explains the change
   and leaves fewer than half of those columns moved. The frame is then judged as a still one,
   the columns that count as moved since the turn as above: a column only one neighbour saw
   (the image's side the turn brought in) against that one, and counted as moved; one neither
   saw is REJECTED (a line or "no return" there). The near rows of step 7 are not turned:
   there the neighbours count as they moved. A turned neighbour is resampled: a sharp edge the
   image drew within a row (an edge the lens leaves sharp, or a renderer's point-sampled
   pixels) comes back up to half a row from where the lit frame has it, a short horizontal
   residue as high as half the edge (a phantom line: 6-8 columns at 14-45 deg/s where a wall
   meets the floor). So the lit frame is held
   against the turned neighbours' mean allowed a row's misplacement: each pixel against the
   nearest value between the least and the greatest of the mean over its row and the rows above
   and below, that range narrowed by ``resample_slack`` levels each side (sensor noise alone
   opens none: 2-3 levels there on a 3x lit wall), so a line loses only what an edge under it
   spans. Where the edge's row in the lit frame shows what neither neighbour's shows (a texture
   that still rises up to the edge), a residue a row high stays: a line there must also stand
   ``edge_ratio`` times above the largest step the turned neighbours' mean makes from one row to
   the next within a row of it.

   A line in a column that counts as still, in a turned frame or, where ``agree_share`` of the
   columns moved and no turn was taken (the robot drives), within ``agree_reach_columns`` of a
   moved one, must stand ``agree_ratio`` times above where the two neighbours disagree
   along it (a sharp edge that one turned neighbour's resampling put a fraction of a row from
   the other's; a horizontal edge that moved a row between them as the robot drove, whose
   blocks changed by less than the bar for one block), and what is left there be part of a run
   holding ``moving_min_run`` of them on one surface: a column whose line was found but whose
   range the gate rejected (step 5) continues the run, as on a still frame (its line is there,
   only its row is not precise enough; not a peak detection rejected), where the depth changes by less than
   ``jump_rel`` from one column to the next; a gap without a line, or a depth jump, ends it
   (a phantom beside gated columns of a wall is no part of the wall's line). The disagreement
   is that of the neighbours as detection sees them:
   their difference smoothed by detection's 5 x 3 box, then its magnitude (the background
   detection measures a line against is the neighbours' mean, smoothed so). Sensor noise and
   the pixel-scale residue of resampling a sharp texture at two fractions of a pixel average
   out in it as they do in detection; the magnitude of the difference before smoothing counted
   them in full (a textured wall's turned neighbours differ there by 3-4 levels where the
   smoothed difference is ~2), and a turned textured wall lost lines 3x above that. A still scene pays nothing for it (noise marks 1-2 % of its columns
   moved), nor the person crossing a still robot of ``laserpi bench motion`` (16-17 %).
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
   occlusion edge continues alone on its side. See ``choose_second`` in ``columns/columns.c``.
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
   The range gate (``max_range_sigma``; off, ``inf``, by default: what it costs in valid columns
   is in BENCHMARKS.md "Motion"). Far away one row is worth 5-8 % of range, so a fit 0.7 px off
   is a gross error. Each fitted row's 1 sigma is propagated from its fit: a sandwich estimator
   over the window's columns (each column's residual over its leverage, at least its centre of
   mass's noise for its peak), plus the squared bias where the lines through the window's left
   and right halves disagree beyond their own sigmas (a depth edge the fit bridges into a dark
   surface with little peak of its own); at a run's end the column's own row, also an outlier's,
   stands for the missing side (a surface that ended a column earlier). Times the range's change
   per row (the 1/z table's slope) it is the range's predicted relative 1 sigma; above
   ``max_range_sigma`` the column is REJECTED (NaN), never a guess (``columns.c``: ``Line``,
   ``fit_sigma``). A line next to rows the pulse missed is UNLIT rather than REJECTED (the cause).
   A saturated background (a lamp, a sunlit patch, a long exposure in bright light): where the
   background the lit frame is measured against is within ``min_peak`` of full scale, the laser
   cannot brighten the lit frame by a line's least amplitude, so the sensor hides the line there.
   A line with such a pixel among its centre-of-mass rows was measured on the rest of its profile
   (its row pulled away from the hidden part: ~1 px, 5 % of the range at 2 m; a poster wall in 3x
   light at a 40 ms exposure gave 38 % of its ranges > 5 % off), and a column with 3 such rows
   in a row anywhere in the band (a line's height), or among the near rows of step 7, cannot
   claim "no return" (+inf: free space to a robot, where a wall can be hiding): both are SATURATED
   (NaN; ``_saturated``; the device reports it in HEALTH, error SATURATED).
6. Triangulation by the per-column ray table, post-calibration (docs/thesis-notes.md N8), scan angle/range.
   In a turned frame (step 0), a depth edge is smeared: while a row is exposed, the turn sweeps
   the scene by the turn between the frames (the larger of the neighbours' registered shifts)
   times the exposure over the frame period (the lit frame's metadata, or the operating point's
   for a bare image; the pulse covers every row's exposure), and a column within that sweep of the edge sees both surfaces at rows a
   fraction of a row apart: one line, centred between them (its profile cannot tell: at 90
   deg/s, seed 2, BENCHMARKS.md "Motion", their RMS spread is within the right columns' 99th
   percentile). Its range lies between the surfaces, a wrong range on neither. So a valid
   column whose depth lies more than ``mixed_tol`` (relative) from both the nearest and the
   farthest valid depth within half that sweep plus detection's box (2 columns) each side, where
   those two differ by more than ``mixed_jump``, is REJECTED (a mixture of surfaces no more
   than ``mixed_jump`` apart is never more than half of it off either). A surface slanted so
   steeply that its depth changes by ``mixed_jump`` within that window (at 90 deg/s, 17
   columns: ~75 deg from its normal) loses those columns too while the robot turns.
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

Steps 1-5 run in a compiled kernel, ``device/vision/columns/`` (columns.c says why C): the
image passes (difference, detection blur, noise level: equal to the OpenCV operations they fuse,
tested in ``tests/test_vision_kernel.py``) and one loop per column for each step after them; the
sub-pixel estimators other than the centre of mass stay in :mod:`device.vision.peaks` (numpy).
This module keeps the order of the steps, the tracking and the parameters.
"""

from __future__ import annotations

import functools
import logging
import math
from dataclasses import dataclass

import numpy as np

from ..camera.frame import Frame
from ..config import SensorConfig
from ..model.scan_frame import scan_frame
from ..model.triangulation import RangeStatus
from .geometry import column_geometry
from .measurements import STATUS_U8, ColumnMeasurements, ColumnStatus, finish, luminance
from .kernel import columns_kernel
from .peaks import ESTIMATORS, ColumnPeaks, clamp, refine_com_padded, refine_peaks, rows_read
from .yaw import NoTurnToSearch, registrations, yaw_grid

log = logging.getLogger(__name__)

#: Rows per block of the candidate search (``COLUMNS_BLOCK_ROWS`` in columns/columns.h, which
#: also fixes the detection blur at 5 columns x 3 rows).
BLOCK_ROWS = 16
#: Smallest difference at a saturated lit pixel for it to count as part of a saturated line.
SATURATED_LINE_MIN = 24
#: Largest centre-of-mass half width: the rows within half_width + 1 of the first candidate span
#: at most two 16-row blocks, which the second candidate's search leaves out (columns/columns.c).
MAX_HALF_WIDTH = (BLOCK_ROWS - 3) // 2
#: Step 7 reads the near rows of the columns without a return only, in spans, and step 0 the
#: moved columns' band: runs fewer than this many columns apart are read as one (a call per run
#: would cost more than the columns between them; a span over the whole image, as before, read
#: 1664 columns for 70).
SPAN_JOIN = 64
#: RangeStatus.TOO_CLOSE as the triangulation's status array holds it (numpy compares an IntEnum
#: member ~7x slower: it asks the member for the array protocols first)
_TOO_CLOSE_RANGE = np.uint8(RangeStatus.TOO_CLOSE)
_NO_PEAKS = ColumnPeaks(*(np.empty(0, t) for t in (np.float64, np.float64, np.intp, bool, bool, np.float64)))


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
    max_range_sigma: float = math.inf  # a range whose predicted 1 sigma (relative, step 5) exceeds this is REJECTED (inf: off)
    track_margin: int = 0  # rows searched each side of the previous frame's line (0: whole ROI every frame)
    track_full_every: int = 5  # with tracking: a full search at least every this many frames (new objects)
    track_lost_run: int = 10  # with tracking: this many adjacent columns losing their line force a full search
    # with both unlit neighbours (step 0): background that moved or flickered
    blind_noise: float = 4.0  # a column noisier than this (8-bit levels) cannot report "no return": REJECTED
    moved_level: float = 0.9  # a column whose neighbours differ by more than this on average (levels, block means) moved; there
    moved_block_level: float = 3.0  # ... or one of its blocks by this much (levels)
    moved_block_ratio: float = 5.0  # ... and this x the median block change sensor noise makes
    moved_mean_ratio: float = 1.5  # the average's bar is also this x the median change of 8 x 2 blocks noise makes in those columns
    moving_noise_ratio: float = 1.5  # a line must exceed this x the largest noise of the columns
    moving_noise_columns: int = 16  # this many either side,
    moving_max_spread_px: float = 2.0  # be no wider than this (RMS, px),
    flank_rows: int = 6  # and this many rows above and below it
    flank_fraction: float = 0.5  # be darker than this x its peak (a moved texture is a wide band), or it is REJECTED
    lit_ridge_fraction: float = 0.7  # ... and stand this x its smoothed peak above the lit frame's own rows half_width above and below it
    texture_ridge_ratio: float = 1.0  # ... and stand as a ridge above this x the ridges of the unlit frames
    moving_reach_columns: int = 64  # ... within this many columns (as far as the background may move)
    moving_min_run: int = 5  # ... and, after these checks, be part of a run of this many continuous columns
    trend_rows: int = 11  # the moved background's trend along each column is taken over this many rows (taller than a line)
    turn_share: float = 0.25  # when at least this share of the columns moved, the neighbours are turned to the lit frame (inf: never)
    max_turn_deg: float = 20.0  # ... by at most this much each (and at most what the lens allows: device/vision/yaw.py)
    agree_ratio: float = 3.0  # a line in a still column of a turned frame, or beside a moved one, must stand this x above where the neighbours disagree
    agree_reach_columns: int = 16  # ... beside: within this many columns,
    agree_share: float = 0.25  # ... where at least this share of the columns moved (the robot drives; not a person crossing, nor noise)
    resample_slack: float = 4.0  # a turned frame's background may be off by a row where it changes by more than this (levels) over three rows (inf: not at all)
    edge_ratio: float = 0.75  # ... and a line there must stand this x above the background's largest step between two rows within a row of it
    mixed_jump: float = 0.1  # in a turned frame, where the depths within the turn's sweep differ by more than this (relative; inf: off),
    mixed_tol: float = 0.02  # ... a column this far from both the nearest and the farthest is a mixture of them: REJECTED

    def __post_init__(self) -> None:
        if self.estimator not in ESTIMATORS:
            raise ValueError(f"unknown estimator {self.estimator!r}; choose from {', '.join(ESTIMATORS)}")
        for name in ("half_width", "min_run", "support_half"):
            if getattr(self, name) < 1:
                raise ValueError(f"{name} must be >= 1, got {getattr(self, name)}")
        if self.half_width > MAX_HALF_WIDTH:
            raise ValueError(f"half_width must be <= {MAX_HALF_WIDTH} (two candidates at least half_width + 1 rows "
                             f"apart within a {BLOCK_ROWS}-row block), got {self.half_width}")
        if self.track_margin < 0 or self.track_full_every < 1 or self.track_lost_run < 1:
            raise ValueError(f"need track_margin >= 0, track_full_every >= 1, track_lost_run >= 1, got "
                             f"{self.track_margin}, {self.track_full_every}, {self.track_lost_run}")
        if math.isfinite(self.max_range_sigma) and self.smooth_half == 0:
            raise ValueError("max_range_sigma needs the line fit (smooth_half > 0): the range gate propagates its sigma")
        if not (self.moved_level >= 0 and self.moved_block_level > 0 and self.moved_block_ratio >= 0
                and self.moved_mean_ratio >= 0):
            raise ValueError(f"need moved_level >= 0, moved_block_level > 0, moved_block_ratio >= 0 and "
                             f"moved_mean_ratio >= 0, got {self.moved_level}, {self.moved_block_level}, "
                             f"{self.moved_block_ratio}, {self.moved_mean_ratio}")
        if not (self.turn_share > 0 and 0 < self.max_turn_deg <= 45 and self.agree_ratio >= 0
                and self.agree_reach_columns >= 0 and self.agree_share > 0 and self.resample_slack >= 0
                and self.edge_ratio >= 0):
            raise ValueError(f"need turn_share > 0 (inf: never turn), 0 < max_turn_deg <= 45, agree_ratio >= 0, "
                             f"agree_reach_columns >= 0, agree_share > 0, resample_slack >= 0 and edge_ratio >= 0, got "
                             f"{self.turn_share}, {self.max_turn_deg}, {self.agree_ratio}, {self.agree_reach_columns}, "
                             f"{self.agree_share}, {self.resample_slack}, {self.edge_ratio}")
        if self.trend_rows <= 2 * self.half_width + 1 or self.moving_min_run < 1:
            raise ValueError(f"need trend_rows > 2 half_width + 1 (taller than a line) and moving_min_run >= 1, got "
                             f"{self.trend_rows}, {self.moving_min_run}")
        if min(self.lit_ridge_fraction, self.texture_ridge_ratio, self.moving_reach_columns) < 0:
            raise ValueError(f"need lit_ridge_fraction, texture_ridge_ratio and moving_reach_columns >= 0, got "
                             f"{self.lit_ridge_fraction}, {self.texture_ridge_ratio}, {self.moving_reach_columns}")
        if self.flank_rows < self.half_width:
            raise ValueError(f"flank_rows must be >= half_width, got {self.flank_rows} < {self.half_width}")
        if self.smooth_half < 0:
            raise ValueError(f"smooth_half must be >= 0, got {self.smooth_half}")
        if not (0 < self.jump_rel < 1 and self.min_peak > 0 and self.max_range_sigma > 0):
            raise ValueError(f"need 0 < jump_rel < 1, min_peak > 0 and max_range_sigma > 0, got {self.jump_rel}, "
                             f"{self.min_peak}, {self.max_range_sigma}")
        if not 0 <= 2 * self.mixed_tol < self.mixed_jump:
            raise ValueError(f"need 0 <= 2 mixed_tol < mixed_jump (inf: off; no depth is more than half the jump from "
                             f"both ends), got {self.mixed_tol}, {self.mixed_jump}")
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
        self._kernel = columns_kernel()
        # the kernel's ColumnsResolveParams (device/vision/columns/columns.h), in its order
        self._resolve_params = (params.dim_peak_fraction, params.own_peak_fraction, params.max_spread_px, params.jump_rel,
                                params.jump_factor, params.min_peak, params.max_range_sigma, params.min_run,
                                params.smooth_half, params.support_half, params.max_gap)
        # and its ColumnsMovedParams (step 0's bars)
        self._moved_params = (params.moved_level, params.moved_block_level, params.moved_block_ratio,
                              params.moved_mean_ratio)
        self._pad = rows_read(params.estimator, params.half_width)  # zero rows around the difference
        # image-sized temporaries kept between frame pairs (a search uses their first rows): one
        # allocated per frame costs page faults whenever the allocator returns it to the system
        W = config.width
        self._padded_buf = np.zeros((self.rows + 2 * self._pad, W), np.uint8)
        self._sm_buf = np.zeros((self.rows, W), np.uint8)
        # step 0's disagreement: the neighbours' difference, its box, its magnitude (_disagreed)
        self._disagree_bufs = (np.zeros((self.rows, W), np.int16), np.zeros((self.rows, W), np.int16),
                               np.zeros((self.rows, W), np.uint8))
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

    def process(self, lit, unlit, lit_rows: np.ndarray | None = None, other_unlit=None) -> ColumnMeasurements:
        import cv2

        shape = (self.config.height, self.config.width)
        lum_lit, lum_unlit = luminance(lit, "lit", shape), luminance(unlit, "unlit", shape)
        background = lum_unlit[self.top : self.top + self.rows]  # the band's rows of the unlit frame
        lit_band = lum_lit[self.top : self.top + self.rows]
        p = self.params
        moved = moved_raw = neighbours = lum_other = brought_in = turn_rad = None
        noise_background = residue_noise = None
        bright = background  # the background as the sensor saw it, whatever step 0 makes of it (step 5)
        if other_unlit is not None:  # step 0
            lum_other = luminance(other_unlit, "other unlit", shape)
            other = lum_other[self.top : self.top + self.rows]
            grid = self._yaw_grid if math.isfinite(p.turn_share) else None  # built at the first call with both
            moved = moved_raw = self._moved(background, other, background)
            if grid is not None and _share(moved) >= p.turn_share:
                shares = readout_shares(lit, (unlit, other_unlit))
                background, other, moved, brought_in, turn_rad = self._turned(grid, lum_lit, lum_unlit, lum_other,
                                                                              background, other, moved, shares)
            neighbours = (background, other)
            background = turned_mean = bright = cv2.addWeighted(background, 0.5, other, 0.5, 0.0)
            if brought_in is not None and math.isfinite(p.resample_slack):
                background = _within_a_row(lit_band, background, p.resample_slack)
            if moved.any():
                # a line hidden in what the moved background left cannot be told from no line:
                # "no return" is judged on that residue's noise (blind_noise)
                residue_noise = np.empty(background.shape[1])
                self._kernel.noise_level(lit_band, background, residue_noise)
                background, noise_background = _moved_backgrounds(lit_band, background, moved, p.trend_rows)
        band = self._tracking_band()
        if band is None:
            found, row, peak, status, seen, noise = self._search(lum_lit, background, noise_background, 0, self.rows)
        else:
            found, row, peak, status, seen, noise = self._search(lum_lit, background, noise_background, *band)
            lost = self._track.found & ~found
            edge = p.half_width + 1
            if (np.any(_run_length(lost) >= p.track_lost_run)
                    or (band[0] > 0 and seen[0] < band[0] + edge) or (band[1] < self.rows and seen[1] >= band[1] - edge)):
                # the line left the band in some columns (a depth jump, a new object in front of
                # the tracked surface, a lost line), or a candidate touches the band's edge (it
                # may continue outside): search the whole region of interest now
                found, row, peak, status, seen, noise = self._search(lum_lit, background, noise_background, 0, self.rows)
                band = None
        t0, t1 = band or (0, self.rows)
        self.searched_rows = (self.top + t0, self.top + t1)
        # a line found but its range too uncertain (the range gate, step 5: REJECTED, ``found``
        # kept; columns.c) still continues a line's run (step 0); not a column REJECTED at
        # detection (a peak too dim or too wide to be a line's: not found)
        gated = found & (status == STATUS_U8[ColumnStatus.REJECTED])
        if p.track_margin:
            tr = self._track
            self._track = _Track(found.copy(), *seen, 0 if band is None or tr is None else tr.since_full + 1)
        W = self.cols.size
        # too close: only columns in runs of >= min_run without a return can become a run of
        # "too close" ones (none: a wall fills every column; scattered dark speckle grains)
        empty = _run_length(status == STATUS_U8[ColumnStatus.NO_RETURN]) >= p.min_run
        spans = _spans(empty, SPAN_JOIN) if self.near_bottom > self.near_top else []
        near_hidden = np.zeros(W, bool)  # step 5's saturated background, among these rows
        if len(spans):
            close = np.zeros(W, bool)
            for c0, c1 in spans:  # only these columns are read (a wall's dim ends: ~70 of 1664 columns)
                # every other row (a line is at least two rows high), in one kernel pass: the
                # largest rise of the lit frame over the unlit one, its largest fall (the noise),
                # and the brightest two rows in a row of the unlit frame
                near, near_noise, pair = (np.empty(c1 - c0, np.uint8) for _ in range(3))
                self._kernel.near_rows(lum_lit, lum_unlit, self.near_mask, (self.near_top, self.near_bottom, 2),
                                       (int(c0), int(c1)), near, near_noise, pair)
                # stricter than in range (twice the noise ratio): a false "too close" stops a robot
                close[c0:c1] = near >= np.maximum(2 * p.min_peak, 2 * p.noise_ratio * near_noise)
                # a saturated background there (step 5, _saturated: two of these rows in a row,
                # a line's height) could hide a return nearer than the range
                near_hidden[c0:c1] = pair >= 255 - p.min_peak
            close &= empty
            # the near rows are outside the band and not turned: there the neighbours moved as they are
            if moved_raw is not None and np.any(close & moved_raw):
                above = self._near_above_moved_background(lum_lit, lum_unlit, lum_other, close & moved_raw)
                # within moving_reach_columns of the image's edge the texture may have come in from
                # outside it, where the neighbours are not seen: such a return cannot be trusted
                unseen = np.zeros(W, bool)
                edge = self.geometry.active_width  # the image's right edge (the buffer's padding beyond it)
                unseen[: p.moving_reach_columns] = unseen[edge - p.moving_reach_columns :] = True
                status[close & moved_raw & above & unseen] = STATUS_U8[ColumnStatus.REJECTED]
                close &= ~moved_raw | (above & ~unseen)
            if close.any():
                status[_run_length(close) >= p.min_run] = STATUS_U8[ColumnStatus.TOO_CLOSE]
        if moved is not None:
            status = self._untrusted(status, row, peak, noise, noise if residue_noise is None else residue_noise,
                                     moved, neighbours, lit_band, t0)
        if brought_in is not None:
            # no neighbour saw what the lit frame shows there: neither a line nor "nothing there"
            none = status == STATUS_U8[ColumnStatus.NO_RETURN]
            status = np.where(((status == STATUS_U8[ColumnStatus.OK]) | none) & brought_in,
                              STATUS_U8[ColumnStatus.REJECTED], status)
            status = self._disagreed(status, row, peak, moved, neighbours, np.ones(moved.size, bool), gated,
                                     turned_mean)
        elif moved is not None and _share(moved) >= p.agree_share:
            near = cv2.dilate(moved.astype(np.uint8)[None, :], np.ones((1, 2 * p.agree_reach_columns + 1), np.uint8))[0]
            status = self._disagreed(status, row, peak, moved, neighbours, near > 0, gated)
        if lit_rows is not None:
            status = self._unlit(status, found, row, np.asarray(lit_rows, dtype=bool))
        status = self._saturated(status, row, bright, near_hidden)
        found = status == STATUS_U8[ColumnStatus.OK]
        row = np.where(found, row, np.nan)
        tri = self.geometry.triangulate(row)
        if moved_raw is not None:
            # a line in a moved column that triangulates nearer than the range lies at the region of
            # interest's near edge, where a moved edge's residue passes for one as well: it is no
            # "too close" (step 7 judges the near rows of columns without a line), it is REJECTED
            _reject(moved_raw & found & (tri.status == _TOO_CLOSE_RANGE), status, found, row)
        if turn_rad is not None:
            _reject(self._mixed(tri.depth, found, turn_rad * exposure_share(lit, self.config.operating_point)),
                    status, found, row)
        return finish(self.geometry, self.cols, row, np.where(found, peak, 0.0), status, tri, self.config.post_calibration)

    def _saturated(self, status: np.ndarray, row: np.ndarray, bright: np.ndarray, near_hidden: np.ndarray) -> np.ndarray:
        """Step 5's saturated background: ``status`` with SATURATED where ``bright`` (the band of
        the background the lit frame is measured against) leaves the laser no room to show, within
        each column's region of interest (beyond it a line would be out of range anyway): a line
        with such a pixel among its centre-of-mass rows, and "no return" in a column with 3 such
        rows in a row (a line's height: a line there would leave nothing in the column; a lone
        pixel of noise that bright does not hide one) or where ``near_hidden`` (step 7's rows
        nearer than the range saturated). After the unlit step: a column the pulse missed stays
        UNLIT (the cause)."""
        import cv2

        p = self.params
        full = 255 - p.min_peak  # from here up the lit frame cannot stand min_peak above it
        none = status == STATUS_U8[ColumnStatus.NO_RETURN]
        hidden = near_hidden & none
        bright_columns = bright.max(axis=0) >= full
        if bright_columns.any():  # else (the common case) one reduction
            seen = cv2.bitwise_and(bright, self.mask)  # each column's region of interest
            W = bright.shape[1]
            c = np.nonzero(bright_columns & none)[0]
            if c.size:  # only such columns' span is read again (a lamp's, a window's)
                span = slice(int(c[0]), int(c[-1]) + 1)
                b = seen[:, span]
                hidden[span] |= none[span] & (np.minimum(np.minimum(b[:-2], b[1:-1]), b[2:]).max(axis=0, initial=0) >= full)
            ok = np.nonzero(bright_columns & (status == STATUS_U8[ColumnStatus.OK]))[0]
            if ok.size:
                h = p.half_width
                rows = clamp(np.rint(row[ok]).astype(np.intp)[None, :] - self.top + np.arange(-h, h + 1)[:, None], 0,
                             self.rows - 1)
                hidden[ok] = (seen.ravel().take(rows * W + ok[None, :]) >= full).any(axis=0)
        return np.where(hidden, STATUS_U8[ColumnStatus.SATURATED], status)

    def _moved(self, a: np.ndarray, b: np.ndarray, unlit: np.ndarray) -> np.ndarray:
        """Step 0: the columns where the neighbours' bands ``a`` and ``b`` differ (moved);
        ``unlit``: the unlit frame's own band, whose sensor noise sets the bar for one block.
        One pass of the kernel (columns_moved in columns/columns.h, which states the arithmetic);
        the reasons for each bar are here.

        Each band is averaged over blocks of 8 columns x 4 of every other row (sensor noise / 5.7;
        a texture that moved stays), then their mean |difference| per 8 columns is held against
        ``moved_level``. A change over the whole band, or a local one (an edge a few rows high
        that moved: under forward motion a horizontal edge crosses the rows, its residue a bright
        band): a block changed by ``moved_block_level``, and by ``moved_block_ratio`` x the median
        change sensor noise alone makes between such blocks (higher on a bright scene). That is
        measured within one frame, between the blocks of every 4th row and of the rows 2 below
        them, of a texture that hardly changes over 2 rows: motion inflates the median change
        between the neighbours' blocks (at 90 deg/s in 1x light an edge crossing the rows of a
        few blocks went unseen: a phantom line). These blocks are 8 columns x 2 rows, so their
        noise is sqrt(2) that of the 8 x 4 above; rounded to whole levels (as the 8 x 4 blocks
        are), the two medians came out equal on still 90 % walls (1), where this term sets the bar.

        The mean change sensor noise alone makes grows with the light (shot noise): on a still
        90 % wall at a 40 ms exposure it is ~0.9 levels, and half of the columns counted as moved
        and lost lines to step 0's checks. In noise the mean |difference| of the neighbours' 8 x 4
        blocks is ~0.84 x the median |difference| of these 8 x 2 ones (half-normal: E|d| of
        sqrt(2) sigma against the median of 2 sigma); the bar is ``moved_mean_ratio`` times that
        median, ~4 standard deviations of a still column's mean over n = 20 blocks above it. The
        median is taken over each 8-column group's blocks and its two neighbours' (their own
        light: over the frame, a bright wall before a dark backdrop took the backdrop's, and its
        columns counted as moved). On still 90 % walls at 40 ms 0.9 % of the groups still count
        as moved (by either bar; the block means are rounded to whole levels). A texture's change
        over 2 rows raises the median too (the office in 10x light: 1.06, noise alone ~0.5), which
        moves the bar only where that exceeds ``moved_level``. The noise is measured only where
        some group reaches a bar: else no column reaches one, whatever the noise."""
        moved = np.empty(a.shape[1], bool)
        self._kernel.moved(a, b, unlit, self._moved_params, moved)
        return moved

    def _turned(self, grid, lum_lit: np.ndarray, lum_unlit: np.ndarray, lum_other: np.ndarray, background: np.ndarray,
                other: np.ndarray, moved: np.ndarray, shares: tuple[float, float] | None):
        """Step 0 when ``turn_share`` of the columns moved: the neighbours read into the lit frame's
        band under the turn that matches each (device/vision/yaw.py; ``shares``: their
        readout_shares, the rolling shutter), where a turn explains how
        they differ and leaves fewer than half of the ``moved`` columns moved; else the bands as
        they were. Columns a neighbour did not see (the turn brought them in from outside the
        image) keep the raw bands and count as moved. Returns (band of the unlit frame, band of
        the other, moved, the columns brought in, the larger of the two turns in rad; the last
        two None where the bands were not turned). Of a periodic texture's aliases the next is
        tried where one leaves half of them moved (yaw.registrations)."""
        for regs in registrations(grid, lum_lit, (lum_unlit, lum_other), shares):
            a, b = regs[0].band, regs[1].band
            only_a, only_b = regs[0].seen & ~regs[1].seen, regs[1].seen & ~regs[0].seen
            b[:, only_a] = a[:, only_a]
            a[:, only_b] = b[:, only_b]
            brought_in = ~(regs[0].seen | regs[1].seen)
            for turned, raw in ((a, background), (b, other)):
                turned[:, brought_in] = raw[:, brought_in]
            turned_moved = self._moved(a, b, background) | brought_in | only_a | only_b
            if turned_moved.sum() < 0.5 * moved.sum():
                return a, b, turned_moved, brought_in, max(abs(r.shift_rad) for r in regs)
        return background, other, moved, None, None

    def _mixed(self, depth: np.ndarray, found: np.ndarray, sweep_rad: float) -> np.ndarray:
        """Step 6's mixtures of two surfaces in a turned frame (module docstring): the turn swept
        the scene by ``sweep_rad`` while a row was exposed."""
        p = self.params
        half = math.ceil(sweep_rad / self.column_spacing_rad / 2) + 2  # + detection's 5-column box
        return between_surfaces(depth, found & np.isfinite(depth), half, p.mixed_jump, p.mixed_tol)

    def _disagreed(self, status: np.ndarray, row: np.ndarray, peak: np.ndarray, moved: np.ndarray,
                   neighbours: tuple[np.ndarray, np.ndarray], judged: np.ndarray, gated: np.ndarray,
                   turned_mean: np.ndarray | None = None) -> np.ndarray:
        """Step 0's rejections among the ``judged`` columns (every column of a frame whose
        neighbours were turned to it; else, where ``agree_share`` of them moved, those within
        ``agree_reach_columns`` of a moved one): a
        line in a column that counts as still that does not stand ``agree_ratio`` times above where
        the two neighbours disagree along it (their difference smoothed as detection sees it, over its rows +-
        half_width: a sharp edge that one turned neighbour's resampling put a fraction of a row
        from the other's; a horizontal edge that moved a row between them as the robot drove,
        its blocks' change under the bar for one block), and what is left among them outside a
        run holding ``moving_min_run`` of them (such residue passes in fragments, as a moved
        edge's does: _untrusted), where ``gated`` columns (a line found, its range
        gated) continue a run on one surface (``jump_rel``). With ``turned_mean`` (the
        turned neighbours' mean: a turned frame), a line must also stand ``edge_ratio`` times above the largest step that
        mean makes from one row to the next within a row of the line's (an edge's row the lit
        frame shows and neither neighbour does)."""
        import cv2

        p = self.params
        ok = status == STATUS_U8[ColumnStatus.OK]
        bad = np.zeros(status.size, bool)
        cols = np.nonzero(ok & ~moved & judged)[0]
        if cols.size:
            diff, box, d = self._disagree_bufs
            cv2.convertScaleAbs(cv2.blur(cv2.subtract(*neighbours, dst=diff, dtype=cv2.CV_16S), (5, 3), dst=box), dst=d)
            h, n = p.half_width, d.shape[0]
            r = np.rint(row[cols]).astype(np.intp) - self.top
            rows = clamp(r[None, :] + np.arange(-h, h + 1)[:, None], 0, n - 1)
            disagree = d.ravel().take(rows * d.shape[1] + cols[None, :]).max(axis=0)
            bad[cols] = peak[cols] < p.agree_ratio * disagree
            if turned_mean is not None:
                steps = cv2.absdiff(turned_mean[1:], turned_mean[:-1])  # row y: between rows y and y + 1
                near = clamp(r[None, :] + np.arange(-2, 2)[:, None], 0, n - 2)  # rows r - 1 .. r + 1
                edge = steps.ravel().take(near * steps.shape[1] + cols[None, :]).max(axis=0)
                bad[cols] |= peak[cols] < p.edge_ratio * edge
        ok &= ~bad
        depth = self.geometry.triangulate(np.where(ok | gated, row, np.nan)).depth
        bad |= ok & judged & (_lines_in_run(ok, gated, depth, p.jump_rel) < p.moving_min_run)
        return np.where(bad, STATUS_U8[ColumnStatus.REJECTED], status)

    @functools.cached_property
    def _yaw_grid(self):
        """The (elevation, azimuth) grid of the band (device/vision/yaw.py), built at the first
        frame with both neighbours (~0.1 s here; not at the first turn, which would stall a scan);
        None, said once in the log, where this lens and band leave no turn to search: the frames
        are then judged without it (the checks on a moved background)."""
        c = self.config
        try:
            return yaw_grid(c.camera, scan_frame(c.plane), c.width, c.height, self.top, self.rows,
                            math.radians(self.params.max_turn_deg))
        except NoTurnToSearch as exc:
            log.warning("the unlit neighbours cannot be turned to the lit frame: %s", exc)
            return None

    def _near_above_moved_background(self, lit: np.ndarray, unlit: np.ndarray, other: np.ndarray,
                                     candidates: np.ndarray) -> np.ndarray:
        """Step 7 where the background moved: which of the ``candidates`` (columns) keep a return
        in the near rows that brightens the lit frame against both unlit neighbours (a moved edge
        brightens it against one and darkens it against the other) and stands above the brightest
        of them within ``moving_reach_columns`` (a bright stripe of a periodic texture that aliases
        with the frame step is in the lit frame, dark in both neighbours at that column, and
        bright in them where the motion took it; the laser's return is in neither). Every other
        column: False. Only the candidates' columns (in spans, as step 7 reads them) and
        ``moving_reach_columns`` around them are read (rarely any)."""
        import cv2

        p, W = self.params, self.cols.size
        rows = slice(self.near_top, self.near_bottom, 2)
        reach = np.ones((1, 2 * p.moving_reach_columns + 1), np.uint8)
        out = np.zeros(W, bool)
        for k0, k1 in _spans(candidates, SPAN_JOIN):
            a0, a1 = max(k0 - p.moving_reach_columns, 0), min(k1 + p.moving_reach_columns, W)
            la, mask = lit[rows, k0:k1], self.near_mask[:, k0:k1]
            noise = cv2.bitwise_and(cv2.subtract(cv2.max(unlit[rows, k0:k1], other[rows, k0:k1]), la), mask).max(axis=0)
            around = cv2.dilate(cv2.max(unlit[rows, a0:a1], other[rows, a0:a1]), reach)[:, k0 - a0 : k1 - a0]
            above = cv2.bitwise_and(cv2.subtract(la, around), mask).max(axis=0)
            out[k0:k1] = above >= np.maximum(2 * p.min_peak, 2 * p.noise_ratio * noise)
        return out & candidates

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

    def _search(self, lum_lit: np.ndarray, background: np.ndarray, noise_background: np.ndarray | None, t0: int, t1: int):
        """Find the line in rows [t0, t1) of the band (whole blocks) of ``lum_lit`` against
        ``background`` (the band's rows of the unlit frame(s)): steps 1-5 of the module docstring. Returns (found, row, peak, status, seen): rows in image coordinates, ``seen``
        the first and last band row of the line or a run of second candidates (a ghost; (t1, -1)
        if none), from which tracking sizes the next frame's band; ``noise`` the column's noise
        level (its largest smoothed negative difference)."""
        a = lum_lit[self.top + t0 : self.top + t1]
        b = background[t0:t1]
        p = self.params
        W = self.cols.size
        lo, hi = clamp(self.lo - t0, 0, t1 - t0), clamp(self.hi - t0, 0, t1 - t0)
        # noise: the largest smoothed negative difference over the whole band, also when tracking
        # (a maximum over fewer rows would be lower: more, and dimmer, detections). The ROI mask is
        # left out: the band's rows are as noisy as the column's own interval, and it saves work.
        # Computed first: it streams the whole band through the cache, the steps below reuse theirs
        noise = np.empty(W)
        self._kernel.noise_level(lum_lit[self.top : self.top + self.rows],
                                 background if noise_background is None else noise_background, noise)
        # the difference goes into a buffer with zero rows above and below (sub-pixel windows at
        # the band's edges need no clamping). A saturated lit pixel that the laser clearly
        # brightened is "at least full scale": flat top at 255, so the estimators' plateau handling
        # finds its centre whatever the unlit frame's noise (a bright background that merely
        # touches 255 is left alone: the pixel must be brightened by the laser and one of its
        # vertical neighbours too). Detection runs on a copy smoothed along the line (5 columns)
        # and across it (3 rows), which averages speckle and noise; the sub-pixel estimate uses
        # the unsmoothed difference.
        n, pad = t1 - t0, self._pad
        padded, sm = self._padded(n), self._sm_buf[:n]
        self._kernel.band_difference(a, b, self.mask[t0:t1], padded, pad, sm, SATURATED_LINE_MIN)
        k, sv = np.empty(2 * W, np.intp), np.empty(2 * W)  # first candidates, then second ones
        self._kernel.candidates(sm, padded, pad, p.half_width + 1, k, sv)
        k2, s2 = k[W:], sv[W:]
        thr = np.maximum(p.min_peak, p.noise_ratio * noise)
        c1 = self._refine(padded, k[:W], self.cols, lo, hi)
        # second candidates: refined only where they are strong enough to matter (few columns)
        idx = np.nonzero(s2 >= thr)[0]
        c2 = self._refine(padded, k2[idx], idx, lo[idx], hi[idx]) if idx.size else _NO_PEAKS
        found, row, peak = np.empty(W, bool), np.empty(W), np.empty(W)
        status = np.empty(W, np.uint8)
        seen = self._kernel.resolve((k, sv), thr, noise, (c1.row, c1.peak, c1.valid, c1.spread),
                                    (idx, c2.row, c2.peak, c2.valid, c2.spread),
                                    (self.geometry.inv_depth, self.geometry.top), (self.top, t0, t1),
                                    self._resolve_params, (found, row, peak, status))
        return found, row, peak, status, seen, noise

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

    def _untrusted(self, status: np.ndarray, row: np.ndarray, peak: np.ndarray, noise: np.ndarray,
                   residue_noise: np.ndarray, moved: np.ndarray, neighbours: tuple[np.ndarray, np.ndarray],
                   lit: np.ndarray, t0: int) -> np.ndarray:
        """Step 0's rejections. In a column whose background moved: a line that does not stand
        far enough above what the background left there and around it (``moving_noise_columns``),
        does not have a line's shape (wider than a line, as bright ``flank_rows`` above or below
        it: a band of moved texture; no ridge in the lit frame itself, or none above the unlit
        frames' ridges within ``moving_reach_columns``), or is left in a fragment shorter than
        ``moving_min_run``.
        Anywhere: "no return" where the noise of the residue (``residue_noise``) could hide a line."""
        import cv2

        p = self.params
        ok = status == STATUS_U8[ColumnStatus.OK]
        none = status == STATUS_U8[ColumnStatus.NO_RETURN]
        cols = np.nonzero(ok & moved)[0]
        blind = none & (residue_noise > p.blind_noise)
        if not cols.size:  # nothing moved where a line was found (a still scene): no shape to check
            return np.where(blind, STATUS_U8[ColumnStatus.REJECTED], status)
        # the difference of the last search (band rows t0.. at buffer rows pad..) from
        # flank_rows above each line to flank_rows below it, in one gather
        d = self._padded_buf
        r = np.rint(row[cols]).astype(np.intp) - (self.top + t0) + self._pad
        f, h = p.flank_rows, p.half_width
        rows = clamp(r[None, :] + np.arange(-f, f + 1)[:, None], 0, d.shape[0] - 1)
        around_line = d.ravel().take(rows * d.shape[1] + cols[None, :]).astype(np.float32)
        flank = np.maximum(around_line[0], around_line[-1])
        v = around_line[f - h : f + h + 1]  # the line's profile
        j = np.arange(-h, h + 1, dtype=np.float32)[:, None]
        with np.errstate(invalid="ignore", divide="ignore"):
            mean = (v * j).sum(axis=0) / v.sum(axis=0)
            spread = np.sqrt((v * (j - mean) ** 2).sum(axis=0) / v.sum(axis=0))
        # the residue a moved feature leaves lies beside it (where it was): the noise of the
        # columns around, ``moving_noise_columns`` each side
        k = 2 * p.moving_noise_columns + 1
        around = cv2.dilate(noise.astype(np.float32)[None, :], np.ones((1, k), np.uint8))[0]
        n, W = lit.shape
        rb = clamp(r - self._pad + t0, 0, n - 1)  # the lines' band rows
        # on the 5 x 3 smoothed images as detection sees them, over the rows the checks read and
        # the columns they need (the lines' +- moving_reach_columns, +- 2 for the smoothing: a
        # still scene's few moved columns are not worth the whole band)
        lo, hi = max(int(rb.min()) - 2 * h - 2, 0), min(int(rb.max()) + 2 * h + 3, n)
        c0, c1 = max(int(cols.min()) - p.moving_reach_columns - 2, 0), min(int(cols.max()) + p.moving_reach_columns + 3, W)
        smoothed = lambda x: cv2.blur(x[lo:hi, c0:c1], (5, 3)).astype(np.int16)  # noqa: E731
        core = clamp(rb[None, :] + np.arange(-1, 2)[:, None], 0, n - 1)  # the line's middle rows
        at = (core - lo) * (c1 - c0) + (cols - c0)[None, :]  # ... in the window of rows lo..hi, columns c0..c1
        # the laser adds a narrow ridge to the lit frame itself, whatever the background did: a
        # band of residue where an edge of the unlit frames moved against the lit one's is not one
        blurred = smoothed(lit)
        ridge = _ridges(blurred, h).ravel().take(at)
        lit_ridge = ridge.max(axis=0)
        sm = self._sm_buf  # the smoothed difference of the last search (its band rows t0..)
        smoothed_peak = sm.ravel().take(clamp(core - t0, 0, sm.shape[0] - 1) * sm.shape[1] + cols[None, :]).max(axis=0)
        # a saturated line's difference counts as full scale (step 1), but the laser lifts the lit
        # frame at most to 255: it can stand only as far above the rows beside it as that leaves
        room = 255 - blurred.ravel().take(at) + ridge
        smoothed_peak = np.minimum(smoothed_peak, room.max(axis=0))
        # a narrow ridge of the texture itself (the bright corner of a stripe above a moved edge)
        # is in the unlit neighbours too, where the background moved it: the line must outshine
        # their ridges within moving_reach_columns and half_width rows
        ridges = cv2.max(*(_ridges(smoothed(x), h) for x in neighbours))
        reach = cv2.dilate(ridges, np.ones((2 * h + 1, 2 * p.moving_reach_columns + 1), np.uint8))
        texture_ridge = reach.ravel().take(at).max(axis=0)
        shape = np.zeros(status.size, bool)
        shape[cols] = ((peak[cols] < p.moving_noise_ratio * around[cols]) | (flank >= p.flank_fraction * peak[cols])
                       | ~(spread <= p.moving_max_spread_px)
                       | (lit_ridge < p.lit_ridge_fraction * smoothed_peak) | (lit_ridge <= 0)
                       | (lit_ridge < p.texture_ridge_ratio * texture_ridge))
        status = np.where(shape | blind, STATUS_U8[ColumnStatus.REJECTED], status)
        # what these checks leave of a moved edge's residue are fragments: in moved columns a
        # line is one only as part of moving_min_run continuous columns
        ok = status == STATUS_U8[ColumnStatus.OK]
        short = moved & ok & (_run_length(ok) < p.moving_min_run)
        return np.where(short, STATUS_U8[ColumnStatus.REJECTED], status)

    def _unlit(self, status: np.ndarray, found: np.ndarray, row: np.ndarray, lit_rows: np.ndarray) -> np.ndarray:
        """UNLIT: columns without a line where the pulse missed rows of their region of interest, and
        columns whose line (``found``: measured, also where a later check REJECTED it) lies near
        such rows."""
        H = self.config.height
        if lit_rows.shape != (H,):
            raise ValueError(f"lit_rows must have shape ({H},), got {lit_rows.shape}")
        if lit_rows.all():
            return status  # the usual case: the pulse lit every row
        dark = np.concatenate([[0], np.cumsum(~lit_rows)])
        lo, hi = self.lo + self.top, self.hi + self.top
        roi_dark = dark[hi] - dark[lo] > 0
        status = status.copy()
        status[(status == STATUS_U8[ColumnStatus.NO_RETURN]) & roi_dark] = STATUS_U8[ColumnStatus.UNLIT]
        r = np.where(found, np.rint(row), 0).astype(np.intp)
        w = self.params.half_width
        near_dark = dark[clamp(r + w + 1, 0, H)] - dark[clamp(r - w, 0, H)] > 0
        status[found & near_dark] = STATUS_U8[ColumnStatus.UNLIT]
        return status


def _reject(mask: np.ndarray, status: np.ndarray, found: np.ndarray, row: np.ndarray) -> None:
    """Columns ``mask`` (of a line found) REJECTED after triangulation, in place: no line, no row."""
    status[mask] = STATUS_U8[ColumnStatus.REJECTED]
    found &= ~mask
    row[mask] = np.nan


def exposure_share(frame, op) -> float:
    """The share of the frame period a row of ``frame`` was exposed: its own metadata (a Frame:
    ExposureTime over FrameDuration, both microseconds, the second the time from one frame's start
    to the next's: raspberrypi/libcamera src/libcamera/control_ids_core.yaml; device/camera/
    picamera2_camera.py fills them from the request's metadata), the operating point's ``op`` for
    a bare image."""
    if isinstance(frame, Frame):
        return frame.exposure_us / frame.frame_duration_us
    return op.exposure_us * 1e-6 / op.frame_duration_s


def readout_shares(lit, neighbours) -> tuple[float, ...] | None:
    """One row's readout time over the time from ``lit`` to each of its unlit ``neighbours``, as
    device/vision/yaw.py registrations turns a ray by the rows it moved (the rolling shutter): from
    the Frames' own line time and SensorTimestamps (row r of a frame is read at its timestamp +
    (readout offset + r) line times, the same offset in every frame of a mode:
    device/camera/frame.py); 0 for a neighbour with the lit frame's timestamp (no time between
    them to correct by). None where any of them is a bare image, which carries no timing: its
    rows are then taken as read at one instant (the device, a recording and the simulator hand
    the pipeline Frames)."""
    if not (isinstance(lit, Frame) and all(isinstance(n, Frame) for n in neighbours)):
        return None
    gaps = [n.sensor_timestamp_ns - lit.sensor_timestamp_ns for n in neighbours]
    return tuple(lit.line_time_ns / gap if gap else 0.0 for gap in gaps)


def between_surfaces(depth: np.ndarray, valid: np.ndarray, half: int, jump: float, tol: float) -> np.ndarray:
    """Mask of the ``valid`` columns of ``depth`` (W,) that lie more than ``tol`` (relative) from
    both the nearest and the farthest valid depth within ``half`` columns each side, where those
    two differ by more than ``jump``: a mixture of two surfaces, not a range on either."""
    import cv2

    depth, valid = np.asarray(depth), np.asarray(valid, dtype=bool)
    if depth.ndim != 1 or depth.shape != valid.shape or half < 0:
        raise ValueError(f"need depth and valid of one 1-D shape and half >= 0, got {depth.shape}, {valid.shape}, {half}")
    z = depth.astype(np.float32)[None, :]
    kernel = np.ones((1, 2 * half + 1), np.uint8)
    nearest = cv2.erode(np.where(valid, z, np.inf), kernel, borderType=cv2.BORDER_REPLICATE)[0]
    farthest = cv2.dilate(np.where(valid, z, -np.inf), kernel, borderType=cv2.BORDER_REPLICATE)[0]
    with np.errstate(invalid="ignore"):
        return (valid & (farthest > nearest * (1 + jump))
                & (z[0] > nearest * (1 + tol)) & (z[0] * (1 + tol) < farthest))


def _ridges(image: np.ndarray, k: int) -> np.ndarray:
    """How far each pixel of ``image`` (int16) stands above both the pixels ``k`` rows above and
    below it (0 where it does not, and in the first and last ``k`` rows), as uint8."""
    out = np.zeros(image.shape, np.int16)
    out[k:-k] = np.minimum(image[k:-k] - image[: -2 * k], image[k:-k] - image[2 * k :])
    return np.clip(out, 0, 255).astype(np.uint8)


def _within_a_row(lit: np.ndarray, background: np.ndarray, slack: float) -> np.ndarray:
    """(rows, W) uint8: the background each pixel of ``lit`` is held against when ``background``
    may be misplaced by up to a row: ``lit`` itself where it lies between the least and the
    greatest of ``background`` over its row and the rows above and below, each moved ``slack``
    levels towards ``background`` (no further), else the nearer of them (step 0, turned frames)."""
    import cv2

    column = np.ones((3, 1), np.uint8)
    # in place: each new band-sized array costs this as much as the operation (fresh pages)
    hi = cv2.dilate(background, column)
    cv2.max(cv2.subtract(hi, slack, dst=hi), background, dst=hi)
    lo = cv2.erode(background, column)
    cv2.min(cv2.add(lo, slack, dst=lo), background, dst=lo)
    return cv2.min(cv2.max(lit, lo, dst=lo), hi, dst=lo)


def _moved_backgrounds(lit: np.ndarray, background: np.ndarray, moved: np.ndarray, trend_rows: int):
    """Step 0's backgrounds where the background moved (``moved`` columns): the residue
    ``lit - background`` a moved texture leaves varies slowly along a column except at its
    horizontal edges, while the line is a few rows high. So the residue's trend along the column
    (its opening over ``trend_rows`` rows: the largest envelope from below of what is at least
    that tall) joins the background the line is measured against, and the closing of that trend
    joins the one the noise level is measured against (narrow dark dips, the counterpart of
    narrow bright ridges that are not a line; the closing of the residue itself would bridge
    from the line to the texture beside it). Returns (background for the line, for the noise)."""
    import cv2

    n, W = background.shape
    line_bg, noise_bg = background.copy(), background.copy()  # the columns that did not move keep the mean
    se = np.ones((trend_rows, 1), np.uint8)
    # only the moved columns' spans are read, each with the 2 columns either side the smoothing
    # needs (the opening and the closing work down each column)
    for k0, k1 in _spans(moved, SPAN_JOIN):
        a0, a1 = max(k0 - 2, 0), min(k1 + 2, W)
        residue = cv2.blur(cv2.subtract(lit[:, a0:a1], background[:, a0:a1], dtype=cv2.CV_16S), (5, 3))
        # the band's ends continue flat (trend_rows rows, as far as an opening and a closing
        # look): a residue that rises towards them is not a ridge there
        residue = cv2.copyMakeBorder(residue, trend_rows, trend_rows, 0, 0, cv2.BORDER_REPLICATE)
        below = cv2.morphologyEx(residue, cv2.MORPH_OPEN, se)
        above = cv2.morphologyEx(below, cv2.MORPH_CLOSE, se)[trend_rows : trend_rows + n, k0 - a0 : k1 - a0]
        below = below[trend_rows : trend_rows + n, k0 - a0 : k1 - a0]
        span = background[:, k0:k1]
        line_bg[:, k0:k1], noise_bg[:, k0:k1] = cv2.add(span, below, dtype=cv2.CV_8U), cv2.add(span, above, dtype=cv2.CV_8U)
        still = ~moved[k0:k1]
        if still.any():  # inside a span too, the columns that did not move keep the mean
            line_bg[:, k0:k1][:, still] = noise_bg[:, k0:k1][:, still] = span[:, still]
    return line_bg, noise_bg


def _spans(mask: np.ndarray, join: int) -> np.ndarray:
    """[start, end) of the runs of True in a 1-D ``mask``, runs less than ``join`` apart joined
    into one span (with the False elements between them), shape (spans, 2)."""
    out = np.empty(((mask.size + 1) // 2, 2), np.intp)
    return out[: columns_kernel().spans(np.ascontiguousarray(mask, bool), join, out)]


def _lines_in_run(ok: np.ndarray, gated: np.ndarray, depth: np.ndarray, jump: float) -> np.ndarray:
    """How many ``ok`` columns lie in each column's run (0 outside ``ok | gated``): consecutive ok
    columns, joined through ``gated`` ones (a line found, its range too uncertain) where
    ``depth`` changes by less than ``jump`` (relative to the nearer) from one column to the next:
    one surface. A NaN depth joins only two ok columns."""
    line = ok | gated
    with np.errstate(invalid="ignore"):
        surface = np.abs(np.diff(depth)) < jump * np.fmin(depth[1:], depth[:-1])
    joined = (ok[1:] & ok[:-1]) | (line[1:] & line[:-1] & surface)
    starts = line.copy()
    starts[1:] &= ~joined
    run = np.cumsum(starts)
    totals = np.bincount(run, weights=ok, minlength=int(run[-1]) + 1)
    return np.where(line, totals[run], 0).astype(np.intp)


def _share(mask: np.ndarray) -> float:
    """The share of True in ``mask``: its mean, counted (numpy's mean of bools converts them first)."""
    return np.count_nonzero(mask) / mask.size


def _run_length(mask: np.ndarray) -> np.ndarray:
    """Length of the run of consecutive True elements that each element belongs to (0 if False)."""
    out = np.empty(mask.size, np.intp)
    columns_kernel().run_length(np.ascontiguousarray(mask, bool), out)
    return out
