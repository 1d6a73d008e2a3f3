"""The ROS 2 node without ROS: scans in, LaserScan and DiagnosticArray samples out.

``run_node`` publishes every scan a scan iterator yields until it ends, and DiagnosticsThread,
on a thread, the diagnostics a callable returns. It knows the sensor only through
those two (a Scan iterator and a callable returning (name, level, message, {key: value})
tuples, the shape of diagnostic_msgs/DiagnosticStatus), so tests feed it fakes.

Per scan (conventions.py cites the ROS 2 rules):
- the host-side crop (host_sdk/crop.py) with urg_node's conventions, then Scan.to_laserscan;
- header.stamp: the LaserScan's stamp (the SDK's corrected time of its first ray, host
  CLOCK_MONOTONIC) moved onto CLOCK_REALTIME, the clock ROS time runs on, with the difference of
  the two clocks sampled as the scan is published; time_increment and scan_time as the SDK gives.
"""

from __future__ import annotations

import logging
import math
import threading
import time
from dataclasses import dataclass
from typing import Callable, Iterable

from host_sdk.errors import LaserPiError
from host_sdk.ros2.conventions import DIAGNOSTIC_LEVELS, ros_time
from host_sdk.scan import Scan

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class ScanOptions:
    """What becomes of each scan: frame and the crop (rad, m; the defaults keep everything)."""

    frame_id: str = "laser"
    angle_min: float = -math.inf
    angle_max: float = math.inf
    range_min: float = 0.0
    range_max: float = math.inf


def realtime_minus_monotonic_ns() -> int:
    return time.time_ns() - time.monotonic_ns()


def publish_scan(publisher, scan: Scan, options: ScanOptions) -> tuple[int, int]:
    """Crop, convert and publish one scan; returns the header stamp (sec, nanosec)."""
    cropped = scan.cropped(angle_min=options.angle_min, angle_max=options.angle_max, range_min=options.range_min,
                           range_max=options.range_max)
    ls = cropped.to_laserscan(options.frame_id)
    stamp = ros_time(ls.stamp, realtime_minus_monotonic_ns())
    publisher.publish_scan(ls, stamp)
    return stamp


class DiagnosticsThread:
    """Publishes ``diagnostics()`` every 1/hz s; a LaserPiError becomes one ERROR status."""

    def __init__(self, publisher, diagnostics: Callable[[], list], hardware_id: str, hz: float):
        if not hz > 0:
            raise ValueError(f"diagnostics rate must be positive, got {hz} Hz")
        self._publisher, self._diagnostics, self._hardware_id = publisher, diagnostics, hardware_id
        self._period = 1.0 / hz
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="laserpi-ros2-diagnostics", daemon=True)

    def start(self) -> DiagnosticsThread:
        self._thread.start()
        return self

    def stop(self) -> None:
        self._stop.set()
        self._thread.join(timeout=5.0)

    def _run(self) -> None:
        while True:
            try:
                statuses = self._diagnostics()
            except LaserPiError as exc:
                statuses = [("device", DIAGNOSTIC_LEVELS["ERROR"], f"no answer: {exc}", {})]
            self._publisher.publish_diagnostics(statuses, ros_time(time.monotonic(), realtime_minus_monotonic_ns()),
                                                self._hardware_id)
            if self._stop.wait(self._period):
                return


def run_node(publisher, scans: Iterable[Scan], options: ScanOptions,
             on_published: Callable[[Scan, tuple[int, int]], None] | None = None) -> int:
    """Publish every scan until ``scans`` ends; returns how many."""
    n = 0
    for scan in scans:
        stamp = publish_scan(publisher, scan, options)
        n += 1
        if on_published is not None:
            on_published(scan, stamp)
    return n
