"""`laserpi safety`: IEC 60825-1 Class 1 check of a pulsed line laser (thesis 3.3, 4.1.4).

With ``--nohd-mm D`` it prints the largest power whose NOHD is D. With ``--power-mw P`` it
prints the NOHD of that laser, and Class 1 holds if that NOHD is within ``--closest-eye-mm``
(default 10 mm: thesis 4.1.4 assumes no eye gets closer than 1 cm to the source).
"""

from __future__ import annotations

import argparse
import json
import math

from host_sdk.commands.argtypes import positive_float


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--wavelength-nm", type=positive_float, required=True, help="600-1050 nm")
    parser.add_argument("--pulse-ms", type=positive_float, required=True, help="pulse duration, 0.005-250 ms")
    parser.add_argument("--rate-hz", type=positive_float, required=True, help="pulse repetition rate")
    parser.add_argument("--fan-deg", type=positive_float, required=True, help="horizontal fan angle of the line")
    parser.add_argument("--line-height-mm", type=positive_float, required=True, help="height of the projected line")
    parser.add_argument("--source-mm", type=positive_float, required=True, help="diameter of the apparent source")
    which = parser.add_mutually_exclusive_group(required=True)
    which.add_argument("--nohd-mm", type=positive_float, help="required NOHD: print the largest allowed power")
    which.add_argument("--power-mw", type=positive_float, help="laser peak power: print its NOHD")
    parser.add_argument("--closest-eye-mm", type=positive_float, default=10.0,
                        help="closest distance an eye can reach, for --power-mw (default 10)")
    parser.add_argument("--json", action="store_true", help="print one JSON object")
    parser.set_defaults(_parser=parser)


def run(args: argparse.Namespace) -> int:
    from device.model import safety

    try:
        laser = safety.PulsedLineLaser(
            wavelength_nm=args.wavelength_nm, pulse_s=args.pulse_ms * 1e-3, rate_hz=args.rate_hz,
            fan_rad=math.radians(args.fan_deg), line_height_m=args.line_height_mm * 1e-3,
            source_diameter_m=args.source_mm * 1e-3)
    except ValueError as exc:
        args._parser.error(_name_argument(str(exc)))
    if args.nohd_mm is not None:
        result = safety.assess(laser, args.nohd_mm * 1e-3)
    else:
        result = safety.assess(laser, args.closest_eye_mm * 1e-3, args.power_mw * 1e-3)
    out = {
        "max_power_mw": result.max_power_w * 1e3,
        "nohd_mm": result.nohd_m * 1e3,
        "class1": result.class1 if result.power_w is not None else None,  # no laser given: nothing to judge
        "limiting_condition": result.limiting_condition,
    }
    if args.json:
        print(json.dumps(out))
        return 0
    lim = result.limit
    print(f"angular subtense   {lim.subtense_mrad:.3f} mrad   C4 {lim.c4:.4f}   C6 {lim.c6:.4f}")
    print(f"T2 {lim.t2_s:.3f} s: N = {lim.pulses_in_t2} pulses, C5 {lim.c5:.4f}; N in 100 s = {lim.pulses_in_t}")
    print("per-pulse energy limits (uJ):")
    for name, value in (("single pulse", lim.single_pulse_j), ("average over 100 s", lim.average_power_j),
                        ("pulse train (x C5)", lim.pulse_train_j)):
        print(f"  {name:<20} {value * 1e6:10.2f}")
    print(f"limiting condition {result.limiting_condition}; H_mpe {lim.h_mpe_j_per_m2:.4g} J/m^2")
    print(f"max power at {result.closest_eye_m * 1e3:g} mm: {safety.mw_down(result.max_power_w):.2f} mW")
    if result.power_w is None:  # --nohd-mm: the limit is the answer; no laser was given to judge
        print(f"a laser of at most that peak power is Class 1 with no eye nearer than {result.closest_eye_m * 1e3:g} mm")
        return 0
    print(f"NOHD of {result.power_w * 1e3:g} mW: {out['nohd_mm']:.2f} mm")
    print("Class 1" if result.class1 else "NOT Class 1")
    return 0


# The model's messages name quantities; the user typed options. Map one to the other.
_OPTION_OF = (("period", "--pulse-ms/--rate-hz"), ("wavelength", "--wavelength-nm"), ("pulse duration", "--pulse-ms"),
              ("pulse rate", "--rate-hz"), ("fan angle", "--fan-deg"), ("line height", "--line-height-mm"),
              ("source diameter", "--source-mm"))


def _name_argument(message: str) -> str:
    for phrase, option in _OPTION_OF:
        if phrase in message:
            return f"argument {option}: {message}"
    return message
