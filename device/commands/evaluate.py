"""`laserpi evaluate`: run pipeline variants over simulated frame pairs against ground truth.

Reports per variant: sub-pixel RMS error of the line row, range error (mean, std, p95 of |e|)
and valid-column share by distance bin, valid share of all columns with a return, false returns
on columns without one, gross errors (> 5 %), and the effective angular resolution.
"""

from __future__ import annotations

import argparse
import json
import math


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--scene", required=True,
                        help="scene name (wall, room, corridor, clutter, targets, near, far, sunlight, glossy-floor, "
                             "empty), 'wall:distance=2,reflectivity=0.1', or a scene .toml")
    parser.add_argument("--pipeline", default="fast-com",
                        help="variant name, comma-separated list, or 'all' (default fast-com)")
    parser.add_argument("--frames", type=int, default=3, help="frame pairs to render (default 3)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--preset", default="thesis-calibrated", help="sensor preset (default thesis-calibrated)")
    parser.add_argument("--config", help="sensor configuration TOML (instead of --preset)")
    parser.add_argument("--min-range", type=float, default=0.1,
                        help="fast pipeline depth limits: its region of interest (m, default 0.1)")
    parser.add_argument("--max-range", type=float, default=10.0, help="(m, default 10)")
    parser.add_argument("--gain", type=float, default=None, help="simulated analogue gain (default: the simulator's, 10)")
    parser.add_argument("--exposure-us", type=float, default=None, help="simulated exposure (default 40000)")
    parser.add_argument("--isp", choices=("linear", "default"), default="linear",
                        help="the camera's luminance: linear and full range as LaserPi sets it up (default), or the "
                             "Raspberry Pi ISP's defaults (gamma, sharpening, denoise, 16-235; device/sim/isp.py)")
    parser.add_argument("--no-lit-rows", action="store_true",
                        help="do not tell the pipeline which rows the pulse lit (as without synchronisation)")
    parser.add_argument("--json", action="store_true", help="print JSON")


def _config(args):
    from ..config import load_config, load_preset

    return load_config(args.config) if args.config else load_preset(args.preset)


def evaluate(args) -> list[dict]:
    from ..vision.evaluation import EXPOSURE_US, run_pipeline, simulated_pairs
    from ..vision.pipelines import VARIANTS, make_pipeline

    cfg = _config(args)
    names = list(VARIANTS) if args.pipeline == "all" else [n.strip() for n in args.pipeline.split(",") if n.strip()]
    pipes = [make_pipeline(n, cfg, args.min_range, args.max_range) for n in names]  # validates names first
    pairs = simulated_pairs(cfg, args.scene, args.frames, args.seed,
                            exposure_us=args.exposure_us or EXPOSURE_US, analog_gain=args.gain, isp=args.isp)
    out = []
    for name, pipe in zip(names, pipes):
        score = run_pipeline(pipe, pairs, use_lit_rows=not args.no_lit_rows)
        s = score.summary()
        s.update({"variant": name, "scene": args.scene, "frames": args.frames, "isp": args.isp,
                  "resolution_deg": getattr(pipe, "resolution_deg", float("nan")),
                  "valid_fraction_within_2_5m": score.valid_fraction_within(2.5)})
        out.append(s)
    return out


def _fmt(v, spec=".3f") -> str:
    return "-" if v is None or (isinstance(v, float) and math.isnan(v)) else format(v, spec)


def run(args: argparse.Namespace) -> int:
    from ..config import ConfigError
    from ..sim.scene import SceneError

    if args.frames < 1:
        print("laserpi evaluate: --frames must be >= 1")
        return 2
    try:
        results = evaluate(args)
    except (ConfigError, SceneError, ValueError) as exc:
        print(f"laserpi evaluate: {exc}")
        return 2
    if args.json:
        print(json.dumps(results, indent=2))
        return 0
    print(f"scene {args.scene}, {args.frames} frame pair(s), simulated (sensor noise, speckle, rolling shutter)")
    for s in results:
        print(f"\n{s['variant']}: sub-pixel RMS {_fmt(s['subpixel_rms_px'])} px (bias {_fmt(s['subpixel_bias_px'], '+.3f')}), "
              f"valid {_fmt(s['valid_fraction'])} of {s['columns_with_return']} columns with a return "
              f"({_fmt(s['valid_fraction_within_2_5m'])} within 2.5 m), false returns "
              f"{_fmt(s['false_return_fraction'], '.4f')} of {s['columns_without_return']} empty columns, "
              f"gross errors {_fmt(s['gross_error_fraction'], '.4f')}, resolution {_fmt(s['resolution_deg'], '.2f')} deg")
        if s["range_error_by_distance"]:
            print(f"  {'range bin (m)':>14} {'columns':>8} {'valid':>6} {'mean %':>8} {'std %':>7} {'p95 %':>7}")
        for b in s["range_error_by_distance"]:
            lo, hi = b["bin_m"]
            print(f"  {lo:>6.1f} - {hi:<5.1f} {b['columns']:>8d} {_fmt(b['valid_fraction'], '.3f'):>6} "
                  f"{_fmt(b['mean_pct'], '+.2f'):>8} {_fmt(b['std_pct'], '.2f'):>7} {_fmt(b['p95_abs_pct'], '.2f'):>7}")
    return 0
