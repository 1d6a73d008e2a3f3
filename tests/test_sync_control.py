"""Closed-loop synchronisation against the simulator's ground truth: targets and hard cases.

The targets (issue 4, simulated, 100 ppm drift, 20 us GPIO jitter): lock within 10 frames,
p99 error <= 20 us and no frame whose ROI is partly unlit after lock. The 1-hour figure is in
BENCHMARKS.md; here a 3-minute run checks the same targets, with the p99 taken over the
settled frames (10 s after lock: the guard is still shrinking while the clock map fills).
"""

from dataclasses import replace

import numpy as np
import pytest

from device.camera.modes import MODE5
from device.sim.mcu import McuConfig
from device.sync.control import (FrameInfo, SyncConfig, SyncController, SyncState, ThesisController,
                                 algorithm1_start_estimate, thesis_error_s)
from device.sync.simulate import SimParams, run

BASE = SimParams(seconds=60.0, seed=11)


def _assert_clean(m):
    assert m["frames_partly_unlit_after_lock"] == 0
    assert m["frames_leaked_after_lock"] == 0


def test_targets_over_three_minutes():
    m = run(replace(BASE, seconds=180.0)).metrics
    assert m["lock_frames"] <= 10
    _assert_clean(m)
    assert m["frames_lit_after_lock"] > 850
    assert m["p99_error_us_settled"] <= 20.0
    assert m["median_error_us"] <= 12.0
    assert m["drift_ppm_estimated"] == pytest.approx(100.0, abs=1.0)
    # the pulse is the ROI window (5 ms + 400 rows x the 18.904 us line time) plus a guard of microseconds
    assert 12561.6 < m["pulse_us"] < 12561.6 + 40


def test_thesis_scheme_is_open_loop_in_drift():
    m = run(replace(BASE, controller="thesis")).metrics
    assert m["lock_frames"] <= 30  # the P controller converges on its own estimate ...
    assert m["p99_error_us"] > 3000  # ... but 100 ppm over a minute moves the pulse by ~6 ms
    assert m["frames_partly_unlit_after_lock"] > 0.5 * m["frames_lit_after_lock"]


def test_outlier_and_spurious_gpio_edges():
    p = replace(BASE, mcu=McuConfig(gpio_spurious_hz=20.0, gpio_outlier_prob=0.05))
    r = run(p)
    m = r.metrics
    assert m["lock_frames"] <= 10 and m["final_state"] == "locked" and m["clock_source"] == "gpio"
    _assert_clean(m)
    assert m["p99_error_us_settled"] <= 25.0


def test_dropped_frames_burst_keeps_the_schedule():
    m = run(replace(BASE, drop_bursts=((20.0, 30),))).metrics
    _assert_clean(m)
    assert m["final_state"] == "locked"
    assert m["p99_error_us_settled"] <= 20.0


def _relock_frames(r, t_event):
    f = r.frames
    after = np.flatnonzero((f["T"] > t_event) & f["delivered"])
    first_locked = after[np.argmax(f["locked"][after])]
    return int(np.sum(f["delivered"][after[0]:first_locked + 1]))


def test_camera_restart_relocks():
    r = run(replace(BASE, camera_restart_s=(20.0,)))
    assert [e for _, e in r.events].count("camera-restart") == 1
    _assert_clean(r.metrics)
    assert _relock_frames(r, 20.05) <= 10


def test_mcu_reset_relocks():
    r = run(replace(BASE, mcu_reset_s=(20.0,)))
    assert [e for _, e in r.events].count("mcu-reset") == 1
    _assert_clean(r.metrics)
    assert _relock_frames(r, 20.0) <= 12
    assert r.metrics["final_state"] == "locked"


def test_no_gpio_wire_falls_back_to_ping_with_a_wider_guard():
    m = run(replace(BASE, mcu=McuConfig(gpio_connected=False))).metrics
    assert m["clock_source"] == "ping" and m["final_state"] == "locked"
    _assert_clean(m)
    assert m["median_error_us"] > 20.0  # lower accuracy, said so ...
    assert m["pulse_us"] < 12561.6 + 4000  # ... but still far from the thesis's 17.4 ms


def test_huge_drift_is_an_error_not_a_wrong_schedule():
    r = run(replace(BASE, seconds=20.0, mcu=McuConfig(drift_ppm=10_000.0)))
    m = r.metrics
    assert m["final_state"] == "error" and "drift" in m["final_reason"]
    assert m["lock_frames"] is None
    assert m["frames_in_error_state"] > 0.9 * m["frames_delivered"]
    assert m["frames_lit_after_lock"] == 0
    assert m["laser_pulses"] == 0  # refused before any train was scheduled


def test_an_mcu_that_refuses_the_pulse_is_never_reported_lit():
    # the firmware's envelope is narrower than the ROI window: every SCHEDULE is refused
    r = run(replace(BASE, seconds=10.0, mcu=McuConfig(max_width_ticks=20_000)))
    m = r.metrics
    assert m["lock_frames"] is None and m["laser_pulses"] == 0
    assert m["final_state"] == "acquiring" and "refused" in m["final_reason"] and "width" in m["final_reason"]


def test_roi_that_does_not_fit_between_frames_is_refused():
    p = replace(BASE, seconds=2.0, camera=replace(BASE.camera, exposure_s=0.045), row_min=0, row_max=900)
    with pytest.raises(ValueError, match="does not fit in the frame duration"):
        run(p)


def test_config_validation():
    with pytest.raises(ValueError, match="ROI rows"):
        SyncConfig(row_min=10, row_max=5, frame_duration_s=0.05)
    with pytest.raises(ValueError, match="pattern"):
        SyncConfig(row_min=1, row_max=5, frame_duration_s=0.05, pattern=(False, False))


def test_thesis_error_equations_5_1_to_5_3():
    p = 0.05
    # frame 3 periods + 10 ms after the PWM start; delta -5 ms; interval 200 us
    e = thesis_error_s(1.0 + 3 * p + 0.010, 1.0, p, -0.005, 200e-6)
    assert e == pytest.approx(0.010 - 0.005 - 100e-6)
    e = thesis_error_s(1.0 + 3 * p + 0.040, 1.0, p, 0.0, 0.0)  # closer to the next pulse: early
    assert e == pytest.approx(-0.010)


def test_algorithm1_retries_until_the_interval_is_small():
    times = iter([0, 500, 900, 1000, 1100, 1150])  # tries: (0..900) too long, (1000..1150) ok
    starts = []
    t_pwm, interval = algorithm1_start_estimate(lambda: starts.append(1), lambda: next(times),
                                                lambda: next(times), interval_max_ns=300)
    assert len(starts) == 2 and interval == 150 and t_pwm == 1100 - 150
    with pytest.raises(RuntimeError, match="interval"):
        algorithm1_start_estimate(lambda: None, iter(range(0, 10**6, 400)).__next__, lambda: 0, 300, max_tries=3)


class _Recorder:
    def __init__(self):
        self.calls = []

    def schedule(self, *a):
        self.calls.append(("schedule", a))
        return 0

    def trim(self, *a):
        self.calls.append(("trim", a))
        return 0

    def stop(self):
        self.calls.append(("stop",))

    def request(self, frame_duration_s=None, exposure_s=None):
        self.calls.append(("request", frame_duration_s))


def test_controller_waits_for_a_clock_map_and_labels_unknown_until_locked():
    rec = _Recorder()
    ctrl = SyncController(SyncConfig(row_min=300, row_max=700, frame_duration_s=0.05), rec)
    lab = ctrl.on_frame(FrameInfo(0, 1_000_000_000, 0.005, MODE5.mode.line_time_s, 0.05), now_ns=1_020_000_000)
    assert lab.lit is None and lab.state is SyncState.ACQUIRING and "clock" in lab.reason
    assert rec.calls == []


def test_thesis_p_controller_gain_is_0_233_f():
    rec = _Recorder()
    cfg = SyncConfig(row_min=300, row_max=700, frame_duration_s=1 / 30)
    ctrl = ThesisController(cfg, rec, t_pwm_ns=0, interval_ns=0, delta_s=0.0, pattern=(True,))
    p = 1 / 30
    ctrl.on_frame(FrameInfo(0, int((10 * p + 0.1 * p) * 1e9), 0.005, MODE5.mode.line_time_s, p), 0)
    f = 1 / rec.calls[-1][1]
    assert f == pytest.approx(30 + 7 * 0.1, rel=1e-6)  # P = 7 at 30 Hz on e/p = 0.1


def test_the_first_train_waits_for_the_co_mcus_quiet_time_after_its_boot():
    """The firmware lights nothing before Info.first_rise_min_ticks of a boot (it may not know
    when the last pulse before a reset ended): the controller places its first train after that
    tick, instead of having it refused.  The simulated MCU boots at 0; a quiet time of 3 s here."""
    quiet_ticks = int(3.0 * McuConfig().tick_hz)
    r = run(replace(BASE, seconds=8.0, sync={"first_rise_min_tick": quiet_ticks}))
    lit = r.frames["label"] == 1
    assert lit.any() and r.metrics["final_state"] == "locked"
    assert r.frames["T"][lit].min() >= 3.0
    _assert_clean(r.metrics)
    free = run(replace(BASE, seconds=8.0))  # the same run without it lights before 3 s
    assert free.frames["T"][free.frames["label"] == 1].min() < 3.0


def test_at_20_scans_per_second_the_first_lit_frames_after_lock_are_not_lost_to_new_trains():
    """Issue 18: at 40 frames/s lit every other one, with the device's sync settings (20 ms command
    latency: device.service.assembly), a train scheduled while processing frame N reaches N + 3 at
    the earliest, so every new train after lock costs a lit frame, a scan. The old controller
    narrowed at once when the GPIO map took over from the pings (also at the frame that locked),
    then widened the narrow train again as the few-pair map's uncertainty grew before its pulses
    fed it: 29 lit frames lost and 2 labelled lit but partly unlit over these 8 seeds."""
    from device.sim.timing import CameraTimingConfig

    lost = 0
    for seed in range(8):
        p = SimParams(seconds=4.0, seed=seed, camera=CameraTimingConfig(frame_duration_s=0.025, exposure_s=0.005, clock_ppm=30.0),
                      mcu=McuConfig(min_period_ticks=90_000, max_duty=0.4),
                      sync=dict(cmd_latency_max_s=0.02, min_guard_s=100e-6, narrow_interval_s=5.0))
        r = run(p)
        f, m = r.frames, r.metrics
        _assert_clean(m)
        first = int(np.argmax(f["label"] == 1))
        lit = (f["sequence"] % 2 == 0) & f["delivered"]
        lost += int(np.sum(lit[first:] & (f["label"][first:] != 1)))
    # 4 were left (an unlock 3 s in at seed 1, a widening at seed 6, from the early clock map's
    # sigma) until the controller took the surer of the GPIO and ping maps (1 left) and the GPIO
    # map's slope stopped resting on clustered block minima
    assert lost == 0


def test_trims_reach_the_mcu_when_every_next_slot_begins_within_the_command_latency():
    """The controller does not know whether a trim arrives before or after the start of the slot
    ahead of the one it aims at (the command latency): the MCU's answer names the slot it moved.
    The old controller waited a frame instead; with a latency that covers most of a frame (or the
    simulated serve's 20 ms at its frame phase) every frame had that doubt, no trim was ever sent,
    and the train drifted out of its guard (here: unlocks at 16 and 19 s)."""
    from device.sim import mcu as sim_mcu

    trims = []
    real_trim = sim_mcu.SimulatedMcu.trim

    def counted(self, phase, period):
        trims.append(real_trim(self, phase, period))
        return trims[-1]

    # the controller's copy of the train, which it aims its trims with, predicts every reported
    # rise to the tick (those of slots from the last trim's on: earlier ones it no longer holds)
    misses = []
    real_edges = SyncController.on_mcu_edges

    def checked(self, reports):
        tr = self.train
        for rise, _ in reports if tr is not None else ():
            slot = tr.ref_slot + round((rise - tr.ref_tick) / tr.period)
            if slot >= tr.ref_slot and rise != tr.start(slot):
                misses.append((slot, rise - tr.start(slot)))
        real_edges(self, reports)

    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(sim_mcu.SimulatedMcu, "trim", counted)
        mp.setattr(SyncController, "on_mcu_edges", checked)
        r = run(replace(BASE, seconds=20.0, seed=0, sync={"cmd_latency_max_s": 0.04}))
    assert [e for _, e in r.events if e != "lock"] == []
    assert len(trims) >= 20 and misses == []
    m = r.metrics
    _assert_clean(m)
    assert m["p99_error_us_settled"] <= 20


def test_the_clock_map_is_the_surer_of_the_gpio_pairs_and_the_pings():
    """A fresh GPIO map of few pairs can be looser than the pings' (its sigma extrapolated from
    three pulses against 40 exchanges bounded to 40 us): the controller takes the pings' then, the
    GPIO map once its pairs make it the surer."""
    cfg = SyncConfig(row_min=300, row_max=700, frame_duration_s=0.05)
    ctrl = SyncController(cfg, _Recorder())
    t0 = 10**9  # the MCU's tick t is at Pi time t0 + t / 2 MHz exactly
    ns = lambda tick: t0 + tick * 500  # noqa: E731
    for i in range(40):  # the MCU stamps its tick within 40 us bounds (the link's minima are known)
        tick = i * 100_000
        ctrl.on_ping(ns(tick) - int(cfg.link_up_min_s * 1e9) - 20_000, tick, ns(tick) + int(cfg.link_down_min_s * 1e9) + 20_000)
    rng = np.random.default_rng(0)

    def pulses(first, n):
        for k in range(first, first + n):
            rise = 4_000_000 + k * 200_000
            ctrl.on_mcu_edges([(rise, rise + 17_220)])
            ctrl.on_gpio_edges([(ns(rise) + 3_000 + int(rng.exponential(20e3)), True),
                                (ns(rise + 17_220) + 3_000 + int(rng.exponential(20e3)), False)])
            seq = 2 * k + 81
            ctrl.on_frame(FrameInfo(seq, ns(rise) + 30_000_000, 0.005, MODE5.mode.line_time_s, 0.05), ns(rise) + 40_000_000)

    pulses(0, 3)
    assert len(ctrl.gpio_map) == 6 and ctrl.clock().source == "ping"
    pulses(3, 30)
    assert len(ctrl.gpio_map) == 66 and ctrl.clock().source == "gpio"


def test_a_loose_early_gpio_map_does_not_stop_the_laser():
    """With three pulses' pairs the GPIO map's slope rested on two block minima 8.6 ms apart
    (seed 0, ROI rows 50-150): its honest sigma then needed a guard above the limit. Trusting it
    because it was fresh, the old controller refused to place a train, so no pulse ever tightened
    the map: unlocked for 2 s until it went stale. Either the fit's fallback to the block medians'
    slope (tests/test_sync_clock_map.py) or taking the surer map (above) keeps it pulsing."""
    r = run(replace(BASE, seconds=4.0, seed=0, row_min=50, row_max=150))
    assert [e for _, e in r.events if e != "lock"] == []
    f = r.frames
    first = int(np.argmax(f["label"] == 1))
    lit = (f["sequence"] % 2 == 0) & f["delivered"]
    assert np.sum(lit[first:] & (f["label"][first:] != 1)) == 0
    _assert_clean(r.metrics)
