"""The sensor configuration file (TOML): everything the model, simulator and pipeline need to know
about one physical sensor, versioned and validated with errors that name the offending field.

Layout (schema_version 1; SI units unless the key names another unit)::

    schema_version = 1
    name = "thesis-calibrated"

    [image]            # buffer size and the active area inside it (thesis B.1.4, docs/thesis-notes.md N6)
    width = 1664
    height = 928
    active_width = 1640
    active_height = 922
    sensor_mode = "1640x1232"  # the active area is cut from this mode (device/camera/modes.py) ...
    mode_left = 0      # ... starting this many of the mode's output columns ...
    mode_top = 155     # ... and rows in (ScalerCrop): image row r is the mode's row 155 + r

    [camera]           # eq. 3.2-3.4; model: a name in device.model.camera.LENS_MODELS, "brown-conrady"
                       # (k1 k2 k3 p1 p2) or "kannala-brandt" (k1..k4); distortion in that order
    model = "brown-conrady"
    fx = 592.139
    fy = 590.933
    cx = 802.362
    cy = 413.244
    skew = 0.0
    distortion = [-0.02077, -0.0393, 0.00889, -0.00259, 0.00025]

    [laser_plane]      # z = a x + b y + c in the OpenCV camera frame (eq. 3.16), c in metres
    a = 0.03099
    b = -1.6272
    c_m = 0.09405262
    beta_deg = 90.0    # laser rotation w.r.t. the baseline, to derive alpha/psi/s (D.2.2)

    # ... or instead of [laser_plane], the design form (thesis Table 4.4):
    # [triangulation]
    # alpha_deg = 58.9
    # beta_deg = 90.0
    # psi_deg = 90.0
    # s_m = 0.055

    [laser]            # Table 4.4; pulse_s and rate_hz are the thesis's 17.4 ms at 10 Hz
    wavelength_m = 8.08e-7
    power_w = 0.025
    fan_angle_rad = 2.0944
    line_height_m = 0.004
    source_diameter_m = 0.001
    pulse_s = 0.0174
    rate_hz = 10.0

    [optics]
    bandpass_width_m = 5e-8
    f_number = 2.0
    pixel_pitch_m = 2.24e-6

    [range]            # Algorithm 2's filter, 1..10000 mm (docs/thesis-notes.md N3)
    min_m = 0.001
    max_m = 10.0

    [operating_point]  # how `laserpi serve` runs the sensor
    scan_rate_hz = 10.0    # scans/s: a lit and an unlit frame each (docs/thesis-notes.md N10); at most [laser] rate_hz
    exposure_us = 10000.0  # every frame's exposure, shorter than a frame (1 / (2 scan_rate_hz));
                           # a whole number of 10 ms: lamps on 50 Hz mains flicker at 100 Hz
    analog_gain = 4.0      # IMX219 analogue gain, 1..10.67
    min_m = 0.4            # depths the line is searched for: their rows are the region of
    max_m = 3.2            # interest (and the pulse covers their readout)
    flicker_hz = [100.0, 120.0]  # the lighting's flicker the frames must cancel (twice the mains
                                 # frequency; [] outdoors or under DC light): device/model/flicker.py

    [pi]               # optional: how this sensor is wired to its Raspberry Pi
    gpio_edge = "gpiochip0:17"  # the laser trigger line's GPIO (CHIP:LINE) for edge-timestamp sync;
                                # absent: PING-only sync, reported as degraded (device/sync/gpio_edges.py)

    [post_calibration] # optional, z_corrected = z - sum c_k X^i_k Z^j_k  (eq. 6.5, docs/thesis-notes.md N8)
    terms = [[0, 0], [1, 0], [0, 1]]
    coefficients = [0.0, 0.0, 0.0]
    x_scale_m = 1.0
    z_offset_m = 0.0
    z_scale_m = 1.0

Every table and key added after schema_version 1 was first written is optional, with the value
it replaced as its default (``[image]`` sensor_mode/mode_left/mode_top, ``[operating_point]``:
the constants device/sensor.py had), so that every file written before still loads and means
what it meant; the version goes up only when a key changes meaning or becomes required.

Presets (``device/presets/*.toml``) hold the thesis's inputs only, never its results.
"""

from __future__ import annotations

import dataclasses
import math
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from .camera.modes import IMX219_ANALOG_GAIN_MAX, IMX219_EXPOSURE_MARGIN_LINES, MODE5, ImageWindow, sensor_mode_named
from .model import flicker
from .model.camera import CameraModel, Intrinsics, lens_model, lens_model_named
from .model.triangulation import DegeneratePlaneError, LaserPlane, TriangulationParams, plane_from_params

SCHEMA_VERSION = 1
PRESET_DIR = Path(__file__).with_name("presets")


class ConfigError(ValueError):
    """A configuration file or value that cannot be used; the message names the field."""


@dataclass(frozen=True)
class LaserSpec:
    wavelength_m: float = 808e-9
    power_w: float = 0.025
    fan_angle_rad: float = math.radians(120.0)
    line_height_m: float = 0.004
    source_diameter_m: float = 0.001
    pulse_s: float = 0.0174
    rate_hz: float = 10.0


@dataclass(frozen=True)
class Optics:
    bandpass_width_m: float = 50e-9
    f_number: float = 2.0
    pixel_pitch_m: float = 2.24e-6  # IMX219 1.12 um, 2x2 binned in mode 5


@dataclass(frozen=True)
class RangeLimits:
    min_m: float = 0.001
    max_m: float = 10.0


@dataclass(frozen=True)
class OperatingPoint:
    """How ``laserpi serve`` runs the sensor: scans per second (a lit and an unlit frame each,
    docs/thesis-notes.md N10), every frame's exposure and analogue gain, and the depths the line is searched
    for, whose rows form the region of interest (narrower than ``RangeLimits``, the
    triangulation's filter), and the flicker of the ambient light (Hz) that the difference of a
    lit and an unlit frame must not keep: lamps on 50 Hz and 60 Hz mains by default, [] where the
    sensor works under none (outdoors, DC lighting). The exposure or the frame period must be a
    whole number of each one's period (device/model/flicker.py): the default 10 ms exposure is
    one of 100 Hz, and the frame periods of 10, 12, 15 and 20 scans/s are whole numbers of 120
    Hz's."""

    scan_rate_hz: float = 10.0
    exposure_us: float = 10000.0
    analog_gain: float = 4.0
    min_m: float = 0.4
    max_m: float = 3.2
    flicker_hz: tuple[float, ...] = flicker.MAINS_FLICKER_HZ

    @property
    def frame_duration_s(self) -> float:
        """A frame's period: a lit and an unlit frame per scan."""
        return 0.5 / self.scan_rate_hz


@dataclass(frozen=True)
class PostCalibration:
    """z_corrected = z - sum_k c_k X^i_k Z^j_k with X = x / x_scale_m, Z = (z - z_offset_m) / z_scale_m.

    The thesis's eq. 6.5 in raw millimetre monomials is this form with x_scale = z_scale = 1 mm;
    fitting in scaled coordinates keeps it well conditioned (docs/thesis-notes.md N8).
    """

    terms: tuple[tuple[int, int], ...] = ()
    coefficients: tuple[float, ...] = ()
    x_scale_m: float = 1.0
    z_offset_m: float = 0.0
    z_scale_m: float = 1.0


@dataclass(frozen=True)
class SensorConfig:
    name: str
    width: int
    height: int
    camera: CameraModel
    plane: LaserPlane
    beta_rad: float = math.pi / 2
    active_width: int | None = None
    active_height: int | None = None
    laser: LaserSpec = field(default_factory=LaserSpec)
    optics: Optics = field(default_factory=Optics)
    range: RangeLimits = field(default_factory=RangeLimits)
    post_calibration: PostCalibration | None = None
    sensor_mode: str = MODE5.mode.name
    mode_left: int = MODE5.left
    mode_top: int = MODE5.top
    operating_point: OperatingPoint = field(default_factory=OperatingPoint)
    gpio_edge: str | None = None  # [pi] gpio_edge: CHIP:LINE of the laser trigger line, None if not wired

    @property
    def window(self) -> ImageWindow:
        """The active area as a crop of the sensor mode (device/camera/modes.py): the mode's
        line time and frame-rate limits, and where each image row is read."""
        return ImageWindow(sensor_mode_named(self.sensor_mode), self.mode_left, self.mode_top,
                           self.active_width or self.width, self.active_height or self.height)


# ---------------------------------------------------------------- reading
def _take(table: dict[str, Any], where: str, key: str, kind: type, default: Any = ..., positive: bool = False) -> Any:
    if key not in table:
        if default is ...:
            raise ConfigError(f"{where}: missing required key '{key}'")
        return default
    v = table.pop(key)
    if kind is float and isinstance(v, int) and not isinstance(v, bool):
        v = float(v)
    if not isinstance(v, kind) or isinstance(v, bool) and kind is not bool:
        raise ConfigError(f"{where}: '{key}' must be a {kind.__name__}, got {v!r}")
    if kind is float and not math.isfinite(v):
        raise ConfigError(f"{where}: '{key}' must be finite, got {v}")
    if positive and not v > 0:
        raise ConfigError(f"{where}: '{key}' must be positive, got {v}")
    return v


def _no_extra(table: dict[str, Any], where: str) -> None:
    if table:
        raise ConfigError(f"{where}: unknown key(s) {', '.join(sorted(table))} (typo?)")


def _table(doc: dict[str, Any], name: str, required: bool = True) -> dict[str, Any] | None:
    if name not in doc:
        if required:
            raise ConfigError(f"missing required table [{name}]")
        return None
    t = doc.pop(name)
    if not isinstance(t, dict):
        raise ConfigError(f"[{name}] must be a table")
    return dict(t)


def config_from_dict(doc: dict[str, Any], source: str = "<config>") -> SensorConfig:
    """Validate a parsed TOML document; raises ConfigError naming the source and the field."""
    doc = dict(doc)
    try:
        return _parse(doc, source)
    except (DegeneratePlaneError, ValueError) as exc:
        if isinstance(exc, ConfigError):
            raise ConfigError(f"{source}: {exc}") from None
        raise ConfigError(f"{source}: {exc}") from None


def _parse(doc: dict[str, Any], source: str) -> SensorConfig:
    version = _take(doc, "top level", "schema_version", int)
    if version != SCHEMA_VERSION:
        raise ConfigError(f"schema_version {version} is not supported; this software reads version {SCHEMA_VERSION}")
    name = _take(doc, "top level", "name", str, default=Path(source).stem)

    img = _table(doc, "image")
    width = _take(img, "[image]", "width", int, positive=True)
    height = _take(img, "[image]", "height", int, positive=True)
    active_w = _take(img, "[image]", "active_width", int, default=None)
    active_h = _take(img, "[image]", "active_height", int, default=None)
    mode_name = _take(img, "[image]", "sensor_mode", str, default=MODE5.mode.name)
    mode_left = _take(img, "[image]", "mode_left", int, default=MODE5.left)
    mode_top = _take(img, "[image]", "mode_top", int, default=MODE5.top)
    _no_extra(img, "[image]")
    for key, v, lim in (("active_width", active_w, width), ("active_height", active_h, height)):
        if v is not None and not 0 < v <= lim:
            raise ConfigError(f"[image]: '{key}' = {v} must be in 1..{lim}")
    try:
        window = ImageWindow(sensor_mode_named(mode_name), mode_left, mode_top, active_w or width, active_h or height)
    except ValueError as exc:
        raise ConfigError(f"[image]: {exc} (sensor_mode, mode_left, mode_top)") from None

    cam = _table(doc, "camera")
    model = _take(cam, "[camera]", "model", str, default="brown-conrady")
    k = Intrinsics(
        fx=_take(cam, "[camera]", "fx", float, positive=True),
        fy=_take(cam, "[camera]", "fy", float, positive=True),
        cx=_take(cam, "[camera]", "cx", float),
        cy=_take(cam, "[camera]", "cy", float),
        skew=_take(cam, "[camera]", "skew", float, default=0.0),
        width=width,
        height=height,
    )
    coeffs = _take(cam, "[camera]", "distortion", list, default=[])
    if not all(isinstance(c, (int, float)) and not isinstance(c, bool) and math.isfinite(c) for c in coeffs):
        raise ConfigError(f"[camera]: 'distortion' must be a list of finite numbers, got {coeffs!r}")
    try:
        lens = lens_model_named(model)
    except ValueError as exc:
        raise ConfigError(f"[camera]: {exc}") from None
    names = lens.coefficient_names
    if len(coeffs) > len(names):
        raise ConfigError(f"[camera]: {model} takes up to {len(names)} coefficients {' '.join(names)}, got {len(coeffs)}")
    dist = lens.distortion(*[float(c) for c in coeffs])
    _no_extra(cam, "[camera]")

    plane_t, tri_t = _table(doc, "laser_plane", required=False), _table(doc, "triangulation", required=False)
    if (plane_t is None) == (tri_t is None):
        raise ConfigError("give exactly one of [laser_plane] (a, b, c_m) or [triangulation] (alpha_deg, beta_deg, psi_deg, s_m)")
    if plane_t is not None:
        a = _take(plane_t, "[laser_plane]", "a", float)
        b = _take(plane_t, "[laser_plane]", "b", float)
        c = _take(plane_t, "[laser_plane]", "c_m", float)
        beta = math.radians(_take(plane_t, "[laser_plane]", "beta_deg", float, default=90.0))
        _no_extra(plane_t, "[laser_plane]")
        plane = LaserPlane.from_abc(a, b, c)
    else:
        p = TriangulationParams(
            alpha=math.radians(_take(tri_t, "[triangulation]", "alpha_deg", float)),
            beta=math.radians(_take(tri_t, "[triangulation]", "beta_deg", float, default=90.0)),
            psi=math.radians(_take(tri_t, "[triangulation]", "psi_deg", float, default=90.0)),
            s=_take(tri_t, "[triangulation]", "s_m", float, positive=True),
        )
        _no_extra(tri_t, "[triangulation]")
        plane, beta = LaserPlane.from_abc(*plane_from_params(p)), p.beta

    laser = _read_dataclass(doc, "laser", LaserSpec)
    if not 600e-9 <= laser.wavelength_m <= 1050e-9:
        raise ConfigError(f"[laser]: wavelength_m = {laser.wavelength_m} is outside the modelled 600-1050 nm band")
    if laser.pulse_s * laser.rate_hz > 1.0:
        raise ConfigError(f"[laser]: pulse_s x rate_hz = {laser.pulse_s * laser.rate_hz:.3f} > 1: pulses would overlap")
    optics = _read_dataclass(doc, "optics", Optics)
    limits = _read_dataclass(doc, "range", RangeLimits)
    if not limits.max_m > limits.min_m:
        raise ConfigError(f"[range]: max_m ({limits.max_m}) must exceed min_m ({limits.min_m})")
    post = _read_post_calibration(_table(doc, "post_calibration", required=False))
    op = _read_dataclass(doc, "operating_point", OperatingPoint)
    _check_operating_point(op, laser, window)
    gpio_edge = _read_pi(_table(doc, "pi", required=False))
    _no_extra(doc, "top level")
    return SensorConfig(name, width, height, CameraModel(k, dist), plane, beta, active_w, active_h, laser, optics, limits, post,
                        mode_name, mode_left, mode_top, op, gpio_edge)


def _read_pi(t: dict[str, Any] | None) -> str | None:
    """``[pi]``: the GPIO line of the laser trigger (``gpio_edge``, CHIP:LINE), or None."""
    if t is None:
        return None
    from .sync.gpio_edges import parse_gpio_edge

    gpio_edge = _take(t, "[pi]", "gpio_edge", str, default=None)
    _no_extra(t, "[pi]")
    if gpio_edge is not None:
        try:
            parse_gpio_edge(gpio_edge)
        except ValueError as exc:
            raise ConfigError(f"[pi]: gpio_edge: {exc}") from None
    return gpio_edge


def _check_operating_point(op: OperatingPoint, laser: LaserSpec, window: ImageWindow) -> None:
    where, mode = "[operating_point]", window.mode
    # a file's numbers are checked as they are read (_take); with_operating_point's here
    for name in ("scan_rate_hz", "exposure_us", "analog_gain", "min_m", "max_m"):
        if not _finite_positive(v := getattr(op, name)):
            raise ConfigError(f"{where}: '{name}' must be a finite positive number, got {v!r}")
    if not isinstance(op.flicker_hz, tuple) or not all(_finite_positive(f) for f in op.flicker_hz):
        raise ConfigError(f"{where}: 'flicker_hz' must be a list of finite positive numbers, got {op.flicker_hz!r}")
    if not op.max_m > op.min_m:
        raise ConfigError(f"{where}: max_m ({op.max_m}) must exceed min_m ({op.min_m})")
    if op.scan_rate_hz > laser.rate_hz:
        raise ConfigError(f"{where}: scan_rate_hz = {op.scan_rate_hz:g} exceeds [laser] rate_hz = {laser.rate_hz:g}, "
                          "the pulse rate the laser's eye-safety envelope is built for (a faster rate needs a [laser] "
                          "of that rate and power, and the co-MCU firmware built for it: `laserpi design` lists both)")
    frame_s = op.frame_duration_s
    if not mode.min_frame_duration_s <= frame_s <= mode.max_frame_duration_s:
        raise ConfigError(f"{where}: scan_rate_hz = {op.scan_rate_hz:g} needs {2 * op.scan_rate_hz:g} frames/s; the "
                          f"{mode.name} sensor mode runs at {1 / mode.max_frame_duration_s:.3g} to "
                          f"{mode.max_frame_rate_hz:.2f} frames/s")
    longest_s = frame_s - IMX219_EXPOSURE_MARGIN_LINES * mode.line_time_s  # the driver's exposure limit
    if op.exposure_us * 1e-6 > longest_s:
        raise ConfigError(f"{where}: exposure_us = {op.exposure_us:g} is longer than a frame ({frame_s * 1e6:g} us "
                          f"at {op.scan_rate_hz:g} scans/s) less {IMX219_EXPOSURE_MARGIN_LINES} lines")
    if not 1.0 <= op.analog_gain <= IMX219_ANALOG_GAIN_MAX:
        raise ConfigError(f"{where}: analog_gain = {op.analog_gain:g} is outside the IMX219's 1..{IMX219_ANALOG_GAIN_MAX:.2f}")
    left = flicker.uncancelled(op.exposure_us * 1e-6, frame_s, op.flicker_hz)
    if left:
        ok = flicker.cancelling_exposures_s(frame_s, longest_s, op.flicker_hz)
        need = " and ".join(f"{f:g}" for f in flicker.not_cancelled_by_period(frame_s, op.flicker_hz))
        fix = (f"an exposure_us of {' or '.join(f'{e * 1e6:.0f}' for e in ok[:3])} cancels it" if ok else
               f"no exposure within a frame cancels {need} Hz at this rate (a rate whose frame period is a whole "
               "number of their periods, or an exposure of a whole number of each, does)")
        raise ConfigError(
            f"{where}: exposure_us = {op.exposure_us:g} at {op.scan_rate_hz:g} scans/s (frames {frame_s * 1e6:.0f} us "
            f"apart) leaves {' and '.join(f'{f:g} Hz' for f, _ in left)} flicker of mains lighting in the difference of a "
            f"lit and an unlit frame, up to {max(r for _, r in left):.0%} of the lamps' modulation "
            f"(device/model/flicker.py): {fix}; or set flicker_hz to the light the sensor works under "
            "([] for none)")


def with_operating_point(cfg: SensorConfig, **changes: Any) -> SensorConfig:
    """``cfg`` with ``[operating_point]`` fields changed (``laserpi serve --scan-rate-hz``), checked
    as a file's are: ConfigError naming the field otherwise."""
    if isinstance(changes.get("flicker_hz"), list):
        changes["flicker_hz"] = tuple(changes["flicker_hz"])  # as a file's list is read
    op = dataclasses.replace(cfg.operating_point, **changes)
    _check_operating_point(op, cfg.laser, cfg.window)
    return dataclasses.replace(cfg, operating_point=op)


def _finite_positive(x: Any) -> bool:
    return isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x) and x > 0


def _positive_floats(table: dict[str, Any], where: str, key: str, default: tuple[float, ...]) -> tuple[float, ...]:
    v = _take(table, where, key, list, default=list(default))
    if not all(_finite_positive(x) for x in v):
        raise ConfigError(f"{where}: '{key}' must be a list of finite positive numbers, got {v!r}")
    return tuple(float(x) for x in v)


#: how a field is read, by the type of its default: a positive number, or a list of them
_FIELD_READERS = {
    float: lambda t, where, f, default: _take(t, where, f, float, default=default, positive=True),
    tuple: _positive_floats,
}


def _read_dataclass(doc: dict[str, Any], name: str, cls: type) -> Any:
    t = _table(doc, name, required=False)
    if t is None:
        return cls()
    defaults = cls()
    values = {f: _FIELD_READERS[type(getattr(defaults, f))](t, f"[{name}]", f, getattr(defaults, f))
              for f in cls.__dataclass_fields__}
    _no_extra(t, f"[{name}]")
    return cls(**values)


def _read_post_calibration(t: dict[str, Any] | None) -> PostCalibration | None:
    if t is None:
        return None
    where = "[post_calibration]"
    terms = _take(t, where, "terms", list)
    coeffs = _take(t, where, "coefficients", list)
    if not all(isinstance(p, list) and len(p) == 2 and all(isinstance(e, int) and e >= 0 for e in p) for p in terms):
        raise ConfigError(f"{where}: 'terms' must be a list of [i, j] pairs of non-negative integers")
    if len(coeffs) != len(terms) or not all(isinstance(c, (int, float)) and math.isfinite(c) for c in coeffs):
        raise ConfigError(f"{where}: 'coefficients' must be {len(terms)} finite numbers, one per term")
    post = PostCalibration(
        tuple((int(i), int(j)) for i, j in terms),
        tuple(float(c) for c in coeffs),
        _take(t, where, "x_scale_m", float, default=1.0, positive=True),
        _take(t, where, "z_offset_m", float, default=0.0),
        _take(t, where, "z_scale_m", float, default=1.0, positive=True),
    )
    _no_extra(t, where)
    return post


def load_config(path: str | Path) -> SensorConfig:
    path = Path(path)
    try:
        with path.open("rb") as fh:
            doc = tomllib.load(fh)
    except FileNotFoundError:
        raise ConfigError(f"{path}: no such configuration file") from None
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{path}: not valid TOML: {exc}") from None
    return config_from_dict(doc, str(path))


def preset_names() -> list[str]:
    return sorted(p.stem for p in PRESET_DIR.glob("*.toml"))


def load_preset(name: str) -> SensorConfig:
    path = PRESET_DIR / f"{name}.toml"
    if not path.exists():
        raise ConfigError(f"unknown preset {name!r}; choose from: {', '.join(preset_names())}")
    return load_config(path)


# ---------------------------------------------------------------- writing
def config_to_dict(cfg: SensorConfig) -> dict[str, Any]:
    """The TOML document of a configuration (always in the [laser_plane] form)."""
    k, d = cfg.camera.intrinsics, cfg.camera.distortion
    lens = lens_model(d)
    model, coeffs = lens.name, [getattr(d, n) for n in lens.coefficient_names]
    a, b, c = cfg.plane.to_abc()
    doc: dict[str, Any] = {"schema_version": SCHEMA_VERSION, "name": cfg.name}
    doc["image"] = {"width": cfg.width, "height": cfg.height}
    if cfg.active_width is not None:
        doc["image"]["active_width"] = cfg.active_width
    if cfg.active_height is not None:
        doc["image"]["active_height"] = cfg.active_height
    doc["image"].update(sensor_mode=cfg.sensor_mode, mode_left=cfg.mode_left, mode_top=cfg.mode_top)
    doc["camera"] = {"model": model, "fx": k.fx, "fy": k.fy, "cx": k.cx, "cy": k.cy, "skew": k.skew, "distortion": coeffs}
    doc["laser_plane"] = {"a": a, "b": b, "c_m": c, "beta_deg": math.degrees(cfg.beta_rad)}
    for name in ("laser", "optics", "range", "operating_point"):
        obj = getattr(cfg, name)
        doc[name] = {f: _document_value(getattr(obj, f)) for f in obj.__dataclass_fields__}
    if cfg.gpio_edge is not None:
        doc["pi"] = {"gpio_edge": cfg.gpio_edge}
    if cfg.post_calibration is not None:
        p = cfg.post_calibration
        doc["post_calibration"] = {
            "terms": [list(t) for t in p.terms],
            "coefficients": list(p.coefficients),
            "x_scale_m": p.x_scale_m,
            "z_offset_m": p.z_offset_m,
            "z_scale_m": p.z_scale_m,
        }
    return doc


def _document_value(v: Any) -> Any:
    """A field as the TOML document holds it: a tuple as a list."""
    return list(v) if isinstance(v, tuple) else v


def _toml_value(v: Any) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, int):
        return str(v)
    if isinstance(v, float):
        return repr(float(v))
    if isinstance(v, str):
        return '"' + v.replace("\\", "\\\\").replace('"', '\\"') + '"'
    if isinstance(v, (list, tuple)):
        return "[" + ", ".join(_toml_value(x) for x in v) + "]"
    raise TypeError(f"cannot write {type(v).__name__} to TOML")


def dumps_config(cfg: SensorConfig) -> str:
    """TOML text of a configuration.

    Written by hand rather than with a TOML library: the schema is a flat set of tables of
    numbers, strings and number lists, which is a dozen lines and not worth a dependency.
    """
    lines = []
    tables = []
    for key, v in config_to_dict(cfg).items():
        (tables if isinstance(v, dict) else lines).append((key, v))
    out = [f"{k} = {_toml_value(v)}" for k, v in lines]
    for name, t in tables:
        out.append(f"\n[{name}]")
        out.extend(f"{k} = {_toml_value(v)}" for k, v in t.items())
    return "\n".join(out) + "\n"


def save_config(cfg: SensorConfig, path: str | Path) -> None:
    """Write atomically: a half-written configuration file is never left behind."""
    path = Path(path)
    text = dumps_config(cfg)
    config_from_dict(tomllib.loads(text), str(path))  # never write what we could not read back
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text(text)
    tmp.replace(path)
