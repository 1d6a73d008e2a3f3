"""True ranges of a simulated scene along scan rays, computed on the host side of the demo.

The demo must not take its truth from the device it checks: it rebuilds the scene from the same
description the simulator renders and intersects each scan ray with it here.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from device.analytic_source import wall_ranges


@dataclass(frozen=True)
class WallTruth:
    """A wall perpendicular to +x at ``distance_m`` (REP 103 scan frame), as the 'wall' scene."""

    distance_m: float
    half_width_m: float = 10.0

    def ranges(self, angles: np.ndarray) -> np.ndarray:
        """(n,) true range of each ray at ``angles`` (rad), +inf where a ray misses the wall."""
        a = np.asarray(angles, dtype=np.float64)
        r = wall_ranges(a, self.distance_m)
        return np.where(np.abs(r * np.sin(a)) <= self.half_width_m, r, np.inf)

    def draw(self, ax) -> None:
        w = min(self.half_width_m, 2.0 * self.distance_m)
        ax.plot([-w, w], [self.distance_m, self.distance_m], "k-", lw=2, label=f"wall at {self.distance_m:g} m (truth)")


def scene_truth(spec: str, distance_m: float) -> WallTruth:
    """The truth of the scene ``spec`` as ``laserpi serve --scene`` understands it."""
    if spec != "wall":
        raise ValueError(f"scene {spec!r}: the demo knows the truth of 'wall' only")
    return WallTruth(distance_m)
