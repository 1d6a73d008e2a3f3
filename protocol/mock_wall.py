"""Analytic scan source for the mock device: a flat wall in front of the sensor.

No images: each ray's range is computed in closed form, then a simulated noise model is applied.
This is the scene behind ``sim://wall`` (host_sdk/protocol_sim.py) and ``laserpi serve --simulate
--mock``; it is here, with the link server, so that the host SDK's mock device needs nothing of the
device's code. The whole simulated sensor (``laserpi serve --simulate``: device/sim, the pipeline)
serves scans behind the same ScanSource interface.

Scene: an infinite wall perpendicular to +x at ``distance_m`` (REP 103: x forward, y left).
A ray at bearing θ (counter-clockwise from +x) hits it at r = d / cos θ.

Noise model (SIMULATED, chosen to look like triangulation, not fitted to the thesis): Gaussian
with σ(r) = noise_floor_m + noise_rel_m⁻¹ · r², because triangulation error grows with the
square of the range; a fraction ``dropout`` of rays is invalid (NaN). Ranges beyond range_max
are +inf (no return), below range_min -inf (too close), as REP 117 says. Quality falls with
1/r² like the returned laser power: round(255 · min(1, (0.5 m / r)²)) of the ray's own noisy
range, 0 where it is not finite; the host's min_quality and median filter then apply to the
ranges (protocol/median.py ``scan_filters``, as on the device), so a filtered range keeps the
quality of the ray's own return.
``start_delay_s`` holds back the first scan after start() like a real sensor starting its camera
and locking its laser (SIMULATED time, not measured on a Pi).
"""

from __future__ import annotations

import math
import threading
import time

import numpy as np

from protocol.median import scan_filters
from protocol.messages import ScanSettings
from protocol.server import ScanGeometry, SourceScan, SourceStatus, device_clock_us

#: The thesis prototype's field of view (abstract: 105 degrees over the 1640 columns of mode 5).
DEFAULT_FOV_RAD = math.radians(105.0)
#: The mock device's Class 1 limit on laser power, mW (it has no laser: the limit it reports and
#: enforces; ``laserpi serve --mock --laser-limit-mw`` can only lower it).
LASER_LIMIT_MW = 5.0
#: The mock device's laser power at power-on, mW (below its limit).
POWER_ON_MW = 4.0


def column_angles(n_points: int, fov_rad: float) -> np.ndarray:
    """Bearings of n equally spaced columns: column 0 at the image's left = +fov/2 (CCW)."""
    if n_points < 1 or not 0 < fov_rad < math.pi:
        raise ValueError(f"need n_points >= 1 and 0 < fov < pi, got {n_points}, {fov_rad}")
    return np.linspace(fov_rad / 2, -fov_rad / 2, n_points, dtype=np.float32)


def wall_ranges(angles: np.ndarray, distance_m: float) -> np.ndarray:
    """Exact range (m) of each ray to a wall perpendicular to +x at distance_m; +inf if the ray
    does not hit it (|θ| >= 90°)."""
    if not distance_m > 0:
        raise ValueError(f"wall distance must be positive, got {distance_m}")
    c = np.cos(np.asarray(angles, dtype=np.float64))
    with np.errstate(divide="ignore"):
        return np.where(c > 1e-9, distance_m / np.where(c > 1e-9, c, 1.0), np.inf)


def quality_of(ranges_m: np.ndarray) -> np.ndarray:
    """uint8 quality from range (see module docstring)."""
    r = np.asarray(ranges_m, dtype=np.float64)
    q = np.zeros(r.shape, dtype=np.uint8)
    ok = np.isfinite(r) & (r > 0)
    q[ok] = np.rint(255 * np.minimum(1.0, (0.5 / r[ok]) ** 2))
    return q


class AnalyticWallSource:
    """ScanSource (protocol/server.py) of a wall at ``distance_m``, paced at the configured rate."""

    def __init__(self, distance_m: float = 2.0, *, n_points: int = 1640, fov_rad: float = DEFAULT_FOV_RAD,
                 range_min_m: float = 0.1, range_max_m: float = 3.0, noise_floor_m: float = 0.001,
                 noise_rel_per_m: float = 0.0025, dropout: float = 0.01, seed: int | None = 0,
                 start_delay_s: float = 0.0):
        self.distance_m = float(distance_m)
        wall_ranges(np.zeros(1), self.distance_m)  # validates
        self._geometry = ScanGeometry(column_angles(n_points, fov_rad), range_min_m, range_max_m)
        self.noise_floor_m = noise_floor_m
        self.noise_rel_per_m = noise_rel_per_m
        self.dropout = dropout
        self.start_delay_s = start_delay_s
        self._rng = np.random.default_rng(seed)
        self._truth = wall_ranges(self._geometry.angles, self.distance_m)
        self._settings: ScanSettings | None = None
        self._running = False
        self._next_due_s = 0.0
        self._frames_dropped = 0
        self._lock = threading.Lock()

    def geometry(self) -> ScanGeometry:
        return self._geometry

    def apply(self, settings: ScanSettings) -> None:
        with self._lock:
            self._settings = settings

    def start(self) -> None:
        with self._lock:
            self._running = True
            self._next_due_s = time.monotonic() + self.start_delay_s

    def stop(self) -> None:
        with self._lock:
            self._running = False

    def status(self) -> SourceStatus:
        return SourceStatus(laser_on=self._running, sync_locked=self._running, frames_dropped=self._frames_dropped)

    def next_scan(self, timeout_s: float) -> SourceScan | None:
        with self._lock:
            if not self._running:
                return None
            s = self._settings
            period = 1.0 / s.scan_rate_hz
            due = self._next_due_s
        wait = due - time.monotonic()
        if wait > timeout_s:
            time.sleep(timeout_s)
            return None
        if wait > 0:
            time.sleep(wait)
        now = time.monotonic()
        missed = int((now - due) // period)  # late by whole periods: those frames never happened
        self._frames_dropped += missed
        with self._lock:
            self._next_due_s = due + (missed + 1) * period
        return self.scan_now(device_clock_us())

    def scan_now(self, device_time_us: int) -> SourceScan:
        """One noisy scan of the wall under the current settings, stamped device_time_us."""
        s = self._settings
        sl = slice(s.roi_first, s.roi_first + s.roi_count)
        truth = self._truth[sl]
        sigma = self.noise_floor_m + self.noise_rel_per_m * np.where(np.isfinite(truth), truth, 0.0) ** 2
        r = truth + self._rng.normal(0.0, 1.0, truth.size) * sigma
        g = self._geometry
        r = np.where(r > g.range_max_m, np.inf, np.where(r < g.range_min_m, -np.inf, r))
        r[self._rng.random(truth.size) < self.dropout] = np.nan
        q = quality_of(r)
        r = scan_filters(r, q, s.min_quality, s.median_window)
        # a wall seen squarely lies in one row of the image: every ray measured at device_time_us
        times = np.where(np.isfinite(r), device_time_us * 1000.0, np.nan)
        return SourceScan(device_time_us, r.astype(np.float32), q, first_index=s.roi_first, ray_times_ns=times)


def default_settings(n_points: int, limit_mw: float = LASER_LIMIT_MW) -> ScanSettings:
    """Power-on settings of the simulated device: 10 Hz, all columns, no filters, no ray times, and
    POWER_ON_MW of laser power, or ``limit_mw`` (the limit it enforces) where that is lower."""
    return ScanSettings(scan_rate_hz=10.0, exposure_us=2000, roi_first=0, roi_count=n_points,
                        median_window=1, min_quality=0, laser_power_mw=min(POWER_ON_MW, limit_mw), ray_times=False)
