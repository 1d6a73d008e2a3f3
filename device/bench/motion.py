"""`laserpi bench motion`: the sensor on a moving robot (issue 16), reference against fast.

Every sweep point renders one simulated sequence (device/sim/render.py step 9): the scene
(``office``: a bright, textured near-infrared background; ``person``: a person crossing) at the
device's operating point (the configuration's [operating_point]: exposure, gain, depth range;
20 frames/s, every other frame lit by a pulse covering every row's exposure, as
device/service/assembly.py places it), the sensor turning and driving at the point's yaw rate and
speed (mounted on the robot's turning axis, or 0.1 m ahead of it where the point says so: a turn
then also moves it sideways), in the point's ambient light (x the default indoor) with or without 100 Hz flicker
(depth 0.3). Each lit frame is processed

- ``reference``: the thesis pipeline, lit minus the unlit frame after it;
- ``fast one-unlit``: the device's pipeline before issue 16 (fast-com-track, lit minus the unlit
  frame after it);
- ``fast no turn``: the device's pipeline with both unlit neighbours (device/scan/pairing.py,
  device.vision.fast step 0: the checks on a moved background) and the range gate (step 5), but
  the neighbours never turned to the lit frame (``turn_share`` inf);
- ``fast``: the device's pipeline now (device/vision/pipelines.py DEVICE_VARIANT): as ``fast no turn``,
  and the unlit neighbours turned to the lit frame when the robot turns (device/vision/yaw.py).

Measured against the truth at each column's light's time: gross errors (a valid range > 5 %
off the truth) as a share of the columns with a true return; false returns (a valid range where
there is none); false "too close" (-inf, an obstacle nearer than the region of interest, where
the truth has none that near: it stops a robot as a false return does); valid share of the
columns with a true return; "blind" columns (+inf, "nothing there", where there is a surface);
the range error's sigma (%, valid columns without the gross errors). Speed beside it: CPU time
per lit frame of each variant on the still office scene, on the office turning at 90 deg/s and
driving at 1 m/s, all in 3x light (median of ``--repeats`` calls after one untimed call, one
thread, the variants interleaved call by call), and its ratio to ``fast one-unlit``. And the static
accuracy as ``laserpi bench pipeline`` measures it (fast-com, 90 % walls at 2 m and 3 m, the
simulator's 40 ms exposure), with one unlit frame and with both neighbours, on the same frames.
And the simulator's own cost: the wall-clock time per sweep point to render its sequence, per lit
frame (``render_s_per_lit_frame``; the renderer's setup and the unlit neighbours included).
"""

from __future__ import annotations

import argparse
import json
import math
import platform
import time

#: (label, scene, yaw deg/s, speed m/s, ambient x indoor, flicker depth, sensor ahead of the
#: robot's turning axis m)
SWEEP = (
    ("still", "office", 0, 0.0, 3, 0.0, 0.0),
    ("yaw 14", "office", 14, 0.0, 3, 0.0, 0.0),
    ("yaw 45", "office", 45, 0.0, 3, 0.0, 0.0),
    ("yaw 90", "office", 90, 0.0, 3, 0.0, 0.0),
    ("yaw 180", "office", 180, 0.0, 3, 0.0, 0.0),
    ("yaw 90, 0.1 m ahead", "office", 90, 0.0, 3, 0.0, 0.1),
    ("speed 0.5", "office", 0, 0.5, 3, 0.0, 0.0),
    ("speed 1.0", "office", 0, 1.0, 3, 0.0, 0.0),
    ("yaw 90, 1x", "office", 90, 0.0, 1, 0.0, 0.0),
    ("yaw 90, 10x", "office", 90, 0.0, 10, 0.0, 0.0),
    ("yaw 180, 1 m/s, 10x", "office", 180, 1.0, 10, 0.0, 0.0),
    ("flicker", "office", 0, 0.0, 3, 0.3, 0.0),
    ("flicker, yaw 90", "office", 90, 0.0, 3, 0.3, 0.0),
    ("person", "person", 0, 0.0, 3, 0.0, 0.0),
    ("person, yaw 45", "person", 45, 0.0, 3, 0.0, 0.0),
    ("person, yaw 45, 0.1 m ahead", "person", 45, 0.0, 3, 0.0, 0.1),
    ("poster wall", "poster-wall", 0, 0.0, 3, 0.0, 0.0),
    ("poster wall, yaw 14", "poster-wall", 14, 0.0, 3, 0.0, 0.0),
    ("poster wall, yaw 90", "poster-wall", 90, 0.0, 3, 0.0, 0.0),
)
VARIANTS = ("reference", "fast one-unlit", "fast no turn", "fast")
#: the variants that take both unlit neighbours
BOTH_NEIGHBOURS = {"fast no turn", "fast"}
#: the sweep points the variants are timed on (the office in 3x light)
TIMED = ("still", "yaw 90", "speed 1.0")
FLICKER_HZ = 100.0


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--frames", type=int, default=3, help="lit frames per sweep point (default 3)")
    parser.add_argument("--repeats", type=int, default=30, help="timed calls per variant (default 30)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--preset", default="thesis-calibrated")
    parser.add_argument("--points", help="semicolon-separated labels of the sweep points to run (labels hold commas; "
                                         "default all)")
    parser.add_argument("--png", help="write the plot to this PNG")
    parser.add_argument("--json", action="store_true", help="print the results as JSON")


def sequence(cfg, scene, lit_frames: int, seed: int, options=None):
    """(lit, unlit after, unlit before, truth) of ``lit_frames`` lit frames at the operating point
    (``options``: the renderer's RenderOptions, default its defaults)."""
    from ..vision.evaluation import simulated_pairs

    op = cfg.operating_point
    pulse_us = op.exposure_us + (cfg.height - 1) * cfg.window.mode.line_time_ns * 1e-3  # every row's whole exposure
    return simulated_pairs(cfg, scene, lit_frames, seed, options=options, exposure_us=op.exposure_us,
                           analog_gain=op.analog_gain, pulse_us=pulse_us, neighbours=True)


def point_scene(label: str):
    """The scene of the sweep point ``label`` (SWEEP), moving as the point says."""
    from ..sim.scene import get_scene, with_motion

    rows = {row[0]: row for row in SWEEP}
    if label not in rows:
        raise ValueError(f"no sweep point {label!r}; the points: {'; '.join(rows)}")
    _, scene_name, yaw, speed, ambient, flicker, ahead = rows[label]
    return with_motion(get_scene(scene_name), yaw_rate_deg_s=yaw, speed_m_s=speed, ambient_scale=ambient,
                       flicker_hz=FLICKER_HZ, flicker_depth=flicker, sensor_ahead_m=ahead)


def _pipelines(cfg):
    from ..vision.pipelines import DEVICE_VARIANT, make_pipeline

    op = cfg.operating_point
    device = make_pipeline(DEVICE_VARIANT, cfg, op.min_m, op.max_m)
    return {"reference": make_pipeline("reference", cfg),
            "fast one-unlit": make_pipeline("fast-com-track", cfg, op.min_m, op.max_m),
            "fast no turn": _no_turn(device),
            "fast": device}


def _no_turn(pipe):
    """``pipe`` (a FastPipeline) with its unlit neighbours never turned to the lit frame
    (``turn_share`` inf): the checks on a moved background alone, as for a motion no turn
    explains (driving, a person crossing)."""
    import dataclasses

    from ..vision.fast import FastPipeline

    g = pipe.geometry
    return FastPipeline(pipe.config, dataclasses.replace(pipe.params, turn_share=math.inf), g.min_m, g.max_m)


def _process(name, pipe, pair):
    if name in BOTH_NEIGHBOURS:
        return pipe.process(pair.lit, pair.unlit, pair.lit_rows, other_unlit=pair.unlit_before)
    return pipe.process(pair.lit, pair.unlit, pair.lit_rows)


def score(meas_truths, min_m: float) -> dict:
    """Gross errors, false returns, valid share, blind share, sigma (the module docstring), and
    false "too close" (-inf): columns reported nearer than ``min_m`` (the region of interest's
    near end) where the truth is not, an obstacle that is not there."""
    import numpy as np

    from ..vision.evaluation import GROSS_ERROR_REL, nearest_true_range, range_error_rel
    from ..vision.measurements import ColumnStatus

    n_true = n_empty = valid = gross = false = blind = false_close = 0
    rel = []
    for meas, truth in meas_truths:
        c = meas.column
        has = np.isfinite(truth.row[c]) & np.isfinite(truth.range_m[c])
        ok = meas.valid & np.isfinite(meas.range)
        e = range_error_rel(meas.range, truth, c)
        n_true += int(has.sum())
        n_empty += int((~has).sum())
        valid += int((has & ok).sum())
        false += int((~has & ok).sum())
        bad = has & ok & (np.abs(e) > GROSS_ERROR_REL)
        gross += int(bad.sum())
        blind += int((has & (meas.status == ColumnStatus.NO_RETURN)).sum())
        with np.errstate(invalid="ignore"):
            false_close += int(((meas.status == ColumnStatus.TOO_CLOSE) & ~(nearest_true_range(truth, c) < min_m)).sum())
        rel.append(e[has & ok & ~bad])
    rel = np.concatenate(rel) if rel else np.zeros(0)
    return {"columns_with_return": n_true, "columns_without_return": n_empty,
            "valid_fraction": valid / n_true if n_true else float("nan"),
            "gross_fraction": gross / n_true if n_true else float("nan"), "gross": gross, "false_returns": false,
            "false_too_close": false_close,
            "blind_fraction": blind / n_true if n_true else float("nan"),
            "sigma_pct": float(np.std(rel) * 100) if rel.size > 1 else float("nan")}


def measure(args) -> dict:
    import cv2

    from ..config import load_preset

    cv2.setNumThreads(1)
    cfg = load_preset(args.preset)
    wanted = wanted_points(args.points)
    points = []
    timed = {}
    for label, scene_name, yaw, speed, ambient, flicker, ahead in SWEEP:
        if wanted is not None and label not in wanted:
            continue
        started = time.perf_counter()
        pairs = sequence(cfg, point_scene(label), args.frames, args.seed)
        render_s = (time.perf_counter() - started) / args.frames
        if label in TIMED:
            timed[label] = pairs[0]
        row = {"point": label, "scene": scene_name, "yaw_deg_s": yaw, "speed_m_s": speed, "ambient_x": ambient,
               "flicker_depth": flicker, "sensor_ahead_m": ahead, "render_s_per_lit_frame": render_s}
        for name, pipe in _pipelines(cfg).items():
            row[name] = score([(_process(name, pipe, p), p.truth) for p in pairs], cfg.operating_point.min_m)
        points.append(row)
    for label in TIMED:
        if label not in timed:
            timed[label] = sequence(cfg, point_scene(label), 1, args.seed)[0]
    ms = {label: _ms_per_lit_frame(cfg, pair, args.repeats) for label, pair in timed.items()}
    return {"points": points, "ms_per_lit_frame": ms["still"], "ms_per_moving_lit_frame": ms["yaw 90"],
            "ms_per_driving_lit_frame": ms["speed 1.0"],
            "static": static_accuracy(cfg, args.frames, args.seed),
            "ratio_vs_one_unlit": ms["still"]["fast"] / ms["still"]["fast one-unlit"],
            "operating_point": {"exposure_us": cfg.operating_point.exposure_us,
                                "analog_gain": cfg.operating_point.analog_gain}}


def _ms_per_lit_frame(cfg, pair, repeats: int) -> dict[str, float]:
    """CPU ms per call of each variant on ``pair``: the median of ``repeats`` calls, the variants
    interleaved call by call (each round in another order), so that what the machine does
    meanwhile falls on all of them alike: their ratio is what is compared."""
    pipes = _pipelines(cfg)
    times: dict[str, list[float]] = {name: [] for name in pipes}
    names = list(pipes)
    for name in names:  # what a pipeline builds at its first frame (fast: the turn's grid) is not timed
        _process(name, pipes[name], pair)
    for k in range(max(repeats, 1)):
        for name in names[k % len(names):] + names[:k % len(names)]:
            t0 = time.thread_time()
            _process(name, pipes[name], pair)
            times[name].append(time.thread_time() - t0)
    return {name: sorted(t)[len(t) // 2] * 1e3 for name, t in times.items()}


def static_accuracy(cfg, frames: int, seed: int) -> dict:
    """Range error (1 sigma, %) of fast-com on still 90 % walls, one unlit frame against both."""
    from ..vision.evaluation import FramePair, run_pipeline, simulated_pairs
    from ..vision.pipelines import make_pipeline

    out = {}
    for i, d in enumerate((2, 3)):
        pairs = simulated_pairs(cfg, f"wall:distance={d},reflectivity=0.9", frames, seed + i, neighbours=True)
        one = [FramePair(p.lit, p.unlit, p.truth, p.lit_rows) for p in pairs]
        for label, pp in (("one-unlit", one), ("both", pairs)):
            score = run_pipeline(make_pipeline("fast-com", cfg), pp)
            out[f"{label} {d} m"] = {"sigma_pct": score.range_error_near(float(d))[1],
                                     "valid_fraction": score.summary()["valid_fraction"]}
    return out


def targets(result: dict) -> list[str]:
    """The issue's targets, each met or not, with the worst number; judged on the sweep points
    run (``--points``): a target met on some of its points says how many."""
    out = []
    fast = [(p, p["fast"]) for p in result["points"]]
    worst_g = max((s["gross_fraction"] for _, s in fast), default=float("nan"))
    worst_f = max((s["false_returns"] + s["false_too_close"] for _, s in fast), default=0)
    out.append(f"{_verdict(worst_g <= 0.001 and worst_f == 0, fast, lambda row: True)}: gross errors <= 0.1 % of "
               f"the columns with a return, no false returns, up to 180 deg/s, 1 m/s, 10x ambient (worst gross "
               f"{worst_g * 100:.2f} %, worst false returns and false 'too close' {worst_f})")
    judged = lambda yaw, speed, ambient: yaw <= 90 and ambient <= 3 and speed == 0  # noqa: E731
    slow = [(p, s) for p, s in fast if judged(p["yaw_deg_s"], p["speed_m_s"], p["ambient_x"])]
    worst_v = min((s["valid_fraction"] for _, s in slow), default=float("nan"))
    worst_at = min(slow, key=lambda ps: ps[1]["valid_fraction"])[0]["point"] if slow else "-"
    out.append(f"{_verdict(worst_v >= 0.9, slow, lambda row: judged(row[2], row[3], row[4]))}: valid >= 90 % of "
               f"the wall's columns up to 90 deg/s at 3x ambient, every scene (worst {worst_v * 100:.1f} %, {worst_at})")
    r = result["ratio_vs_one_unlit"]
    out.append(f"{'MET' if r <= 1.5 else 'NOT MET'}: pipeline time <= 1.5x today's on a still scene ({r:.2f}x)")
    return out


def _verdict(ok: bool, run: list, belongs) -> str:
    """MET or NOT MET; MET on only some of the SWEEP points ``belongs`` to the target (a SWEEP
    row -> bool) says on how many of them."""
    needed = [row[0] for row in SWEEP if belongs(row)]
    ran = {p["point"] for p, _ in run}
    if not ok:
        return "NOT MET"
    return "MET" if ran >= set(needed) else f"MET on {len(ran & set(needed))} of its {len(needed)} sweep points (the rest not run)"


def _plot(result: dict, path: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    pts = result["points"]
    x = np.arange(len(pts))
    fig, axes = plt.subplots(3, 1, figsize=(9, 8), sharex=True)
    colours = {"reference": "tab:red", "fast one-unlit": "tab:orange", "fast no turn": "tab:green", "fast": "tab:blue"}
    w = 0.8 / len(VARIANTS)
    for k, name in enumerate(VARIANTS):
        at = x + (k - (len(VARIANTS) - 1) / 2) * w
        axes[0].bar(at, [p[name]["gross_fraction"] * 100 for p in pts], w, color=colours[name],
                    label=f"{name} ({result['ms_per_lit_frame'][name]:.2f} ms)")
        axes[1].bar(at, [p[name]["false_returns"] + p[name]["false_too_close"] for p in pts], w,
                    color=colours[name])
        axes[2].bar(at, [p[name]["valid_fraction"] * 100 for p in pts], w, color=colours[name])
    axes[0].axhline(0.1, color="k", lw=0.8, ls="--")
    axes[0].set_yscale("symlog", linthresh=0.1)
    axes[0].set_ylabel("gross errors\n(% of columns\nwith a return)")
    axes[1].set_ylabel("false returns and\nfalse 'too close'\n(columns)")
    axes[2].axhline(90, color="k", lw=0.8, ls="--")
    axes[2].set_ylabel("valid (%)")
    axes[2].set_xticks(x, [p["point"] for p in pts], rotation=35, ha="right", fontsize=8)
    axes[0].legend(fontsize=8, title="variant (CPU per lit frame, still scene)", title_fontsize=8)
    axes[0].set_title("LaserPi on a moving robot (simulated; office, person and poster-wall scenes; dashed: the targets)")
    for ax in axes:
        ax.grid(True, axis="y", alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def run(args: argparse.Namespace) -> int:
    from ..config import ConfigError

    try:
        if min(args.frames, args.repeats) < 1:
            raise ValueError("--frames and --repeats must be >= 1")
        result = measure(args)
    except (ConfigError, ValueError) as exc:
        print(f"laserpi bench motion: {exc}")
        return 2
    if args.json:
        print(json.dumps(result, indent=2))
    else:
        _print(result, args.frames)
    if args.png:
        _plot(result, args.png)
    return 0


def wanted_points(points: str | None) -> set[str] | None:
    """The sweep points' labels ``--points`` names (separated by semicolons: labels hold commas),
    None for all; an unknown label is refused, naming the choices."""
    if not points:
        return None
    wanted = {p.strip() for p in points.split(";") if p.strip()}
    unknown = wanted - {s[0] for s in SWEEP}
    if unknown or not wanted:
        raise ValueError(f"unknown sweep point(s) {', '.join(sorted(unknown)) or repr(points)}; choose from "
                         f"{'; '.join(s[0] for s in SWEEP)}")
    return wanted


def _print(result: dict, frames: int) -> None:
    op = result["operating_point"]
    print(f"machine: {platform.processor() or platform.machine()}, python {platform.python_version()}, OpenCV 1 thread; "
          f"exposure {op['exposure_us']:g} us, gain {op['analog_gain']:g}, {frames} lit frame(s) per point")
    f = lambda v, s: "-" if v is None or (isinstance(v, float) and math.isnan(v)) else format(v, s)  # noqa: E731
    w = max(len(p["point"]) for p in result["points"]) if result["points"] else 5
    print(f"{'point':<{w}} {'variant':<15} {'gross %':>8} {'false':>6} {'close':>6} {'valid %':>8} {'blind %':>8} "
          f"{'sigma %':>8}")
    for p in result["points"]:
        for name in VARIANTS:
            s = p[name]
            print(f"{p['point'] if name == VARIANTS[0] else '':<{w}} {name:<15} {f(s['gross_fraction'] * 100, '8.2f')} "
                  f"{s['false_returns']:>6d} {s['false_too_close']:>6d} {f(s['valid_fraction'] * 100, '8.1f')} "
                  f"{f(s['blind_fraction'] * 100, '8.1f')} {f(s['sigma_pct'], '8.2f')}")
    ms, moving = result["ms_per_lit_frame"], result["ms_per_moving_lit_frame"]
    print("CPU per lit frame (still office scene): " + ", ".join(f"{n} {ms[n]:.3f} ms" for n in VARIANTS)
          + f"; fast / fast one-unlit = {result['ratio_vs_one_unlit']:.2f}")
    print("CPU per lit frame (office, turning 90 deg/s): " + ", ".join(f"{n} {moving[n]:.3f} ms" for n in VARIANTS)
          + f"; fast / fast one-unlit = {moving['fast'] / moving['fast one-unlit']:.2f}")
    driving = result["ms_per_driving_lit_frame"]
    print("CPU per lit frame (office, driving 1 m/s): " + ", ".join(f"{n} {driving[n]:.3f} ms" for n in VARIANTS)
          + f"; fast / fast one-unlit = {driving['fast'] / driving['fast one-unlit']:.2f}")
    print("simulator, wall-clock s to render a lit frame with its unlit neighbours (the renderer's setup included): "
          + ", ".join(f"{p['point']} {p['render_s_per_lit_frame']:.1f}" for p in result["points"]))
    print("still 90 % walls, fast-com (range error 1 sigma, valid): " + ", ".join(
        f"{k} {v['sigma_pct']:.3f} % {v['valid_fraction']:.3f}" for k, v in result["static"].items()))
    for line in targets(result):
        print(line)
