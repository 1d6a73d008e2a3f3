"""`laserpi serve`: run the device end of the host link.

    laserpi serve --simulate --scene wall --distance-m 2.0 --link /tmp/laserpi   # pty, symlinked
    laserpi serve --simulate --port /dev/ttyAMA0 --baud 921600                   # a real UART

Today the only source is the analytic wall (--simulate); the device-process issue plugs the
image pipeline or the full simulated sensor in through ``serve_source`` (a ScanSource, see
device/link.py). Stops cleanly on SIGTERM or SIGINT and removes the --link symlink.
"""

from __future__ import annotations

import argparse
import logging
import math
import signal
import threading

log = logging.getLogger(__name__)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    where = parser.add_mutually_exclusive_group(required=True)
    where.add_argument("--link", metavar="PATH", help="create a pseudo-terminal and symlink PATH to it")
    where.add_argument("--port", metavar="DEV", help="serve on this serial device (e.g. /dev/ttyAMA0)")
    parser.add_argument("--baud", type=int, default=921600,
                        help="baud rate of --port; with --link, writes are paced at this rate like a UART")
    parser.add_argument("--simulate", action="store_true", help="serve an analytic scene instead of the camera")
    parser.add_argument("--scene", choices=["wall"], default="wall", help="analytic scene (with --simulate)")
    parser.add_argument("--distance-m", type=float, default=2.0, help="wall distance in metres")
    parser.add_argument("--points", type=int, default=1640, help="columns per scan")
    parser.add_argument("--fov-deg", type=float, default=105.0, help="field of view in degrees")
    parser.add_argument("--seed", type=int, default=0, help="noise seed")
    parser.add_argument("--laser-limit-mw", type=float, default=5.0,
                        help="Class 1 limit on laser power the device enforces (until the IEC model sets it)")


def serve_source(source, config, *, link: str | None = None, port: str | None = None, baudrate: int = 921600) -> int:
    """Serve ``source`` (a device.link.ScanSource) with ``config`` (a device.link.DeviceConfig)
    on a pty symlinked at ``link`` or on the serial device ``port`` until SIGTERM/SIGINT.
    Returns 0 after a clean stop, 1 if the port failed."""
    from device.link import LinkServer
    from device.ports import PacedPort, PtyLink

    stop = threading.Event()
    previous = {sig: signal.signal(sig, lambda *_: stop.set()) for sig in (signal.SIGTERM, signal.SIGINT)}
    try:
        if link is not None:
            with PtyLink(link) as pty:
                print(f"serving on {link} -> {pty.slave_name}", flush=True)
                server = LinkServer(PacedPort(pty.port, baudrate), source, config)
                server.serve(stop)
        else:
            import serial

            with serial.Serial(port, baudrate, timeout=0.05, write_timeout=None, exclusive=True) as ser:
                print(f"serving on {port} at {baudrate} baud", flush=True)
                server = LinkServer(ser, source, config)
                server.serve(stop)
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)
    if not stop.is_set():
        log.error("the port failed; stopped")
        return 1
    return 0


def run(args: argparse.Namespace) -> int:
    if not args.simulate:
        print("laserpi serve: the camera pipeline is not wired in yet; use --simulate")
        return 2
    from device.analytic_source import AnalyticWallSource, default_settings
    from device.link import DeviceConfig

    try:
        source = AnalyticWallSource(args.distance_m, n_points=args.points, fov_rad=math.radians(args.fov_deg),
                                    seed=args.seed)
        config = DeviceConfig(laser_limit_mw=args.laser_limit_mw, settings=default_settings(args.points, min(4.0, args.laser_limit_mw)))
    except ValueError as exc:
        print(f"laserpi serve: {exc}")
        return 2
    return serve_source(source, config, link=args.link, port=args.port, baudrate=args.baud)
