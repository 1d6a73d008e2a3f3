"""`laserpi sync-sim`: laser-camera synchronisation against a simulated camera clock and co-MCU.

Runs our controller (free-running camera, MCU phase and period trimmed through the GPIO clock
map) and/or the thesis's scheme (Algorithm 1 start estimate + P controller on the frame rate,
eq. 5.1-5.3, open loop in drift) through the same simulator and scores them against ground truth.
Error = distance between the pulse edges and the ROI's exposure window, over frames labelled
lit after the first lock. All figures are simulated (noise model: device/sim/timing.py and
device/sim/mcu.py).
"""

from __future__ import annotations

import argparse
import json

from host_sdk.commands.argtypes import nonnegative_float, positive_float

KEYS = ("lock_frames", "p99_error_us", "p99_error_us_settled", "max_error_us", "median_error_us", "pulse_us",
        "frames_lit_after_lock", "frames_partly_unlit_after_lock", "frames_leaked_after_lock",
        "frames_unknown_after_lock", "frames_in_error_state", "final_state")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--seconds", type=positive_float, default=60.0, help="simulated time (default 60)")
    parser.add_argument("--drift-ppm", type=float, default=100.0, help="MCU clock error against the Pi's (default 100)")
    parser.add_argument("--wander-ppm", type=nonnegative_float, default=0.0, help="amplitude of a 600 s sinusoidal drift wander")
    parser.add_argument("--gpio-jitter-us", type=nonnegative_float, default=20.0,
                        help="mean GPIO interrupt latency excess, exponential (default 20)")
    parser.add_argument("--no-gpio", action="store_true", help="no GPIO wire: the clock map falls back to PING")
    parser.add_argument("--camera-jitter-us", type=nonnegative_float, default=10.0, help="mean SensorTimestamp latency (default 10)")
    parser.add_argument("--drop-prob", type=nonnegative_float, default=1e-3, help="probability of a dropped frame (default 0.001)")
    parser.add_argument("--fps", type=positive_float, default=20.0, help="camera frame rate (default 20: 10 Hz scans, every other frame lit)")
    parser.add_argument("--exposure-us", type=positive_float, default=5000.0, help="exposure (default 5000)")
    parser.add_argument("--roi-rows", type=int, nargs=2, default=(300, 700), metavar=("MIN", "MAX"),
                        help="rows the laser can land on (default 300 700)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--controller", choices=("ours", "thesis"), default=None,
                        help="run one controller (default: ours with --json, both side by side without)")
    parser.add_argument("--json", action="store_true", help="print one JSON object")
    parser.set_defaults(_parser=parser)


def _params(args: argparse.Namespace, controller: str):
    from device.sim.mcu import McuConfig
    from device.sim.timing import CameraTimingConfig
    from device.sync.simulate import SimParams

    rmin, rmax = args.roi_rows
    rows = CameraTimingConfig.active_rows
    if not 0 <= rmin <= rmax < rows:
        args._parser.error(f"--roi-rows must satisfy 0 <= MIN <= MAX < {rows}, got {rmin} {rmax}")
    camera = CameraTimingConfig(frame_duration_s=1.0 / args.fps, exposure_s=args.exposure_us * 1e-6, clock_ppm=30.0,
                                timestamp_jitter_s=args.camera_jitter_us * 1e-6, drop_probability=min(args.drop_prob, 0.5))
    mcu = McuConfig(drift_ppm=args.drift_ppm, wander_ppm=args.wander_ppm, gpio_jitter_s=args.gpio_jitter_us * 1e-6,
                    gpio_connected=not args.no_gpio)
    return SimParams(seconds=args.seconds, controller=controller, seed=args.seed, camera=camera, mcu=mcu,
                     row_min=rmin, row_max=rmax)


def run(args: argparse.Namespace) -> int:
    from device.sync.placement import check_separation, class1_power_w, pulse_budget
    from device.sync.simulate import run as simulate

    controllers = [args.controller] if args.controller else (["ours"] if args.json else ["ours", "thesis"])
    params = _params(args, controllers[0])
    try:
        check_separation(params.camera.frame_duration_s, params.camera.exposure_s, params.camera.line_time_s,
                         params.row_min, params.row_max)
    except ValueError as exc:
        args._parser.error(str(exc))
    results = {c: simulate(_params(args, c)).metrics for c in controllers}
    budget = pulse_budget(params.camera.exposure_s, params.camera.line_time_s, params.row_min, params.row_max,
                          params.camera.frame_duration_s, params.pattern)
    power = {}
    for c, m in results.items():
        pulse_s = (m["pulse_us"] or 0.0) * 1e-6
        power[c] = class1_power_w(pulse_s, budget.pulse_rate_hz) * 1e3 if pulse_s > 0 else None
    thesis_mw = class1_power_w(budget.thesis_pulse_s, budget.pulse_rate_hz) * 1e3
    if args.json:
        out = dict(results[controllers[0]])
        out["class1_power_mw"] = power[controllers[0]]
        out["thesis_pulse_us"] = budget.thesis_pulse_s * 1e6
        out["thesis_class1_power_mw"] = thesis_mw
        print(json.dumps(out))
        return 0
    print(f"simulated {args.seconds:g} s at {args.fps:g} fps, MCU drift {args.drift_ppm:g} ppm, GPIO latency jitter "
          f"{args.gpio_jitter_us:g} us{' (no GPIO wire: ping fallback)' if args.no_gpio else ''}, seed {args.seed}")
    print(f"ROI rows {params.row_min}-{params.row_max}, exposure {args.exposure_us:g} us: ROI window "
          f"{budget.pulse_s * 1e6:.1f} us, every other frame lit ({budget.pulse_rate_hz:g} pulses/s)")
    names = {"ours": "ours (closed loop)", "thesis": "thesis (Alg. 1 + P)"}
    print(f"{'':32}" + "".join(f"{names[c]:>22}" for c in controllers))
    for key in KEYS:
        print(f"{key:32}" + "".join(f"{_fmt(results[c].get(key)):>22}" for c in controllers))
    print(f"{'class1_power_mw (10 mm NOHD)':32}" + "".join(f"{_fmt(power[c]):>22}" for c in controllers))
    print(f"thesis's 17.4 ms pulse at {budget.pulse_rate_hz:g} Hz: duty {budget.thesis_duty:.3f}, "
          f"Class 1 power {thesis_mw:.1f} mW")
    return 0


def _fmt(v) -> str:
    if v is None:
        return "-"
    if isinstance(v, float):
        return f"{v:.2f}"
    return str(v)
