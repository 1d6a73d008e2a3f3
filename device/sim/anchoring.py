"""The thesis's measured range error rebuilt from the simulator: the anchoring's explicit part.

The thesis's figures (section 6.4.3, Table 6.3: ~1.8 % at 2 m and ~2.4 % at 2.5 m, std of the
relative error on a 90 % wall) are the scatter of its whole prototype against a Hokuyo UTM-30LX
through a hand-measured transform (6.2). Besides what the image gives (speckle and sensor noise:
the simulator, whose speckle is the coherent model checked against Dorsch et al.'s bound), they
contain its calibration's residual: the laser plane and post-calibration were fitted to manually
picked laser pixels (4.2.2, 7.2.2), and lens distortion is still visible after post-calibration
(Figure 6.3 caption); plus the reference scanner's own scatter. Those are fixed per column, not
per frame, so they are modelled as one per-column row error of ``residual_px`` (RMS): its range
error is the row error times the geometry's relative range change per row at that column
(device.vision.geometry.ColumnGeometry.inverse_depth), added in quadrature to the simulated
scatter.

THESIS_RESIDUAL_PX is an ASSUMPTION fitted to the thesis's 2 m figure with the reference
pipeline on the simulator's defaults (``laserpi bench sim --anchor``); the 2.5 m figure is then a
prediction (tests/test_sim_anchoring.py). It belongs to the thesis's prototype, not to the
simulator: the pipelines here are scored against exact truth with an exact calibration, and the
calibration issue's own residual is measured separately (BENCHMARKS.md "Calibration").
"""

from __future__ import annotations

import numpy as np

#: RMS per-column row error of the thesis prototype's calibration and reference (px), fitted at 2 m.
THESIS_RESIDUAL_PX = 0.28


def relative_range_per_row(inverse_depth: np.ndarray, slope: np.ndarray) -> np.ndarray:
    """|d z / z| per row of line displacement: |d(1/z)/d row| / (1/z) (thesis eq. 3.12's
    sensitivity, from the per-column table). Shapes must match; NaN where either is NaN."""
    inverse_depth, slope = np.asarray(inverse_depth, dtype=np.float64), np.asarray(slope, dtype=np.float64)
    if inverse_depth.shape != slope.shape:
        raise ValueError(f"inverse_depth and slope shapes differ: {inverse_depth.shape} vs {slope.shape}")
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.abs(slope / inverse_depth)


def with_thesis_residual(rel_errors: np.ndarray, rel_per_row: np.ndarray,
                         residual_px: float = THESIS_RESIDUAL_PX) -> float:
    """Std of the relative range error the thesis would have measured: the simulated errors'
    std and a per-column row error of ``residual_px`` (RMS) in quadrature,
    sqrt(std(e)^2 + residual^2 mean(s^2)) with s the relative range change per row of each
    column (:func:`relative_range_per_row`)."""
    rel_errors, rel_per_row = np.asarray(rel_errors, dtype=np.float64), np.asarray(rel_per_row, dtype=np.float64)
    if rel_errors.shape != rel_per_row.shape or rel_errors.ndim != 1 or rel_errors.size < 2:
        raise ValueError(f"need two 1-D arrays of equal length >= 2, got {rel_errors.shape} and {rel_per_row.shape}")
    if not residual_px >= 0:
        raise ValueError(f"residual_px must be >= 0, got {residual_px}")
    if not (np.all(np.isfinite(rel_errors)) and np.all(np.isfinite(rel_per_row))):
        raise ValueError("errors and sensitivities must be finite (valid columns only)")
    return float(np.sqrt(np.var(rel_errors) + residual_px**2 * np.mean(rel_per_row**2)))
