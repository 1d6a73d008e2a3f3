"""The calibration target: a printed checkerboard on a white mount (thesis section 4.2.1), as
calibration detects it and the simulator renders it (device/sim/checkerboard.py)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class BoardSpec:
    """A checkerboard of ``squares_x`` x ``squares_y`` squares of side ``square_m`` (thesis 4.2.1:
    7x10 squares of 41.4 mm) on a white mount ``margin_squares`` wide on every side.

    Board frame: origin at the first inner corner, x along the ``squares_x`` direction, y along
    ``squares_y``, z into the board (OpenCV's object-point convention); inner corners at
    (i, j, 0) * square_m for i < squares_x - 1, j < squares_y - 1.
    """

    squares_x: int = 10
    squares_y: int = 7
    square_m: float = 0.0414
    margin_squares: float = 1.0

    def __post_init__(self) -> None:
        if self.squares_x < 3 or self.squares_y < 3 or self.square_m <= 0:
            raise ValueError(f"a checkerboard needs >= 3x3 squares of positive size, got {self}")

    @property
    def pattern_size(self) -> tuple[int, int]:
        """Inner corners (columns, rows), as OpenCV's patternSize."""
        return self.squares_x - 1, self.squares_y - 1

    def object_points(self) -> np.ndarray:
        """(N, 3) inner-corner coordinates in the board frame, row by row (OpenCV order)."""
        nx, ny = self.pattern_size
        j, i = np.mgrid[0:ny, 0:nx]
        return np.stack([i.ravel(), j.ravel(), np.zeros(nx * ny)], axis=-1) * self.square_m

    def outline(self, margin: float = 0.0) -> np.ndarray:
        """(4, 3) corners of the checker area grown by ``margin`` squares, board frame, metres."""
        lo_x, lo_y = -1.0 - margin, -1.0 - margin
        hi_x, hi_y = self.squares_x - 1.0 + margin, self.squares_y - 1.0 + margin
        pts = [(lo_x, lo_y), (hi_x, lo_y), (hi_x, hi_y), (lo_x, hi_y)]
        return np.array([(x, y, 0.0) for x, y in pts]) * self.square_m
