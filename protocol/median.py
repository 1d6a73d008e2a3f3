"""The filters of a scan's ranges that ``ScanSettings`` asks for (SPEC.md, SET_CONFIG): its
``min_quality`` and ``median_window``. Every scan source applies these (:func:`scan_filters`):
the device's scan assembly (device/scan/source.py) and the mock device (protocol/mock_wall.py)."""

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


def scan_filters(ranges: np.ndarray, quality: np.ndarray, min_quality: int, median_window: int) -> np.ndarray:
    """``ranges`` with the returns weaker than ``min_quality`` invalid (NaN; REP 117's codes, +inf
    nothing there and -inf too close, have no line and stay: a host that filters weak returns
    still learns of an obstacle nearer than the range), then :func:`median_filter`."""
    if min_quality:
        ranges = np.where((quality < min_quality) & np.isfinite(ranges), np.float32(np.nan), ranges)
    return median_filter(ranges, median_window)
