"""`laserpi fuzz-firmware`: the co-MCU's eye-safety envelope under random command sequences in
the emulator, judged on the true laser pin (device/sim/firmware_fuzz.py: the rules, what a sequence
is, the paths counted).

    laserpi fuzz-firmware --sequences 100000 --jobs 2 --seed 1 --json

Builds the production firmware and the simavr harness first (make -C firmware_pwm all harness)
unless --elf names another build.  Exit status 1 if the pin broke any rule.  Every violation
names its sequence and the batch it ran in: the same --seed and --batch with
``--first BATCH_FIRST --sequences BATCH`` run that batch again, bit for bit.
"""

from __future__ import annotations

import argparse
import json
import platform
import sys
import time
from pathlib import Path

from host_sdk.commands.argtypes import positive_float, positive_int


def add_arguments(parser: argparse.ArgumentParser) -> None:
    which = parser.add_argument_group("which sequences (the same ones, bit for bit, for the same values)")
    which.add_argument("--sequences", type=positive_int, default=1000, help="how many (default 1000)")
    which.add_argument("--seed", type=int, default=1, help="random seed (default 1)")
    which.add_argument("--batch", type=positive_int, default=1000,
                       help="sequences per emulator process, checked as one pin log (default 1000)")
    which.add_argument("--first", type=int, default=0, help="index of the first sequence (a multiple of --batch)")
    how = parser.add_argument_group("how")
    how.add_argument("--jobs", type=positive_int, default=1, help="emulator processes at once (default 1)")
    how.add_argument("--minutes", type=positive_float,
                     help="start no batch after this many minutes (the result says how many sequences ran)")
    how.add_argument("--elf", type=Path, help="firmware ELF to fuzz (default: build the production one)")
    how.add_argument("--harness", type=Path, help="simavr harness for --elf (default: firmware_pwm/build's)")
    parser.add_argument("--json", action="store_true", help="print the result as one JSON object")


def run(args: argparse.Namespace) -> int:
    from device.sim.comcu_emulator import HARNESS, build_emulator
    from device.sim.firmware_fuzz import fuzz

    if args.elf is None:
        harness, elf = build_emulator()
    else:
        harness, elf = args.harness or HARNESS, args.elf
    t0, done = time.monotonic(), [0, 0]

    def progress(batch) -> None:  # one line per finished batch on stderr
        done[0] += batch.sequences
        done[1] += len(batch.violations)
        print(f"{done[0]}/{args.sequences} sequences, {done[0] / (time.monotonic() - t0):.1f}/s, "
              f"{done[1]} violations", file=sys.stderr, flush=True)

    result = fuzz(args.sequences, seed=args.seed, jobs=args.jobs, batch=args.batch, first=args.first,
                  harness=harness, elf=elf, minutes=args.minutes, progress=progress)
    result.update(elf=str(elf), python=platform.python_version(), argv=sys.argv[1:])
    if args.json:
        print(json.dumps(result, indent=1))
    else:
        _print(result)
    return 1 if result["violations"] else 0


def _print(r: dict) -> None:
    env = r["envelope"]
    print(f"envelope: max pulse {env['max_pulse_ticks']} ticks, duty {env['max_duty_ppm']} ppm, "
          f"min period {env['min_period_ticks']} ticks")
    print(f"{r['sequences']} sequences in {r['batches']} emulator processes ({r['jobs']} at once), "
          f"{r['simulated_s']} s simulated, {r['duration_s']} s ({r['sequences_per_s']} sequences/s)")
    print(f"{r['pulses']} pulses on the pin; violations: {r['violations']} "
          f"({r['violations_within_boot']} within one boot, {r['violations_across_reset']} across an MCU reset)")
    for kind, k in r["violations_by_kind"].items():
        print(f"  {kind}: {k['count']}, missed by at most {k['most_missed_by']} ticks; first:")
        for v in k["first"]:
            print(f"    {v['detail']} (sequence {v['sequence']}, batch {v['batch_first']}, cycle {v['cycle']})")
    print("closest to the limits: " + ", ".join(f"{k} {v}" for k, v in r["extremes"].items()))
    print(f"fall-to-fall checks of pulses cut short, judged on their scheduled fall: "
          f"{r['cut_pulse_falls_judged_as_scheduled']}")
    print(f"{'path':<52} {'sequences':>9} {'times':>8}")
    for path, n in r["paths"].items():
        print(f"{path:<52} {n['sequences']:>9} {n['times']:>8}")
