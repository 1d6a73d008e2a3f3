"""The thesis's image pipeline, steps 1-7 of section 6.1.2 and Algorithm 2, as the baseline.

Implemented as written (with docs/thesis-notes.md N3 and N7); every improvement in :mod:`device.vision.fast` is
measured against it. The GPU stages (steps 2-4) run on the whole frame, as the thesis's OpenGL
shaders did; OpenCV's ``filter2D`` stands in for the blur shader. Values are on the 8-bit scale
(0..255) and clamped there after every stage, like the shaders' 8-bit render targets.

Choices where the text leaves room, and why:

* Step 2 far-row gain (docs/thesis-notes.md N7): the far returns land next to the laser plane's horizon in the
  image. The side of the image nearer the horizon is found from the geometry (the depth of the
  principal column at the top and bottom rows); the 20 % of rows on that side get a gain rising
  linearly from 1 (inner boundary) to 10 (image edge).
* Step 3's floor "below 0.1" is on the shaders' normalised scale, i.e. 0.1 x 255 here.
* Step 4's running blend keeps its state across calls (one call per frame pair); the state starts
  at the first filtered frame so a single pair already gives a result.
* Step 5 skips every other column and row when searching the maximum; the output therefore has
  one measurement per even column.
* Algorithm 2's blob walk stops at the first pixel not above 70 % of the maximum and the weighted
  average runs over [m, n] including those two boundary pixels, as the pseudo-code does; the
  weight test is on the blob's total weight (docs/thesis-notes.md N3).
* Step 7: backward projection by the 5-iteration Heikkila scheme (``undistort_fixed``), plane
  intersection, the 1..10000 mm filter on z (docs/thesis-notes.md N3, from ``[range]``), then eq. 6.5 with the
  configuration's post-calibration.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..config import SensorConfig
from ..model.camera import undistort_fixed
from ..model.triangulation import intersect_plane
from .geometry import column_geometry
from .measurements import ColumnMeasurements, ColumnStatus, finish, luminance


@dataclass(frozen=True)
class ReferenceParams:
    """The thesis's constants (section 6.1.2, Algorithm 2)."""

    far_fraction: float = 0.20  # step 2: share of rows boosted
    far_gain: float = 10.0  # step 2: gain at the far edge
    blur_floor: float = 0.1 * 255  # step 3
    blend: float = 0.75  # step 4, eq. 6.2
    min_lum: float = 10.0  # Algorithm 2
    min_blob: float = 0.70
    min_weight: float = 25.0
    stride: int = 2  # step 5: every other column and row
    heikkila_iterations: int = 5
    #: The thesis used every 5-iteration result; up to ~0.27 px off at the image sides with this
    #: lens. Accepted within 0.5 px (the prototype's own line accuracy), flagged beyond.
    heikkila_tol_px: float = 0.5


def blur_kernel() -> np.ndarray:
    """5x5 inverse-distance window of eq. 6.1, normalised to sum 1."""
    d = np.arange(-2, 3)
    w = 1.0 / np.sqrt(d[:, None] ** 2 + d[None, :] ** 2 + 1.0)
    return (w / w.sum()).astype(np.float32)


def far_row_gain(config: SensorConfig, params: ReferenceParams = ReferenceParams()) -> np.ndarray:
    """(H,) gain of step 2: 1 .. far_gain over the far_fraction of rows nearest the horizon."""
    H = config.height
    u = int(np.clip(round(config.camera.intrinsics.cx), 0, config.width - 1))
    z_top = _depth_at(config, u, 0.0)
    z_bottom = _depth_at(config, u, H - 1.0)
    far_on_top = z_top >= z_bottom
    n = max(int(round(params.far_fraction * H)), 1)
    ramp = np.ones(H, dtype=np.float32)
    g = np.linspace(params.far_gain, 1.0, n, dtype=np.float32)  # edge row first
    if far_on_top:
        ramp[:n] = g
    else:
        ramp[H - n :] = g[::-1]
    return ramp


def _depth_at(config: SensorConfig, u: float, v: float) -> float:
    xy = undistort_fixed(np.array([[u, v]]), config.camera, iterations=20).xy
    d = intersect_plane(xy, config.plane).depth[0]
    return float(d) if np.isfinite(d) else np.inf  # beyond the horizon counts as farthest


class ReferencePipeline:
    """Thesis pipeline; ``process(lit, unlit)`` per frame pair (stateful: the running blend)."""

    name = "reference"

    def __init__(self, config: SensorConfig, params: ReferenceParams = ReferenceParams()):
        self.config = config
        self.params = params
        # only the scan frame and the per-column angles are used from it (triangulation is the
        # thesis's own, below); a band from 0.1 m keeps its one-off construction short
        self.geometry = column_geometry(config, min(max(config.range.min_m, 0.1), config.range.max_m / 2))
        self.gain = far_row_gain(config, params)[:, None]
        self.kernel = blur_kernel()
        self.columns = np.arange(0, config.width, params.stride)
        spacing = np.abs(np.diff(self.geometry.column_angle))
        #: effective angular resolution: the 5-column blur window (step 3)
        self.resolution_deg = float(np.degrees(5 * np.median(spacing[np.isfinite(spacing)])))
        self._blend: np.ndarray | None = None

    def reset(self) -> None:
        self._blend = None

    def filtered(self, lit, unlit) -> np.ndarray:
        """Steps 1-4: the blended, filtered frame (float32, 0..255)."""
        import cv2

        shape = (self.config.height, self.config.width)
        a = luminance(lit, "lit", shape)
        b = luminance(unlit, "unlit", shape)
        p = self.params
        diff = cv2.absdiff(a, b).astype(np.float32)  # step 2
        diff = np.minimum(diff * self.gain, 255.0)
        blur = cv2.filter2D(diff, -1, self.kernel, borderType=cv2.BORDER_REPLICATE)  # step 3
        blur[blur < p.blur_floor] = 0.0
        if self._blend is None:  # step 4
            self._blend = blur
        else:
            self._blend = blur * (1.0 - p.blend) + self._blend * p.blend
        return self._blend

    def process(self, lit, unlit, lit_rows: np.ndarray | None = None, other_unlit=None) -> ColumnMeasurements:
        """Steps 1-7. ``lit_rows`` and ``other_unlit`` are accepted for the common interface and
        ignored (the thesis has no notion of partly lit frames, and differences one pair)."""
        frame = self.filtered(lit, unlit)
        p = self.params
        cols = self.columns
        f = frame[:, cols]  # (H, N)
        H = f.shape[0]
        # step 5: maximum over every other row (Algorithm 2 lines 3-6)
        maxidx = np.argmax(f[:: p.stride], axis=0) * p.stride
        n_cols = np.arange(cols.size)
        fmax = f[maxidx, n_cols]
        found = fmax >= p.min_lum  # noise threshold 1
        # step 6: uninterrupted blob above 70 % of the maximum (lines 9-14)
        thr = p.min_blob * fmax
        rows = np.arange(H)[:, None]
        below = ~(f > thr[None, :])
        m = np.where(below & (rows < maxidx), rows, -1).max(axis=0)
        n = np.where(below & (rows > maxidx), rows, H).min(axis=0)
        m, n = np.maximum(m, 0), np.minimum(n, H - 1)  # "m in ROWS": the walk stops at the edge
        inblob = (rows >= m) & (rows <= n)
        w = np.where(inblob, f, 0.0)
        weight = w.sum(axis=0)
        with np.errstate(invalid="ignore", divide="ignore"):
            j_laser = (w * rows).sum(axis=0) / weight  # lines 15-19
        found &= weight >= p.min_weight  # noise threshold 2 (docs/thesis-notes.md N3)
        status = np.where(found, ColumnStatus.OK, ColumnStatus.NO_RETURN).astype(np.uint8)
        row = np.where(found, j_laser, np.nan)
        # step 7: backward projection (5-iteration Heikkila) and the plane (lines 22-28)
        un = undistort_fixed(np.stack([cols.astype(np.float64), np.where(found, row, 0.0)], axis=-1),
                             self.config.camera, iterations=p.heikkila_iterations, tol_px=p.heikkila_tol_px)
        tri = intersect_plane(un.xy, self.config.plane, self.config.range.min_m, self.config.range.max_m)
        return finish(self.geometry, cols, row, np.where(found, fmax, 0.0), status, tri, self.config.post_calibration)
