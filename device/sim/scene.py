"""Scenes for the simulator: a small declarative TOML format and the built-in scenes.

Coordinates are the sensor's scan frame (device.model.scan_frame, REP 103): x forward, y left,
z up, metres, with z = 0 the laser plane and the laser source at the origin. A scene is a 2-D
layout (walls, boxes, cylinders as vertical prisms with a height range) plus an optional floor
(a horizontal plane below the laser plane) and the ambient light::

    name = "room"
    ambient = "indoor"          # "dark", "indoor" or "sunlight"; or ambient_w_m2 = 3.0 (in band)
    [floor]                     # optional
    z = -0.1
    reflectivity = 0.3
    gloss = 0.0                 # fraction mirrored: a ghost of the laser line (0 = matte)
    texture = "noise"           # "plain", "noise", "checker", "stripes"
    [[wall]]
    from = [2.0, -3.0]
    to = [2.0, 3.0]
    z = [-0.3, 1.5]             # bottom and top, default [-1, 2]
    reflectivity = 0.9
    [[box]]
    center = [1.0, 0.5]
    size = [0.4, 0.3]
    yaw_deg = 20.0
    [[cylinder]]
    center = [1.2, -0.4]
    radius = 0.1

Every surface takes ``reflectivity`` (diffuse, (0, 1]), ``gloss`` ([0, 1)), ``texture``,
``texture_scale_m`` and ``texture_depth`` (the texture's contrast: reflectivity x (1 +- depth),
default 0.3; a poster or a door frame against a pale wall is 0.8 or more).

Motion (issue 16; device/sim/motion.py moves everything, at time t seconds after the scene's
time zero, which the simulated camera puts at its first frame's exposure)::

    ambient_scale = 3.0         # the ambient irradiance times this (a window, a halogen lamp)
    flicker_hz = 100.0          # the ambient light's flicker (twice the mains frequency) ...
    flicker_depth = 0.3         # ... and its modulation depth: irradiance x (1 + depth sin 2 pi f t)
    [motion]                    # the sensor on a robot: a constant yaw rate and forward speed
    yaw_rate_deg_s = 90.0       # counter-clockwise (REP 103), about the robot's vertical axis
    speed_m_s = 0.5             # along the robot's x axis (forward; the sensor faces forward)
    sensor_ahead_m = 0.1        # the sensor's x in the robot's base_link: ahead of that axis (< 0: behind; default 0)
    [[cylinder]]                # a person crossing: a moving box or cylinder
    center = [1.5, -1.0]
    radius = 0.2
    velocity = [0.0, 1.2]       # m/s in the scene's frame
    [[wall]]                    # a door swinging about its hinge ('from')
    from = [1.2, 0.3]
    to = [1.2, 1.1]
    swing_deg_s = 90.0          # counter-clockwise

A scene with none of these is still: rendered exactly as before.
"""

from __future__ import annotations

import math
import tomllib
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

SCENE_DIR = Path(__file__).with_name("scenes")
TEXTURES = ("plain", "noise", "checker", "stripes")

#: Ambient light as a fraction of full sunlight through the sensor's bandpass (the renderer takes
#: the in-band solar irradiance from device.model.irradiance, ASTM G173 AM1.5 global-tilt).
#: "indoor" = 0.5 % (~0.25 W/m^2 in band): ASSUMPTION. The thesis (4.1.4, citing [36]) bounds
#: indoor light at "typically less than 20 %" of outdoor, a visible-light bound; at 808 nm LED and
#: fluorescent lighting emit almost nothing, so what is left is daylight through windows. At 20 %
#: the prototype's ~40 ms exposure would saturate a 90 % wall (BENCHMARKS.md, Simulator budget),
#: contradicting the thesis's working indoor measurements; 0.5 % is consistent with them
#: (render.py, anchoring).
AMBIENT_FRACTION = {"dark": 0.0, "indoor": 0.005, "sunlight": 1.0}


class SceneError(ValueError):
    """A scene file or value that cannot be used; the message names the field."""


@dataclass(frozen=True)
class Material:
    reflectivity: float = 0.5
    gloss: float = 0.0
    texture: str = "noise"
    texture_scale_m: float = 0.05
    # left out of repr (the speckle's random numbers are keyed by the scene's repr): scenes that
    # differ only in texture contrast or motion keep one speckle pattern
    texture_depth: float = field(default=0.3, repr=False)


@dataclass(frozen=True)
class Wall:
    start: tuple[float, float]
    end: tuple[float, float]
    z_range: tuple[float, float] = (-1.0, 2.0)
    material: Material = Material()
    swing_rad_s: float = field(default=0.0, repr=False)  # a door: turns about ``start`` (counter-clockwise)


@dataclass(frozen=True)
class Box:
    center: tuple[float, float]
    size: tuple[float, float]
    yaw_rad: float = 0.0
    z_range: tuple[float, float] = (-1.0, 2.0)
    material: Material = Material()
    velocity: tuple[float, float] = field(default=(0.0, 0.0), repr=False)  # m/s

    def corners(self) -> list[tuple[float, float]]:
        c, s = math.cos(self.yaw_rad), math.sin(self.yaw_rad)
        hx, hy = self.size[0] / 2, self.size[1] / 2
        out = []
        for dx, dy in ((-hx, -hy), (hx, -hy), (hx, hy), (-hx, hy)):
            out.append((self.center[0] + c * dx - s * dy, self.center[1] + s * dx + c * dy))
        return out


@dataclass(frozen=True)
class Cylinder:
    center: tuple[float, float]
    radius: float
    z_range: tuple[float, float] = (-1.0, 2.0)
    material: Material = Material()
    velocity: tuple[float, float] = field(default=(0.0, 0.0), repr=False)  # m/s (a person crossing)


@dataclass(frozen=True)
class Floor:
    z: float
    material: Material = Material(reflectivity=0.3)


@dataclass(frozen=True)
class Motion:
    """The sensor's motion: the robot's constant yaw rate (rad/s, counter-clockwise) and forward
    speed (m/s), the sensor mounted ``sensor_ahead_m`` ahead of the robot's turning axis (its x
    in the robot's base_link, REP 105; negative: behind the axis): a turn then also moves it
    sideways. The sensor sits on the robot's centre line facing forward, its scan frame's z axis
    the robot's yaw axis; no sideways offset or mounting yaw is modelled."""

    yaw_rate_rad_s: float = 0.0
    speed_m_s: float = 0.0
    sensor_ahead_m: float = 0.0

    @property
    def still(self) -> bool:
        return self.yaw_rate_rad_s == 0 and self.speed_m_s == 0


@dataclass(frozen=True)
class Flicker:
    """Mains flicker of the ambient light: irradiance x (1 + depth sin(2 pi hz t))."""

    hz: float = 100.0
    depth: float = 0.0


@dataclass(frozen=True)
class Scene:
    name: str
    walls: tuple[Wall, ...] = ()
    boxes: tuple[Box, ...] = ()
    cylinders: tuple[Cylinder, ...] = ()
    floor: Floor | None = None
    ambient: str = "indoor"  # a key of AMBIENT_FRACTION
    ambient_w_m2: float | None = None  # in-band irradiance on surfaces, overrides ``ambient``
    # issue 16, left out of repr like Material.texture_depth
    ambient_scale: float = field(default=1.0, repr=False)
    flicker: Flicker = field(default=Flicker(), repr=False)
    motion: Motion = field(default=Motion(), repr=False)
    surfaces: tuple = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        # one id per surface: walls, then boxes, then cylinders, then the floor
        object.__setattr__(self, "surfaces", (*self.walls, *self.boxes, *self.cylinders, *((self.floor,) if self.floor else ())))

    @property
    def objects_move(self) -> bool:
        return any(w.swing_rad_s for w in self.walls) or any(o.velocity != (0.0, 0.0) for o in (*self.boxes, *self.cylinders))

    @property
    def still(self) -> bool:
        """Nothing moves: neither the sensor nor an object (flicker may still change the light)."""
        return self.motion.still and not self.objects_move


# ---------------------------------------------------------------- parsing and validation
def _num(t: dict, where: str, key: str, default: Any = ..., lo: float | None = None, hi: float | None = None,
         lo_open: bool = False, hi_open: bool = False) -> float:
    if key not in t:
        if default is ...:
            raise SceneError(f"{where}: missing required key '{key}'")
        return default
    v = t.pop(key)
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
        raise SceneError(f"{where}: '{key}' must be a finite number, got {v!r}")
    v = float(v)
    if lo is not None and (v < lo or (lo_open and v == lo)) or hi is not None and (v > hi or (hi_open and v == hi)):
        lb, hb = "(" if lo_open else "[", ")" if hi_open else "]"
        raise SceneError(f"{where}: '{key}' = {v} must be in {lb}{lo}, {hi}{hb}")
    return v


def _pair(t: dict, where: str, key: str, default: Any = ...) -> tuple[float, float]:
    if key not in t:
        if default is ...:
            raise SceneError(f"{where}: missing required key '{key}'")
        return default
    v = t.pop(key)
    if not (isinstance(v, list) and len(v) == 2 and all(isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x) for x in v)):
        raise SceneError(f"{where}: '{key}' must be a pair of finite numbers [a, b], got {v!r}")
    return float(v[0]), float(v[1])


def _material(t: dict, where: str, default_reflectivity: float = 0.5) -> Material:
    tex = t.pop("texture", "noise")
    if tex not in TEXTURES:
        raise SceneError(f"{where}: 'texture' must be one of {', '.join(TEXTURES)}, got {tex!r}")
    return Material(
        reflectivity=_num(t, where, "reflectivity", default_reflectivity, lo=0.0, hi=1.0, lo_open=True),
        gloss=_num(t, where, "gloss", 0.0, lo=0.0, hi=1.0, hi_open=True),
        texture=tex,
        texture_scale_m=_num(t, where, "texture_scale_m", 0.05, lo=0.0, lo_open=True),
        texture_depth=_num(t, where, "texture_depth", 0.3, lo=0.0, hi=1.0),
    )


def _z_range(t: dict, where: str) -> tuple[float, float]:
    z = _pair(t, where, "z", (-1.0, 2.0))
    if not z[1] > z[0]:
        raise SceneError(f"{where}: 'z' = [{z[0]}, {z[1]}] must be [bottom, top] with top > bottom")
    return z


def _done(t: dict, where: str) -> None:
    if t:
        raise SceneError(f"{where}: unknown key(s) {', '.join(sorted(t))} (typo?)")


def _list(doc: dict, key: str) -> list[dict]:
    v = doc.pop(key, [])
    if not isinstance(v, list) or not all(isinstance(x, dict) for x in v):
        raise SceneError(f"'{key}' must be an array of tables ([[{key}]])")
    return [dict(x) for x in v]


def scene_from_dict(doc: dict[str, Any], source: str = "<scene>") -> Scene:
    """Validate a parsed scene document; raises SceneError naming the source, surface and field."""
    try:
        return _parse(dict(doc), source)
    except SceneError as exc:
        raise SceneError(f"{source}: {exc}") from None


def _parse(doc: dict[str, Any], source: str) -> Scene:
    name = doc.pop("name", Path(source).stem)
    if not isinstance(name, str):
        raise SceneError(f"'name' must be a string, got {name!r}")
    if "ambient" in doc and "ambient_w_m2" in doc:
        raise SceneError("give 'ambient' (a name) or 'ambient_w_m2' (a number), not both")
    ambient = doc.pop("ambient", "indoor")
    if ambient not in AMBIENT_FRACTION:
        raise SceneError(f"'ambient' must be one of {', '.join(AMBIENT_FRACTION)}, got {ambient!r}")
    ambient_w = _num(doc, "top level", "ambient_w_m2", None, lo=0.0)
    walls, boxes, cyls = [], [], []
    for i, t in enumerate(_list(doc, "wall")):
        w = f"wall[{i}]"
        a, b = _pair(t, w, "from"), _pair(t, w, "to")
        if math.dist(a, b) < 1e-6:
            raise SceneError(f"{w}: 'from' and 'to' are the same point; a wall needs a length")
        walls.append(Wall(a, b, _z_range(t, w), _material(t, w), math.radians(_num(t, w, "swing_deg_s", 0.0))))
        _done(t, w)
    for i, t in enumerate(_list(doc, "box")):
        w = f"box[{i}]"
        c, s = _pair(t, w, "center"), _pair(t, w, "size")
        if not (s[0] > 0 and s[1] > 0):
            raise SceneError(f"{w}: 'size' must be two positive lengths, got {list(s)}")
        yaw = math.radians(_num(t, w, "yaw_deg", 0.0))
        boxes.append(Box(c, s, yaw, _z_range(t, w), _material(t, w), _pair(t, w, "velocity", (0.0, 0.0))))
        _done(t, w)
    for i, t in enumerate(_list(doc, "cylinder")):
        w = f"cylinder[{i}]"
        c = _pair(t, w, "center")
        r = _num(t, w, "radius", lo=0.0, lo_open=True)
        cyls.append(Cylinder(c, r, _z_range(t, w), _material(t, w), _pair(t, w, "velocity", (0.0, 0.0))))
        _done(t, w)
    floor = None
    if "floor" in doc:
        t = doc.pop("floor")
        if not isinstance(t, dict):
            raise SceneError("[floor] must be a table")
        t = dict(t)
        z = _num(t, "[floor]", "z", hi=0.0, hi_open=True)
        floor = Floor(z, _material(t, "[floor]", 0.3))
        _done(t, "[floor]")
    motion = Motion()
    if "motion" in doc:
        t = doc.pop("motion")
        if not isinstance(t, dict):
            raise SceneError("[motion] must be a table")
        t = dict(t)
        motion = Motion(math.radians(_num(t, "[motion]", "yaw_rate_deg_s", 0.0)), _num(t, "[motion]", "speed_m_s", 0.0),
                        _num(t, "[motion]", "sensor_ahead_m", 0.0))
        _done(t, "[motion]")
    scale = _num(doc, "top level", "ambient_scale", 1.0, lo=0.0)
    flicker = Flicker(_num(doc, "top level", "flicker_hz", 100.0, lo=0.0, lo_open=True),
                      _num(doc, "top level", "flicker_depth", 0.0, lo=0.0, hi=1.0))
    _done(doc, "top level")
    return Scene(name, tuple(walls), tuple(boxes), tuple(cyls), floor, ambient, ambient_w, scale, flicker, motion)


def load_scene(path: str | Path) -> Scene:
    path = Path(path)
    try:
        with path.open("rb") as fh:
            doc = tomllib.load(fh)
    except FileNotFoundError:
        raise SceneError(f"{path}: no such scene file") from None
    except tomllib.TOMLDecodeError as exc:
        raise SceneError(f"{path}: not valid TOML: {exc}") from None
    return scene_from_dict(doc, str(path))


# ---------------------------------------------------------------- built-in scenes
def wall_scene(distance_m: float = 2.0, angle_deg: float = 0.0, reflectivity: float = 0.9,
               ambient: str = "indoor", width_m: float = 20.0, texture: str = "plain") -> Scene:
    """A flat wall whose closest point is ``distance_m`` ahead, turned by ``angle_deg`` about z.

    angle 0 faces the sensor (normal along -x); the wall spans ``width_m`` centred on the x axis.
    """
    if not distance_m > 0:
        raise SceneError(f"wall: 'distance' must be positive, got {distance_m}")
    if not abs(angle_deg) < 89.0:
        raise SceneError(f"wall: 'angle' must be within +-89 deg, got {angle_deg}")
    if ambient not in AMBIENT_FRACTION:
        raise SceneError(f"wall: 'ambient' must be one of {', '.join(AMBIENT_FRACTION)}, got {ambient!r}")
    if texture not in TEXTURES:
        raise SceneError(f"wall: 'texture' must be one of {', '.join(TEXTURES)}, got {texture!r}")
    if not 0 < reflectivity <= 1:
        raise SceneError(f"wall: 'reflectivity' must be in (0, 1], got {reflectivity}")
    a = math.radians(angle_deg)
    # the wall's foot of perpendicular from the origin is at distance_m along direction a
    px, py = distance_m * math.cos(a), distance_m * math.sin(a)
    tx, ty = -math.sin(a), math.cos(a)
    h = width_m / 2
    w = Wall((px - h * tx, py - h * ty), (px + h * tx, py + h * ty), (-1.0, 2.0), Material(reflectivity, 0.0, texture))
    return Scene(f"wall-{distance_m:g}m-{angle_deg:g}deg-{reflectivity:g}", walls=(w,), ambient=ambient)


def with_motion(scene: Scene, yaw_rate_deg_s: float | None = None, speed_m_s: float | None = None,
                ambient_scale: float | None = None, flicker_hz: float | None = None,
                flicker_depth: float | None = None, sensor_ahead_m: float | None = None) -> Scene:
    """``scene`` with the given motion, ambient scale and flicker in place of its own (None: keep)."""
    motion, flicker = scene.motion, scene.flicker
    if yaw_rate_deg_s is not None:
        motion = replace(motion, yaw_rate_rad_s=math.radians(yaw_rate_deg_s))
    if speed_m_s is not None:
        motion = replace(motion, speed_m_s=speed_m_s)
    if sensor_ahead_m is not None:
        if not math.isfinite(sensor_ahead_m):
            raise SceneError(f"sensor_ahead_m must be finite, got {sensor_ahead_m}")
        motion = replace(motion, sensor_ahead_m=sensor_ahead_m)
    if flicker_hz is not None:
        if not flicker_hz > 0:
            raise SceneError(f"flicker frequency must be positive, got {flicker_hz} Hz")
        flicker = replace(flicker, hz=flicker_hz)
    if flicker_depth is not None:
        if not 0 <= flicker_depth <= 1:
            raise SceneError(f"flicker depth must be in [0, 1], got {flicker_depth}")
        flicker = replace(flicker, depth=flicker_depth)
    if ambient_scale is not None and not ambient_scale >= 0:
        raise SceneError(f"ambient scale must be >= 0, got {ambient_scale}")
    scale = scene.ambient_scale if ambient_scale is None else ambient_scale
    return replace(scene, motion=motion, flicker=flicker, ambient_scale=scale)


def scene_names() -> list[str]:
    return sorted(["wall", *(p.stem for p in SCENE_DIR.glob("*.toml"))])


def get_scene(spec: str) -> Scene:
    """A scene by built-in name, ``wall:distance=2,angle=30,reflectivity=0.1,ambient=dark``, or a TOML path."""
    name, _, params = spec.partition(":")
    if name == "wall":
        kw: dict[str, Any] = {}
        keys = {"distance": "distance_m", "angle": "angle_deg", "reflectivity": "reflectivity",
                "ambient": "ambient", "width": "width_m", "texture": "texture"}
        for item in filter(None, params.split(",")):
            k, _, v = item.partition("=")
            if k not in keys:
                raise SceneError(f"wall: unknown parameter {k!r}; use {', '.join(keys)}")
            try:
                kw[keys[k]] = v if k in ("ambient", "texture") else float(v)
            except ValueError:
                raise SceneError(f"wall: parameter {k!r} must be a number, got {v!r}") from None
        return wall_scene(**kw)
    if params:
        raise SceneError(f"scene {name!r} takes no parameters")
    builtin = SCENE_DIR / f"{name}.toml"
    if builtin.exists():
        return load_scene(builtin)
    if name.endswith(".toml"):
        return load_scene(name)
    raise SceneError(f"unknown scene {name!r}; choose from: {', '.join(scene_names())} (or a .toml file)")
