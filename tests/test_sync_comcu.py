"""The controller's LaserScheduler on the real firmware (simavr), and the simulator's MCU model
against it: the same commands give the same pulse ticks."""

import numpy as np
import pytest

from device.comcu import CoMcu
from device.comcu_emulator import SteppedMcuPort, build_emulator
from device.sim.mcu import McuConfig, SimulatedMcu
from device.sync.comcu_scheduler import CoMcuScheduler

MS = 2000


@pytest.fixture(scope="module")
def emulator():
    try:
        return build_emulator()
    except Exception as exc:  # a missing simavr must fail loudly, not skip
        pytest.fail(f"simavr harness unavailable: {exc}")


def _run(port, comcu, seconds):
    end = port.seconds + seconds
    while port.seconds < end:
        port.advance(min(0.02, end - port.seconds))
        comcu.heartbeat()


def test_schedule_and_trim_on_the_firmware_match_the_simulated_mcu(emulator):
    period, width, pattern = 100_000, 25_000, [True, False]
    with SteppedMcuPort(*emulator) as port:
        comcu = CoMcu(port)
        sched = CoMcuScheduler(comcu)
        first = comcu.ping().mcu_ticks + 60 * MS
        sched.schedule(first, period, width, pattern)
        _run(port, comcu, 0.13)  # lit pulse 0 (0-12.5 ms after first) is over, the next (at 100 ms) not begun
        sched.trim(-321, period + 40)
        sched.trim(21, period + 50)  # before the same boundary: phases add, the period is the last one
        _run(port, comcu, 0.6)
        second = comcu.ping().mcu_ticks + 120 * MS
        sched.schedule(second, period, width, pattern)  # replaces the train: stopped first
        _run(port, comcu, 0.3)
        fw = sched.edge_reports()
    # the same commands on the simulated MCU, at the same MCU times (no drift, no latency)
    sim = SimulatedMcu(McuConfig(drift_ppm=0.0, gpio_connected=False, cmd_latency_min_s=0.0, cmd_latency_max_s=0.0),
                       np.random.default_rng(0))
    sim.now_s = first / 2e6 - 0.06
    sim.schedule(first, period, width, pattern)
    sim.now_s += 0.13
    sim.trim(-321, period + 40)
    sim.trim(21, period + 50)
    sim.advance_to(first / 2e6 + 0.7)
    fw_rise = [r for r, _ in fw][:len(sim.pulses.rise_tick)]
    assert len(fw_rise) >= 4
    assert fw_rise == sim.pulses.rise_tick[:len(fw_rise)]
    assert fw_rise[2] == first + 2 * period + (-321 + 21) + 2 * (period + 50)
    assert all(f - r == width for r, f in fw)
    assert [r for r, _ in fw if r >= second][:2] == [second, second + 2 * period]


def test_adapter_sends_the_period_change_and_refuses_a_trim_without_a_train(mocker):
    comcu = mocker.Mock()
    sched = CoMcuScheduler(comcu)
    with pytest.raises(RuntimeError, match="trim before any schedule"):
        sched.trim(1, 100)
    sched.schedule(10_000, 100_000, 20_000, [True, False, False])
    comcu.schedule.assert_called_once_with(10_000, 100_000, 20_000, mask=0b001, n=3, stream_edges=True)
    sched.trim(5, 100_012)
    comcu.trim.assert_called_once_with(5, 12)
    with pytest.raises(ValueError, match="1 to 32"):
        sched.schedule(0, 1, 1, [True] * 33)
