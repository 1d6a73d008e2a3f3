"""`laserpi view --port P --png OUT`: draw one scan, top view, to a PNG (matplotlib)."""

from __future__ import annotations

import argparse

from .argtypes import positive_int


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--port", required=True, help="device path or pyserial URL (e.g. sim://wall)")
    parser.add_argument("--baud", type=positive_int, default=921600)
    parser.add_argument("--png", required=True, help="output image")


def draw(scan, path: str) -> None:
    """Top view in the sensor frame (REP 103: x forward, y left) with the field of view."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    xy = scan.points()
    fig, ax = plt.subplots(figsize=(6, 6))
    ax.scatter(-xy[:, 1], xy[:, 0], s=2, c=scan.intensities, cmap="viridis")  # y left drawn to the left
    for a in (scan.angles.min(), scan.angles.max()):
        ax.plot([0, -scan.range_max * np.sin(a)], [0, scan.range_max * np.cos(a)], "k:", lw=0.8)
    ax.plot(0, 0, "r^")
    ax.set_aspect("equal")
    ax.set_xlabel("-y (m, right)")
    ax.set_ylabel("x (m, forward)")
    fin = np.isfinite(scan.ranges)
    ax.set_title(f"scan {scan.seq}: {int(fin.sum())}/{scan.ranges.size} finite")
    fig.savefig(path, dpi=100)
    plt.close(fig)


def run(args: argparse.Namespace) -> int:
    from host_sdk import LaserPi, LaserPiError

    try:
        import matplotlib  # noqa: F401
    except ImportError:
        print("laserpi view needs matplotlib: pip install 'laserpi[plots]'")
        return 2

    try:
        with LaserPi(args.port, args.baud) as sensor:
            scan = next(iter(sensor.scans()))
    except LaserPiError as exc:
        print(f"laserpi view: {exc}")
        return 1
    draw(scan, args.png)
    print(f"wrote {args.png}")
    return 0
