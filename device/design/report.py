"""The design report of a sensor configuration: range limits, resolution table, camera-tilt sweep,
eye safety and background light (thesis 3.5 steps 1-6, 4.1.3-4.1.5, 4.2.3), and both at 10, 15
and 20 scans/s.

``design_report`` computes; ``format_report`` renders the readable table that
``laserpi design`` prints. No I/O here.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np

from device.design import limits
from device.model import envelope as envelope_model
from device.model import irradiance, safety

#: Thesis 4.1.4: no eye gets closer than 1 cm to the source.
CLOSEST_EYE_M = 0.010
#: Thesis 4.1.3 / Figure 4.2 sweep settings.
SWEEP_ALPHAS_DEG = (50.0, 120.0, 1.0)
SWEEP_SUBPIXEL = 0.2
SWEEP_MAX_RESOLUTION = 0.01
SWEEP_MIN_RANGE_OVER_S = 25.0
SWEEP_COLUMN_STEP = 16
#: Thesis requirement 3: > 2 m detection range.
TARGET_RANGE_M = 2.0
#: Background-limited range: the return at 1 % of the background (Figure 4.4).
BACKGROUND_FRACTION = 0.01
#: Scan rates of the eye-safety and range table, scans/s (a lit and an unlit frame each).
SCAN_RATES_HZ = (10.0, 15.0, 20.0)


@dataclass(frozen=True)
class RatePoint:
    """Eye safety and range at one scan rate, one pulse of ``pulse_s`` per scan (the longest the
    sensor fires: device/service/assembly.py's laser_pulse_s).

    ``class1_power_w``: the largest Class 1 peak power of that regular train; ``envelope``: the
    co-MCU firmware envelope for it (device/model/envelope.py: pulses up to ``pulse_s``, at least
    1 / rate - SYNC_SLACK_S apart), and ``envelope_power_w`` the largest power at which every
    train that envelope allows is Class 1 (at most ``class1_power_w``: it also allows denser
    trains of shorter pulses); ``power_w``: the laser's power capped at that; the distances where
    its return falls to BACKGROUND_FRACTION of the background (eq. 3.46, Figure 4.4) at that
    power. ``frames_fit``: the sensor mode runs 2 x ``scan_rate_hz`` frames/s (device/camera/modes.py)."""

    scan_rate_hz: float
    pulse_s: float
    frames_fit: bool
    class1_power_w: float
    envelope: envelope_model.FirmwareEnvelope
    envelope_power_w: float
    power_w: float
    background_range_m: float
    background_range_indoor_m: float


@dataclass(frozen=True)
class DesignReport:
    name: str
    geometry: limits.RangeGeometry
    q_min_m: float
    q_max_m: float                      # +inf when the horizon is inside the principal column
    subpixels: np.ndarray
    ranges_m: np.ndarray
    resolution: np.ndarray              # (S, D) relative; NaN where not seen
    columns: limits.ColumnLimits | None
    sweep: limits.AlphaSweep | None
    safety: safety.SafetyAssessment
    background_w_m2: float
    background_range_m: float           # outdoor, return = 1 % of background
    background_range_indoor_m: float
    rates: tuple[RatePoint, ...] = ()
    max_scan_rate_hz: float = math.nan  # the sensor mode's frame-rate limit / 2


def laser_of(cfg) -> safety.PulsedLineLaser:
    """The safety model's laser from a configuration's [laser] table."""
    las = cfg.laser
    return safety.PulsedLineLaser(
        wavelength_nm=las.wavelength_m * 1e9, pulse_s=las.pulse_s, rate_hz=las.rate_hz,
        fan_rad=las.fan_angle_rad, line_height_m=las.line_height_m, source_diameter_m=las.source_diameter_m)


def principal_limits(geom: limits.RangeGeometry) -> tuple[float, float]:
    """(q_min, q_max) on the column through the principal point (docs/thesis-notes.md N5), metres."""
    col = limits.column_limits(geom, geom.principal_column)
    return float(col.q_min[0]), float(col.q_max[0])


def rate_points(cfg, rates_hz=SCAN_RATES_HZ) -> tuple[RatePoint, ...]:
    """:class:`RatePoint` of ``cfg`` at each scan rate, for the pulse the device fires for the
    operating point's exposure and region of interest."""
    from device.service.assembly import laser_limit_mw, laser_pulse_s, roi_rows
    from device.vision.geometry import column_geometry

    op, mode = cfg.operating_point, cfg.window.mode
    pulse_s = laser_pulse_s(cfg, *roi_rows(column_geometry(cfg, op.min_m, op.max_m)))
    background = irradiance.band_irradiance_w_m2(cfg.laser.wavelength_m * 1e9, cfg.optics.bandpass_width_m * 1e9)
    las = cfg.laser
    optics = envelope_model.LineLaserOptics(las.wavelength_m * 1e9, las.fan_angle_rad, las.line_height_m,
                                            las.source_diameter_m)
    points = []
    for rate in rates_hz:
        limit_w = laser_limit_mw(cfg, pulse_s, CLOSEST_EYE_M, rate) * 1e-3
        envelope = envelope_model.envelope_for(pulse_s, 1.0 / rate - envelope_model.SYNC_SLACK_S)
        envelope_w = envelope_model.envelope_max_power_w(optics, CLOSEST_EYE_M, envelope)
        power_w = min(las.power_w, envelope_w)
        points.append(RatePoint(float(rate), pulse_s, 2 * rate <= mode.max_frame_rate_hz, limit_w, envelope, envelope_w,
                                power_w, _background_range_m(cfg, power_w, background),
                                _background_range_m(cfg, power_w, irradiance.INDOOR_FRACTION * background)))
    return tuple(points)


def sensor_at_rate(cfg, rate_hz: float):
    """``cfg`` made to run at ``rate_hz`` scans/s, and the co-MCU firmware envelope it needs
    (:class:`RatePoint`): its [laser] pulsed at that rate at the laser's power capped at the
    envelope's Class 1 power, its [operating_point] at that rate. ConfigError if the sensor mode
    cannot run that fast."""
    from device.config import with_operating_point

    (point,) = rate_points(cfg, (rate_hz,))
    laser = dataclasses.replace(cfg.laser, rate_hz=float(rate_hz), power_w=point.power_w)
    return with_operating_point(dataclasses.replace(cfg, laser=laser), scan_rate_hz=float(rate_hz)), point.envelope


def _background_range_m(cfg, power_w: float, background_w_m2: float) -> float:
    return irradiance.background_limited_distance_m(power_w, background_w_m2, BACKGROUND_FRACTION,
                                                    cfg.laser.fan_angle_rad, cfg.laser.line_height_m)


def design_report(cfg, subpixels, ranges_m, *, sweep: bool = True, columns: bool = True,
                  rates: bool = True) -> DesignReport:
    """Everything ``laserpi design`` shows for ``cfg`` (a :class:`device.config.SensorConfig`)."""
    geom = limits.geometry_from_config(cfg)
    q_min, q_max = principal_limits(geom)
    subpixels = np.asarray(subpixels, dtype=float)
    ranges_m = np.asarray(ranges_m, dtype=float)
    table = limits.resolution_table(geom, subpixels, ranges_m)
    col = None
    if columns:
        col = limits.column_limits(geom, np.r_[np.arange(0, geom.columns, SWEEP_COLUMN_STEP), geom.columns - 1])
    sw = None
    if sweep:
        lo, hi, step = SWEEP_ALPHAS_DEG
        sw = limits.alpha_sweep(
            cfg.camera, geom.rows,
            np.r_[np.arange(0, geom.columns, SWEEP_COLUMN_STEP), geom.principal_column],
            np.radians(np.arange(lo, hi + step / 2, step)), subpixel=SWEEP_SUBPIXEL,
            max_resolution=SWEEP_MAX_RESOLUTION, min_range_over_s=SWEEP_MIN_RANGE_OVER_S, beta=cfg.beta_rad)
    laser = laser_of(cfg)
    assessment = safety.assess(laser, CLOSEST_EYE_M, cfg.laser.power_w)
    background = irradiance.band_irradiance_w_m2(cfg.laser.wavelength_m * 1e9, cfg.optics.bandpass_width_m * 1e9)

    return DesignReport(cfg.name, geom, q_min, q_max, subpixels, ranges_m, table, col, sw, assessment, background,
                        _background_range_m(cfg, cfg.laser.power_w, background),
                        _background_range_m(cfg, cfg.laser.power_w, irradiance.INDOOR_FRACTION * background),
                        rate_points(cfg) if rates else (), cfg.window.mode.max_frame_rate_hz / 2)


def _mm(x: float) -> str:
    return "unbounded" if math.isinf(x) else ("n/a" if math.isnan(x) else f"{x * 1e3:.1f} mm")


def format_report(rep: DesignReport) -> str:
    """The readable design report (a plain-text table)."""
    g = rep.geometry
    p = g.params
    a, b, c = g.plane.to_abc()
    k = g.camera.intrinsics
    out = [f"LaserPi design report: {rep.name}", ""]
    out.append(f"image {g.columns}x{g.rows} px, fx {k.fx:.3f} fy {k.fy:.3f} cx {k.cx:.3f} cy {k.cy:.3f}")
    out.append(f"laser plane z = a x + b y + c: a {a:.5f}, b {b:.5f}, c {c * 1e3:.3f} mm")
    out.append(f"triangulation (section 3.2.2, beta {math.degrees(p.beta):.2f} deg): alpha {math.degrees(p.alpha):.2f} deg, "
               f"theta {math.degrees(p.theta):.2f} deg, psi {math.degrees(p.psi):.2f} deg, s {p.s * 1e3:.2f} mm")
    out.append("")
    out.append(f"range on the principal column (u = {g.principal_column:.1f} px, rows 0..{g.rows - 1}):")
    out.append(f"  min(q) {_mm(rep.q_min_m)}   max(q) {_mm(rep.q_max_m)}")
    if rep.columns is not None:
        finite = rep.columns.q_max[np.isfinite(rep.columns.q_max)]
        out.append(f"  over {rep.columns.columns.size} sampled columns: min(q) {_mm(float(np.nanmin(rep.columns.q_min)))} .. "
                   f"{_mm(float(np.nanmax(rep.columns.q_min)))}; horizon inside "
                   f"{int(np.sum(np.isinf(rep.columns.q_max)))} columns"
                   + (f", elsewhere max(q) >= {_mm(float(finite.min()))}" if finite.size else ""))
    out.append("")
    out.append("resolution, % of distance (docs/thesis-notes.md N5: principal column, min of the two sigma-neighbours):")
    out.append("  sub-px " + "".join(f"{r * 1e3:>10.0f} mm" for r in rep.ranges_m))
    for s, row in zip(rep.subpixels, rep.resolution):
        out.append(f"  {s:6.2f} " + "".join("       n/a   " if not np.isfinite(v) else f"{v * 100:10.3f} % " for v in row))
    if rep.sweep is not None:
        sw = rep.sweep
        out.append("")
        out.append(f"camera tilt sweep (Figure 4.2: ideal model, s = 1, beta = psi = 90 deg, sigma {SWEEP_SUBPIXEL} px, "
                   f"resolution < {SWEEP_MAX_RESOLUTION:.0%}, q > {SWEEP_MIN_RANGE_OVER_S:g} s, "
                   f"{sw.columns.size} columns):")
        if math.isfinite(sw.best_alpha):
            out.append(f"  best alpha {math.degrees(sw.best_alpha):.2f} deg: the whole field of view reaches q = "
                       f"{sw.best_usable:.2f} s; baseline for {TARGET_RANGE_M:g} m: "
                       f"s >= {limits.baseline_for_range(TARGET_RANGE_M, sw.best_usable) * 1e3:.1f} mm")
        else:
            out.append("  no tilt in the sweep meets the constraints on every column")
        infeasible = sw.alphas[~sw.feasible]
        raw = np.where(sw.feasible, -np.inf, np.nan_to_num(sw.usable, nan=-np.inf))
        if infeasible.size and np.isfinite(raw.max()):
            k = int(np.argmax(raw))
            out.append(f"  (tilts >= {math.degrees(infeasible.min()):.0f} deg put the laser axis behind the camera, theta <= 0: "
                       f"no usable laser plane; best of those q = {sw.usable[k]:.2f} s at {math.degrees(sw.alphas[k]):.0f} deg)")
    sa = rep.safety
    lim = sa.limit
    out.append("")
    out.append(f"eye safety (IEC 60825-1 Class 1, section 3.3; eye no closer than {sa.closest_eye_m * 1e3:g} mm):")
    out.append(f"  subtense {lim.subtense_mrad:.2f} mrad, C4 {lim.c4:.4f}, C6 {lim.c6:.4f}, T2 {lim.t2_s:.2f} s, "
               f"N {lim.pulses_in_t2}, C5 {lim.c5:.3f}")
    out.append(f"  per-pulse limits: single {lim.single_pulse_j * 1e6:.1f} uJ, average {lim.average_power_j * 1e6:.1f} uJ, "
               f"train {lim.pulse_train_j * 1e6:.1f} uJ -> {lim.limiting_condition} limits")
    out.append(f"  max power {safety.mw_down(sa.max_power_w):.2f} mW; NOHD of the {sa.power_w * 1e3:g} mW laser {sa.nohd_m * 1e3:.2f} mm: "
               + ("Class 1" if sa.class1 else "NOT Class 1"))
    out.append("")
    out.append(f"background (ASTM G173 AM1.5 global, {rep.background_w_m2 / 10:.2f} mW/cm^2 in the bandpass):")
    out.append(f"  return falls to {BACKGROUND_FRACTION:.0%} of the background at {_mm(rep.background_range_m)} outdoors, "
               f"{_mm(rep.background_range_indoor_m)} indoors ({irradiance.INDOOR_FRACTION:.0%} of outdoor)")
    if rep.rates:
        out.append("")
        out.append(f"scan rate (a lit and an unlit frame per scan; the sensor mode allows at most "
                   f"{rep.max_scan_rate_hz:.2f} scans/s), pulses up to {rep.rates[0].pulse_s * 1e3:.2f} ms, one per scan:")
        out.append("  scans/s   Class 1 max: this train   its firmware envelope   laser power   "
                   "range at 1 % of background: outdoors   indoors")
        for r in rep.rates:
            out.append(f"  {r.scan_rate_hz:7g}   {safety.mw_down(r.class1_power_w):20.2f} mW   {safety.mw_down(r.envelope_power_w):18.2f} mW   "
                       f"{safety.mw_down(r.power_w):8.2f} mW   {_mm(r.background_range_m):>33}   {_mm(r.background_range_indoor_m):>9}"
                       + ("" if r.frames_fit else "   (too fast for the sensor mode)"))
        out.append("  the firmware envelope of each rate, built into a directory of its own (flash the co-MCU with its "
                   "ELF, firmware_pwm/BUILD/laserpi_pwm.elf, to run at that rate; `laserpi serve --simulate --firmware` "
                   "runs it in the emulator):")
        out.extend(f"  {r.scan_rate_hz:7g}   {r.envelope.make_command()}" for r in rep.rates)
    return "\n".join(out)
