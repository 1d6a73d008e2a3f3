"""`laserpi calibrate`: camera and laser plane from checkerboard frames (thesis 4.2).

    laserpi calibrate run DIR --out sensor.toml [--report DIR] [--base PRESET|TOML]
    laserpi calibrate capture DIR --poses 20          (live, on the Pi)
    laserpi calibrate --simulate --poses 20 --seed 1 --out sensor.toml [--json] [--scale 0.5]

DIR holds pose_NNN_unlit.png / pose_NNN_lit.png pairs (see device.calibration.pipeline).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path


def _board_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("--squares", default="10x7", help="checkerboard squares, COLSxROWS (default 10x7, thesis 4.2.1)")
    p.add_argument("--square-mm", type=float, default=41.4, help="square side in mm (default 41.4)")
    p.add_argument("--base", default="thesis-calibrated", help="preset name or TOML file for what calibration does not measure (laser, optics, range)")
    p.add_argument("--model", default="auto", choices=["auto", "brown-conrady", "kannala-brandt"], help="lens model (auto: by evidence)")
    p.add_argument("--report", help="folder for report.json and PNG plots (default: next to --out)")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--simulate", action="store_true", help="render a capture set from a known configuration and compare")
    parser.add_argument("--poses", type=int, default=20, help="poses to render or capture (default 20)")
    parser.add_argument("--seed", type=int, default=1, help="seed of the simulated poses and noise")
    parser.add_argument("--scale", type=float, default=1.0, help="simulate at this fraction of the resolution (faster)")
    parser.add_argument("--out", help="sensor configuration to write (TOML)")
    parser.add_argument("--json", action="store_true", help="print the result as JSON")
    _board_args(parser)
    sub = parser.add_subparsers(dest="action", metavar="{run,capture}")
    run_p = sub.add_parser("run", help="calibrate from a capture-set folder")
    run_p.add_argument("dir", help="folder of pose_NNN_lit.png / pose_NNN_unlit.png pairs")
    run_p.add_argument("--out", dest="run_out", required=True, help="sensor configuration to write (TOML)")
    run_p.add_argument("--json", dest="run_json", action="store_true", help="print the summary as JSON")
    _board_args(run_p)
    cap = sub.add_parser("capture", help="capture lit/unlit pose pairs live from the camera")
    cap.add_argument("dir", help="folder to write the pose pairs to")
    cap.add_argument("--count", type=int, default=20, help="poses to capture (default 20)")
    cap.add_argument("--camera", default="device.camera.picamera2:Picamera2Camera", help="camera backend MODULE:CLASS")
    cap.add_argument("--squares", default="10x7")
    cap.add_argument("--square-mm", type=float, default=41.4)


def _spec(args):
    from ..sim.checkerboard import BoardSpec

    try:
        nx, ny = (int(v) for v in args.squares.lower().split("x"))
    except ValueError:
        raise SystemExit(f"--squares must look like 10x7, got {args.squares!r}") from None
    return BoardSpec(nx, ny, args.square_mm / 1000.0)


def _base(name: str):
    from ..config import load_config, load_preset

    return load_config(name) if name.endswith(".toml") else load_preset(name)


def _summary(result) -> dict:
    from ..calibration.pipeline import triangulation_table

    k = result.config.camera.intrinsics
    fit = result.plane_fit
    return {
        "fx": k.fx, "fy": k.fy, "cx": k.cx, "cy": k.cy, "rms_px": result.intrinsics.rms_px,
        "views_used": len(result.intrinsics.poses), "views": len(result.detections),
        "plane_rms_mm": 1000 * fit.rms_m, "plane_normal_std_deg": fit.normal_std_deg,
        "plane_offset_std_mm": 1000 * fit.offset_std_m, **triangulation_table(result),
    }


def _finish(result, out: str | None, report: str | None, as_json: bool, extra: dict | None = None) -> int:
    from ..calibration.report import write_report
    from ..config import save_config

    summary = _summary(result)
    if extra:
        summary.update(extra)
    if out:
        Path(out).parent.mkdir(parents=True, exist_ok=True)
        save_config(result.config, out)
        folder = report or str(Path(out).with_suffix("")) + "_report"
        write_report(result, folder, extra)
    if as_json:
        print(json.dumps(extra if extra is not None else summary))
    else:
        for key, v in summary.items():
            print(f"{key:>24}: {v:.6g}" if isinstance(v, float) else f"{key:>24}: {v}")
        for det in result.detections:
            if det.reason:
                print(f"dropped {det.name}: {det.reason}")
    return 0


def run(args: argparse.Namespace) -> int:
    from ..calibration.intrinsics import CalibrationError

    try:
        if args.action == "run":
            from ..calibration.pipeline import calibrate, load_capture_dir

            result = calibrate(load_capture_dir(args.dir), _base(args.base), _spec(args), args.model)
            return _finish(result, args.run_out, args.report, args.run_json)
        if args.action == "capture":
            from ..calibration.capture import run_capture

            return run_capture(args, _spec(args))
        if args.simulate:
            from ..calibration.pipeline import calibrate
            from ..calibration.simulate import compare, scaled_config, simulate_capture

            truth = scaled_config(_base(args.base), args.scale)
            poses, _ = simulate_capture(truth, args.poses, args.seed, _spec(args))
            result = calibrate(poses, truth, _spec(args), args.model)
            return _finish(result, args.out, args.report, args.json, compare(truth, result.config))
        print("laserpi calibrate: give 'run DIR --out FILE', 'capture DIR' or '--simulate'", file=sys.stderr)
        return 2
    except CalibrationError as exc:
        print(f"calibration failed: {exc}", file=sys.stderr)
        return 1
