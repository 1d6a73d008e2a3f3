"""`laserpi scans --port P`: print one line per scan (Ctrl-C to stop)."""

from __future__ import annotations

import argparse

import numpy as np

from .argtypes import positive_int


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--port", required=True, help="device path or pyserial URL (e.g. sim://wall)")
    parser.add_argument("--baud", type=positive_int, default=921600)
    parser.add_argument("--count", type=positive_int, help="stop after this many scans (default: never)")


def scan_line(scan) -> str:
    """seq, stamp, points, valid/no-return/too-close/invalid counts, min and median range."""
    r = scan.ranges
    fin = np.isfinite(r)
    rng = f"min {r[fin].min():.3f} m median {np.median(r[fin]):.3f} m" if fin.any() else "no finite range"
    return (f"seq {scan.seq} stamp {scan.stamp:.6f} points {r.size} valid {int(fin.sum())} "
            f"+inf {int(np.isposinf(r).sum())} -inf {int(np.isneginf(r).sum())} nan {int(np.isnan(r).sum())} {rng}")


def run(args: argparse.Namespace) -> int:
    from host_sdk import LaserPi, LaserPiError

    try:
        with LaserPi(args.port, args.baud) as sensor:
            for i, scan in enumerate(sensor.scans(), 1):
                print(scan_line(scan), flush=True)
                if i == args.count:
                    break
            print(f"# {sensor.stats.as_dict()}")
    except LaserPiError as exc:
        print(f"laserpi scans: {exc}")
        return 1
    return 0
