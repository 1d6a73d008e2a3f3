"""`laserpi evaluate`: run pipeline variants over simulated frame pairs against ground truth,
or one pipeline over any recording.

``--scene``: renders frame pairs (each lit frame with the unlit frames before and after it when
the scene moves, device/scan/pairing.py) and reports per variant: sub-pixel RMS error of the
line row, range error (mean, std, p95 of |e|) and valid-column share by distance bin, valid
share of all columns with a return, false returns on columns without one, gross errors (> 5 %),
and the effective angular resolution.

``--recording FRAMES.npz --out OUT.npz``: runs one pipeline (default: the device's,
device/vision/pipelines.py DEVICE_VARIANT, with the configuration's [operating_point] depth limits)
over a recording in the ReplayCamera format (device/camera/replay.py: frames in time order with
their lit flags), each lit frame with its unlit neighbours as the device pairs them. OUT.npz
holds, per scan in time order, every array indexed by image column (W = the frames' width):
``row`` (n, W) sub-pixel image row of the line, NaN where none (a line found beyond the depth
limits, TOO_CLOSE or TOO_FAR, keeps its row); ``points`` (n, W, 3) the camera-frame point in
metres, NaN where none (and beyond the depth limits); ``status`` (n, W) ColumnStatus
(device/vision/measurements.py; 255 for a column the pipeline does not process: the reference's
odd columns, the frame buffer's padding beyond the image's ``[image] active_width``);
``time_ns`` (n, W) when the column's line was lit (device/scan/timing.py: the middle of its
row's exposure, as the device's pulse lights it), NaN where none; ``lit_seq`` (n,) the lit
frame's seq. With ``--truth TRUTH.npz`` (as ``laserpi simulate`` writes it: per frame, with
``seq``) it also prints the scores against the lit frames' truth. The recording's metadata is
checked whole before a frame is processed (device/camera/replay.py ``check_frames``: it may come
from another renderer or camera stack; a folder's PNGs as they are read), as are a lit frame's
unlit neighbours' exposures (one exposure, as the device pairs them) and the truth (the
configuration's size, one per frame, lit where the recording is); options that only set up a
simulated scene are refused; OUT.npz is written last, whole or not at all (``save_npz``): a
refusal leaves nothing behind, and never an overwritten input.
"""

from __future__ import annotations

import argparse
import json
import math

from .argtypes import add_motion_arguments, scene_with_motion


#: what only a simulated scene takes: given with --recording, whose frames are what they are, refused
SIMULATION_ONLY = ("frames", "seed", "gain", "exposure_us", "isp", "no_lit_rows", "yaw_rate_deg_s", "speed_m_s",
                   "sensor_ahead_m", "ambient_scale", "flicker_hz", "flicker_depth")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from ..sim.scene import scene_names

    source = parser.add_mutually_exclusive_group(required=True)
    source.add_argument("--scene",
                        help=f"scene name ({', '.join(scene_names())}), 'wall:distance=2,reflectivity=0.1', "
                             "or a scene .toml")
    source.add_argument("--recording", help="a recording (FRAMES.npz or a frames.json folder) to reprocess")
    parser.add_argument("--out", help="with --recording: write the per-scan results to this .npz")
    parser.add_argument("--truth", help="with --recording: score against this truth.npz (from laserpi simulate)")
    parser.add_argument("--pipeline",
                        help="variant name, comma-separated list, or 'all' (default fast-com; with --recording one "
                             "variant, default the device's)")
    parser.add_argument("--frames", type=int, default=3, help="frame pairs to render (default 3)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--preset", default="thesis-calibrated", help="sensor preset (default thesis-calibrated)")
    parser.add_argument("--config", help="sensor configuration TOML (instead of --preset)")
    parser.add_argument("--min-range", type=float, default=None,
                        help="fast pipeline depth limits: its region of interest (m, default 0.1; with --recording "
                             "the configuration's [operating_point])")
    parser.add_argument("--max-range", type=float, default=None, help="(m, default 10)")
    parser.add_argument("--gain", type=float, default=None, help="simulated analogue gain (default: the simulator's, 10)")
    parser.add_argument("--exposure-us", type=float, default=None, help="simulated exposure (default 40000)")
    parser.add_argument("--isp", choices=("linear", "default"), default="linear",
                        help="the camera's luminance: linear and full range as LaserPi sets it up (default), or the "
                             "Raspberry Pi ISP's defaults (gamma, sharpening, denoise, 16-235; device/sim/isp.py)")
    parser.add_argument("--no-lit-rows", action="store_true",
                        help="do not tell the pipeline which rows the pulse lit (as without synchronisation)")
    parser.add_argument("--json", action="store_true", help="print JSON")
    add_motion_arguments(parser)


def _config(args):
    from ..config import load_config, load_preset

    return load_config(args.config) if args.config else load_preset(args.preset)


def evaluate(args) -> list[dict]:
    from ..sim.scene import get_scene
    from ..vision.evaluation import EXPOSURE_US, run_pipeline, simulated_pairs
    from ..vision.pipelines import VARIANTS, make_pipeline

    cfg = _config(args)
    pipeline = args.pipeline or "fast-com"
    names = list(VARIANTS) if pipeline == "all" else [n.strip() for n in pipeline.split(",") if n.strip()]
    lo = 0.1 if args.min_range is None else args.min_range
    hi = 10.0 if args.max_range is None else args.max_range
    pipes = [make_pipeline(n, cfg, lo, hi) for n in names]  # validates names first
    scene = scene_with_motion(get_scene(args.scene), args)
    pairs = simulated_pairs(cfg, scene, args.frames, args.seed, exposure_us=args.exposure_us or EXPOSURE_US,
                            analog_gain=args.gain, isp=args.isp, neighbours=not scene.still)
    out = []
    for name, pipe in zip(names, pipes):
        score = run_pipeline(pipe, pairs, use_lit_rows=not args.no_lit_rows)
        s = score.summary()
        s.update({"variant": name, "scene": args.scene, "frames": args.frames, "isp": args.isp,
                  "resolution_deg": getattr(pipe, "resolution_deg", float("nan")),
                  "valid_fraction_within_2_5m": score.valid_fraction_within(2.5)})
        out.append(s)
    return out


NOT_PROCESSED = 255  # status of a column the pipeline does not process


def reprocess(args) -> dict:
    """``--recording``: one pipeline over every lit frame of a recording (module docstring)."""
    import numpy as np

    from ..camera.base import EndOfRecording
    from ..camera.replay import ReplayCamera, save_npz
    from ..scan.pairing import NeighbourPairing
    from ..scan.timing import column_times_ns
    from ..vision.evaluation import Score
    from ..vision.pipelines import DEVICE_VARIANT, make_pipeline

    cfg = _config(args)
    op = cfg.operating_point
    name = args.pipeline or DEVICE_VARIANT
    if "," in name or name == "all":
        raise ValueError(f"--recording runs one pipeline, got {name!r}")
    lo = op.min_m if args.min_range is None else args.min_range
    hi = op.max_m if args.max_range is None else args.max_range
    pipe = make_pipeline(name, cfg, lo, hi)
    if args.out:
        _check_out(args.out, args.recording, args.truth)
    cam = ReplayCamera(args.recording)
    if (cam.width, cam.height) != (cfg.width, cfg.height):
        raise ValueError(f"{args.recording}: frames are {cam.width}x{cam.height}, the configuration "
                         f"{cfg.name!r} expects {cfg.width}x{cfg.height}")
    truth = _load_truth(args.truth, cfg) if args.truth else None
    pairing, neighbours, unknown = NeighbourPairing(), [], 0
    cam.start()
    while True:
        try:
            frame = cam.capture()
        except EndOfRecording:
            break
        if frame.lit is None:  # no lit flag: this frame cannot be paired, nor across it
            unknown += 1
            pairing.reset()
            continue
        found = pairing.push(frame, frame.lit)
        neighbours += [found] if found else []
    last = pairing.flush()
    neighbours += [last] if last else []
    if not neighbours:
        raise ValueError(f"{args.recording}: no lit frame with an unlit neighbour"
                         + (f" ({unknown} frames have no lit flag)" if unknown else ""))
    for f in neighbours:
        _check_same_exposure(args.recording, f.lit, f.unlit, f.other_unlit)
    W = cfg.width
    n = len(neighbours)
    out = {"row": np.full((n, W), np.nan), "points": np.full((n, W, 3), np.nan),
           "status": np.full((n, W), NOT_PROCESSED, np.uint8), "time_ns": np.full((n, W), np.nan),
           "lit_seq": np.array([f.lit.seq for f in neighbours], np.int64)}
    score = Score()
    if hasattr(pipe, "reset"):
        pipe.reset()
    for k, f in enumerate(neighbours):
        meas = pipe.process(f.lit, f.unlit, other_unlit=f.other_unlit)
        c = np.asarray(meas.column)
        out["row"][k, c], out["points"][k, c], out["status"][k, c] = meas.row, meas.points, meas.status
        out["time_ns"][k, c] = column_times_ns(f.lit, meas.row)
        if truth is not None:
            if f.lit.seq not in truth:
                raise ValueError(f"{args.truth}: no truth for frame seq {f.lit.seq}")
            if not truth[f.lit.seq].lit_rows.any():
                raise ValueError(f"{args.truth}: the truth of frame seq {f.lit.seq} has no lit rows (an unlit frame's), "
                                 f"but the recording's frame seq {f.lit.seq} is lit: not this recording's truth")
            score.add(meas, truth[f.lit.seq])
    result = {"variant": name, "recording": args.recording, "scans": n, "frames_without_lit_flag": unknown,
              "out": args.out, "flicker_kept": _flicker_kept([f.lit for f in neighbours], op.flicker_hz),
              "assumed": cam.assumed}
    if truth is not None:
        result.update(score.summary())
        result["valid_fraction_within_2_5m"] = score.valid_fraction_within(2.5)
        result["resolution_deg"] = getattr(pipe, "resolution_deg", float("nan"))
    if args.out:  # last: nothing is written unless everything before it worked
        save_npz(args.out, **out)
    return result


def _check_same_exposure(recording: str, lit, *unlit) -> None:
    """Refuse a lit frame paired with an unlit neighbour of another exposure: their difference
    keeps the background's change, which a line search takes for lines. The device never pairs
    such frames (device/scan/source.py refuses an exposure change while it runs); a recording
    from elsewhere may hold them. The IMX219 exposes whole lines (device/camera/modes.py: its
    exposure control counts lines), so two exposures differ by at least a line time: anything
    from half a line apart is another exposure (what is reported, e.g. libcamera's whole us, is
    within half a line of it)."""
    for u in unlit:
        if u is not None and abs(u.exposure_us - lit.exposure_us) * 1e3 >= lit.line_time_ns / 2:
            raise ValueError(f"{recording}: lit frame seq {lit.seq} ({lit.exposure_us:g} us) and its unlit neighbour seq "
                             f"{u.seq} ({u.exposure_us:g} us) differ in exposure: their difference would keep the "
                             "background's change; a lit frame is measured against unlit frames of its own exposure")


def _check_out(out: str, recording: str, truth: str | None) -> None:
    """Refuse an --out that would not be the .npz asked for, or would overwrite an input."""
    from pathlib import Path

    path = Path(out)
    if path.suffix != ".npz":
        raise ValueError(f"--out {out}: the results are an .npz file; name it so (numpy would write {out}.npz)")
    for name, given in (("--recording", recording), ("--truth", truth)):
        if given is not None and path.resolve() == Path(given).resolve():
            raise ValueError(f"--out {out} is the {name} file: it would be overwritten")
    if not path.parent.is_dir():
        raise ValueError(f"--out {out}: no directory {path.parent}")
    if path.is_dir():
        raise ValueError(f"--out {out} is a directory; name the .npz file to write")


def _flicker_kept(lit_frames, flicker_hz) -> list[dict]:
    """The mains flicker a recording's frames keep in the difference of a lit and an unlit frame
    (device/model/flicker.py), from each lit frame's exposure and frame period (metadata), the
    largest share per frequency: frames the device would not take (device/config.py refuses such an
    [operating_point]), but a recording may come from elsewhere."""
    from ..model.flicker import uncancelled

    kept: dict[float, float] = {}
    for exposure_us, frame_us in {(f.exposure_us, f.frame_duration_us) for f in lit_frames}:
        for hz, r in uncancelled(exposure_us * 1e-6, frame_us * 1e-6, flicker_hz):
            kept[hz] = max(kept.get(hz, 0.0), r)
    return [{"hz": hz, "residue": r} for hz, r in sorted(kept.items())]


def _load_truth(path: str, cfg) -> dict:
    """{seq: FrameTruth} of a truth.npz as ``laserpi simulate`` writes it."""
    import numpy as np

    from ..camera.replay import NpzUnreadable, read_npz
    from ..sim.truth import FrameTruth

    required = ("row", "range_m", "angle_rad", "points", "surface", "lit_rows")  # FrameTruth's fields in order,
    optional = ("time_ns", "range_span_m")  # then these (older truth files lack them)
    try:
        arrays = read_npz(path, ("seq", *required, *optional))
    except NpzUnreadable as exc:
        raise ValueError(f"--truth {path}: not a readable truth .npz of laserpi simulate ({exc})") from None
    missing = [k for k in ("seq", *required) if k not in arrays]
    if missing:
        raise ValueError(f"{path}: not a truth file of laserpi simulate, missing {', '.join(missing)}")
    seq = arrays.pop("seq")
    if seq.ndim != 1 or not np.issubdtype(seq.dtype, np.integer):
        raise ValueError(f"{path}: seq must be one whole number per frame, got {seq.shape} {seq.dtype}")
    values, counts = np.unique(seq, return_counts=True)
    if np.any(counts > 1):
        raise ValueError(f"{path}: frame seq {values[np.argmax(counts > 1)].item()} has {counts.max()} truths; one per frame")
    n, W = seq.size, cfg.width
    shapes = {"row": (n, W), "range_m": (n, W), "angle_rad": (n, W), "points": (n, W, 3), "surface": (n, W),
              "lit_rows": (n, cfg.height), "time_ns": (n, W), "range_span_m": (n, W, 2)}
    for k, a in arrays.items():
        if a.shape != shapes[k]:
            raise ValueError(f"{path}: {k} has shape {a.shape}, {shapes[k]} expected ({n} frames, the "
                             f"configuration's {W} columns and {cfg.height} rows)")
    return {int(s): FrameTruth(*(arrays[k][i] for k in required), *(arrays[k][i] if k in arrays else None for k in optional))
            for i, s in enumerate(seq)}


def _fmt(v, spec=".3f") -> str:
    return "-" if v is None or (isinstance(v, float) and math.isnan(v)) else format(v, spec)


def run(args: argparse.Namespace) -> int:
    from ..config import ConfigError
    from ..sim.scene import SceneError

    if args.frames < 1:
        print("laserpi evaluate: --frames must be >= 1")
        return 2
    if args.recording is None and (args.out or args.truth):
        print("laserpi evaluate: --out and --truth go with --recording")
        return 2
    if args.recording is not None and (given := _simulation_options_given(args)):
        print(f"laserpi evaluate: {', '.join(given)} set up a simulated scene; a recording's frames are what they are "
              "(drop them, or use --scene)")
        return 2
    try:
        if args.recording is not None:
            return _report_recording(reprocess(args), args.json)
        results = evaluate(args)
    except (ConfigError, SceneError, ValueError, OSError) as exc:
        print(f"laserpi evaluate: {exc}")
        return 2
    if args.json:
        print(json.dumps(results, indent=2))
        return 0
    print(f"scene {args.scene}, {args.frames} frame pair(s), simulated (sensor noise, speckle, rolling shutter)")
    for s in results:
        _print_score(s)
    return 0


def _simulation_options_given(args) -> list[str]:
    """The SIMULATION_ONLY options ``args`` sets to other than their defaults, as flags."""
    parser = argparse.ArgumentParser()
    add_arguments(parser)
    return ["--" + d.replace("_", "-") for d in SIMULATION_ONLY if getattr(args, d) != parser.get_default(d)]


def _report_recording(result: dict, as_json: bool) -> int:
    if as_json:
        print(json.dumps(result, indent=2))
        return 0
    print(f"{result['recording']}: {result['scans']} scan(s) by {result['variant']}"
          + (f" -> {result['out']}" if result["out"] else "")
          + (f"; {result['frames_without_lit_flag']} frame(s) without a lit flag skipped"
             if result["frames_without_lit_flag"] else ""))
    for field, (value, meaning) in result["assumed"].items():
        print(f"warning: the recording has no {field}, taken as {value}: {meaning}")
    for k in result["flicker_kept"]:
        print(f"warning: its {k['hz']:g} Hz flicker of mains lighting is not cancelled between lit and unlit frames "
              f"(up to {k['residue']:.0%} of the lamps' modulation: exposure and frame period are not whole numbers "
              "of its period, device/model/flicker.py); under such lamps lines are lost")
    if "valid_fraction" in result:
        _print_score(result)
    return 0


def _print_score(s: dict) -> None:
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
