"""Every pipeline's output on 14 simulated scenes, to check that a refactor changes nothing.

    .venv/bin/python tools/golden_scenes.py dump before.npz      # on the old code
    .venv/bin/python tools/golden_scenes.py dump after.npz       # on the new code
    .venv/bin/python tools/golden_scenes.py compare before.npz after.npz

The scenes: every built-in scene plus four walls (distance x reflectivity), three frame pairs
each, processed in order by every variant (so tracked bands carry over), then one pair with its
lit rows withheld and one with lit and unlit swapped.  `compare` demands equality bit for bit
(NaNs equal) of every array and exits 1 naming the first differences otherwise.
"""

from __future__ import annotations

import sys

import numpy as np

SCENES = ("wall", "room", "corridor", "clutter", "targets", "near", "far", "sunlight", "glossy-floor", "empty",
          "wall:distance=0.6,reflectivity=0.9", "wall:distance=2.5,reflectivity=0.1",
          "wall:distance=4,reflectivity=0.5", "wall:distance=1.2,reflectivity=0.3")
FIELDS = ("column", "row", "angle", "range", "quality", "points", "status")


def runs_of(pairs) -> list:
    """The frame pairs each variant processes, in order, from a scene's (lit, unlit, lit_rows)
    triples: each pair, then the first with its lit rows withheld and with lit and unlit swapped."""
    lit, unlit, rows = pairs[0]
    return list(pairs) + [(lit, unlit, None), (unlit, lit, rows)]


def scene_pairs(cfg, scene: str, pairs_per_scene: int = 3) -> list:
    """A scene's simulated (lit, unlit, lit_rows) triples."""
    from device.vision.evaluation import simulated_pairs

    return [(p.lit, p.unlit, p.lit_rows) for p in simulated_pairs(cfg, scene, pairs_per_scene, seed=3)]


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
