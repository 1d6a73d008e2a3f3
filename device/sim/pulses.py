"""Laser pulse schedules for the simulator: when the laser is on, in CLOCK_MONOTONIC ns.

The simulator lights frames from these windows through the rolling shutter (render step 7), so
which frames (and rows) are lit follows the timing, never a flag.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol


class PulseSource(Protocol):
    def windows(self, start_ns: int, end_ns: int) -> list[tuple[int, int]]:
        """The laser's on-windows [(on, off), ...] that overlap [start_ns, end_ns]."""
        ...


@dataclass(frozen=True)
class PulseTrain:
    """Periodic pulses: on at ``first_on_ns + k * period_ns`` for ``width_ns`` (k >= 0)."""

    first_on_ns: int
    period_ns: int
    width_ns: int

    def __post_init__(self) -> None:
        if not 0 < self.width_ns <= self.period_ns:
            raise ValueError(f"pulse width {self.width_ns} ns must be in (0, period {self.period_ns} ns]")

    def windows(self, start_ns: int, end_ns: int) -> list[tuple[int, int]]:
        k0 = max(0, (start_ns - self.width_ns - self.first_on_ns) // self.period_ns)
        out = []
        k = k0
        while True:
            on = self.first_on_ns + k * self.period_ns
            if on > end_ns:
                break
            if on + self.width_ns >= start_ns:
                out.append((on, on + self.width_ns))
            k += 1
        return out


@dataclass(frozen=True)
class NoPulses:
    """The laser never fires (dark frames only)."""

    def windows(self, start_ns: int, end_ns: int) -> list[tuple[int, int]]:
        return []


def frame_aligned_train(first_timestamp_ns: int, frame_duration_us: float, exposure_us: float, line_time_ns: float,
                        height: int, pulse_us: float, every: int = 2) -> PulseTrain:
    """Pulses that light every ``every``-th frame starting with the frame at ``first_timestamp_ns``.

    The pulse is centred on T + ((H-1) t_line - E) / 2 (T = the frame's SensorTimestamp): the
    middle of the window [T + (H-1) t_line - E, T] where all rows expose at once, which is also
    the middle of the frame's whole exposure span. If that window is shorter than the pulse the
    top and bottom rows are only partly lit.
    """
    center = ((height - 1) * line_time_ns - exposure_us * 1e3) / 2  # relative to T
    on = int(round(first_timestamp_ns + center - pulse_us * 1e3 / 2))
    return PulseTrain(on, int(round(every * frame_duration_us * 1e3)), int(round(pulse_us * 1e3)))
