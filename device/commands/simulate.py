"""`laserpi simulate`: render simulated frames of a scene with their ground truth.

Writes to ``--out DIR``: ``frames.npz`` (a recording ReplayCamera plays back), ``truth.npz``
(per frame: ``row`` (N, W), ``range_m``, ``angle_rad``, ``points`` (N, W, 3), ``surface``,
``lit_rows`` (N, H), ``time_ns`` (N, W): when each column's laser light came, NaN for a still
scene, where it does not matter, and where there is no return; ``range_span_m`` (N, W, 2): the
nearest and farthest range each column's light had during the exposure, NaN likewise (a moving
line may cross a depth jump: device.sim.truth.FrameTruth); ``seq`` (N,)), ``metadata.json`` (scene, configuration, seed, timing, render options,
sensor constants) and with ``--png`` ``scene.png``, the scene from above with the laser hits.
The laser fires on every ``--every``-th frame (a pulse schedule, see device/sim/pulses.py).
The sensor can move and the light flicker (``--yaw-rate-deg-s``, ``--speed-m-s``,
``--ambient-scale``, ``--flicker-hz``, ``--flicker-depth``, or the scene's own, device/sim/scene.py).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
from pathlib import Path

from host_sdk.commands.argtypes import positive_float

from .argtypes import add_motion_arguments, scene_with_motion

EFFECTS = ("noise", "speckle", "ambient", "gloss", "texture", "rolling_shutter")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from ..sim.scene import scene_names

    parser.add_argument("--scene", required=True,
                        help=f"built-in scene name ({', '.join(scene_names())}), "
                             "wall:distance=2,angle=30,reflectivity=0.1, or a scene .toml")
    parser.add_argument("--frames", type=int, default=4, help="number of frames (default 4)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--config", help="sensor configuration .toml (default: preset thesis-calibrated)")
    parser.add_argument("--out", required=True, help="output folder")
    parser.add_argument("--png", action="store_true", help="also draw the scene from above with the laser hits")
    parser.add_argument("--exposure-us", type=positive_float, default=40000.0)
    parser.add_argument("--frame-duration-us", type=positive_float, default=50000.0)
    parser.add_argument("--pulse-us", type=positive_float, help="laser pulse (default: the configuration's [laser] pulse_s)")
    parser.add_argument("--every", type=int, default=2, help="fire the laser on every N-th frame (default 2)")
    parser.add_argument("--jitter-us", type=float, default=0.0, help="mean SensorTimestamp latency (default 0)")
    parser.add_argument("--drop", type=float, default=0.0, help="probability that a frame is dropped (default 0)")
    parser.add_argument("--analog-gain", type=positive_float, default=None, help="sensor analog gain (default: simulator's)")
    parser.add_argument("--isp-denoise", type=float, default=0.0, help="ISP denoise strength 0..1 (default off)")
    parser.add_argument("--isp-sharpen", type=float, default=0.0, help="ISP sharpening amount 0..2 (default off)")
    parser.add_argument("--off", action="append", default=[], choices=EFFECTS, help="switch an effect off (repeatable)")
    add_motion_arguments(parser)


def run(args: argparse.Namespace) -> int:
    import numpy as np

    from device.camera.replay import save_npz, save_recording
    from device.config import ConfigError, load_config, load_preset
    from device.sim.camera import SimulatedCamera
    from device.sim.pulses import frame_aligned_train
    from device.sim.render import RenderOptions
    from device.sim.scene import SceneError, get_scene
    from device.sim.sensor import SIMULATOR_DEFAULT
    from device.sim.timing import CameraTimingConfig, quantise_frame_duration

    if args.frames < 1 or args.every < 1:
        print("error: --frames and --every must be >= 1")
        return 2
    try:
        cfg = load_config(args.config) if args.config else load_preset("thesis-calibrated")
        scene = scene_with_motion(get_scene(args.scene), args)
        sensor = SIMULATOR_DEFAULT if args.analog_gain is None else dataclasses.replace(SIMULATOR_DEFAULT, analog_gain=args.analog_gain)
    except (ConfigError, SceneError, ValueError) as exc:
        print(f"error: {exc}")
        return 2
    try:
        options = RenderOptions(isp_denoise=args.isp_denoise, isp_sharpen=args.isp_sharpen).without(*args.off)
    except ValueError as exc:
        print(f"error: {exc}")
        return 2
    pulse_us = args.pulse_us or cfg.laser.pulse_s * 1e6
    start_ns = 1_000_000_000
    try:
        if args.exposure_us > args.frame_duration_us:
            raise ValueError(f"--exposure-us {args.exposure_us} exceeds --frame-duration-us {args.frame_duration_us}")
        mode = cfg.window.mode  # the sensor reads all of the mode's rows and its blanking (device/camera/modes.py)
        if args.frame_duration_us < mode.min_frame_duration_s * 1e6:
            raise ValueError(f"--frame-duration-us {args.frame_duration_us:g} is shorter than the sensor mode "
                             f"{mode.name}'s shortest frame, {mode.min_frame_duration_s * 1e6:.0f} us "
                             f"({mode.min_frame_lines} lines)")
        timing = CameraTimingConfig(frame_duration_s=args.frame_duration_us * 1e-6, exposure_s=args.exposure_us * 1e-6,
                                    start_time_s=start_ns * 1e-9, timestamp_jitter_s=args.jitter_us * 1e-6,
                                    drop_probability=args.drop)
        frame_us = quantise_frame_duration(timing.frame_duration_s, timing.exposure_s, timing) * timing.line_time_s * 1e6
        train = frame_aligned_train(start_ns, frame_us, args.exposure_us, timing.line_time_s * 1e9,
                                    timing.active_rows, pulse_us, every=args.every)
        cam = SimulatedCamera(cfg, scene, train, timing=timing, seed=args.seed, options=options, sensor=sensor)
    except ValueError as exc:
        print(f"error: {exc}")
        return 2
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    cam.start()
    shots = [cam.capture_with_truth() for _ in range(args.frames)]
    cam.stop()
    frames, truths = [f for f, _ in shots], [t for _, t in shots]
    save_recording(out / "frames.npz", frames)
    nan = np.full(cfg.width, np.nan)
    save_npz(out / "truth.npz", seq=np.array([f.seq for f in frames]),
             time_ns=np.stack([nan if t.time_ns is None else t.time_ns for t in truths]),
             range_span_m=np.stack([np.full((cfg.width, 2), np.nan) if t.range_span_m is None else t.range_span_m
                                    for t in truths]),
             **{k: np.stack([getattr(t, k) for t in truths]) for k in ("row", "range_m", "angle_rad", "points", "surface",
                                                                       "lit_rows")})
    r = cam.renderer
    meta = {
        "scene": scene.name, "config": cfg.name, "seed": args.seed, "frames": args.frames,
        "width": cfg.width, "height": cfg.height, "exposure_us": args.exposure_us,
        "frame_duration_us": args.frame_duration_us, "pulse_us": pulse_us, "lit_every": args.every,
        "pulse_windows_ns": train.windows(start_ns - int(args.exposure_us * 1e3), frames[-1].sensor_timestamp_ns + 10**8),
        "ambient_w_m2": r.ambient_w_m2, "render_options": dataclasses.asdict(options),
        "sensor": dataclasses.asdict(sensor), "noise_model": "Gaussian shot (var = N_e) + read noise, 10-bit ADC, linear 8-bit Y",
        "lit": [f.lit for f in frames], "seq": [f.seq for f in frames], "simulated": True,
        "motion": {"yaw_rate_deg_s": math.degrees(scene.motion.yaw_rate_rad_s), "speed_m_s": scene.motion.speed_m_s,
                   "sensor_ahead_m": scene.motion.sensor_ahead_m, "objects_move": scene.objects_move},
        "ambient_scale": scene.ambient_scale, "flicker": dataclasses.asdict(scene.flicker),
    }
    (out / "metadata.json").write_text(json.dumps(meta, indent=1))
    valid = np.isfinite(truths[0].row)
    print(f"{args.frames} frames of scene {scene.name!r} -> {out} ({int(valid.sum())} columns with a return, "
          f"lit frames: {sum(bool(f.lit) for f in frames)})")
    if args.png:
        _plot(out / "scene.png", scene, truths[0], r)
        print(f"top view -> {out / 'scene.png'}")
    return 0


def _plot(path: Path, scene, truth, renderer) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    from device.sim.scene import Box, Cylinder, Wall

    fig, ax = plt.subplots(figsize=(7, 7))
    for s in scene.surfaces:
        shade = str(1 - 0.8 * s.material.reflectivity)
        if isinstance(s, Wall):
            ax.plot([s.start[0], s.end[0]], [s.start[1], s.end[1]], color=shade, lw=3)
        elif isinstance(s, Box):
            c = s.corners() + [s.corners()[0]]
            ax.fill([p[0] for p in c], [p[1] for p in c], color=shade, alpha=0.6)
        elif isinstance(s, Cylinder):
            ax.add_patch(plt.Circle(s.center, s.radius, color=shade, alpha=0.6))
    ok = np.isfinite(truth.row)
    frame = renderer.frame
    q = (truth.points[ok] - frame.origin) @ frame.rotation.T
    ax.scatter(q[:, 0], q[:, 1], s=1, color="red", zorder=3, label="laser hits seen by the camera")
    half = renderer.cfg.laser.fan_angle_rad / 2
    for a in (-half, half):
        ax.plot([0, 6 * math.cos(a)], [0, 6 * math.sin(a)], color="red", lw=0.5, ls=":")
    cam = renderer.camera_scan
    ax.plot([0], [0], "r^", label="laser")
    ax.plot([cam[0]], [cam[1]], "bs", label=f"camera (z = {cam[2]:.3f} m)")
    ax.set_aspect("equal")
    ax.set_xlabel("x forward (m)")
    ax.set_ylabel("y left (m)")
    ax.set_title(f"scene {scene.name} (scan frame, from above)")
    ax.legend(loc="upper right", fontsize=8)
    pts = np.concatenate([q[:, :2], [[0, 0]]]) if q.size else np.zeros((1, 2))
    span = max(1.0, float(np.abs(pts).max()) * 1.15)
    ax.set_xlim(-0.3 * span, span)
    ax.set_ylim(-span, span)
    fig.savefig(path, dpi=110)
    plt.close(fig)
