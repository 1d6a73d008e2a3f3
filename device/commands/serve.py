"""`laserpi serve`: the device process (or a simulated sensor) on the host link.

    laserpi serve --port /dev/ttyGS0 --gpio-edge gpiochip0:17         # on a Pi: camera, co-MCU, pipeline
    laserpi serve --simulate --scene wall --distance-m 2.0 --link /tmp/laserpi   # simulated sensor on a pty
    laserpi serve --simulate --mock --distance-m 2.0 --link /tmp/laserpi         # analytic mock, no images

``--simulate`` runs the whole sensor (device/scan/source.py) on simulated parts: the scene renderer
as the camera, the real co-MCU firmware in the simavr harness behind a pty, the image pipeline
(device/service/assembly.py, device/sim/). ``--mock`` serves the analytic wall of protocol/mock_wall.py
instead (the protocol's mock device: scans computed in closed form, no camera or co-MCU).
Either way the link is served by device.link.supervisor.LinkSupervisor: the port is opened again when it
fails, and the process stops cleanly on SIGTERM or SIGINT with the laser off and the --link
symlink removed.

Fault injection (``--simulate`` without ``--mock`` only, for tests): SIGUSR1 power-cycles the
simulated co-MCU (the emulator boots the firmware again), SIGUSR2 stalls the simulated camera
for 1 s of simulated time.
"""

from __future__ import annotations

import argparse
import logging
import math
import signal
import threading

from host_sdk.commands.argtypes import nonnegative_float, positive_float, positive_int

log = logging.getLogger(__name__)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from protocol.mock_wall import LASER_LIMIT_MW

    where = parser.add_mutually_exclusive_group(required=True)
    where.add_argument("--link", metavar="PATH", help="create a pseudo-terminal and symlink PATH to it")
    where.add_argument("--port", metavar="DEV", help="serve on this serial device (e.g. /dev/ttyAMA0, /dev/ttyGS0)")
    parser.add_argument("--baud", type=positive_int, default=921600,
                        help="baud rate of --port; with --link, writes are paced at this rate like a UART")
    parser.add_argument("--link-rate-bps", type=positive_float, default=None,
                        help="what the host link carries, bits/s (default: --baud, a UART at 8N1; a USB CDC port "
                             "carries more): settings whose scans need more are refused")
    parser.add_argument("--scan-rate-hz", type=positive_float, default=None,
                        help="scans/s (default: the configuration's [operating_point] scan_rate_hz; not with --mock)")
    parser.add_argument("--firmware", metavar="ELF", default=None,
                        help="with --simulate: the co-MCU firmware to run (default: firmware_pwm/build/laserpi_pwm.elf, "
                             "the production envelope; another rate needs its own build, see `laserpi design`)")
    parser.add_argument("--simulate", action="store_true",
                        help="simulated camera and scene, co-MCU firmware in the emulator, real pipeline")
    parser.add_argument("--mock", action="store_true", help="with --simulate: the analytic wall, no images")
    parser.add_argument("--scene", default="wall",
                        help="simulated scene: a built-in name, wall:distance=2,angle=30, or a TOML path")
    parser.add_argument("--distance-m", type=positive_float, default=2.0, help="distance of the 'wall' scene in metres")
    parser.add_argument("--config", metavar="TOML", help="sensor configuration file")
    parser.add_argument("--preset", default="thesis-calibrated", help="sensor configuration preset (without --config)")
    parser.add_argument("--points", type=positive_int, default=None,
                        help="points per scan (default: 1640 for --mock, the active image width otherwise)")
    parser.add_argument("--comcu", metavar="DEV", default="/dev/serial0",
                        help="serial device of the co-MCU (ignored with --simulate)")
    parser.add_argument("--gpio-edge", metavar="CHIP:LINE", default=None,
                        help="GPIO line of the laser trigger for edge-timestamp sync, e.g. gpiochip0:17 (default: the "
                             "configuration's [pi] gpio_edge; neither: sync by pings only, reported as degraded)")
    parser.add_argument("--fov-deg", type=positive_float, default=105.0, help="field of view in degrees (--mock)")
    parser.add_argument("--seed", type=int, default=0, help="noise seed of the simulation")
    parser.add_argument("--stats-file", metavar="JSON", help="write health and CPU time here every 2 s and at exit")
    parser.add_argument("--host-timeout-s", type=nonnegative_float, default=5.0,
                        help="stop scanning (laser off) when the host sent nothing for this long; 0 never "
                             "(a one-way cable, a host of protocol minor < 2 that streams silently)")
    parser.add_argument("--laser-limit-mw", type=positive_float, default=None,
                        help="Class 1 limit on laser power the device enforces (default and maximum: from the safety model "
                             f"for the sensor's laser and pulse; {LASER_LIMIT_MW:g} mW for --mock)")


def serve_source(source, config, *, link: str | None = None, port: str | None = None, baudrate: int = 921600,
                 on_health=None) -> int:
    """Serve ``source`` (a protocol.server.ScanSource) with ``config`` (a protocol.server.DeviceConfig)
    on a pty symlinked at ``link`` or on the serial device ``port`` until SIGTERM/SIGINT.
    The port is reopened when it fails (host unplugged). Returns 0 after a clean stop."""
    from protocol.ports import PacedPort, PtyLink
    from device.link.supervisor import LinkSupervisor

    stop = threading.Event()
    previous = {sig: signal.signal(sig, lambda *_: stop.set()) for sig in (signal.SIGTERM, signal.SIGINT)}
    try:
        if link is not None:
            with PtyLink(link) as pty:
                print(f"serving on {link} -> {pty.slave_name}", flush=True)
                LinkSupervisor(lambda: PacedPort(pty.port, baudrate), source, config, health_log_s=2.0 if on_health else 10.0,
                               on_health=on_health).run(stop)
        else:
            import serial

            def open_port():
                try:
                    return serial.Serial(port, baudrate, timeout=0.05, write_timeout=None, exclusive=True)
                except serial.SerialException as exc:
                    raise OSError(str(exc)) from exc

            print(f"serving on {port} at {baudrate} baud", flush=True)
            LinkSupervisor(open_port, source, config, on_health=on_health).run(stop)
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)
    return 0


def _stats_writer(path: str, hw):
    """on_health callback writing the health and the process's CPU time to ``path`` (JSON)."""
    import dataclasses
    import json
    import os
    import resource
    import time

    def write(health) -> None:
        ru = resource.getrusage(resource.RUSAGE_SELF)
        doc = {"monotonic_s": time.monotonic(), "cpu_process_s": ru.ru_utime + ru.ru_stime,
               "cpu_sim_hardware_s": hw.cpu_s if hw is not None else 0.0,
               "cpu_sim_gpio_s": hw.gpio_cpu_s if hw is not None else 0.0,
               "sim_lag_s": hw.lag_s if hw is not None else 0.0, "max_rss_kb": ru.ru_maxrss,
               **dataclasses.asdict(health)}
        tmp = f"{path}.tmp"
        with open(tmp, "w") as f:
            json.dump(doc, f)
        os.replace(tmp, path)

    return write


def _injector(name: str, fault):
    """Signal handler that injects a simulated fault from a thread (not inside the handler)."""

    def handler(*_):
        log.warning("fault injection: %s", name)
        threading.Thread(target=fault, name=f"inject-{name}", daemon=True).start()

    return handler


def _laser_limit(asked_mw: float | None, limit_mw: float, whose: str) -> float:
    """The laser power limit to enforce: ``limit_mw`` (``whose``), or --laser-limit-mw below it;
    ValueError if --laser-limit-mw is above it."""
    if asked_mw is None:
        return limit_mw
    from device.model.safety import mw_down

    if asked_mw > limit_mw:
        raise ValueError(f"--laser-limit-mw {asked_mw:g} is above {whose}, {mw_down(limit_mw * 1e-3):.2f} mW; "
                         "it can only lower the limit")
    return asked_mw


def run(args: argparse.Namespace) -> int:
    from protocol.server import DeviceConfig

    closers = []
    faults = {}
    hw = None
    try:
        if args.mock:
            # what is wrong with --mock's options, first found first
            refused = [why for wrong, why in ((not args.simulate, "--mock needs --simulate"),
                                              (args.scan_rate_hz is not None,
                                               "--mock runs at its own rate: --scan-rate-hz does not apply to it"),
                                              (args.firmware is not None,
                                               "--mock runs no firmware: --firmware does not apply to it")) if wrong]
            if refused:
                print(f"laserpi serve: {refused[0]}")
                return 2
            from protocol.mock_wall import LASER_LIMIT_MW, AnalyticWallSource, default_settings

            limit_mw = _laser_limit(args.laser_limit_mw, LASER_LIMIT_MW, "the mock device's Class 1 limit")
            n = args.points or 1640
            source = AnalyticWallSource(args.distance_m, n_points=n, fov_rad=math.radians(args.fov_deg), seed=args.seed)
            settings = default_settings(n, limit_mw)
        else:
            from device.service.assembly import AssemblyConfig, build_sensor

            if args.firmware is not None and not args.simulate:
                print("laserpi serve: --firmware needs --simulate (on a Pi the co-MCU runs the firmware flashed into it)")
                return 2

            built = build_sensor(AssemblyConfig(simulate=args.simulate, config_path=args.config, preset=args.preset,
                                                points=args.points, comcu=args.comcu, gpio_edge=args.gpio_edge,
                                                scene=args.scene, distance_m=args.distance_m, seed=args.seed,
                                                scan_rate_hz=args.scan_rate_hz, firmware=args.firmware))
            source, settings, closers, faults = built.source, built.settings, built.closers, built.faults
            hw = built.hardware
            limit_mw = _laser_limit(args.laser_limit_mw, built.laser_limit_mw,
                                    "the Class 1 limit the safety model gives for this laser and pulse")
        config = DeviceConfig(laser_limit_mw=limit_mw, settings=settings, host_timeout_s=args.host_timeout_s,
                              link_rate_bps=args.baud if args.link_rate_bps is None else args.link_rate_bps)
    except (ValueError, OSError, RuntimeError) as exc:
        for close in reversed(closers):
            close()
        print(f"laserpi serve: {exc}")
        return 2
    try:
        for sig, name in ((signal.SIGUSR1, "comcu-reset"), (signal.SIGUSR2, "camera-stall")):
            if name in faults:
                signal.signal(sig, _injector(name, faults[name]))
        on_health = _stats_writer(args.stats_file, hw) if args.stats_file else None
        return serve_source(source, config, link=args.link, port=args.port, baudrate=args.baud, on_health=on_health)
    finally:
        for close in reversed(closers):
            close()
