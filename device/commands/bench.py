"""`laserpi bench NAME`: benchmarks that compare variants in one run, speed next to error.

Each benchmark is a module with ``add_arguments(parser)`` and ``run(args)``; only the chosen
one is imported. Results are printed (``--json`` for machines) and recorded in BENCHMARKS.md
together with the command and the machine.
"""

from __future__ import annotations

import argparse
import importlib

BENCHMARKS: dict[str, tuple[str, str]] = {
    "model": ("device.bench.model", "backward projection variants: time per full pixel grid and error"),
    "pipeline": ("device.bench.pipeline", "image pipeline variants: ms per frame pair against error"),
    "sim": ("device.bench.sim", "scene renderer: ms per frame pair"),
    "protocol": ("device.bench.protocol", "scan encode/decode throughput and bytes per point"),
    "process": ("device.bench.process", "device process: CPU per scan of serve --simulate, Pi Zero 2 W headroom"),
    "ros2": ("device.bench.ros2", "laserpi ros2: rate and latency from scan arrival to a DDS subscriber, p50/p99"),
    "motion": ("device.bench.motion", "the sensor on a moving robot: phantoms, valid columns, CPU; reference against fast"),
}


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.epilog = "benchmarks: " + "; ".join(f"{n}: {h}" for n, (_, h) in BENCHMARKS.items())
    parser.add_argument("benchmark", choices=list(BENCHMARKS), help="which benchmark to run")
    parser.add_argument("options", nargs=argparse.REMAINDER, help="options of that benchmark (see NAME --help)")


def run(args: argparse.Namespace) -> int:
    module_name, help_ = BENCHMARKS[args.benchmark]
    module = importlib.import_module(module_name)
    parser = argparse.ArgumentParser(prog=f"laserpi bench {args.benchmark}", description=help_)
    module.add_arguments(parser)
    return int(module.run(parser.parse_args(args.options)) or 0)
