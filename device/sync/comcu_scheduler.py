"""The controllers' ``LaserScheduler`` on the real co-MCU link (``device.comcu.CoMcu``).

Translates between the controller's terms and protocol/mcu.py:

- ``schedule(first, period, width, pattern)`` -> SCHEDULE with ``mask`` bit i = ``pattern[i]``,
  ``n = len(pattern)`` and edge streaming on (the controller verifies every lit pulse).
- ``trim(phase, period)``: same timing as the firmware's TRIM (applied at the fall of the lit
  pulse in progress or next; the next lit rise = that rise + phase + k x new period), but the
  controller gives the new period *absolute* and TRIM takes its *change*.
- ``schedule`` while a train runs: the firmware refuses (BUSY), so the train is stopped first.
- ``edge_reports()``: the MCU's EDGE reports as (rise tick, fall tick), leaving out pulses whose
  fall was forced late or that were cut (their ticks are not the scheduled ones).
- ``ping_sample()``: (Pi send ns, MCU tick when the PING arrived, Pi receive ns).
"""

from __future__ import annotations

from typing import Sequence

from protocol import mcu


class CoMcuScheduler:
    """One job: speak the controller's LaserScheduler through a CoMcu (commands raise CoMcuNack on refusal)."""

    def __init__(self, comcu) -> None:
        self.comcu = comcu
        self._period: int | None = None

    def schedule(self, first_start_tick: int, period_ticks: int, width_ticks: int, pattern: Sequence[bool]) -> None:
        if not 1 <= len(pattern) <= 32:
            raise ValueError(f"pattern must have 1 to 32 slots (SCHEDULE's mask is 32 bits), got {len(pattern)}")
        mask = sum(1 << i for i, lit in enumerate(pattern) if lit)
        if self._period is not None:
            self.stop()
        self.comcu.schedule(first_start_tick, period_ticks, width_ticks, mask=mask, n=len(pattern), stream_edges=True)
        self._period = period_ticks

    def trim(self, phase_ticks: int, period_ticks: int) -> None:
        if self._period is None:
            raise RuntimeError("trim before any schedule: there is no period to change")
        self.comcu.trim(phase_ticks, period_ticks - self._period)
        self._period = period_ticks

    def stop(self) -> None:
        self.comcu.stop()
        self._period = None

    def edge_reports(self) -> list[tuple[int, int]]:
        bad = mcu.EdgeFlag.FALL_FORCED | mcu.EdgeFlag.CUT
        return [(e.rise_ticks, e.fall_ticks) for e in self.comcu.edges() if not e.flags & bad]

    def ping_sample(self) -> tuple[int, int, int]:
        r = self.comcu.ping()
        return r.host_send_ns, r.mcu_rx_ticks, r.host_recv_ns
