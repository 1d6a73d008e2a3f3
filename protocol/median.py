"""The median filter of a scan's ranges that ``ScanSettings.median_window`` asks for (SPEC.md,
SET_CONFIG): every scan source applies this one, the device's scan assembly
(device/scan/source.py) and the mock device (protocol/mock_wall.py)."""

from __future__ import annotations

import warnings

import numpy as np


def median_filter(ranges: np.ndarray, window: int) -> np.ndarray:
    """Running median of odd ``window`` over finite neighbours; non-finite points stay as they are."""
    if window <= 1:
        return ranges
    half = window // 2
    padded = np.pad(ranges.astype(np.float64), half, constant_values=np.nan)
    windows = np.lib.stride_tricks.sliding_window_view(padded, window)
    with warnings.catch_warnings():  # windows with no finite value: the point is not finite anyway
        warnings.simplefilter("ignore", RuntimeWarning)
        med = np.nanmedian(np.where(np.isfinite(windows), windows, np.nan), axis=1)
    return np.where(np.isfinite(ranges), med, ranges).astype(np.float32)
