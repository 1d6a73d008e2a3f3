"""When each ray of a scan was measured, under the rolling shutter (issue 16).

Image row r of a frame is read at T + (o + r) t_line and exposed during the exposure E before
that (T: the frame's SensorTimestamp, the start of the sensor's whole readout; o: the mode's
rows read before image row 0, ``readout_offset_rows``; device/camera/frame.py
``Frame.row_exposure_ns`` says where each comes from). The device's laser pulse covers the whole
exposure of every row the line can land in (device/service/assembly.py: exposure + the region
of interest's rows), so the light of a column's line arrived evenly over its row's exposure: the
column was measured at that window's middle, ``T + (o + row) t_line - E / 2``. That holds only
where the pulse covers the row's exposure: frames lit by a shorter pulse (``laserpi simulate``'s
defaults, a 17.4 ms pulse in a 40 ms exposure) got their line's light during the pulse, which
these times do not know. A column's time thus follows from the row its line was found in, and
differs from column to column with the range (a near return lies in other rows than a far one):
up to (rows of the region of interest) x t_line, 2.8 ms for the thesis geometry's 0.4-3.2 m.

A LaserScan has one time per ray on a line: ``stamp + i time_increment``. The scan's
``device_time`` and ``ray_interval_ns`` are the least-squares line through the measured rays'
times (device time of ray 0, and the step per ray). The rays' times are not on a line: the laser
line's row curves across the image (the lens's distortion), also on a flat wall seen squarely,
and steps at every depth jump; the line is off by its residual, which :func:`scan_timing`
returns (README "Scans on a moving robot" gives it: up to 0.9 ms in an office, 0.7 ms on a
square wall). Where no ray was measured, the middle of the region of interest's rows. The rays'
own times (``ScanRays.ray_times_ns``) go to a host that asks for them (settings ``ray_times``,
protocol minor 4: ``Scan.ray_times``); every ray with a range has one (its line's column:
``columns_scan_rays``). A host de-skews a scan with odometry by moving each ray i by the robot's
motion between its time (its own, or ``device_time + i time_increment``) and the time it wants
the scan at (README, "Scans on a moving robot").
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from device.camera.frame import Frame
from device.vision.kernel import columns_kernel


def column_times_ns(frame: Frame, rows: np.ndarray) -> np.ndarray:
    """CLOCK_MONOTONIC ns at which each column's line (sub-pixel ``rows``, NaN: none) was lit."""
    start, end = frame.row_exposure_ns(np.asarray(rows, dtype=np.float64))
    return (start + end) / 2


@dataclass(frozen=True)
class ScanTiming:
    first_ray_ns: int  # device time of ray 0
    ray_interval_ns: int  # step per ray (may be negative: the rays' order is the scan's, not the rows')
    residual_ns: float  # largest |measured ray time - the line| over the rays with a time


def scan_timing(times_ns: np.ndarray, fallback_ns: float) -> ScanTiming:
    """The line ``first + i interval`` through the rays' times (NaN: no time), least squares:
    its slope rounded to whole ns, then the offset that is the mean of ``time - slope i``, both
    rounded to nearest (ties to even); ``residual_ns`` the largest |time - line| over the rays
    with a time; ``fallback_ns`` for every ray when fewer than two have a time. One compiled pass
    (columns_scan_timing in device/vision/columns/columns.h), its sums taken relative to the
    first ray's time, where a clock's ~1e15 ns would cost digits."""
    t = np.ascontiguousarray(times_ns, dtype=np.float64).reshape(-1)
    first, interval, residual = columns_kernel().scan_timing(t, float(fallback_ns))
    return ScanTiming(first, interval, residual)
