"""The simulated Pi's co-MCU (device/sim/hardware.py): the heartbeats reach the firmware."""

from __future__ import annotations

import pytest

from device.laser.comcu import HEARTBEAT_SEQ
from device.sim.hardware import SimulatedHardware
from protocol import mcu


@pytest.fixture
def hardware():
    hw = SimulatedHardware(seed=5)
    yield hw
    hw.close()


def test_heartbeats_reach_the_firmware_at_their_interval_far_inside_its_timeout(hardware):
    """The simulated heartbeat thread (the tickers) writes every tick_s of simulated time through
    the pty (CoMcu's non-blocking writes); the firmware (timeout: its INFO's heartbeat_timeout_ms,
    50 ms) sees them ~15 ms apart, never near 50."""
    comcu = hardware.open_comcu()
    arrived: list[int] = []  # simulated ns at which a heartbeat's bytes entered the MCU's UART
    write = hardware.mcu.write
    heartbeat = mcu.encode_message(mcu.Heartbeat(), HEARTBEAT_SEQ)

    def recording(data: bytes) -> int:
        if heartbeat in bytes(data):
            arrived.append(hardware.now_ns())
        return write(data)

    hardware.mcu.write = recording
    try:
        timeout_ns = comcu.info().heartbeat_timeout_ms * 1_000_000
        hardware.tickers.append(comcu.send_heartbeat)
        assert hardware.wait_until(hardware.now_ns() + 1_000_000_000, 5.0)
        hardware.tickers.clear()
        gaps = [b - a for a, b in zip(arrived, arrived[1:])]
        assert len(gaps) >= 50
        assert sorted(gaps)[len(gaps) // 2] == pytest.approx(hardware.tick_ns, abs=hardware.step_ns)
        assert max(gaps) <= hardware.tick_ns + 2 * hardware.step_ns + 10_000_000 < timeout_ns, max(gaps) / 1e6
        comcu.edges()
        assert comcu.heartbeat_acks >= len(arrived) - 2 and comcu.heartbeat_state[1] == mcu.Fault(0)
    finally:
        comcu.port.close()
