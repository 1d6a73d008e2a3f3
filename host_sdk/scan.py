"""Scan: one 2-D scan on the host, with host time stamp, ROS conventions and LaserScan export.

Time stamps. ``Scan.stamp`` is the host's ``time.monotonic()`` at the moment the first ray was
exposed. It is computed from what the host can observe:

    first_ray ≈ t_end - wire_bytes · byte_time - age

where t_end is when the frame's last byte arrived (the read that delivered it, minus the bytes
that came after it in the same read), wire_bytes the frame's encoded length, byte_time
10 / baudrate (8N1 UART) and age the device's own measure of how old the scan was when it
started sending (SCAN.age_us). Reads only ever arrive late, so the per-scan estimates are
turned into a clock offset (host − device) by taking the minimum over the last
StampClock.window scans; stamp = device_time + offset. This removes host scheduling jitter and
leaves a constant error of the order of the serial driver's latency (about a millisecond).
A scan whose timing is a lie (an age of 0xFFFFFFFF µs, a device time far off) gives an estimate
far below the others: the minimum is only taken over estimates no more than
StampClock.tolerance_s below the fifth smallest in the window (the median while the window holds
fewer than ten), so up to four such scans in a window shift no stamp - not even their own, which
comes from the others. tolerance_s (0.5 s) is above what a loaded host adds to a read (a late
read must not make the good estimates before it look low), and far below what a lie does. A genuine jump of the offset (the device restarted) is followed within
five scans; the Receiver also resets the clock when it sees a restart.
A frame that had to wait in the device's UART buffer behind the previous one gives a late
estimate, which the minimum also ignores as long as the link is not saturated (54 % at
921600 baud and full rate, protocol/SPEC.md).
Clock drift between device and host over the window (5 s at 10 Hz) is < 0.3 ms for 50 ppm
crystals. For a USB CDC link the baud rate is nominal: pass the real throughput as
``link_rate_bps`` to LaserPi.
"""

from __future__ import annotations

import collections
import math
from dataclasses import dataclass, replace

import numpy as np

from protocol.messages import UART_BITS_PER_BYTE, Info, ScanMessage


@dataclass(frozen=True, eq=False)
class LaserScan:
    """The fields of sensor_msgs/msg/LaserScan (``stamp`` and ``frame_id`` are its header).

    Angles increase (angle_increment > 0); ranges and intensities are float32 arrays.
    """

    stamp: float
    frame_id: str
    angle_min: float
    angle_max: float
    angle_increment: float
    time_increment: float
    scan_time: float
    range_min: float
    range_max: float
    ranges: np.ndarray
    intensities: np.ndarray


@dataclass(frozen=True, eq=False)
class Scan:
    """One scan. Arrays are float32 of shape (n,), index i is one ray.

    seq: device scan counter (u32); a jump means scans were lost (Stats.scans_missing).
    stamp: host time.monotonic() of the first ray, s (module docstring).
    device_time: device clock of the first ray, s.
    angles: bearing of each ray, rad, counter-clockwise from +x (REP 103).
    ranges: m; REP 117: NaN invalid, +inf no return within range_max, -inf closer than range_min.
    intensities: the device's per-point quality, 0..255 (no physical unit).
    time_increment: s between consecutive rays; scan_time: s between scans. Ray i was measured at
    device_time + i time_increment, within the line's residual (README "Scans on a moving robot").
    ray_times: float64 (n,), device clock (s) at which each ray was measured, exact (to the µs) from
    the image row its range was found in; a ray without a measured time has the line's. None
    unless asked for (``configure(ray_times=True)``, a device of protocol minor >= 4). Host time of
    ray i: ``stamp + (ray_times[i] - device_time)``.
    """

    seq: int
    stamp: float
    device_time: float
    angles: np.ndarray
    ranges: np.ndarray
    intensities: np.ndarray
    time_increment: float
    scan_time: float
    range_min: float
    range_max: float
    ray_times: np.ndarray | None = None

    def points(self) -> np.ndarray:
        """(n, 2) x, y in metres in the sensor frame; rows of non-finite ranges are NaN."""
        r = np.where(np.isfinite(self.ranges), self.ranges, np.nan)
        return np.stack([r * np.cos(self.angles), r * np.sin(self.angles)], axis=1)

    def cropped(self, *, angle_min: float = -math.inf, angle_max: float = math.inf, range_min: float = 0.0,
                range_max: float = math.inf) -> Scan:
        """This scan cropped to [angle_min, angle_max] and filtered to [range_min, range_max]
        (see Crop, which says how)."""
        return Crop(angle_min, angle_max, range_min, range_max).apply(self)

    def to_laserscan(self, frame_id: str = "laser", stamp: float | None = None, *, angle_min: float = -math.inf,
                     angle_max: float = math.inf, range_min: float = 0.0, range_max: float = math.inf) -> LaserScan:
        """The scan as sensor_msgs/LaserScan fields, with increasing, equally spaced angles.

        angle_min .. range_max crop and filter it first (Crop); the LaserScan's angle_min and
        angle_max are then those of its first and last ray, its range_min and range_max the
        filter's.

        LaserScan can only express equally spaced angles. If the device's angles (from its
        calibration) are within a quarter step of equal spacing the rays are copied in
        increasing-angle order; otherwise each equally spaced angle takes the range of the
        nearest ray (never an interpolation across an edge), a bearing error of at most half the
        local ray spacing. ``stamp`` (default Scan.stamp, host monotonic time) is the time of the
        device's first ray; when the order is reversed, the LaserScan's stamp is moved to its own
        first ray and time_increment changes sign, as LaserScan defines them.
        """
        order = np.argsort(self.angles, kind="stable")
        a = self.angles[order].astype(np.float64)
        ranges, inten = self.ranges[order], self.intensities[order]
        n = a.size
        inc = (a[-1] - a[0]) / (n - 1) if n > 1 else 0.0
        grid = a[0] + inc * np.arange(n)
        if n > 1 and np.abs(a - grid).max() > 0.25 * inc:
            right = np.clip(np.searchsorted(a, grid), 1, n - 1)
            nearest = np.where(grid - a[right - 1] <= a[right] - grid, right - 1, right)
            ranges, inten = ranges[nearest], inten[nearest]
        crop = Crop(angle_min, angle_max, range_min, range_max)
        if crop != _NO_CROP:
            return crop.apply(self).to_laserscan(frame_id, stamp)
        stamp = self.stamp if stamp is None else stamp
        time_inc = self.time_increment
        if n > 1 and order[0] != 0:  # the device's first ray is now last: stamp the new first one
            stamp += (n - 1) * time_inc
            time_inc = -time_inc
        return LaserScan(stamp, frame_id, float(grid[0]), float(grid[-1]), float(inc), float(time_inc),
                         self.scan_time, self.range_min, self.range_max, ranges.astype(np.float32),
                         inten.astype(np.float32))


@dataclass(frozen=True)
class Crop:
    """Crop a scan to [angle_min, angle_max] (rad) and filter it to [range_min, range_max] (m)
    on the host, with the conventions of the ROS drivers of other 2-D scanners:

    - Angles as in urg_node (ros-drivers/urg_node, src/urg_c_wrapper.cpp,
      URGCWrapper::setAngleLimitsAndCluster): each limit is rounded to the nearest ray (urg_rad2step),
      the rays between them are kept inclusive, and at least two are kept (the neighbour of the
      one ray is added); the scan then starts at its first kept ray (stamp and device time move
      with it) and a LaserScan made of it reports the first and last kept ray's angles, not the
      requested limits. A limit outside the field of view keeps the field's edge.
    - Ranges: the LaserScan's range_min and range_max are the limits a consumer must apply
      (urg_node reports the device's, urg_c_wrapper.cpp getRangeMin/getRangeMax; rplidar_ros
      likewise, src/node.cpp publish_scan). Here they become the tighter of the device's and the
      requested ones, and the ranges are made to agree with them as REP 117 says: a finite range
      beyond range_max is +inf (no return within range), one below range_min is -inf (too close);
      NaN stays NaN. Limits wider than the device's keep the device's.

    Bad limits (NaN, min above max, a negative range, a range window outside the sensor's)
    raise ValueError naming them.
    """

    angle_min: float = -math.inf
    angle_max: float = math.inf
    range_min: float = 0.0
    range_max: float = math.inf

    def __post_init__(self):
        for name in ("angle_min", "angle_max", "range_min", "range_max"):
            if math.isnan(getattr(self, name)):
                raise ValueError(f"{name} is NaN")
        if self.angle_min > self.angle_max:
            raise ValueError(f"angle_min {self.angle_min} is above angle_max {self.angle_max}")
        if not 0 <= self.range_min < self.range_max:
            raise ValueError(f"need 0 <= range_min < range_max, got {self.range_min}, {self.range_max}")

    def apply(self, scan: Scan) -> Scan:
        keep = self._rays(scan.angles)
        first = int(np.argmax(keep)) if keep.size else 0
        rmin, rmax = max(self.range_min, scan.range_min), min(self.range_max, scan.range_max)
        if not rmin < rmax:
            raise ValueError(f"range limits [{self.range_min}, {self.range_max}] m do not overlap the sensor's "
                             f"[{scan.range_min}, {scan.range_max}] m")
        r = scan.ranges[keep]
        with np.errstate(invalid="ignore"):
            r = np.where(np.isfinite(r) & (r > rmax), np.inf, np.where(np.isfinite(r) & (r < rmin), -np.inf, r))
        shift = first * scan.time_increment
        return replace(scan, stamp=scan.stamp + shift, device_time=scan.device_time + shift,
                       angles=scan.angles[keep], ranges=r.astype(np.float32), intensities=scan.intensities[keep],
                       range_min=float(rmin), range_max=float(rmax),
                       ray_times=None if scan.ray_times is None else scan.ray_times[keep])

    def _rays(self, angles: np.ndarray) -> np.ndarray:
        """Mask of the rays kept: between the rays nearest to the limits, at least two."""
        ordered = np.unique(angles.astype(np.float64))
        if ordered.size < 2 or (self.angle_min <= ordered[0] and self.angle_max >= ordered[-1]):
            return np.ones(angles.shape, bool)
        lo = int(np.argmin(np.abs(ordered - np.clip(self.angle_min, ordered[0], ordered[-1]))))
        hi = int(np.argmin(np.abs(ordered - np.clip(self.angle_max, ordered[0], ordered[-1]))))
        if lo == hi:  # one ray: add its neighbour, as urg_node widens to two steps
            lo, hi = (lo, lo + 1) if lo == 0 else (hi - 1, hi)
        a = angles.astype(np.float64)
        return (a >= ordered[lo]) & (a <= ordered[hi])


_NO_CROP = Crop()


class StampClock:
    """Host time of a scan's first ray from arrival time, frame length and age (module docstring).

    ``outliers`` counts the estimates left out for being more than tolerance_s below the others.
    """

    REFERENCE_RANK = 4  # the fifth smallest estimate is the reference for what is too low

    def __init__(self, link_rate_bps: float, window: int = 50, tolerance_s: float = 0.5):
        if link_rate_bps <= 0:
            raise ValueError(f"link rate must be positive, got {link_rate_bps}")
        self.byte_time_s = UART_BITS_PER_BYTE / link_rate_bps
        self.tolerance_s = tolerance_s
        self.outliers = 0
        self._offsets: collections.deque[float] = collections.deque(maxlen=window)

    def reset(self) -> None:
        self._offsets.clear()

    def stamp(self, t_read: float, tail_bytes: int, wire_len: int, age_us: int, device_time_us: int) -> float:
        first_ray = t_read - (tail_bytes + wire_len) * self.byte_time_s - age_us * 1e-6
        device_s = device_time_us * 1e-6
        estimate = first_ray - device_s
        self._offsets.append(estimate)
        ordered = sorted(self._offsets)
        floor = ordered[min(len(ordered) // 2, self.REFERENCE_RANK)] - self.tolerance_s
        if estimate < floor:
            self.outliers += 1
        return device_s + next(e for e in ordered if e >= floor)


def scan_from_message(msg: ScanMessage, info: Info, stamp: float) -> Scan:
    """Attach geometry from ``info`` to a decoded SCAN. Raises ValueError if the scan's columns
    are not inside info.angles."""
    n = msg.ranges_m.size
    if msg.first_index + n > info.angles.size or n == 0:
        raise ValueError(f"scan columns [{msg.first_index}, {msg.first_index + n}) not inside the "
                         f"{info.angles.size} angles of INFO")
    angles = info.angles[msg.first_index: msg.first_index + n]
    ray_times = None
    if msg.ray_times_us is not None:  # a ray without its own time is on the line
        line_us = msg.device_time_us + np.arange(n) * (msg.ray_interval_ns * 1e-3)
        ray_times = np.where(np.isnan(msg.ray_times_us), line_us, msg.ray_times_us) * 1e-6
    return Scan(msg.scan_seq, stamp, msg.device_time_us * 1e-6, angles, msg.ranges_m,
                msg.quality.astype(np.float32), msg.ray_interval_ns * 1e-9, 1.0 / info.scan_rate_hz,
                info.range_min_m, info.range_max_m, ray_times)
