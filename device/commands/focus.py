"""`laserpi focus`: focus the lens on the laser line, on a headless Pi over SSH.

    laserpi focus                              # on the Pi: live bars in the terminal, Ctrl-C to stop
    laserpi focus --png band.png               # also save the band with the detected line (each update)
    laserpi focus --simulate --seconds 10      # the simulated sensor (here)

It runs the sensor as `laserpi serve` does (camera, the laser pulsed in step by the co-MCU), but
instead of serving scans shows, for each lit/unlit pair, the laser line's width (FWHM across
rows) and peak in column regions of the image, and the width the optics give in focus at
``--distance-m`` (device/vision/focus.py) with the lens blur the accuracy figures assume (the
simulator's in-focus lens, device/sim/render.py ``RenderOptions.blur_sigma_px``), beside the
diffraction limit no M12 lens reaches. Point the sensor at a wall at that distance and turn
the focus ring until every region's width is down at the target and its peak is highest.
"""

from __future__ import annotations

import argparse
import math
import sys
import time

from host_sdk.commands.argtypes import nonnegative_float, positive_float

BAR = 40  # characters of the widest bar (4 x the target width)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--distance-m", type=positive_float, default=2.0,
                        help="distance of the wall focused on (target width; the simulated wall's distance with "
                             "--simulate)")
    parser.add_argument("--regions", type=int, default=16, help="column regions, a bar each (default 16)")
    parser.add_argument("--seconds", type=nonnegative_float, default=0.0,
                        help="stop after this long (default: until Ctrl-C)")
    parser.add_argument("--updates", type=int, default=0, help="stop after this many updates (default: no limit)")
    parser.add_argument("--png", metavar="FILE", help="save the band of the image the line is searched in, with the "
                                                      "detected line in red, at every update")
    parser.add_argument("--config", metavar="TOML", help="sensor configuration file")
    parser.add_argument("--preset", default="thesis-calibrated", help="sensor configuration preset (without --config)")
    parser.add_argument("--comcu", metavar="DEV", default="/dev/serial0", help="serial device of the co-MCU")
    parser.add_argument("--gpio-edge", metavar="CHIP:LINE", default=None, help="GPIO line of the laser trigger (as for serve)")
    parser.add_argument("--simulate", action="store_true", help="the simulated sensor, a wall at --distance-m")


def render(regions, target_px: float, detail: str) -> str:
    """The terminal picture: a bar per region, its length the line width (``|`` marks the target)."""
    scale = BAR / (4 * target_px)
    mark = min(BAR - 1, round(target_px * scale))
    lines = [f"laser line focus: target width {target_px:.2f} px ({detail})",
             f"{'columns':>11}  {'width (| = in focus)':<{BAR}}  {'px':>5}  {'peak':>5}"]
    for r in regions:
        if math.isnan(r.width_px):
            bar, w, p = " " * BAR, "  -  ", "  -  "
        else:
            n = min(BAR, max(1, round(r.width_px * scale)))
            bar = "".join("|" if i == mark else ("#" if i < n else " ") for i in range(BAR))
            w, p = f"{r.width_px:5.2f}", f"{r.peak:5.0f}"
        lines.append(f"{r.first:>5}-{r.last:<5}  {bar}  {w}  {p}")
    return "\n".join(lines)


def save_band(path: str, lit, unlit, row_lo, row_hi, regions) -> None:
    """The rows the line is searched in, lit minus unlit stretched to 0-255, the peak rows in red."""
    import cv2
    import numpy as np

    from device.vision.focus import column_widths

    top, bottom = int(row_lo.min()), int(row_hi.max())
    diff = lit.astype(np.float32) - unlit.astype(np.float32)
    band = diff[top:bottom]
    grey = np.clip(255 * band / max(1.0, float(band.max())), 0, 255).astype(np.uint8)
    img = cv2.cvtColor(grey, cv2.COLOR_GRAY2BGR)
    width, _ = column_widths(diff, row_lo, row_hi, min_peak=8.0)
    rows = np.where(np.isfinite(width), np.argmax(np.where(np.arange(diff.shape[0])[:, None] >= row_lo, diff, -np.inf), axis=0), -1)
    for c in np.nonzero(rows >= top)[0]:
        img[rows[c] - top, c] = (0, 0, 255)
    if not cv2.imwrite(path, img):
        raise OSError(f"could not write {path}")


def run(args: argparse.Namespace) -> int:
    import numpy as np

    from device.service.assembly import AssemblyConfig, build_sensor, sensor_config
    from device.sim.render import RenderOptions
    from device.vision.focus import focused_width_px, region_focus

    try:
        built = build_sensor(AssemblyConfig(simulate=args.simulate, config_path=args.config, preset=args.preset,
                                            comcu=args.comcu, gpio_edge=args.gpio_edge, distance_m=args.distance_m))
    except (ValueError, OSError, RuntimeError) as exc:
        print(f"laserpi focus: {exc}")
        return 2
    source = built.source
    geometry = source.pipeline.pipeline.geometry
    cfg = sensor_config(args.config, args.preset)
    width = cfg.active_width or cfg.width
    row_lo, row_hi = np.asarray(geometry.roi_lo)[:width], np.asarray(geometry.roi_hi)[:width]
    try:
        target = focused_width_px(cfg, args.distance_m, RenderOptions().blur_sigma_px)
        if not 1 <= args.regions <= width:
            raise ValueError(f"--regions must be in 1..{width}, got {args.regions}")
    except ValueError as exc:
        print(f"laserpi focus: {exc}")
        for close in reversed(built.closers):
            close()
        return 2
    limit = focused_width_px(cfg, args.distance_m)
    detail = (f"in focus at {args.distance_m:g} m with the lens blur the accuracy figures assume; "
              f"diffraction limit {limit:.2f} px")
    latest = {}
    scan = source.pipeline

    def tap(lit, dark, other_dark=None):
        latest["pair"] = (lit.image[:, :width], dark.image[:, :width])
        return scan(lit, dark, other_dark)

    source.pipeline = tap
    source.apply(built.settings)
    tty = sys.stdout.isatty()
    updates = 0
    end = time.monotonic() + args.seconds if args.seconds > 0 else math.inf
    source.start()
    try:
        while time.monotonic() < end and not (args.updates and updates >= args.updates):
            if source.next_scan(0.5) is None or "pair" not in latest:
                continue
            lit, unlit = latest.pop("pair")
            regions = region_focus(lit, unlit, row_lo, row_hi, args.regions)
            text = render(regions, target, detail)
            print(("\x1b[H\x1b[2J" if tty else "") + text + ("" if tty else "\n"), flush=True)
            if args.png:
                save_band(args.png, lit, unlit, row_lo, row_hi, regions)
            updates += 1
    except KeyboardInterrupt:
        pass
    finally:
        source.stop()
        for close in reversed(built.closers):
            close()
    if updates == 0:
        print("laserpi focus: no lit/unlit frame pair (is the laser synchronised? laserpi doctor)")
        return 1
    return 0
