"""Build the whole sensor (device.scan.source.SensorSource) from its parts, on a Pi or simulated.

On a Pi: Picamera2Camera -> SyncedLaser (co-MCU on a UART) -> fast pipeline.
Simulated (``laserpi serve --simulate``): the same SensorSource, SyncedLaser and pipeline, with
the simulated hardware of device/sim:
* the camera: the scene renderer on the simulated clock, timed by the IMX219 timing simulation
  (device/sim/timing.py: line-quantised frame length, timestamp latency, dropped frames) --
  device/sim/camera.py's SimulatedCamera, delivering frames in simulated real time;
* the Pi's clock and the co-MCU: the shipped firmware ELF in the simavr harness behind a pty
  (device/sim/hardware.py's SimulatedHardware), opened by CoMcu through pyserial as on a Pi.

Operating point (both), from the configuration's ``[operating_point]`` (device/config.py): by
default 20 frames/s, every other frame lit (docs/thesis-notes.md N10), so 10 scans/s; the
exposure and analogue gain; the depth range narrows the region of interest (rows where the line
can land) and so the pulse, which must fit the firmware's compiled-in eye-safety envelope.
"""

from __future__ import annotations

import functools
import logging
import time
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from device.config import SensorConfig, load_config, load_preset, with_operating_point
from device.laser.comcu import open_comcu
from device.scan.pipeline import ScanPipeline
from device.scan.source import SensorSource
from protocol import messages as m
from protocol.server import ScanGeometry

if TYPE_CHECKING:
    from device.sim.hardware import SimulatedHardware

log = logging.getLogger(__name__)

COMMAND_LATENCY_S = 0.02  # worst request round trip to the co-MCU seen here (emulator pty: median 3 ms, max 20 ms)


# --- assembly ---------------------------------------------------------------------------------
def sensor_config(config_path: str | None, preset: str) -> SensorConfig:
    return load_config(config_path) if config_path else load_preset(preset)


def roi_rows(geometry) -> tuple[int, int]:
    """First and last image row of the pipeline's region of interest (any of the image's columns:
    not the frame buffer's padding, geometry.active_width)."""
    image = slice(0, geometry.active_width)
    return int(geometry.roi_lo[image].min()), int(geometry.roi_hi[image].max()) - 1


def laser_pulse_s(cfg: SensorConfig, row_min: int, row_max: int) -> float:
    """The longest pulse the sensor fires (s): one exposure plus the readout of rows row_min..row_max
    (rolling shutter: the pulse covers the exposure of every row of the region of interest), or the
    [laser] pulse_s if longer (the sync's guards widen the pulse up to that)."""
    return max(cfg.operating_point.exposure_us * 1e-6 + (row_max - row_min) * cfg.window.mode.line_time_s,
               cfg.laser.pulse_s)


def envelope_refusal(cfg: SensorConfig, pulse_s: float, closest_eye_m: float = 0.01):
    """Callable(mcu.Info) -> why the co-MCU's compiled-in envelope does not serve ``cfg``'s laser
    (None if it does): it does not keep the laser, at its measured peak power ([laser] power_w,
    firmware_pwm/README.md "Optical power"), Class 1 for every pulse train that firmware allows;
    or it does not allow the train the sensor fires, one pulse of up to ``pulse_s`` (the sync's
    guards widen it up to that) per scan at the operating point's scan rate, its period shortened
    by up to SYNC_SLACK_S by the sync's trims and phase steps (the slack `laserpi design`'s
    envelopes leave), so that every SCHEDULE, or some, would be refused. The firmware's envelope is what the Class 1 claim rests on when
    the Pi's software errs, so SyncedLaser lights nothing under a firmware built for a weaker
    laser (device/model/envelope.py; eq. 3.45), and starts nothing under one built for a slower
    rate (firmware_pwm/src/core.c checks every schedule against it)."""
    import functools

    from device.model.envelope import SYNC_SLACK_S, FirmwareEnvelope, LineLaserOptics, envelope_max_power_w, us_up
    from device.model.safety import mw_down

    las = cfg.laser
    optics = LineLaserOptics(las.wavelength_m * 1e9, las.fan_angle_rad, las.line_height_m, las.source_diameter_m)
    max_power_w = functools.lru_cache(maxsize=4)(lambda env: envelope_max_power_w(optics, closest_eye_m, env))
    rate_hz = cfg.operating_point.scan_rate_hz
    period_us, pulse_us, slack_us = 1e6 / rate_hz, pulse_s * 1e6, SYNC_SLACK_S * 1e6
    spaced_us = us_up(1 / rate_hz - SYNC_SLACK_S)  # the minimum period design's envelope_for gives this rate

    def refusal(info) -> str | None:
        env = FirmwareEnvelope.from_ticks(info.max_pulse_ticks, info.max_duty_ppm, info.min_period_ticks,
                                          info.ticks_per_second)
        named = (f"the co-MCU's envelope ({env.max_pulse_us} us pulses, {env.max_duty_ppm / 1e4:g} % duty, "
                 f"{env.min_period_us} us apart)")
        limit_w = max_power_w(env)
        if las.power_w > limit_w:
            return (f"{named} keeps a laser Class 1 only up to {mw_down(limit_w):.2f} mW, and [laser] power_w is "
                    f"{las.power_w * 1e3:g} mW: lower the laser's power or flash a firmware built for it "
                    f"(`laserpi design` gives the make line)")
        if (pulse_us > env.max_pulse_us or env.min_period_us > spaced_us
                or pulse_us / period_us * 1e6 > env.max_duty_ppm):
            return (f"{named} does not allow the sensor's train at {rate_hz:g} scans/s: {pulse_us:.0f} us pulses "
                    f"{period_us:.0f} us apart ({pulse_us / period_us:.1%} duty), less the sync's {slack_us:.0f} us "
                    f"for its trims and phase steps: flash the firmware built for this rate (`laserpi design` gives "
                    f"its make line)")
        return None

    return refusal


def laser_limit_mw(cfg: SensorConfig, pulse_s: float, closest_eye_m: float = 0.01, rate_hz: float | None = None) -> float:
    """Class 1 peak power limit (mW) of the configured laser, one ``pulse_s`` pulse per scan at
    ``rate_hz`` scans/s (default: the operating point's); device/model/safety.py, eq. 3.45 with the
    thesis's 1 cm closest eye."""
    from device.sync.placement import class1_power_w

    rate_hz = cfg.operating_point.scan_rate_hz if rate_hz is None else rate_hz
    return 1e3 * class1_power_w(pulse_s, rate_hz, cfg.laser, closest_eye_m)


@dataclass(frozen=True)
class AssemblyConfig:
    """Which sensor ``build_sensor`` builds (``laserpi serve`` makes one of its options).

    ``config_path``: the sensor configuration file (TOML), else the ``preset``; ``scan_rate_hz``
    overrides its [operating_point] scan_rate_hz; ``points``: points per scan (None: the
    configuration's active image width); ``comcu``: the co-MCU's serial device on a Pi;
    ``gpio_edge``: the laser trigger line's GPIO (CHIP:LINE) for edge-timestamp sync on a Pi,
    overriding the configuration's ``[pi] gpio_edge`` (neither: PING-only sync, reported as
    degraded). ``simulate``: the simulated hardware instead, seeing ``scene`` (a built-in name, a
    ``wall:...`` spec or a TOML path; "wall" is a wall at ``distance_m``) with noise ``seed``, its
    co-MCU running ``firmware`` (an ELF; None: the production build).
    """

    simulate: bool = False
    config_path: str | None = None
    preset: str = "thesis-calibrated"
    points: int | None = None
    comcu: str = "/dev/serial0"
    gpio_edge: str | None = None
    scene: str = "wall"
    distance_m: float = 2.0
    seed: int = 0
    scan_rate_hz: float | None = None
    firmware: str | None = None


@dataclass
class BuiltSensor:
    """What ``laserpi serve`` runs: the source, its power-on settings, the Class 1 laser limit it
    enforces, what to close at the end, and in simulation the fault injections {name: callable}
    and the simulated hardware."""

    source: SensorSource
    settings: m.ScanSettings
    laser_limit_mw: float
    closers: list
    faults: dict
    hardware: SimulatedHardware | None = None


def _open_gpio_edges(spec: str | None):
    """The laser trigger line's edge source (device/sync/gpio_edges.py) for ``spec`` (CHIP:LINE),
    None without one; a line that is configured but cannot be opened stops ``serve`` (RuntimeError
    naming it), rather than quietly syncing by pings."""
    if spec is None:
        return None
    from device.sync.gpio_edges import GpioEdgeSource, parse_gpio_edge

    chip, line = parse_gpio_edge(spec)
    try:
        return GpioEdgeSource(chip, line)
    except OSError as exc:
        raise RuntimeError(f"GPIO edge line {spec}: {exc} (is the user in the gpio group? laserpi doctor checks)") from exc


def build_sensor(setup: AssemblyConfig) -> BuiltSensor:
    """The sensor for ``laserpi serve`` (simulated with ``setup.simulate``)."""
    from device.laser.synced import SyncedLaser
    from device.sim.timing import CameraTimingConfig
    from device.sync.control import SyncConfig
    from device.vision.pipelines import DEVICE_VARIANT, make_pipeline

    cfg = sensor_config(setup.config_path, setup.preset)
    if setup.scan_rate_hz is not None:
        cfg = with_operating_point(cfg, scan_rate_hz=setup.scan_rate_hz)
    op = cfg.operating_point  # scan rate, exposure, gain, depth range ([operating_point])
    frame_duration_s = op.frame_duration_s
    pipeline = make_pipeline(DEVICE_VARIANT, cfg, op.min_m, op.max_m)
    count = setup.points or cfg.active_width or cfg.width
    scan = ScanPipeline(pipeline, count)
    row_min, row_max = roi_rows(pipeline.geometry)
    # Guards: a 100 us floor and narrowing at most every 5 s keep the controller from re-placing
    # the train for guard changes of tens of microseconds (each new train costs the frames before
    # it, i.e. a scan). Exposure + ROI span + 2 x 1.3 x the 2 ms guard ceiling = 17.3 ms stays
    # inside the firmware's 17.4 ms pulse envelope.
    # (SyncConfig's PING/PONG minimum line times default to device.laser.comcu's 250000 baud.)
    sync = SyncConfig(row_min, row_max, frame_duration_s, cmd_latency_max_s=COMMAND_LATENCY_S, min_guard_s=100e-6, narrow_interval_s=5.0)
    pulse_s = laser_pulse_s(cfg, row_min, row_max)
    limit = laser_limit_mw(cfg, pulse_s)
    closers = []
    if setup.simulate:
        import cv2

        from device.sim.camera import SimulatedCamera
        from device.sim.hardware import SimulatedHardware
        from device.sim.scene import get_scene
        from device.sim.sensor import SensorParams

        spec = f"wall:distance={setup.distance_m:g}" if setup.scene == "wall" else setup.scene
        # one OpenCV thread: each call's CPU is then its caller's (the renderer's or the pipeline's),
        # which the per-thread CPU figures of `laserpi bench process` need
        cv2.setNumThreads(1)
        hw = SimulatedHardware(seed=setup.seed, elf=setup.firmware)
        closers.append(hw.close)
        timing = CameraTimingConfig(frame_duration_s=frame_duration_s, exposure_s=op.exposure_us * 1e-6)
        camera = SimulatedCamera(cfg, get_scene(spec), hw, timing=timing, seed=setup.seed,
                                 sensor=SensorParams(analog_gain=op.analog_gain), hardware=hw)
        laser = SyncedLaser(hw.open_comcu, sync, gpio_edges=hw.gpio_edges, heartbeat_s=None, clock_ns=hw.now_ns,
                            envelope_refusal=envelope_refusal(cfg, pulse_s))
        hw.tickers.append(laser.heartbeat)
        clock = lambda: hw.now_ns() * 1e-9  # noqa: E731
        faults = {"comcu-reset": hw.reset_mcu,
                  "camera-stall": lambda: setattr(camera, "stall_until_ns", hw.now_ns() + 1_000_000_000)}
        degraded = False  # the simulated Pi has the trigger line's edges (hw.gpio_edges)
    else:
        from device.camera.picamera2_camera import Picamera2Camera, camera_stack_problem

        problem = camera_stack_problem()  # a camera that can never start is a stop, not a retry
        if problem:
            raise RuntimeError(f"no camera: {problem}; or use --simulate to run the simulated sensor here")
        camera = Picamera2Camera(exposure_us=op.exposure_us, frame_duration_us=frame_duration_s * 1e6,
                                 analogue_gain=op.analog_gain, window=cfg.window)

        edges = _open_gpio_edges(setup.gpio_edge or cfg.gpio_edge)
        if edges is not None:
            closers.append(edges.close)
            degraded = False
        else:
            log.warning("sync degraded: no GPIO edge line of the laser trigger (serve --gpio-edge CHIP:LINE or [pi] "
                        "gpio_edge); the laser is synchronised by co-MCU pings alone, with wider guards (HEALTH error "
                        "SYNC_DEGRADED)")
            degraded = True
        laser = SyncedLaser(functools.partial(open_comcu, setup.comcu), sync,
                            gpio_edges=None if edges is None else edges.read,
                            envelope_refusal=envelope_refusal(cfg, pulse_s))
        clock = time.monotonic
        faults, hw = {}, None
    geometry = ScanGeometry(scan.angles.astype(np.float32), op.min_m, op.max_m)
    source = SensorSource(camera, laser, scan, geometry, clock=clock, sync_degraded=degraded)
    power_mw = min(cfg.laser.power_w * 1e3, limit)
    settings = m.ScanSettings(scan_rate_hz=op.scan_rate_hz, exposure_us=int(op.exposure_us), roi_first=0, roi_count=count,
                              median_window=1, min_quality=0, laser_power_mw=power_mw, ray_times=False)
    log.info("sensor %s: %d points, rows %d-%d, pulse %.1f ms, Class 1 limit %.1f mW, %s",
             cfg.name, count, row_min, row_max, pulse_s * 1e3, limit, "simulated" if setup.simulate else "on a Pi")
    return BuiltSensor(source, settings, limit, closers, faults, hw)
