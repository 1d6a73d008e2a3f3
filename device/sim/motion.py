"""What moves in a simulated scene, and when (issue 16): the sensor on a robot, objects, flicker.

Time ``t`` is seconds after the scene's time zero (the simulated camera's first frame). The
scene (device/sim/scene.py) is given in the sensor's scan frame at t = 0; later the sensor has
turned and moved:

- **The sensor** rides a robot on a unicycle trajectory (a differential-drive robot): yaw rate w
  and forward speed v constant, so at time t the robot has turned by w t about its vertical axis
  (the scan frame's z) and that axis has moved by ``(v sin(w t) / w, v (1 - cos(w t)) / w)``
  (``(v t, 0)`` for w = 0). The sensor is mounted ``sensor_ahead_m`` = d ahead of the axis, so
  it stands at the axis + d (cos w t, sin w t), starting at the scene's origin: a turn also
  moves it sideways, by d w per second (translation gives depth-dependent parallax; a pure turn
  about the camera's optical centre, d = 0, shifts the image by a homography, independent of
  depth).
- **Objects**: a box or cylinder moves with its ``velocity``; a wall with ``swing_rad_s`` (a door)
  turns about its ``start`` (the hinge). Their texture moves with them.
- **Flicker**: ambient irradiance x (1 + depth sin(2 pi f t)); lamps on the mains flicker at twice
  its frequency (100 Hz on 50 Hz mains, 120 Hz on 60 Hz). Each image row integrates it over its
  own exposure window, so under the rolling shutter the phase changes from row to row.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

from .scene import Flicker, Motion, Scene


def sensor_pose(motion: Motion, t_s: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(yaw rad, x m, y m) of the sensor's scan frame at times ``t_s`` in the scene's frame."""
    t = np.asarray(t_s, dtype=np.float64)
    w, v, d = motion.yaw_rate_rad_s, motion.speed_m_s, motion.sensor_ahead_m
    a = w * t
    # sin(a) / w = t sinc(a / pi); (1 - cos a) / w = 2 sin^2(a / 2) / w = (w t^2 / 2) sinc(a / 2 pi)^2
    x = v * t * np.sinc(a / math.pi) + d * (np.cos(a) - 1)
    y = v * (w * t * t / 2) * np.sinc(a / (2 * math.pi)) ** 2 + d * np.sin(a)
    return a, x, y


def rotation_z(yaw: np.ndarray) -> np.ndarray:
    """(..., 3, 3) rotations by ``yaw`` about z."""
    c, s = np.cos(yaw), np.sin(yaw)
    z, o = np.zeros_like(c), np.ones_like(c)
    return np.stack([np.stack([c, -s, z], -1), np.stack([s, c, z], -1), np.stack([z, z, o], -1)], -2)


def scene_at(scene: Scene, t_s: float) -> Scene:
    """The scene's surfaces where they are at time ``t_s`` (same surfaces, same order and ids)."""
    if not scene.objects_move:
        return scene
    walls = []
    for w in scene.walls:
        if w.swing_rad_s:
            a = w.swing_rad_s * t_s
            c, s = math.cos(a), math.sin(a)
            dx, dy = w.end[0] - w.start[0], w.end[1] - w.start[1]
            w = replace(w, end=(w.start[0] + c * dx - s * dy, w.start[1] + s * dx + c * dy))
        walls.append(w)
    moved = lambda o: replace(o, center=(o.center[0] + o.velocity[0] * t_s, o.center[1] + o.velocity[1] * t_s))  # noqa: E731
    return replace(scene, walls=tuple(walls), boxes=tuple(moved(b) for b in scene.boxes),
                   cylinders=tuple(moved(c) for c in scene.cylinders))


def flicker_mean(flicker: Flicker, start_s: np.ndarray, end_s: np.ndarray) -> np.ndarray:
    """Mean of 1 + depth sin(2 pi f t) over each window [start, end] (the ambient light's factor)."""
    start, end = np.asarray(start_s, dtype=np.float64), np.asarray(end_s, dtype=np.float64)
    if flicker.depth == 0:
        return np.ones(np.broadcast(start, end).shape)
    k = 2 * math.pi * flicker.hz
    span = end - start
    with np.errstate(invalid="ignore", divide="ignore"):
        mean = (np.cos(k * start) - np.cos(k * end)) / (k * span)
    return 1.0 + flicker.depth * np.where(span > 0, mean, np.sin(k * start))


def image_speed_px_s(scene: Scene, fx_px: float, nearest_m: float = 0.5) -> float:
    """An upper bound of how fast the image moves (px/s): the turn, the forward motion seen at
    ``nearest_m``, and the fastest object at that distance; sets how finely the renderer samples
    an exposure in time."""
    speed = abs(scene.motion.speed_m_s) + abs(scene.motion.yaw_rate_rad_s * scene.motion.sensor_ahead_m)
    for o in (*scene.boxes, *scene.cylinders):
        speed += math.hypot(*o.velocity)
    for w in scene.walls:
        speed += abs(w.swing_rad_s) * math.dist(w.start, w.end)
    return fx_px * (abs(scene.motion.yaw_rate_rad_s) + speed / nearest_m)
