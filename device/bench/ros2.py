"""`laserpi bench ros2`: the ROS 2 publisher's rate and latency, scan to subscriber.

The sensor is sim:// (the analytic wall behind the real link server, paced like a 921600-baud
UART) at full size and rate; `laserpi ros2`'s node publishes its scans; stand-in ROS 2
subscribers (host_sdk/ros2/subscriber.py, separate processes) take the samples. All DDS traffic
is on the loopback interface (host_sdk/ros2/cyclonedds-loopback.xml), on a domain of its own.

Variants in one run: the reliable writer (default) to a reliable and to a best-effort reader, and
the sensor-data writer (best effort) to a best-effort reader. Per variant:
  arrival->sub   the scan leaving LaserPi.scans() (it has arrived and is decoded) to the sample
                 being taken on the subscriber: crop, conversion, CDR, DDS, the other process
  ray->sub       the scan's first ray (its corrected stamp) to the subscriber: adds the device's
                 processing age and the UART transfer
  publish        time in publish_scan (crop, to_laserscan, the write) in the node
  rate           samples per second received, and samples lost
Both clocks are this machine's CLOCK_MONOTONIC, shared by the processes.
The first WARMUP scans of each variant are published but not counted: a reliable writer's first
write to a reliable reader that was there before the writer blocks once, for 0.1 to 1 s here
(Cyclone DDS at start-up; a reader that joins later causes no such stall).
"""

from __future__ import annotations

import argparse
import itertools
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from host_sdk.commands.argtypes import positive_int

ROOT = Path(__file__).resolve().parents[2]
WARMUP = 10


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--scans", type=positive_int, default=100, help="scans per variant (10 per second)")
    parser.add_argument("--points", type=positive_int, default=1640, help="points per scan")
    parser.add_argument("--json", action="store_true", help="machine-readable output")


def _percentiles(values_s: list[float]) -> dict:
    a = np.asarray(values_s) * 1e3
    return {"p50_ms": float(np.percentile(a, 50)), "p99_ms": float(np.percentile(a, 99)), "max_ms": float(a.max())}


def _variant(writer_qos: str, readers: list[tuple[str, int]], n_scans: int, points: int, domain: int) -> list[dict]:
    from rosbags.typesys import Stores, get_typestore

    import host_sdk
    from host_sdk.ros2 import conventions as c
    from host_sdk.ros2.dds import Ros2Publisher
    from host_sdk.ros2.node import ScanOptions, publish_scan
    from host_sdk.ros2.subscriber import read_samples

    typestore = get_typestore(Stores.ROS2_JAZZY)
    tmp = Path(tempfile.mkdtemp(prefix="laserpi-bench-ros2-"))
    subs = [(reliability, subprocess.Popen(
        [sys.executable, "-m", "host_sdk.ros2.subscriber", "--domain-id", str(domain), "--reliability", reliability,
         "--depth", str(depth), "--count", str(n_scans + WARMUP), "--seconds", str(n_scans / 10 + 30), "--out",
         str(tmp / f"{reliability}.bin")], cwd=ROOT, stdout=subprocess.PIPE, text=True))
        for reliability, depth in readers]
    publisher = Ros2Publisher(domain, "/scan", writer_qos)
    scans, publish_s = {}, []
    try:
        for _, proc in subs:
            if proc.stdout.readline().strip() != "matched":
                raise RuntimeError("a subscriber did not match")
        deadline = time.monotonic() + 10
        while publisher.subscriptions_matched() < len(subs) and time.monotonic() < deadline:
            time.sleep(0.01)
        with host_sdk.LaserPi(f"sim://wall?points={points}") as sensor:
            for i, scan in enumerate(itertools.islice(sensor.scans(), n_scans + WARMUP)):
                t_arrival = time.monotonic()
                stamp = publish_scan(publisher, scan, ScanOptions())
                if i >= WARMUP:
                    publish_s.append(time.monotonic() - t_arrival)
                    scans[stamp] = (t_arrival, scan.to_laserscan().stamp)
        for _, proc in subs:
            proc.wait(timeout=30)
    finally:
        publisher.close()
        for _, proc in subs:
            if proc.poll() is None:
                proc.kill()
    rows = []
    for reliability, _ in subs:
        samples = []
        for t_ns, raw in read_samples(str(tmp / f"{reliability}.bin")):
            header = typestore.deserialize_cdr(raw, c.LASERSCAN).header
            if (header.stamp.sec, header.stamp.nanosec) in scans:  # not a warm-up scan
                samples.append((t_ns, scans[(header.stamp.sec, header.stamp.nanosec)]))
        to_sub, ray_to_sub = [], []
        for t_ns, (t_arrival, first_ray) in samples:
            to_sub.append(t_ns * 1e-9 - t_arrival)
            ray_to_sub.append(t_ns * 1e-9 - first_ray)
        span = (samples[-1][0] - samples[0][0]) * 1e-9 if len(samples) > 1 else float("nan")
        rows.append({"writer": writer_qos, "reader": reliability, "received": len(samples), "published": len(scans),
                     "rate_hz": (len(samples) - 1) / span, "arrival_to_sub": _percentiles(to_sub),
                     "ray_to_sub": _percentiles(ray_to_sub), "publish": _percentiles(publish_s)})
    return rows


def run(args: argparse.Namespace) -> int:
    os.environ["CYCLONEDDS_URI"] = (ROOT / "host_sdk" / "ros2" / "cyclonedds-loopback.xml").as_uri()
    domain = 200 + os.getpid() % 30
    rows = (_variant("reliable", [("reliable", 10), ("best-effort", 5)], args.scans, args.points, domain)
            + _variant("sensor", [("best-effort", 5)], args.scans, args.points, domain))
    if args.json:
        print(json.dumps(rows, indent=1))
        return 0
    print(f"laserpi ros2: sim://wall, {args.points} points at 10 Hz, {args.scans} scans per variant; DDS on loopback; "
          f"machine: {os.uname().machine}, {os.cpu_count()} cores, load {os.getloadavg()[0]:.1f}")
    print(f"{'writer':<9} {'reader':<12} {'recv/pub':>9} {'rate Hz':>8}  {'arrival->sub p50/p99 ms':>24}  "
          f"{'ray->sub p50/p99 ms':>20}  {'publish p50/p99 ms':>19}")
    for r in rows:
        a, f, p = r["arrival_to_sub"], r["ray_to_sub"], r["publish"]
        print(f"{r['writer']:<9} {r['reader']:<12} {r['received']:>4}/{r['published']:<4} {r['rate_hz']:>8.2f}  "
              f"{a['p50_ms']:>11.2f} / {a['p99_ms']:<10.2f}  {f['p50_ms']:>8.2f} / {f['p99_ms']:<9.2f}  "
              f"{p['p50_ms']:>7.2f} / {p['p99_ms']:<9.2f}")
    return 0
