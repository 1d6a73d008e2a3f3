"""`laserpi bench pipeline`: every pipeline variant on the same simulated frames, in one run.

Time per frame pair: the median CPU time of the calling thread (``time.thread_time``) over
``--repeats`` calls of ``process`` on one pair, OpenCV limited to one thread; CPU time rather than
wall time because the machine is shared (a loaded machine stretches wall time, not CPU time) next to the error against ground truth on 90 % walls at 2 m and 3 m (indoor light,
thesis-calibrated geometry), and the speed-up over the reference as a ratio.

Two times per variant: back to back (``ms_per_pair``: the calls follow each other, so each finds
the caches as the last one left them), and after a pause (``ms_per_pair_after_idle``: each call
after the thread slept ``IDLE_S``, as the device's thread waits between frames). On this machine
(a VM whose caches empty within a few milliseconds, whatever the thread does) the fast pipeline
costs ~1.6-2x as much after the pause (BENCHMARKS.md "Device process", "Correction"); the device
process (`laserpi bench process`) pays the second.
"""

from __future__ import annotations

import argparse
import json
import math
import platform
import time

#: The pause before each call of the "after idle" time: one frame interval at 40 frames/s (20
#: scans/s), the device's wait for its next frame.
IDLE_S = 0.025


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--frames", type=int, default=3, help="frame pairs per wall for the error (default 3)")
    parser.add_argument("--repeats", type=int, default=50, help="timed calls per variant (default 50)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--preset", default="thesis-calibrated")
    parser.add_argument("--min-range", type=float, default=0.1, help="fast pipeline depth limits, m (default 0.1)")
    parser.add_argument("--max-range", type=float, default=10.0, help="(default 10)")
    parser.add_argument("--variants", default="all", help="comma-separated variants (default all)")
    parser.add_argument("--defocused", action="store_true",
                        help="render with the lens defocused (device.sim.render.COHERENT_DEFOCUSED) instead of in focus")
    parser.add_argument("--png", help="write a plot of time against error to this PNG")
    parser.add_argument("--json", action="store_true", help="print the results as JSON")


def measure(args) -> list[dict]:
    import cv2

    from ..config import load_preset
    from ..sim.render import COHERENT_DEFOCUSED
    from ..vision.evaluation import run_pipeline, simulated_pairs
    from ..vision.pipelines import VARIANTS, make_pipeline

    cv2.setNumThreads(1)  # one core
    cfg = load_preset(args.preset)
    names = list(VARIANTS) if args.variants == "all" else [v.strip() for v in args.variants.split(",")]
    if "reference" not in names:
        names.insert(0, "reference")
    pipes = {n: make_pipeline(n, cfg, args.min_range, args.max_range) for n in names}
    options = COHERENT_DEFOCUSED if args.defocused else None
    walls = {d: simulated_pairs(cfg, f"wall:distance={d},reflectivity=0.9", args.frames, args.seed + i, options=options)
             for i, d in enumerate((2, 3))}
    timing_pair = walls[2][0]
    rows = []
    for name, pipe in pipes.items():
        s2 = run_pipeline(pipe, walls[2])
        s3 = run_pipeline(pipe, walls[3])
        call = lambda: pipe.process(timing_pair.lit, timing_pair.unlit, lit_rows=timing_pair.lit_rows)  # noqa: E731
        ms, _ = _median_ms(call, args.repeats)
        ms_after_idle, _ = _median_ms(call, args.repeats, pause_s=IDLE_S)
        sum2, sum3 = s2.summary(), s3.summary()
        n2, n3 = sum2["columns_with_return"], sum3["columns_with_return"]
        rows.append({
            "variant": name,
            "ms_per_pair": ms,
            "ms_per_pair_after_idle": ms_after_idle,
            "subpixel_rms_px": sum2["subpixel_rms_px"],
            "range_err_pct_2m": s2.range_error_near(2.0)[1],
            "range_err_pct_3m": s3.range_error_near(3.0)[1],
            "valid_fraction": (sum2["valid_fraction"] * n2 + sum3["valid_fraction"] * n3) / (n2 + n3),
            "resolution_deg": float(getattr(pipe, "resolution_deg", float("nan"))),
        })
    ref_ms = next(r["ms_per_pair"] for r in rows if r["variant"] == "reference")
    for r in rows:
        r["speedup_vs_reference"] = ref_ms / r["ms_per_pair"]
    return rows


def triangulation_timing(args) -> dict:
    """Table triangulation against direct backward projection for one row per column."""
    import numpy as np

    from ..config import load_preset
    from ..model.camera import undistort_robust
    from ..model.triangulation import intersect_plane
    from ..vision.geometry import column_geometry

    cfg = load_preset(args.preset)
    g = column_geometry(cfg, args.min_range, args.max_range)
    rows = np.random.default_rng(args.seed).uniform(g.top, g.bottom - 1, cfg.width)
    px = np.stack([np.arange(cfg.width, dtype=float), rows], axis=-1)

    def direct():
        return intersect_plane(undistort_robust(px, cfg.camera).xy, cfg.plane, g.min_m, g.max_m)

    out = {}
    for name, fn in (("table", lambda: g.triangulate(rows)), ("direct", direct)):
        ms, res = _median_ms(fn, args.repeats)
        out[name] = (ms, res.depth)
    ok = np.isfinite(out["table"][1]) & np.isfinite(out["direct"][1])
    err = np.abs(out["table"][1][ok] - out["direct"][1][ok]) / out["direct"][1][ok]
    return {"table_ms": out["table"][0], "direct_ms": out["direct"][0], "max_rel_depth_diff": float(err.max())}


def _median_ms(fn, repeats: int, pause_s: float = 0.0):
    """(median thread CPU ms of ``repeats`` calls of ``fn``, each after ``pause_s`` asleep; the
    last call's result)."""
    import numpy as np

    times = []
    for _ in range(max(repeats, 1)):
        if pause_s:
            time.sleep(pause_s)
        t0 = time.thread_time()
        res = fn()
        times.append(time.thread_time() - t0)
    return float(np.median(times) * 1e3), res


def _plot(rows: list[dict], path: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7, 4.5))
    for r in rows:
        ax.scatter(r["ms_per_pair"], r["range_err_pct_2m"], color="tab:red" if r["variant"] == "reference" else "tab:blue")
    ax.set_xscale("log")
    ax.set_xlabel("CPU time per frame pair (ms, one thread, log)")
    ax.set_ylabel("range error at 2 m, 1 sigma (%)")
    ax.set_title("LaserPi pipelines on simulated 90 % walls: speed against error")
    ax.grid(True, which="both", alpha=0.3)
    ax.margins(x=0.2, y=0.12)
    fig.tight_layout()
    # labels: the first of four places around the point that lies inside the axes and overlaps
    # no label placed before (the last one regardless)
    renderer = fig.canvas.get_renderer()
    inside = ax.get_window_extent(renderer)
    offsets = ((5, 4), (5, -12), (-5, 4), (-5, -12))
    placed = []
    for r in sorted(rows, key=lambda r: r["ms_per_pair"]):
        for i, (dx, dy) in enumerate(offsets):
            label = ax.annotate(r["variant"], (r["ms_per_pair"], r["range_err_pct_2m"]), textcoords="offset points",
                                xytext=(dx, dy), fontsize=8, ha="left" if dx > 0 else "right")
            box = label.get_window_extent(renderer)
            free = inside.contains(box.x0, box.y0) and inside.contains(box.x1, box.y1)
            if i == len(offsets) - 1 or (free and not any(box.overlaps(b) for b in placed)):
                break
            label.remove()
        placed.append(box)
    fig.savefig(path, dpi=120)
    plt.close(fig)


def run(args: argparse.Namespace) -> int:
    from ..config import ConfigError

    if args.frames < 1 or args.repeats < 1:
        print("laserpi bench pipeline: --frames and --repeats must be >= 1")
        return 2
    try:
        rows = measure(args)
    except (ConfigError, ValueError) as exc:
        print(f"laserpi bench pipeline: {exc}")
        return 2
    if args.png:
        _plot(rows, args.png)
    keys = ("variant", "ms_per_pair", "ms_per_pair_after_idle", "speedup_vs_reference", "subpixel_rms_px", "range_err_pct_2m",
            "range_err_pct_3m", "valid_fraction", "resolution_deg")
    if args.json:
        print(json.dumps([{k: r[k] for k in keys} for r in rows], indent=2))
        return 0
    print(f"machine: {platform.processor() or platform.machine()}, python {platform.python_version()}, OpenCV 1 thread")
    print(f"{'variant':<18} {'ms/pair':>8} {'idle ms':>8} {'speed-up':>9} {'subpx RMS':>10} {'err 2m %':>9} "
          f"{'err 3m %':>9} {'valid':>6} {'res deg':>8}")
    for r in rows:
        f = lambda v, s: "-" if v is None or (isinstance(v, float) and math.isnan(v)) else format(v, s)
        print(f"{r['variant']:<18} {f(r['ms_per_pair'], '8.2f')} {f(r['ms_per_pair_after_idle'], '8.2f')} "
              f"{f(r['speedup_vs_reference'], '8.1f')}x "
              f"{f(r['subpixel_rms_px'], '10.3f')} {f(r['range_err_pct_2m'], '9.2f')} {f(r['range_err_pct_3m'], '9.2f')} "
              f"{f(r['valid_fraction'], '6.3f')} {f(r['resolution_deg'], '8.2f')}")
    print(f"idle ms: each call after {IDLE_S * 1e3:g} ms asleep, as the device's thread waits for its next frame")
    t = triangulation_timing(args)
    print(f"triangulation, one sub-pixel row per column: table {t['table_ms']:.3f} ms, direct (robust backward projection) "
          f"{t['direct_ms']:.3f} ms, largest relative depth difference {t['max_rel_depth_diff']:.1e}")
    return 0
