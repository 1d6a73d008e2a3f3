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
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

from golden_scenes import SCENES, measure, runs_of, scene_pairs

PRESET = "thesis-calibrated"
EXACT_FIELDS = ("column", "row", "quality", "points", "status")
SCAN_PLANE_RTOL = 1e-12


def frames(out_dir: Path) -> None:
    from device.config import load_preset
    from device.vision.pipelines import VARIANTS

    cfg = load_preset(PRESET)
    stored, out = {}, {}
    for scene in SCENES:
        pairs = scene_pairs(cfg, scene)
        for k, (lit, unlit, rows) in enumerate(pairs):
            stored.update({f"{scene}|{k}|lit": lit, f"{scene}|{k}|unlit": unlit, f"{scene}|{k}|lit_rows": rows})
        measure(cfg, scene, runs_of(pairs), VARIANTS, out)
        print(f"{scene}: {len(pairs)} pairs, {len(VARIANTS)} variants", flush=True)
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
        pairs = [tuple(stored[f"{scene}|{k}|{part}"] for part in ("lit", "unlit", "lit_rows")) for k in range(count)]
        measure(cfg, scene, runs_of(pairs), VARIANTS, out)
        print(f"{scene}: {count} pairs, {len(VARIANTS)} variants on {platform.machine()}", flush=True)
    np.savez(out_dir / f"{platform.machine()}.npz", **out)


def compare(out_dir: Path) -> int:
    a, b = np.load(out_dir / "x86_64.npz"), np.load(out_dir / "aarch64.npz")
    if set(a.files) != set(b.files):
        print(f"different arrays: {sorted(set(a.files) ^ set(b.files))[:10]}")
        return 1
    exact, differ, worst = 0, [], 0.0
    for key in sorted(a.files):
        x, y = a[key], b[key]
        same = x.dtype == y.dtype and x.shape == y.shape
        if key.rpartition("|")[2] in EXACT_FIELDS:
            same = same and np.array_equal(x, y, equal_nan=x.dtype.kind == "f")
            exact += same
        elif same:  # NaN and infinite values alike, finite ones within the tolerance
            finite = np.isfinite(x)
            same = np.array_equal(finite, np.isfinite(y)) and np.array_equal(x[~finite], y[~finite], equal_nan=True)
            if same and finite.any():
                rel = float(np.max(np.abs(x[finite] - y[finite]) / np.maximum(np.abs(x[finite]), np.finfo(float).tiny)))
                worst = max(worst, rel)
                same = rel <= SCAN_PLANE_RTOL
        if not same:
            differ.append(key)
    print(f"{exact} arrays of {', '.join(EXACT_FIELDS)}: identical bit for bit on aarch64 and x86-64; "
          f"angle and range: largest relative difference {worst:.2g} (at most {SCAN_PLANE_RTOL:g})")
    if differ:
        print(f"{len(differ)} of {len(a.files)} arrays differ, e.g.:\n  " + "\n  ".join(differ[:20]))
        return 1
    return 0


if __name__ == "__main__":
    steps = {"frames": frames, "run": run, "compare": compare}
    if len(sys.argv) != 3 or sys.argv[1] not in steps:
        sys.exit(__doc__)
    sys.exit(steps[sys.argv[1]](Path(sys.argv[2])))
