"""Pulse placement for a rolling shutter: light exactly the exposure of the rows the laser can reach.

Row ``r`` of a frame whose row-0 readout starts at ``T`` is exposed during
``[T - E + r*line_time, T + r*line_time]`` (``E`` the exposure). The laser can only land on rows
``[row_min, row_max]`` (the region of interest, from the calibration and the range limits), so
the pulse that lights every one of those rows for its whole exposure, and nothing more, is::

    start = T - E + row_min * line_time
    end   = T + row_max * line_time        width = E + (row_max - row_min) * line_time

The thesis (Table B.3, section B.3; docs/thesis-notes.md N18) instead kept the laser on for the whole 17.4 ms readout of
the 922 rows of mode 5, which is what set its Class 1 power to 25 mW. Any timing uncertainty is
covered by a guard on both sides (chosen by the controller from the clock map's uncertainty);
the guard is part of the reported pulse width.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, Sequence

import numpy as np

from device.sync.clock_map import ClockEstimate

if TYPE_CHECKING:
    from device.config import LaserSpec

THESIS_PULSE_S = 17.4e-3  # thesis Table 4.2 / B.3: pulse = readout of all 922 rows of mode 5


def roi_exposure_window(t_readout: np.ndarray | float, exposure_s: np.ndarray | float, line_time_s: np.ndarray | float,
                        row_min: np.ndarray | int, row_max: np.ndarray | int) -> tuple[np.ndarray, np.ndarray]:
    """Start and end of the exposure of rows ``row_min..row_max`` (inclusive), in the unit of ``t_readout``.

    All arguments broadcast (per-frame ROI rows allowed); ``t_readout`` and the returned times are in
    seconds if ``t_readout`` is. Raises ValueError for an empty or negative row range.
    """
    if isinstance(exposure_s, float) and isinstance(line_time_s, float) and isinstance(row_min, int) \
            and isinstance(row_max, int):  # the per-frame scalar case, kept cheap
        if not 0 <= row_min <= row_max:
            raise ValueError(f"ROI rows must satisfy 0 <= row_min <= row_max, got {row_min}..{row_max}")
        if exposure_s <= 0 or line_time_s <= 0:
            raise ValueError(f"exposure_s and line_time_s must be positive, got {exposure_s}, {line_time_s}")
        return t_readout - exposure_s + row_min * line_time_s, t_readout + row_max * line_time_s
    if isinstance(row_min, (int, np.integer)) and isinstance(row_max, (int, np.integer)):
        bad_rows = not 0 <= row_min <= row_max
    else:
        bad_rows = bool(np.any(np.asarray(row_min) < 0) or np.any(np.asarray(row_max) < np.asarray(row_min)))
    if bad_rows:
        raise ValueError(f"ROI rows must satisfy 0 <= row_min <= row_max, got {row_min}..{row_max}")
    if np.any(np.asarray(exposure_s) <= 0) or np.any(np.asarray(line_time_s) <= 0):
        raise ValueError("exposure_s and line_time_s must be positive")
    return t_readout - exposure_s + row_min * line_time_s, t_readout + row_max * line_time_s


def check_separation(frame_duration_s: float, exposure_s: float, line_time_s: float, row_min: int, row_max: int,
                     guard_s: float = 0.0) -> None:
    """Raise ValueError if a pulse lighting one frame's ROI would also light the next frame's ROI.

    Frame differencing needs unlit frames (docs/thesis-notes.md N10): the ROI window of frame k must end before
    that of frame k+1 begins, i.e. ``E + (row_max - row_min) * line_time + 2 guard < frame duration``.
    """
    width = exposure_s + (row_max - row_min) * line_time_s + 2 * guard_s
    if not width < frame_duration_s:
        raise ValueError(
            f"ROI exposure window {width * 1e3:.3f} ms (exposure {exposure_s * 1e3:.3f} ms, rows {row_min}-{row_max}, "
            f"guard {guard_s * 1e6:.1f} us) does not fit in the frame duration {frame_duration_s * 1e3:.3f} ms: "
            "lit and unlit frames would overlap; shorten the exposure or the ROI")


def window_to_ticks(start_ns: float, end_ns: float, est: ClockEstimate, guard_s: float) -> tuple[int, int]:
    """MCU (first tick, width in ticks) of a pulse covering ``[start - guard, end + guard]`` (Pi ns).

    The start is rounded down and the end up, so the pulse never covers less than asked.
    """
    if not end_ns > start_ns or guard_s < 0:
        raise ValueError(f"need end > start and guard >= 0, got {start_ns}, {end_ns}, {guard_s}")
    t0 = math.floor(float(est.pi_to_mcu_tick(start_ns - guard_s * 1e9)))
    t1 = math.ceil(float(est.pi_to_mcu_tick(end_ns + guard_s * 1e9)))
    return t0, t1 - t0


@dataclass(frozen=True)
class PulseBudget:
    """Pulse width and duty of a placement, beside the thesis's 17.4 ms pulse at the same frame rate."""

    pulse_s: float
    duty: float
    pulse_rate_hz: float
    thesis_pulse_s: float
    thesis_duty: float

    @property
    def width_ratio(self) -> float:
        return self.thesis_pulse_s / self.pulse_s


def pulse_budget(exposure_s: float, line_time_s: float, row_min: int, row_max: int, frame_duration_s: float,
                 pattern: Sequence[bool], guard_s: float = 0.0) -> PulseBudget:
    """Width and duty of the ROI pulse (guard included) and of the thesis's full-readout pulse."""
    if not pattern or not any(pattern):
        raise ValueError("pattern must light at least one frame")
    start, end = roi_exposure_window(0.0, exposure_s, line_time_s, row_min, row_max)
    width = float(end - start) + 2 * guard_s
    lit = sum(bool(p) for p in pattern) / len(pattern)
    rate = lit / frame_duration_s
    return PulseBudget(pulse_s=width, duty=width * rate, pulse_rate_hz=rate, thesis_pulse_s=THESIS_PULSE_S,
                       thesis_duty=THESIS_PULSE_S * rate)


def class1_power_w(pulse_s: float, rate_hz: float, laser: LaserSpec | None = None, closest_eye_m: float = 0.01) -> float:
    """Largest Class 1 peak power (W) of the configured line laser at this pulse width and rate.

    Calls the project's eye-safety model (``device.model.safety``, thesis 3.3 with docs/thesis-notes.md N1, N2);
    ``laser`` defaults to the thesis's 808 nm, 120 deg, 4 mm line, 1 mm source (Table 4.2) and
    ``closest_eye_m`` to the thesis's 10 mm (section B.3).
    """
    from device.config import LaserSpec
    from device.model import safety

    las = LaserSpec() if laser is None else laser
    model = safety.PulsedLineLaser(wavelength_nm=las.wavelength_m * 1e9, pulse_s=pulse_s, rate_hz=rate_hz,
                                   fan_rad=las.fan_angle_rad, line_height_m=las.line_height_m,
                                   source_diameter_m=las.source_diameter_m)
    return safety.max_power_w(model, closest_eye_m)
