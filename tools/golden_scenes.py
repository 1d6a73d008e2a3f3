"""Every pipeline's output on 14 simulated scenes, to check that a refactor changes nothing.

    .venv/bin/python tools/golden_scenes.py dump before.npz      # on the old code
    .venv/bin/python tools/golden_scenes.py dump after.npz       # on the new code
    .venv/bin/python tools/golden_scenes.py compare before.npz after.npz

The scenes: every built-in scene plus four walls (distance x reflectivity), three frame pairs
each, processed in order by every variant (so tracked bands carry over), then one pair with its
lit rows withheld and one with lit and unlit swapped. And the moving scenes of MOTION (sweep points
of `laserpi bench motion`: turning, driving, flicker, a person crossing, a textured wall), three
lit frames each with both unlit neighbours, processed in order by the device's pipeline as the
device runs it (its depth limits, the unlit frame before the lit one as well: step 0, the checks
on a moved background and the turned neighbours, which a pair alone never reaches).  `compare`
demands equality bit for bit (NaNs equal) of every array and exits 1 naming the first differences
otherwise.
"""

from __future__ import annotations

import sys

import numpy as np

SCENES = ("wall", "room", "corridor", "clutter", "targets", "near", "far", "sunlight", "glossy-floor", "empty",
          "wall:distance=0.6,reflectivity=0.9", "wall:distance=2.5,reflectivity=0.1",
          "wall:distance=4,reflectivity=0.5", "wall:distance=1.2,reflectivity=0.3")
FIELDS = ("column", "row", "angle", "range", "quality", "points", "status")
#: sweep points of device/bench/motion.py SWEEP: turning (with the sensor ahead of the axis, in
#: 10x light while driving, with flicker), driving, a person crossing, the textured wall
MOTION = ("yaw 90", "yaw 180, 1 m/s, 10x", "flicker, yaw 90", "speed 1.0", "person, yaw 45, 0.1 m ahead",
          "poster wall, yaw 14")
#: the parts of a moving scene's frame triple, as stored: (lit, unlit after, lit rows, unlit before)
MOTION_PARTS = ("lit", "unlit", "lit_rows", "unlit_before")


def runs_of(pairs) -> list:
    """The frame pairs each variant processes, in order, from a scene's (lit, unlit, lit_rows)
    triples: each pair, then the first with its lit rows withheld and with lit and unlit swapped."""
    lit, unlit, rows = pairs[0]
    return list(pairs) + [(lit, unlit, None), (unlit, lit, rows)]


def scene_pairs(cfg, scene: str, pairs_per_scene: int = 3) -> list:
    """A scene's simulated (lit, unlit, lit_rows) triples."""
    from device.vision.evaluation import simulated_pairs

    return [(p.lit, p.unlit, p.lit_rows) for p in simulated_pairs(cfg, scene, pairs_per_scene, seed=3)]


def motion_triples(cfg, point: str, lit_frames: int = 3) -> list:
    """The sweep point's (lit, unlit after, lit rows, unlit before) of ``lit_frames`` lit frames."""
    from device.bench.motion import point_scene, sequence

    return [(p.lit, p.unlit, p.lit_rows, p.unlit_before) for p in sequence(cfg, point_scene(point), lit_frames, seed=3)]


def measure_motion(cfg, point: str, triples, out: dict) -> None:
    """The device's pipeline on a moving scene's ``triples`` into ``out`` under "point|pipeline|k|field"."""
    from device.vision.pipelines import DEVICE_VARIANT, make_pipeline

    op = cfg.operating_point
    pipe = make_pipeline(DEVICE_VARIANT, cfg, op.min_m, op.max_m)
    for k, (lit, unlit, rows, before) in enumerate(triples):
        meas = pipe.process(lit, unlit, lit_rows=rows, other_unlit=before)
        for f in FIELDS:
            out[f"{point}|{DEVICE_VARIANT}|{k}|{f}"] = np.asarray(getattr(meas, f))


def measure(cfg, scene: str, runs, variants, out: dict) -> None:
    """Every variant's output on ``runs`` into ``out`` under "scene|variant|run|field"."""
    from device.vision.pipelines import make_pipeline

    for name in variants:
        pipe = make_pipeline(name, cfg)
        for k, (lit, unlit, rows) in enumerate(runs):
            meas = pipe.process(lit, unlit, lit_rows=rows)
            for f in FIELDS:
                out[f"{scene}|{name}|{k}|{f}"] = np.asarray(getattr(meas, f))


def dump(path: str, pairs_per_scene: int = 3) -> None:
    from device.config import load_preset
    from device.vision.pipelines import VARIANTS

    cfg = load_preset("thesis-calibrated")
    out = {}
    for scene in SCENES:
        measure(cfg, scene, runs_of(scene_pairs(cfg, scene, pairs_per_scene)), VARIANTS, out)
        print(f"{scene}: {len(VARIANTS)} variants x {pairs_per_scene + 2} pairs", flush=True)
    for point in MOTION:
        measure_motion(cfg, point, motion_triples(cfg, point), out)
        print(f"{point}: the device's pipeline x 3 lit frames with both neighbours", flush=True)
    np.savez_compressed(path, **out)
    print(f"wrote {len(out)} arrays to {path}")


def compare(a_path: str, b_path: str) -> int:
    a, b = np.load(a_path), np.load(b_path)
    differ = sorted(set(a.files) ^ set(b.files))
    for key in sorted(set(a.files) & set(b.files)):
        x, y = a[key], b[key]
        if x.dtype != y.dtype or x.shape != y.shape or not np.array_equal(x, y, equal_nan=x.dtype.kind == "f"):
            differ.append(key)
    if differ:
        print(f"{len(differ)} of {len(a.files)} arrays differ, e.g.:\n  " + "\n  ".join(differ[:20]))
        return 1
    print(f"all {len(a.files)} arrays identical, bit for bit")
    return 0


if __name__ == "__main__":
    if len(sys.argv) == 3 and sys.argv[1] == "dump":
        dump(sys.argv[2])
    elif len(sys.argv) == 4 and sys.argv[1] == "compare":
        sys.exit(compare(sys.argv[2], sys.argv[3]))
    else:
        sys.exit(__doc__)
