"""`laserpi calibrate`: camera and laser plane from checkerboard frames (thesis 4.2).

    laserpi calibrate run DIR --out sensor.toml [--report DIR] [--base PRESET|TOML]
    laserpi calibrate capture DIR --poses 20          (live, on the Pi)
    laserpi calibrate --simulate --poses 20 --seed 1 --out sensor.toml [--json] [--scale 0.5]

DIR holds pose_NNN_unlit.png / pose_NNN_lit.png pairs (see device.calibration.pipeline), or is a
ReplayCamera recording (.npz) whose lit/unlit frame pairs are selected as a live capture does.
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
    parser.add_argument("--bootstrap", type=int, default=30, help="view-bootstrap samples for the uncertainty (0: skip)")
    parser.add_argument("--no-sweep", action="store_true", help="with --simulate: skip the simulated wall sweep and post-calibration")
    _board_args(parser)
    sub = parser.add_subparsers(dest="action", metavar="{run,capture}")
    run_p = sub.add_parser("run", help="calibrate from a capture-set folder")
    run_p.add_argument("dir", help="folder of pose_NNN_lit.png / pose_NNN_unlit.png pairs, or a camera recording (.npz)")
    run_p.add_argument("--out", dest="run_out", required=True, help="sensor configuration to write (TOML)")
    run_p.add_argument("--json", dest="run_json", action="store_true", help="print the summary as JSON")
    run_p.add_argument("--bootstrap", type=int, default=30, help="view-bootstrap samples for the uncertainty (0: skip)")
    run_p.add_argument("--sweep", help="wall sweep for the post-calibration of section 6.3: a folder of wall_<mm>mm_lit.png/_unlit.png pairs, or a CSV (x_m, z_measured_m, z_true_m[, wall]) of a reference scanner")
    _board_args(run_p)
    cap = sub.add_parser("capture", help="capture lit/unlit pose pairs live from the camera")
    cap.add_argument("dir", help="folder to write the pose pairs to")
    cap.add_argument("--count", type=int, default=20, help="poses to capture (default 20)")
    cap.add_argument("--camera", default="device.camera.picamera2_camera:Picamera2Camera", help="camera backend MODULE:CLASS")
    cap.add_argument("--lit-frames", default="flag", choices=["flag", "even", "odd"],
                     help="which frames are lit: each frame's own flag (default), or even/odd sequence numbers")
    cap.add_argument("--squares", default="10x7")
    cap.add_argument("--square-mm", type=float, default=41.4)


def _spec(args):
    from ..calibration.target import BoardSpec

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


def _postcal(result, sweep):
    """Fit the post-calibration to a wall sweep (x, z_measured, z_true, wall) and attach it."""
    from dataclasses import replace

    from ..calibration.postcal import fit_postcal
    from ..vision.postcal import correction

    x, z, zt, walls = sweep
    fit = fit_postcal(x, z, zt, walls)
    result.config = replace(result.config, post_calibration=fit.post)
    after = z - (correction(fit.post, x, z) if fit.post else 0.0) - zt
    info = {"postcal_order": [fit.x_order, fit.z_order], "postcal_rms_before_mm": 1000 * fit.rms_before_m,
            "postcal_rms_after_mm": 1000 * fit.rms_after_m, "postcal_cv_rmse_mm": {k: 1000 * v for k, v in fit.cv_rmse_m.items()}}
    return info, (z, z - zt, after)


def _finish(result, out: str | None, report: str | None, as_json: bool, comparison: dict | None = None, sweep=None, spec=None, bootstrap: int = 0) -> int:
    """Attach the post-calibration, write config and report, print the summary (with --json: the
    true-vs-estimated comparison when simulating, else the summary)."""
    from ..calibration.report import json_safe, write_report
    from ..config import save_config

    curve, extra = None, dict(comparison or {})
    if bootstrap > 0:
        from dataclasses import asdict

        from ..calibration.pipeline import bootstrap_views

        extra.update({f"view_bootstrap_{k}": v for k, v in asdict(bootstrap_views(result, spec, bootstrap)).items()})
    if sweep is not None:
        info, curve = _postcal(result, sweep)
        extra.update(info)
    summary = {**_summary(result), **extra}
    if out:
        Path(out).parent.mkdir(parents=True, exist_ok=True)
        save_config(result.config, out)
        folder = report or str(Path(out).with_suffix("")) + "_report"
        write_report(result, folder, extra, curve)
    if as_json:
        print(json.dumps(json_safe(extra if comparison is not None else summary)))
        return 0
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

            from ..calibration.postcal import load_sweep_csv

            if Path(args.dir).suffix == ".npz":  # a ReplayCamera recording: pair and select poses as a live capture does
                from ..calibration.capture import capture_poses
                from ..camera.replay import ReplayCamera

                poses = capture_poses(ReplayCamera(args.dir), 10**6, _spec(args).pattern_size)
            else:
                poses = load_capture_dir(args.dir)
            result = calibrate(poses, _base(args.base), _spec(args), args.model)
            sweep = None
            if args.sweep:  # measured with the configuration just calibrated
                from ..calibration.postcal import load_wall_sweep

                sweep = load_wall_sweep(args.sweep, result.config) if Path(args.sweep).is_dir() else load_sweep_csv(args.sweep)
            return _finish(result, args.run_out, args.report, args.run_json, sweep=sweep, spec=_spec(args), bootstrap=args.bootstrap)
        if args.action == "capture":
            from ..calibration.capture import run_capture

            return run_capture(args, _spec(args))
        if args.simulate:
            from ..calibration.pipeline import calibrate
            import numpy as np

            from ..calibration.metrics import compare
            from ..calibration.simulate import scaled_config, simulate_capture, simulated_wall_sweep

            truth = scaled_config(_base(args.base), args.scale)
            poses, _ = simulate_capture(truth, args.poses, args.seed, _spec(args))
            result = calibrate(poses, truth, _spec(args), args.model)
            cmp = compare(truth, result.config)
            # the thesis's sweep: walls every 10 cm from 0.3 to 3 m, line rows with 0.1 px noise
            sweep = None if args.no_sweep else simulated_wall_sweep(truth, result.config, np.arange(0.3, 3.001, 0.1), args.seed)
            return _finish(result, args.out, args.report, args.json, cmp, sweep, _spec(args), args.bootstrap)
        print("laserpi calibrate: give 'run DIR --out FILE', 'capture DIR' or '--simulate'", file=sys.stderr)
        return 2
    except CalibrationError as exc:
        print(f"calibration failed: {exc}", file=sys.stderr)
        return 1
