"""The co-MCU's eye-safety envelope under random command sequences, judged on the true laser pin
(device/sim/firmware_fuzz.py; the full run is `laserpi fuzz-firmware`, see BENCHMARKS.md).

The first tests feed the pin checker made-up pin logs, one broken rule each, so that a checker
that stopped seeing a violation fails here.  The last runs 300 sequences on the production ELF.
"""
from pathlib import Path

import pytest

from device.sim.firmware_fuzz import CYCLES_PER_MS, Envelope, PinLog, check_pin, fuzz
from device.model.envelope import parse_makefile_envelope
from protocol import mcu

ENV = Envelope(max_pulse_ticks=34_800, max_duty_ppm=200_000, min_period_ticks=180_000)
MS = 2000  # ticks


def pin_log(pulses, *, resets=(), timer_starts=(0,), keepalives=None, widths=(), quiet=(), end=None):
    """A PinLog from (rise, fall) pulses in ticks of a timer started at cycle 0 (a reset restarts
    it: give its start in timer_starts, in cycles).  By default one keepalive answers every rise."""
    edges = [(8 * t, level) for rise, fall in pulses for t, level in ((rise, 1), (fall, 0)) if t is not None]
    if keepalives is None:
        keepalives = [(c, c) for c, level in edges if level]
    return PinLog(edges, list(timer_starts), list(resets), list(keepalives), list(widths), list(quiet),
                  end if end is not None else (edges[-1][0] if edges else 0) + 8)


def train(first, period, width, count):
    return [(first + k * period, first + k * period + width) for k in range(count)]


def kinds(check):
    return sorted((v.rule, v.across_reset, v.after_cut) for v in check.violations)


def test_a_train_at_the_limits_passes():
    check = check_pin(pin_log(train(1000, 180_000, 34_800, 6)), ENV)
    assert check.violations == [] and len(check.pulses) == 6
    assert check.extremes["longest_pulse_ticks"] == 34_800
    assert check.extremes["shortest_rise_to_rise_ticks"] == check.extremes["shortest_fall_to_fall_ticks"] == 180_000


def test_a_pulse_one_tick_too_long_beyond_the_compare_lag_is_a_width_violation():
    assert check_pin(pin_log(train(1000, 200_000, 34_801, 2)), ENV).violations == []  # +1: compare lag
    check = check_pin(pin_log(train(1000, 200_000, 34_802, 2)), ENV)
    assert kinds(check) == [("width", False, False)] * 2
    assert check.violations[0].missed_by == 1


def test_duty_and_rate_are_each_checked():
    loose_rate = Envelope(34_800, 200_000, 600)
    # off time 139_199 after a 34_800 pulse: one tick under the duty rule's 4 x 34_800
    assert kinds(check_pin(pin_log(train(1000, 34_800 + 139_199, 34_800, 2)), loose_rate)) == [
        ("duty", False, False)]
    assert check_pin(pin_log(train(1000, 34_800 + 139_200, 34_800, 2)), loose_rate).violations == []
    check = check_pin(pin_log(train(1000, 179_999, 2_000, 2)), ENV)
    assert kinds(check) == [("rate", False, False)] * 2 and {v.missed_by for v in check.violations} == {1}
    # a narrow pulse after a wide one: rises 180_000 apart, falls not
    narrow_after_wide = pin_log([(1000, 11_000), (181_000, 183_000)])
    assert [v.detail for v in check_pin(narrow_after_wide, ENV).violations] == ["falls 172000 ticks apart"]


def test_a_pulse_cut_short_is_judged_on_its_scheduled_fall_but_the_pulse_after_a_cut_is_not():
    widths = [(0, 20_000)]
    cut_second = pin_log([(1000, 21_000), (181_000, 186_000)], widths=widths)  # falls 165_000 apart
    check = check_pin(cut_second, ENV)
    assert check.violations == [] and check.cut_falls == 1 and check.pulses[1].cut
    # the first pulse cut short: the next one's fall is measured from where the pin fell
    widths.append((8 * 100_000, 10_012))  # a second schedule, narrower
    check = check_pin(pin_log([(1000, 11_013), (181_000, 191_012)], widths=widths), ENV)
    assert kinds(check) == [("rate", False, True)] and check.violations[0].missed_by == 1


def test_pulses_on_both_sides_of_a_reset_are_checked_too():
    reset = 8 * 40_000  # the MCU restarts its timer then: the second pulse is 10_000 ticks into its boot
    check = check_pin(pin_log([(1000, 21_000), (50_000, 70_000)], resets=[reset], timer_starts=(0, reset)), ENV)
    assert check.pulses[1].boot == 1
    assert kinds(check) == [("duty", True, False), ("rate", True, False), ("rate", True, False)]
    assert check.extremes["shortest_rise_to_rise_ticks_across_reset"] == 49_000


def test_the_pin_must_stay_low_after_stop_fault_reset_and_heartbeat_loss_and_at_the_end():
    pulses = train(1000, 200_000, 10_000, 3)
    quiet = [(8 * 150_000, 8 * 205_000, "STOP")]  # the second pulse rises at 201_000
    check = check_pin(pin_log(pulses, quiet=quiet), ENV)
    assert [v.rule for v in check.violations] == ["quiet"] and "after STOP" in check.violations[0].detail
    assert check_pin(pin_log(pulses, quiet=[(8 * 150_000, 8 * 201_000, "STOP")]), ENV).violations == []
    # one keepalive only, answered at the start: 100 ms later the pin must be low
    lost = pin_log(pulses, keepalives=[(0, 0)])
    assert [(v.rule, v.cycle) for v in check_pin(lost, ENV).violations] == [("heartbeat", 8 * 201_000)]
    assert check_pin(pin_log(pulses[:1], keepalives=[(0, 0)]), ENV).violations == []
    still_high = pin_log(pulses + [(601_000, None)])
    assert [v.rule for v in check_pin(still_high, ENV).violations] == ["end"]


@pytest.mark.slow
def test_300_random_sequences_keep_the_envelope_on_the_true_pin(emulator):
    harness, elf = emulator
    result = fuzz(300, seed=13, batch=300, harness=harness, elf=elf)
    makefile = parse_makefile_envelope((Path(elf).parents[1] / "Makefile").read_text())
    per_us = mcu.TICKS_PER_SECOND // 1_000_000  # the emulated 16 MHz build's ticks per microsecond
    assert result["envelope"] == {"max_pulse_ticks": makefile.max_pulse_us * per_us,
                                  "max_duty_ppm": makefile.max_duty_ppm,
                                  "min_period_ticks": makefile.min_period_us * per_us}
    paths = {p: n["times"] for p, n in result["paths"].items()}
    taken = {  # the fuzz really exercised the firmware: each path at least this often (seed 13
        # takes each 1.7 to 5 times as often)
        "pulse": 70, "pulse.cut_short": 10, "stop.cut_pulse": 8,
        "schedule.accepted": 60, "schedule.refused.envelope_rate": 50, "schedule.refused.envelope_width": 25,
        "schedule.refused.envelope_duty": 8, "schedule.refused.busy": 40,
        "trim.accepted": 40, "trim.refused.envelope_rate": 5, "trim.arrived_mid_pulse.accepted": 4,
        "trim.arrived_under_1ms_before_a_rise.accepted": 2,
        "fault.heartbeat": 15, "reset.power": 5, "reset.wdt": 5,
        "link.nack.crc": 10, "link.nack.malformed": 300,
    }
    assert {p: paths.get(p, 0) for p in taken if paths.get(p, 0) < taken[p]} == {}
    assert paths.get("boot.unexpected", 0) == 0, "no boot but the resets the fuzz made (no watchdog reset)"
    assert {name: k["first"] for name, k in result["violations_by_kind"].items()} == {}
