"""The pipelines on 64-bit ARM (a Raspberry Pi's aarch64) against x86-64, on the golden scenes.

tools/arm_check.sh runs the whole check; this file is its three steps:

    .venv/bin/python tools/arm_check.py frames DIR    # x86-64: the golden scenes' frame pairs
                                                      #   -> DIR/frames.npz, every variant's output -> DIR/x86_64.npz
    <aarch64 python> tools/arm_check.py run DIR       # aarch64 (qemu-user): the same variants on the
                                                      #   same frames, with the aarch64 kernel -> DIR/aarch64.npz
    .venv/bin/python tools/arm_check.py compare DIR   # DIR/x86_64.npz against DIR/aarch64.npz

The scenes, the order the frame pairs are processed in and the fields compared are
tools/golden_scenes.py's; the frames are rendered once on x86-64 and read on ARM, so the pipelines
alone are compared. What the kernel computes and what follows from it in exact steps (column, row,
quality, points, status) must be identical bit for bit. The scan-plane angle and range are numpy's
rotation of the points into the scan plane, whose matrix already differs in the last bit on
aarch64 (np.linalg.norm in device/model/scan_frame.py, BLAS), then atan2/hypot; they must have the
same NaNs and infinities and agree to SCAN_PLANE_RTOL.

The moving scenes (golden_scenes.MOTION) are compared within bounds, not bit for bit: where the
robot turns, the device's pipeline turns the unlit neighbours to the lit frame (device/vision/yaw.py)
through OpenCV's float arithmetic (the normalised correlation of cv2.matchTemplate, cv2.remap and
cv2.resize of float maps), which rounds differently with NEON than with AVX2 (seen: the turn ~1e-7
rad apart, a few dozen of the turned band's pixels one level apart). Per lit frame: columns and
their NaN and infinite values alike, at most MOTION_STATUS_MAX columns of another status, and in the
others the rows within MOTION_ROW_TOL_PX, the points and ranges within MOTION_RTOL (relative),
the angles within MOTION_ANGLE_TOL_RAD (absolute: they pass through 0) and the qualities (peak
levels) within one level. Measured (BENCHMARKS.md "20 scans per second", ARM): 0.014 px, 8.6e-4
and one status on the 9.2 ms frames; 0.014 px, 7.6e-4 and none on the 10 ms, smeared ones.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

from golden_scenes import MOTION, MOTION_PARTS, SCENES, measure, measure_motion, motion_triples, runs_of, scene_pairs

PRESET = "thesis-calibrated"
EXACT_FIELDS = ("column", "row", "quality", "points", "status")
SCAN_PLANE_RTOL = 1e-12
#: bounds for the moving scenes (module docstring): 0.02 px, under a third of the line's sub-pixel
#: error (0.069 px RMS, BENCHMARKS.md "Pipeline"), moves a range by up to ~1.5e-3 of itself at 2-3 m
MOTION_ROW_TOL_PX = 0.02
MOTION_RTOL = 2e-3
MOTION_ANGLE_TOL_RAD = 1e-5
MOTION_STATUS_MAX = 2
#: a Frame's metadata stored beside its image in frames.npz (the turn reads the rolling shutter
#: from the timestamps and line time: device/vision/fast.py readout_shares); lit: -1 unknown
FRAME_META = ("seq", "sensor_timestamp_ns", "exposure_us", "frame_duration_us", "line_time_ns", "readout_offset_rows",
              "lit")


def _stored(key: str, x) -> dict:
    """``x`` (a Frame or an array) as frames.npz keeps it: a Frame's image under ``key`` and its
    metadata under ``key|frame``."""
    from device.camera.frame import Frame

    if not isinstance(x, Frame):
        return {key: x}
    meta = [(-1 if x.lit is None else int(x.lit)) if f == "lit" else getattr(x, f) for f in FRAME_META]
    return {key: x.image, f"{key}|frame": np.array(meta, np.float64)}


def _loaded(stored, key: str):
    """What _stored kept under ``key``: the Frame again, or the array."""
    from device.camera.frame import Frame

    if f"{key}|frame" not in stored.files:
        return stored[key]
    seq, stamp, exposure, duration, line, offset, lit = stored[f"{key}|frame"]
    return Frame(stored[key], int(seq), int(stamp), float(exposure), float(duration), float(line),
                 None if lit < 0 else bool(lit), int(offset))


def frames(out_dir: Path) -> None:
    from device.config import load_preset
    from device.vision.pipelines import VARIANTS

    cfg = load_preset(PRESET)
    stored, out = {}, {}
    for scene in SCENES:
        pairs = scene_pairs(cfg, scene)
        for k, pair in enumerate(pairs):
            for part, x in zip(("lit", "unlit", "lit_rows"), pair):
                stored.update(_stored(f"{scene}|{k}|{part}", x))
        measure(cfg, scene, runs_of(pairs), VARIANTS, out)
        print(f"{scene}: {len(pairs)} pairs, {len(VARIANTS)} variants", flush=True)
    for point in MOTION:
        triples = motion_triples(cfg, point)
        for k, triple in enumerate(triples):
            for part, x in zip(MOTION_PARTS, triple):
                stored.update(_stored(f"{point}|{k}|{part}", x))
        measure_motion(cfg, point, triples, out)
        print(f"{point}: {len(triples)} lit frames with both neighbours, the device's pipeline", flush=True)
    np.savez(out_dir / "frames.npz", **stored)
    np.savez(out_dir / "x86_64.npz", **out)


def run(out_dir: Path) -> None:
    import platform

    from device.config import load_preset
    from device.vision.pipelines import VARIANTS

    cfg = load_preset(PRESET)
    stored = np.load(out_dir / "frames.npz")
    out = {}
    for scene in SCENES:
        count = sum(1 for key in stored.files if key.startswith(f"{scene}|") and key.endswith("|lit"))
        pairs = [tuple(_loaded(stored, f"{scene}|{k}|{part}") for part in ("lit", "unlit", "lit_rows")) for k in range(count)]
        measure(cfg, scene, runs_of(pairs), VARIANTS, out)
        print(f"{scene}: {count} pairs, {len(VARIANTS)} variants on {platform.machine()}", flush=True)
    for point in MOTION:
        count = sum(1 for key in stored.files if key.startswith(f"{point}|") and key.endswith("|lit"))
        triples = [tuple(_loaded(stored, f"{point}|{k}|{part}") for part in MOTION_PARTS) for k in range(count)]
        measure_motion(cfg, point, triples, out)
        print(f"{point}: {count} lit frames with both neighbours, the device's pipeline on {platform.machine()}", flush=True)
    np.savez(out_dir / f"{platform.machine()}.npz", **out)


def _apart(x: np.ndarray, y: np.ndarray, relative: bool) -> float | None:
    """The largest difference of ``x`` and ``y``'s finite values (relative to ``x``'s, or
    absolute), 0 if none is finite; None where their NaN and infinite values differ."""
    finite = np.isfinite(x)
    if not (np.array_equal(finite, np.isfinite(y)) and np.array_equal(x[~finite], y[~finite], equal_nan=True)):
        return None
    diff = np.abs(x[finite] - y[finite])
    if relative:
        diff = diff / np.maximum(np.abs(x[finite]), np.finfo(float).tiny)
    return float(diff.max()) if diff.size else 0.0


def _motion_frame(a, b, frame: str) -> tuple[list[str], dict]:
    """How the moving scene's lit frame ``frame`` ("point|variant|k") differs on aarch64: what
    exceeds the bounds (module docstring), and the largest differences."""
    fields = ("column", "row", "quality", "points", "range", "angle", "status")
    x, y = ({f: npz[f"{frame}|{f}"] for f in fields} for npz in (a, b))
    stats = {"identical": all(x[f].shape == y[f].shape and np.array_equal(x[f], y[f], equal_nan=x[f].dtype.kind == "f")
                              for f in EXACT_FIELDS)}
    if any(x[f].shape != y[f].shape or x[f].dtype != y[f].dtype for f in fields) or not np.array_equal(x["column"], y["column"]):
        return [f"{frame}: other columns, shapes or dtypes"], stats
    same = x["status"] == y["status"]
    stats["statuses"] = int((~same).sum())
    out = [f"{frame}: {stats['statuses']} columns of another status"] if stats["statuses"] > MOTION_STATUS_MAX else []
    bounds = {"row": MOTION_ROW_TOL_PX, "quality": 1.0, "angle": MOTION_ANGLE_TOL_RAD, "points": MOTION_RTOL,
              "range": MOTION_RTOL}
    for f, bound in bounds.items():
        apart = _apart(x[f][same], y[f][same], relative=f in ("points", "range"))
        if apart is None:
            out.append(f"{frame}|{f}: other NaN or infinite values")
            continue
        stats[f] = apart
        if apart > bound:
            out.append(f"{frame}|{f}: {stats[f]:.3g} apart (at most {bound:g})")
    return out, stats


def compare(out_dir: Path) -> int:
    a, b = np.load(out_dir / "x86_64.npz"), np.load(out_dir / "aarch64.npz")
    if set(a.files) != set(b.files):
        print(f"different arrays: {sorted(set(a.files) ^ set(b.files))[:10]}")
        return 1
    moving = sorted({key.rpartition("|")[0] for key in a.files if key.partition("|")[0] in MOTION})
    exact, differ, worst = 0, [], 0.0
    for key in sorted(a.files):
        if key.partition("|")[0] in MOTION:
            continue
        x, y = a[key], b[key]
        same = x.dtype == y.dtype and x.shape == y.shape
        if key.rpartition("|")[2] in EXACT_FIELDS:
            same = same and np.array_equal(x, y, equal_nan=x.dtype.kind == "f")
            exact += same
        elif same:  # NaN and infinite values alike, finite ones within the tolerance
            rel = _apart(x, y, relative=True)
            same = rel is not None and rel <= SCAN_PLANE_RTOL
            worst = max(worst, rel or 0.0)
        if not same:
            differ.append(key)
    moved, stats = [], []
    for frame in moving:
        problems, frame_stats = _motion_frame(a, b, frame)
        moved += problems
        stats.append(frame_stats)
    print(f"{exact} arrays of {', '.join(EXACT_FIELDS)}: identical bit for bit on aarch64 and x86-64; "
          f"angle and range: largest relative difference {worst:.2g} (at most {SCAN_PLANE_RTOL:g})")
    most = lambda key: max((st.get(key, 0.0) for st in stats), default=0.0)  # noqa: E731
    print(f"moving scenes: {sum(st['identical'] for st in stats)} of {len(stats)} lit frames' {', '.join(EXACT_FIELDS)} "
          "identical bit for bit; "
          f"at most {most('statuses'):g} column(s) of another status in a frame (at most {MOTION_STATUS_MAX}), rows "
          f"{most('row'):.2g} px apart (at most {MOTION_ROW_TOL_PX:g}), ranges {most('range'):.2g} (relative, at most "
          f"{MOTION_RTOL:g}), angles {most('angle'):.2g} rad (at most {MOTION_ANGLE_TOL_RAD:g}), qualities "
          f"{most('quality'):g} level(s)")
    if differ or moved:
        print(f"{len(differ)} of {len(a.files)} arrays differ, and {len(moved)} bounds are exceeded, e.g.:\n  "
              + "\n  ".join((differ + moved)[:20]))
        return 1
    return 0


if __name__ == "__main__":
    steps = {"frames": frames, "run": run, "compare": compare}
    if len(sys.argv) != 3 or sys.argv[1] not in steps:
        sys.exit(__doc__)
    sys.exit(steps[sys.argv[1]](Path(sys.argv[2])))
