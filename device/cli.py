"""The `laserpi` console script: one entry point, one module per subcommand.

Each subcommand lives in its own module that defines ``add_arguments(parser)`` and
``run(args) -> int``. Only the module of the subcommand being run is imported, so
``laserpi scans`` on a robot never imports OpenCV and ``laserpi --help`` imports no command module
but the table of benchmarks (device/commands/bench.py, the standard library only), which names
them in ``bench``'s help.
Command modules import their heavy dependencies inside ``run``.
An OSError out of a command (a file it was given that cannot be opened, read or written) ends it
with one line naming the file, exit code 2, as the commands' own refusals do; stdout's reader
going away (`laserpi scans ... | head`) ends it quietly.
"""

from __future__ import annotations

import argparse
import importlib
import logging
import os
import sys

from device.commands.bench import BENCHMARKS

# name -> (module, one-line help). Grouped by the package that owns the command.
COMMANDS: dict[str, tuple[str, str]] = {
    # sensor model and design tool (device/model, device/design)
    "design": ("device.commands.design", "range limits and resolution of a sensor design"),
    "safety": ("device.commands.safety", "IEC 60825-1 Class 1 check of a pulsed line laser"),
    "plane": ("device.commands.plane", "convert a laser plane to triangulation parameters and back"),
    # simulator, pipeline, calibration, synchronisation (device/)
    "simulate": ("device.commands.simulate", "render simulated frames with ground truth"),
    "evaluate": ("device.commands.evaluate", "run a pipeline on simulated frames against ground truth"),
    "calibrate": ("device.commands.calibrate", "calibrate camera and laser plane from checkerboard frames"),
    "sync-sim": ("device.commands.sync_sim", "simulate laser-camera synchronisation"),
    "serve": ("device.commands.serve", "run the device process (or the simulated sensor)"),
    "focus": ("device.commands.focus", "focus the lens on the laser line: live width and peak bars (over SSH)"),
    "doctor": ("device.commands.doctor", "check a Pi's camera, co-MCU, GPIO, UART and host link before serve"),
    "soak": ("device.commands.soak", "long run of the simulated sensor, watching memory and drops"),
    "demo": ("device.commands.demo", "the simulated sensor end to end, read by the host SDK"),
    "bench": ("device.commands.bench", "benchmarks: " + ", ".join(BENCHMARKS)),
    "fuzz-firmware": ("device.commands.fuzz_firmware", "co-MCU eye-safety envelope fuzzed in the emulator"),
    # host side (host_sdk/)
    "scans": ("host_sdk.commands.scans", "print one line per scan from a sensor"),
    "view": ("host_sdk.commands.view", "draw a scan to a PNG"),
    "record": ("host_sdk.commands.record", "record the raw wire bytes of a sensor"),
    "replay": ("host_sdk.commands.replay", "serve a recording again through a pty"),
    "export-bag": ("host_sdk.commands.export_bag", "write a recording as a ROS 2 bag of LaserScan"),
    "ros2": ("host_sdk.commands.ros2", "publish scans and diagnostics into a ROS 2 graph (DDS, no ROS needed)"),
}


def _top_parser() -> argparse.ArgumentParser:
    width = max(map(len, COMMANDS))
    lines = [f"  {name:<{width}} {help_}" for name, (_, help_) in COMMANDS.items()]
    return argparse.ArgumentParser(
        prog="laserpi",
        description="LaserPi line-laser distance sensor",
        formatter_class=argparse.RawDescriptionHelpFormatter,
        epilog="commands:\n" + "\n".join(lines) + "\n\nRun 'laserpi COMMAND --help' for a command's options.",
        usage="laserpi [-v] COMMAND [options]",
    )


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    top = _top_parser()
    top.add_argument("-v", "--verbose", action="count", default=0, help="more log output (-vv for debug)")
    top.add_argument("command", nargs="?", help=argparse.SUPPRESS)
    # Split the global options from the command and its own options.
    split = next((i for i, a in enumerate(argv) if not a.startswith("-")), len(argv))
    glob = top.parse_args(argv[: split + 1])
    if glob.command is None:
        top.print_help()
        return 2
    if glob.command not in COMMANDS:
        top.error(f"unknown command {glob.command!r}; choose from: {', '.join(COMMANDS)}")
    module_name, help_ = COMMANDS[glob.command]
    logging.basicConfig(
        level=[logging.WARNING, logging.INFO, logging.DEBUG][min(glob.verbose, 2)],
        format="%(asctime)s %(levelname)s %(name)s: %(message)s",
    )
    module = importlib.import_module(module_name)
    parser = argparse.ArgumentParser(prog=f"laserpi {glob.command}", description=help_)
    module.add_arguments(parser)
    args = parser.parse_args(argv[split + 1 :])
    try:
        return int(module.run(args) or 0)
    except KeyboardInterrupt:
        return 130
    except BrokenPipeError:  # the reader of stdout went away (`laserpi scans ... | head`): nothing to say to it
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())  # Python docs, "Note on SIGPIPE"
        return 141
    except OSError as exc:  # a file the command was given cannot be opened, read or written
        reason = f"{exc.filename}: {exc.strerror}" if exc.filename else str(exc)
        print(f"laserpi {glob.command}: {reason}")
        return 2


if __name__ == "__main__":
    sys.exit(main())
