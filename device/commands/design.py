"""`laserpi design`: range limits and resolution of a sensor design (thesis 3.5, 4.1, 4.2.3).

``--json`` prints ``{"q_min_mm", "q_max_mm" (null when unbounded), "resolution_pct":
{sub-pixel: {distance_mm: percent}}}``; without it, the readable design report (which adds the
camera-tilt sweep, eye safety and background light), and ``--plots DIR`` writes its PNGs.
"""

from __future__ import annotations

import argparse
import json
import math

from host_sdk.commands.argtypes import positive_floats

DEFAULT_SUBPIXELS = "0.1,0.2,0.3,0.4,0.5,0.6,0.7,0.8,0.9,1.0"
DEFAULT_DISTANCES_MM = "2000,2500,3500"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    src = parser.add_mutually_exclusive_group(required=True)
    src.add_argument("--preset", metavar="NAME", help="a built-in configuration (thesis-design, thesis-calibrated)")
    src.add_argument("--config", metavar="FILE", help="a sensor configuration file (TOML)")
    parser.add_argument("--subpixel", type=positive_floats, default=positive_floats(DEFAULT_SUBPIXELS),
                        help=f"sub-pixel accuracies in px, comma-separated (default {DEFAULT_SUBPIXELS})")
    parser.add_argument("--distances-mm", type=positive_floats, default=positive_floats(DEFAULT_DISTANCES_MM),
                        help=f"distances for the resolution table, comma-separated (default {DEFAULT_DISTANCES_MM})")
    parser.add_argument("--json", action="store_true", help="print q_min_mm, q_max_mm and resolution_pct as JSON")
    parser.add_argument("--plots", metavar="DIR", help="write PNG plots into DIR")
    parser.set_defaults(_parser=parser)


def _key(v: float) -> str:
    return format(v, "g")


def run(args: argparse.Namespace) -> int:
    from device.config import ConfigError, load_config, load_preset
    from device.design.report import design_report, format_report

    try:
        cfg = load_preset(args.preset) if args.preset is not None else load_config(args.config)
    except ConfigError as exc:
        args._parser.error(f"argument {'--preset' if args.preset is not None else '--config'}: {exc}")
    ranges_m = [d * 1e-3 for d in args.distances_mm]
    want_figures = not args.json or args.plots is not None
    rep = design_report(cfg, args.subpixel, ranges_m, sweep=want_figures, columns=want_figures,
                        rates=want_figures)
    if args.plots is not None:
        from device.design.plots import write_plots

        write_plots(rep, cfg, args.plots)
    if args.json:
        def num(x: float):
            return None if not math.isfinite(x) else x

        out = {
            "q_min_mm": num(rep.q_min_m * 1e3),
            "q_max_mm": num(rep.q_max_m * 1e3),
            "resolution_pct": {
                _key(s): {_key(d): num(float(v) * 100) for d, v in zip(args.distances_mm, row)}
                for s, row in zip(args.subpixel, rep.resolution)
            },
        }
        print(json.dumps(out))
        return 0
    print(format_report(rep))
    return 0
