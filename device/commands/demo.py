"""`laserpi demo` (= `make demo`): the simulated sensor end to end, read by the host SDK.

Starts ``laserpi serve --simulate`` behind a pty, reads it with ``host_sdk.LaserPi`` like a robot
would, prints a line per scan (rate, valid points, range error against the scene's truth) with a
progress bar, and writes a top view of the scene with the true surfaces and the measured points.

The truth does not come from the device: the demo builds the same scene description the
simulator renders (device.sim.scene) and intersects each scan ray with it itself
(device/sim/scene_truth.py).
"""

from __future__ import annotations

import argparse
import math
import tempfile
import time
from pathlib import Path

from host_sdk.commands.argtypes import positive_float


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--seconds", type=positive_float, default=8.0, help="how long to run (default 8 s)")
    parser.add_argument("--run-on", action="store_true", help="run until Ctrl-C")
    parser.add_argument("--scene", default="wall", help="scene name (see laserpi simulate) or wall:distance=...")
    parser.add_argument("--distance-m", type=positive_float, default=2.0, help="distance of the 'wall' scene")
    parser.add_argument("--mock", action="store_true", help="serve the analytic mock instead of the full simulation")
    parser.add_argument("--png", default="out/demo.png", help="where to write the top view")
    parser.add_argument("--log", default="out/demo-serve.log", help="where the device process logs")


def _bar(fraction: float, width: int = 20) -> str:
    done = int(round(max(0.0, min(1.0, fraction)) * width))
    return "[" + "#" * done + "." * (width - done) + "]"


def scan_errors(ranges, truth):
    """(valid count, compared count, mean and std of the relative range error) of one scan.

    Compared: points the device measured (finite) where the truth has a surface (finite)."""
    import numpy as np

    r = np.asarray(ranges, dtype=np.float64)
    t = np.asarray(truth, dtype=np.float64)
    valid = np.isfinite(r)
    both = valid & np.isfinite(t)
    if not both.any():
        return int(valid.sum()), 0, math.nan, math.nan
    rel = (r[both] - t[both]) / t[both]
    return int(valid.sum()), int(both.sum()), float(rel.mean()), float(rel.std())


def run(args: argparse.Namespace) -> int:
    import numpy as np

    import host_sdk
    from device.sim.scene import SceneError
    from device.sim.scene_truth import scene_truth
    from device.service.child import start_serve, stop_serve

    try:
        truth_scene = scene_truth(args.scene, args.distance_m)
    except SceneError as exc:
        print(f"laserpi demo: {exc}")
        return 2
    serve_args = ["--simulate", "--scene", args.scene, "--distance-m", str(args.distance_m)]
    if args.mock:
        serve_args.append("--mock")
    Path(args.log).parent.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(prefix="laserpi-demo-") as tmp:
        link = Path(tmp) / "laserpi"
        print(f"starting the simulated sensor: laserpi serve {' '.join(serve_args)} --link {link}  (log: {args.log})",
              flush=True)
        try:
            proc = start_serve(link, serve_args, log_path=Path(args.log))
        except RuntimeError as exc:
            print(f"laserpi demo: {exc}")
            return 1
        arrivals: list[float] = []
        errs: list[tuple[float, float]] = []
        last = None
        try:
            with host_sdk.LaserPi(str(link), timeout_s=5.0) as sensor:
                info = sensor.info()
                print(f"connected: {info.serial_number}, software {info.software_version}, "
                      f"{info.angles.size} points per scan at {info.scan_rate_hz:g} Hz", flush=True)
                t0 = time.monotonic()
                for scan in sensor.scans():
                    now = time.monotonic()
                    arrivals.append(now)
                    recent = [t for t in arrivals if t > now - 1.0]
                    rate = (len(recent) - 1) / (recent[-1] - recent[0]) if len(recent) > 1 else 0.0
                    valid, compared, mean, std = scan_errors(scan.ranges, truth_scene.ranges(scan.angles))
                    if compared:
                        errs.append((mean, std))
                    elapsed = now - t0
                    bar = "" if args.run_on else _bar(elapsed / args.seconds) + " "
                    print(f"{bar}scan {scan.seq:5d}  {rate:5.1f} scans/s  {valid:4d}/{scan.ranges.size} valid  "
                          f"range error {100 * mean:+6.2f} % mean, {100 * std:5.2f} % 1-sigma", flush=True)
                    last = scan
                    if not args.run_on and elapsed >= args.seconds:
                        break
                health = sensor.health()
        except KeyboardInterrupt:
            health = None
        finally:
            code = stop_serve(proc)
    if last is None:
        print("no scans received")
        return 1
    span = arrivals[-1] - arrivals[0] if len(arrivals) > 1 else math.nan
    rate = (len(arrivals) - 1) / span if span else math.nan
    mean_err = float(np.mean([e[0] for e in errs])) if errs else math.nan
    std_err = float(np.mean([e[1] for e in errs])) if errs else math.nan
    print(f"\n{len(arrivals)} scans, {rate:.2f} scans/s; range error {100 * mean_err:+.2f} % mean, "
          f"{100 * std_err:.2f} % 1-sigma against the scene's truth")
    if health is not None:
        print(f"device health: {health.state.name}, laser {'on' if health.laser_on else 'off'}, "
              f"sync {'locked' if health.sync_locked else 'not locked'}, errors {list(health.errors)}, "
              f"scans sent {health.scans_sent}, dropped {health.scans_dropped}, frames dropped {health.frames_dropped}")
        if health.camera_restarts is not None:  # protocol minor >= 1
            print(f"  camera restarts {health.camera_restarts}, co-MCU resets {health.comcu_resets}, "
                  f"co-MCU lost {health.comcu_lost}, pipeline errors {health.pipeline_errors}, "
                  f"host bytes discarded {health.host_bytes_discarded}")
    print(f"device process exit code {code}")
    _draw(truth_scene, last, args.png)
    print(f"top view written to {args.png}")
    return 0


def _draw(truth_scene, scan, png: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    fig, ax = plt.subplots(figsize=(7, 6))
    truth_scene.draw(ax)
    pts = scan.points()
    ok = np.isfinite(pts).all(axis=1)
    ax.plot(pts[ok, 1], pts[ok, 0], ".", ms=2, color="tab:red", label=f"measured ({ok.sum()} points)")
    a = np.asarray(scan.angles)
    reach = 1.2 * float(np.nanmax(np.where(ok, np.hypot(pts[:, 0], pts[:, 1]), np.nan))) if ok.any() else 3.0
    for edge in (a.min(), a.max()):
        ax.plot([0, reach * math.sin(edge)], [0, reach * math.cos(edge)], ":", color="grey", lw=0.8)
    ax.plot([0], [0], "k^", ms=8, label="sensor")
    ax.set_xlabel("y (m, left positive)")
    ax.set_ylabel("x (m, forward)")
    # the field of view and the measured range, not the whole scene; y to the left (REP 103)
    half = reach * max(abs(math.sin(a.min())), abs(math.sin(a.max())), 0.3) + 0.2
    ax.set_xlim(half, -half)
    ax.set_ylim(-0.3, reach + 0.2)
    ax.set_aspect("equal")
    ax.legend(loc="lower right", fontsize=8)
    ax.set_title("LaserPi simulated: scene from above, true surfaces and one measured scan")
    Path(png).parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(png, dpi=120, bbox_inches="tight")
    plt.close(fig)
