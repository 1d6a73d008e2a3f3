"""The simulator's MCU model against the real firmware (simavr) driven through CoMcuTrain, the
controller's LaserScheduler on device.comcu: the same commands give the same pulse ticks."""

import numpy as np
import pytest

from device.comcu import CoMcu, CoMcuTrain
from device.comcu_emulator import SteppedMcuPort, build_emulator
from device.sim.mcu import McuConfig, SimulatedMcu

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
        sched = CoMcuTrain(comcu)
        first = comcu.ping().mcu_ticks + 60 * MS
        sched.schedule(first, period, width, pattern)
        _run(port, comcu, 0.13)  # lit pulse 0 (0-12.5 ms after first) is over, the next (at 100 ms) not begun
        sched.trim(-321, period + 40)
        sched.trim(21, period + 50)  # before the same boundary: phases add, the period is the last one
        _run(port, comcu, 0.6)
        second = comcu.ping().mcu_ticks + 120 * MS
        sched.schedule(second, period, width, pattern)  # replaces the train: stopped first
        _run(port, comcu, 0.3)
        fw = [(e.rise_ticks, e.fall_ticks) for e in comcu.edges() if not e.flags]
    # the same commands on the simulated MCU, at the same MCU times (no drift, no latency)
    sim = SimulatedMcu(McuConfig(drift_ppm=0.0, gpio_connected=False, cmd_latency_min_s=1e-3, cmd_latency_max_s=1e-3),
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
    # trims sent ~70 ms after the first rise: slot 2 (lit, at 100 ms) is the first they reach
    assert fw_rise[1] == first + 2 * period - 300 and fw_rise[2] == fw_rise[1] + 2 * (period + 50)
    assert all(f - r == width for r, f in fw)
    assert [r for r, _ in fw if r >= second][:2] == [second, second + 2 * period]
