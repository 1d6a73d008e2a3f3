"""True ranges of a simulated scene along scan rays, computed on the host side of the demo.

The demo must not take its truth from the device it checks: it builds the scene from the same
description the simulator renders (device/sim/scene.py) and casts each scan ray against it here.
Scenes are given in the scan frame (REP 103, the laser plane is z = 0, the laser at the origin),
as the renderer casts its laser fan (device/sim/render.py step 1).
"""

from __future__ import annotations

import numpy as np

from device.sim.geometry import cast, laser_prims, primitives
from device.sim.scene import Scene, get_scene


class SceneTruth:
    """Ranges and a top view of one scene."""

    def __init__(self, scene: Scene):
        self.scene = scene
        self._prims = laser_prims(primitives(scene))

    def ranges(self, angles: np.ndarray) -> np.ndarray:
        """(n,) true range (m) along the scan rays at ``angles`` (rad), +inf where nothing is hit."""
        a = np.asarray(angles, dtype=np.float64).ravel()
        dirs = np.stack([np.cos(a), np.sin(a), np.zeros_like(a)], axis=1)
        return cast(np.zeros(3), dirs, self._prims).t

    def draw(self, ax) -> None:
        """True surfaces in the laser plane, seen from above (x up, y to the left)."""
        label = f"{self.scene.name} (truth)"
        for w in self.scene.walls:
            if w.z_range[0] <= 0 <= w.z_range[1]:
                ax.plot([w.start[1], w.end[1]], [w.start[0], w.end[0]], "k-", lw=2, label=label)
                label = None
        for b in self.scene.boxes:
            if b.z_range[0] <= 0 <= b.z_range[1]:
                c = np.array(b.corners() + b.corners()[:1])
                ax.plot(c[:, 1], c[:, 0], "k-", lw=2, label=label)
                label = None
        t = np.linspace(0, 2 * np.pi, 64)
        for c in self.scene.cylinders:
            if c.z_range[0] <= 0 <= c.z_range[1]:
                ax.plot(c.center[1] + c.radius * np.sin(t), c.center[0] + c.radius * np.cos(t), "k-", lw=2, label=label)
                label = None


def scene_truth(spec: str, distance_m: float) -> SceneTruth:
    """The truth of the scene ``spec`` as ``laserpi serve --scene SPEC --distance-m D`` renders it."""
    return SceneTruth(get_scene(f"wall:distance={distance_m:g}" if spec == "wall" else spec))
