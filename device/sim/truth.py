"""Ground truth that the simulator attaches to every rendered frame."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class FrameTruth:
    """Per image column (width W) and per row (height H) truth of one rendered frame.

    ``row``: (W,) true sub-pixel row of the laser line's centre, NaN where the column has no return.
    ``range_m``: (W,) true range in the scan frame (device.model.scan_frame), +inf for no return.
    ``angle_rad``: (W,) true scan angle of the column's laser point, NaN for no return.
    ``points``: (W, 3) true 3-D laser point in the camera frame (metres), NaN for no return.
    ``surface``: (W,) int id of the scene surface hit (-1 none), to tell depth jumps apart.
    ``lit_rows``: (H,) bool, rows whose exposure overlapped the laser pulse.
    ``time_ns``: (W,) CLOCK_MONOTONIC of the column's laser light (the mean time of the light that
    made its line), NaN where none; None for a still scene (time does not matter there).
    ``range_span_m``: (W, 2) the nearest and the farthest of the ranges of the surfaces the
    column's laser light fell on during the exposure (each surface's light-weighted mean over the
    time slices), NaN where none; both ``range_m`` where it fell on one surface; None for a still
    scene. On a moving sensor a column's line may cross a depth jump during the exposure:
    ``range_m``, the light-weighted mean, then lies between the two surfaces, where nothing is,
    and either surface's range is a true one, a range between them none
    (device.vision.evaluation.reference_range).
    """

    row: np.ndarray
    range_m: np.ndarray
    angle_rad: np.ndarray
    points: np.ndarray
    surface: np.ndarray
    lit_rows: np.ndarray
    time_ns: np.ndarray | None = None
    range_span_m: np.ndarray | None = None
