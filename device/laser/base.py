"""The one laser interface the device process drives (device/scan/source.py): SyncedLaser
(device/laser/synced.py) on a Pi and in simulation."""

from __future__ import annotations

from typing import Protocol

from device.camera.frame import Frame


class LaserError(RuntimeError):
    """The co-MCU cannot drive the laser now. ``reason``: "lost" (no answer), "reset" (it
    restarted and forgot the schedule), "fault" (it latched a fault and switched the laser off)
    or "refused" (it declined the schedule)."""

    def __init__(self, reason: str, detail: str):
        super().__init__(f"co-MCU {reason}: {detail}")
        self.reason = reason


class Laser(Protocol):
    locked: bool  # pulses are synchronised to the camera's exposure

    def start(self, frame: Frame) -> bool | None:
        """Schedule pulses for the frames after ``frame`` (its timestamp gives the camera's
        phase); raises LaserError. Returns True if it found that the co-MCU had rebooted since
        the last schedule without a LaserError "reset" having said so (e.g. during an outage)."""

    def stop(self) -> None:
        """Laser off now; best effort, never raises (the co-MCU also stops by itself when its
        heartbeats stop)."""

    def frame_lit(self, frame: Frame) -> bool | None:
        """Service the co-MCU for a new frame (heartbeat, synchronisation step) and say whether
        the schedule lit this frame; None while that is not known (not locked). Raises LaserError."""
