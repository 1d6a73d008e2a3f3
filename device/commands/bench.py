"""`laserpi bench NAME`: benchmarks that compare variants in one run, speed next to error.

Each benchmark is a module with ``add_arguments(parser)`` and ``run(args)``; results are
printed (``--json`` for machines) and recorded by hand in BENCHMARKS.md with the command.
"""

from __future__ import annotations

import argparse
import importlib

BENCHMARKS: dict[str, tuple[str, str]] = {
    "model": ("device.bench.model", "backward projection variants: time per full pixel grid and error"),
    "pipeline": ("device.bench.pipeline", "image pipeline variants: ms per frame pair against error"),
    "sim": ("device.bench.sim", "scene renderer: ms per frame pair"),
    "protocol": ("protocol.bench", "scan encode/decode throughput and bytes per point"),
}


def add_arguments(parser: argparse.ArgumentParser) -> None:
    sub = parser.add_subparsers(dest="benchmark", required=True, metavar="BENCHMARK")
    for name, (module_name, help_) in BENCHMARKS.items():
        p = sub.add_parser(name, help=help_, description=help_)
        p.set_defaults(_bench_module=module_name)
        # Imported only to declare options; benchmark modules keep heavy imports inside run().
        # A benchmark whose module is not there (yet) must not stop the others from running.
        try:
            module = importlib.import_module(module_name)
        except ModuleNotFoundError as exc:
            if exc.name != module_name:
                raise
            p.set_defaults(_bench_missing=module_name)
            continue
        module.add_arguments(p)


def run(args: argparse.Namespace) -> int:
    if getattr(args, "_bench_missing", None):
        print(f"laserpi bench {args.benchmark}: {args._bench_missing} is not in this build")
        return 2
    return int(importlib.import_module(args._bench_module).run(args) or 0)
