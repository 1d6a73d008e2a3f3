"""`laserpi doctor`: every check a person needs before `laserpi serve` on a Pi, each with ok or
FAIL and what to do (device/service/doctor.py). Exit status 1 if any check fails.

    laserpi doctor                      # a table
    laserpi doctor --json               # [{"name", "ok", "detail"}, ...]
    laserpi doctor --config my.toml --gpio-edge gpiochip0:17 --comcu /dev/ttyAMA0 --port /dev/ttyGS0
"""

from __future__ import annotations

import argparse


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--json", action="store_true", help="print the results as JSON")
    parser.add_argument("--config", metavar="TOML", help="sensor configuration file (as for serve)")
    parser.add_argument("--preset", default="thesis-calibrated", help="sensor configuration preset (without --config)")
    parser.add_argument("--comcu", metavar="DEV", default="/dev/serial0", help="serial device of the co-MCU (as for serve)")
    parser.add_argument("--port", metavar="DEV", default="/dev/ttyGS0", help="the host link's serial device (as for serve)")
    parser.add_argument("--gpio-edge", metavar="CHIP:LINE", default=None,
                        help="GPIO line of the laser trigger (default: the configuration's [pi] gpio_edge)")


def run(args: argparse.Namespace) -> int:
    import dataclasses
    import json

    from device.config import ConfigError
    from device.service.assembly import sensor_config
    from device.service.doctor import DoctorSetup, run_checks

    try:
        cfg = sensor_config(args.config, args.preset)
    except (ConfigError, OSError, ValueError) as exc:
        print(f"laserpi doctor: {exc}")
        return 2
    results = run_checks(DoctorSetup(cfg, comcu=args.comcu, port=args.port, gpio_edge=args.gpio_edge))
    if args.json:
        print(json.dumps([dataclasses.asdict(r) for r in results], indent=1))
    else:
        width = max(len(r.name) for r in results)
        for r in results:
            print(f"{'ok  ' if r.ok else 'FAIL'}  {r.name:<{width}}  {r.detail}")
        failed = sum(not r.ok for r in results)
        print(f"\n{len(results) - failed} of {len(results)} checks ok" + (f"; fix the {failed} failing before `laserpi serve`" if failed else ""))
    return 0 if all(r.ok for r in results) else 1
