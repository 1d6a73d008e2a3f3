"""The host-side crop of a scan: ``crop(scan, angle_min=..., range_max=...)``, a pure function.

Conventions of the ROS drivers of other 2-D scanners:

- Angles as urg_node does it (ros-drivers/urg_node, src/urg_c_wrapper.cpp,
  URGCWrapper::setAngleLimitsAndCluster): each limit is rounded to the nearest ray
  (urg_rad2step), the rays between the two are kept, both included, and at least two are kept
  (when both limits fall on one ray its neighbour is added). The cropped scan starts at its first
  kept ray: its stamp and device time move by the rays cut before it times time_increment, so a
  LaserScan made of it reports the first and last kept ray's angles, not the requested limits.
  A limit beyond the field of view keeps the field's edge.
- Ranges: a LaserScan's range_min and range_max are the limits its consumer applies (urg_node
  publishes the device's, urg_c_wrapper.cpp getRangeMin/getRangeMax). Here they become the
  tighter of the device's and the requested ones, and the ranges are made to agree with them as
  REP 117 says: a finite range beyond range_max is +inf (no return within range), one below
  range_min is -inf (too close); NaN stays NaN.

Bad limits (NaN, min above max, a negative range) raise ValueError naming them.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

from host_sdk.scan import Scan


def crop(scan: Scan, *, angle_min: float = -math.inf, angle_max: float = math.inf, range_min: float = 0.0,
         range_max: float = math.inf) -> Scan:
    """``scan`` cropped to [angle_min, angle_max] (rad) and filtered to [range_min, range_max] (m)."""
    for name, value in (("angle_min", angle_min), ("angle_max", angle_max), ("range_min", range_min),
                        ("range_max", range_max)):
        if math.isnan(value):
            raise ValueError(f"{name} is NaN")
    if angle_min > angle_max:
        raise ValueError(f"angle_min {angle_min} is above angle_max {angle_max}")
    if not 0 <= range_min < range_max:
        raise ValueError(f"need 0 <= range_min < range_max, got {range_min}, {range_max}")
    keep = _kept_rays(scan.angles, angle_min, angle_max)
    first = int(np.argmax(keep))
    rmin, rmax = max(range_min, scan.range_min), min(range_max, scan.range_max)
    r = scan.ranges[keep]
    finite = np.isfinite(r)
    r = np.where(finite & (r > rmax), np.inf, np.where(finite & (r < rmin), -np.inf, r)).astype(np.float32)
    shift = first * scan.time_increment
    return replace(scan, stamp=scan.stamp + shift, device_time=scan.device_time + shift, angles=scan.angles[keep],
                   ranges=r, intensities=scan.intensities[keep], range_min=float(rmin), range_max=float(rmax))


def _kept_rays(angles: np.ndarray, angle_min: float, angle_max: float) -> np.ndarray:
    """Mask of the rays between the rays nearest to the limits, at least two (urg_node)."""
    ordered = np.unique(angles.astype(np.float64))
    if ordered.size < 2:
        return np.ones(angles.shape, bool)
    lo = int(np.argmin(np.abs(ordered - np.clip(angle_min, ordered[0], ordered[-1]))))
    hi = int(np.argmin(np.abs(ordered - np.clip(angle_max, ordered[0], ordered[-1]))))
    if lo == hi:  # one ray: add its neighbour, as urg_node widens to two steps
        lo, hi = (lo, lo + 1) if lo == 0 else (hi - 1, hi)
    a = angles.astype(np.float64)
    return (a >= ordered[lo]) & (a <= ordered[hi])
