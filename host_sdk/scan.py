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
A frame that had to wait in the device's UART buffer behind the previous one gives a late
estimate, which the minimum also ignores as long as the link is not saturated (54 % at
921600 baud and full rate, protocol/SPEC.md).
Clock drift between device and host over the window (5 s at 10 Hz) is < 0.3 ms for 50 ppm
crystals. For a USB CDC link the baud rate is nominal: pass the real throughput as
``link_rate_bps`` to LaserPi.
"""

from __future__ import annotations

import collections
from dataclasses import dataclass

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
    time_increment: s between consecutive rays; scan_time: s between scans.
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

    def points(self) -> np.ndarray:
        """(n, 2) x, y in metres in the sensor frame; rows of non-finite ranges are NaN."""
        r = np.where(np.isfinite(self.ranges), self.ranges, np.nan)
        return np.stack([r * np.cos(self.angles), r * np.sin(self.angles)], axis=1)

    def to_laserscan(self, frame_id: str = "laser", stamp: float | None = None) -> LaserScan:
        """The scan as sensor_msgs/LaserScan fields, with increasing, equally spaced angles.

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
        stamp = self.stamp if stamp is None else stamp
        time_inc = self.time_increment
        if n > 1 and order[0] != 0:  # the device's first ray is now last: stamp the new first one
            stamp += (n - 1) * time_inc
            time_inc = -time_inc
        return LaserScan(stamp, frame_id, float(grid[0]), float(grid[-1]), float(inc), float(time_inc),
                         self.scan_time, self.range_min, self.range_max, ranges.astype(np.float32),
                         inten.astype(np.float32))


class StampClock:
    """Host time of a scan's first ray from arrival time, frame length and age (module docstring)."""

    def __init__(self, link_rate_bps: float, window: int = 50):
        if link_rate_bps <= 0:
            raise ValueError(f"link rate must be positive, got {link_rate_bps}")
        self.byte_time_s = UART_BITS_PER_BYTE / link_rate_bps
        self._offsets: collections.deque[float] = collections.deque(maxlen=window)
        self._last_device_us: int | None = None

    def reset(self) -> None:
        self._offsets.clear()
        self._last_device_us = None

    def stamp(self, t_read: float, tail_bytes: int, wire_len: int, age_us: int, device_time_us: int) -> float:
        if self._last_device_us is not None and device_time_us < self._last_device_us:
            self._offsets.clear()  # the device clock restarted (device rebooted)
        self._last_device_us = device_time_us
        first_ray = t_read - (tail_bytes + wire_len) * self.byte_time_s - age_us * 1e-6
        device_s = device_time_us * 1e-6
        self._offsets.append(first_ray - device_s)
        return device_s + min(self._offsets)


def scan_from_message(msg: ScanMessage, info: Info, stamp: float) -> Scan:
    """Attach geometry from ``info`` to a decoded SCAN. Raises ValueError if the scan's columns
    are not inside info.angles."""
    n = msg.ranges_m.size
    if msg.first_index + n > info.angles.size or n == 0:
        raise ValueError(f"scan columns [{msg.first_index}, {msg.first_index + n}) not inside the "
                         f"{info.angles.size} angles of INFO")
    angles = info.angles[msg.first_index: msg.first_index + n]
    return Scan(msg.scan_seq, stamp, msg.device_time_us * 1e-6, angles, msg.ranges_m,
                msg.quality.astype(np.float32), msg.ray_interval_ns * 1e-9, 1.0 / info.scan_rate_hz,
                info.range_min_m, info.range_max_m)
