"""Small fakes of the device process's parts (camera, co-MCU laser, pipeline) with fault switches.

They share one ``FakeRig`` so that the camera knows which frames the laser really lit: the
pipeline fake then checks that the process paired a lit frame with an unlit one.
"""

from __future__ import annotations

import threading
import time

import numpy as np

from device.camera.frame import Frame
from device.camera.modes import MODE5
from device.laser.base import LaserError
from device.scan.pipeline import ScanRays
from protocol.server import ScanGeometry

N_POINTS = 32
WALL_M = 2.0


class FakeRig:
    def __init__(self, fps: float = 40.0):
        self.period_s = 1.0 / fps
        self.lock = threading.Lock()
        self.lit_parity: int | None = None  # frames with seq % 2 == parity are lit, None = laser off
        self.stall_until = 0.0  # camera delivers nothing before this monotonic time
        self.camera_raise = 0  # next captures that raise
        self.mcu_down_until = 0.0  # co-MCU answers nothing before this time
        self.mcu_reset_pending = False  # next service call finds the co-MCU freshly reset
        self.laser_stops = 0


class FakeCamera:
    def __init__(self, rig: FakeRig, height: int = 8):
        self.rig = rig
        self.height = height
        self.running = False
        self.starts = 0
        self.seq = 0
        self.next_at = 0.0

    def start(self) -> None:
        self.running = True
        self.starts += 1
        self.seq = 0
        self.next_at = time.monotonic() + self.rig.period_s

    def stop(self) -> None:
        self.running = False

    def capture(self, timeout_s: float) -> Frame | None:
        if not self.running:
            raise RuntimeError("capture on a stopped camera")
        with self.rig.lock:
            if self.rig.camera_raise:
                self.rig.camera_raise -= 1
                raise OSError("fake camera: dequeue failed")
        now = time.monotonic()
        due = max(self.next_at, self.rig.stall_until)
        if due - now > timeout_s:
            time.sleep(timeout_s)
            return None
        time.sleep(max(0.0, due - now))
        if self.rig.stall_until > self.next_at:  # frames during a stall are lost
            self.seq += int((self.rig.stall_until - self.next_at) / self.rig.period_s)
        self.next_at = max(self.next_at, self.rig.stall_until) + self.rig.period_s
        with self.rig.lock:
            lit = self.rig.lit_parity is not None and self.seq % 2 == self.rig.lit_parity
        image = np.full((self.height, N_POINTS), 200 if lit else 10, dtype=np.uint8)
        frame = Frame(image, self.seq, time.monotonic_ns(), 1000.0, self.rig.period_s * 1e6, MODE5.mode.line_time_ns, lit)
        self.seq += 1
        return frame


class FakeLaser:
    """The co-MCU and synchronisation: lights every other frame after start."""

    def __init__(self, rig: FakeRig):
        self.rig = rig
        self.locked = False
        self.starts = 0

    def _check(self) -> None:
        if time.monotonic() < self.rig.mcu_down_until:
            raise LaserError("lost", "no answer to PING within 50 ms")
        if self.rig.mcu_reset_pending:
            self.rig.mcu_reset_pending = False
            with self.rig.lock:
                self.rig.lit_parity = None
            raise LaserError("reset", "STATUS shows reset cause 'watchdog', schedule gone")

    def start(self, frame: Frame) -> None:
        self._check()
        with self.rig.lock:
            self.rig.lit_parity = (frame.seq + 1) % 2
        self.locked = True
        self.starts += 1

    def stop(self) -> None:
        with self.rig.lock:
            self.rig.lit_parity = None
            self.rig.laser_stops += 1
        self.locked = False

    def frame_lit(self, frame: Frame) -> bool | None:
        self._check()
        with self.rig.lock:
            parity = self.rig.lit_parity
        return None if parity is None else frame.seq % 2 == parity


class FakePipeline:
    """Checks the pairing and returns a flat wall at WALL_M."""

    def __init__(self):
        self.pairs = 0
        self.both = 0  # scans made with both unlit neighbours

    def __call__(self, lit: Frame, dark: Frame, other_dark: Frame | None = None) -> ScanRays:
        for d in (dark, other_dark):
            if d is not None and (lit.lit is not True or d.lit is not False or abs(lit.seq - d.seq) != 1):
                raise AssertionError(f"bad pair: lit {lit.seq} ({lit.lit}), dark {d.seq} ({d.lit})")
        if other_dark is not None and other_dark.seq == dark.seq:
            raise AssertionError(f"both unlit neighbours of lit frame {lit.seq} are frame {dark.seq}")
        self.pairs += 1
        self.both += other_dark is not None
        return ScanRays(np.full(N_POINTS, WALL_M, dtype=np.float32), np.full(N_POINTS, 200, dtype=np.uint8),
                        lit.sensor_timestamp_ns, 0)


def fake_geometry() -> ScanGeometry:
    return ScanGeometry(np.linspace(0.8, -0.8, N_POINTS, dtype=np.float32), 0.05, 4.0)
