"""The simulated IMX219 clock and the simulated co-MCU against their own definitions."""


import copy
import math

import numpy as np
import pytest

from device.sim.mcu import McuConfig, ScheduleRefused, SimulatedMcu
from device.sim.timing import CameraClock, CameraTimingConfig, quantise_frame_duration

LINE_TIME_S = CameraTimingConfig.line_time_s  # the default: mode 5's (device/camera/modes.py MODE5)


def test_mode5_line_time_matches_table_b3():
    # Table B.3: 18904 ns per line; 922 rows -> the 17.4 ms capture time
    assert LINE_TIME_S == 18904e-9
    assert CameraTimingConfig.active_rows * LINE_TIME_S == pytest.approx(17.4e-3, abs=0.05e-3)


def test_free_running_period_is_line_quantised_and_timestamps_late_only():
    cfg = CameraTimingConfig(frame_duration_s=0.05, timestamp_jitter_s=10e-6, drop_probability=0.0)
    cam = CameraClock(cfg, np.random.default_rng(1))
    frames = [cam.next_frame() for _ in range(2000)]
    t = np.array([f.true_start_s for f in frames])
    lines = quantise_frame_duration(0.05, cfg.exposure_s, cfg)
    assert np.allclose(np.diff(t), lines * LINE_TIME_S, atol=1e-12)
    lat = np.array([f.sensor_timestamp_ns for f in frames]) * 1e-9 - t
    assert lat.min() > -1e-9  # an interrupt timestamp is never early
    assert lat.mean() == pytest.approx(10e-6, rel=0.1)


def test_row_exposure_window_rolling_shutter():
    cam = CameraClock(CameraTimingConfig(exposure_s=0.005, drop_probability=0.0), np.random.default_rng(0))
    f = cam.next_frame()
    start, end = f.row_exposure(np.array([0, 921]))
    assert end[0] == pytest.approx(f.true_start_s)
    assert end[1] - end[0] == pytest.approx(921 * f.line_time_s)
    assert np.allclose(end - start, f.exposure_s)


def test_frame_duration_request_takes_effect_two_frames_later():
    cfg = CameraTimingConfig(frame_duration_s=0.05, drop_probability=0.0)
    cam = CameraClock(cfg, np.random.default_rng(0))
    durations = []
    for i in range(8):
        f = cam.next_frame()
        durations.append(f.frame_duration_s)
        if i == 2:
            cam.request(frame_duration_s=0.04)
    old, new = durations[0], durations[-1]
    assert new == pytest.approx(round(0.04 / LINE_TIME_S) * LINE_TIME_S)
    assert durations[3] == old and durations[4] == new  # seen frame 2 -> effective at frame 4
    with pytest.raises(ValueError, match="frame duration"):
        cam.request(frame_duration_s=-1.0)


def test_drops_and_restart_are_deterministic_for_a_seed():
    cfg = CameraTimingConfig(drop_probability=0.05)
    cams = [CameraClock(cfg, np.random.default_rng(7)) for _ in range(2)]
    runs = [[c.next_frame() for _ in range(500)] for c in cams]
    assert runs[0] == runs[1]
    assert 5 < sum(f.dropped for f in runs[0]) < 50
    cams[0].restart(100.0)
    f = cams[0].next_frame()
    assert f.sequence == 0 and 100.0 - 0.06 < f.true_start_s < 100.06


def _mcu(**kw):
    mcu = SimulatedMcu(McuConfig(**kw), np.random.default_rng(0))
    mcu.now_s = 0.01
    return mcu


def test_mcu_pulses_land_on_scheduled_ticks_with_drift():
    mcu = _mcu(drift_ppm=100.0, gpio_connected=False)
    mcu.schedule(100_000, 100_000, 20_000, [True, False])
    mcu.advance_to(1.0)
    rise = np.array(mcu.pulses.rise_tick)
    assert list(rise[:3]) == [100_000, 300_000, 500_000]
    assert list(np.array(mcu.pulses.fall_tick) - rise) == [20_000] * rise.size
    # true time of tick 100000 at 100 ppm fast: 50 ms / 1.0001
    assert mcu.pulses.rise_s[0] == pytest.approx(0.05 / 1.0001, abs=1e-12)


def test_mcu_commands_arrive_in_the_order_they_were_sent():
    # one serial line: a STOP and the SCHEDULE sent right after it (SCHEDULE needs a STOP first)
    # never swap, however their latencies fall (here 0-20 ms each); swapped, the STOP would end
    # the new train before its first pulse
    for seed in range(20):
        mcu = SimulatedMcu(McuConfig(gpio_connected=False, cmd_latency_min_s=0.0, cmd_latency_max_s=0.02),
                           np.random.default_rng(seed))
        mcu.now_s = 0.01
        mcu.stop()
        mcu.schedule(200_000, 100_000, 20_000, [True, False])  # first rise at 100 ms
        mcu.advance_to(0.5)
        assert mcu.pulses.rise_tick[:2] == [200_000, 400_000], seed


def test_mcu_trims_move_the_next_slot_and_add_up():
    # as firmware_pwm (README, TRIM): the first slot, lit or not, starting >= 100 us after arrival
    mcu = _mcu(gpio_connected=False, cmd_latency_min_s=1e-3, cmd_latency_max_s=1e-3)
    mcu.schedule(100_000, 100_000, 20_000, [True, False])
    mcu.advance_to(0.065)  # lit slot 0 (50-60 ms) done; slot 1 (unlit) starts at 100 ms
    mcu.now_s = 0.065
    moved = [mcu.trim(7, 100_010),
             mcu.trim(3, 100_020)]  # waiting for the same slot: the phases add, the last period stays
    mcu.now_s = 0.099  # arrives (1 ms later) as slot 1 begins, less than 100 us before: slot 2 moves
    moved.append(mcu.trim(-5, 100_020))
    mcu.advance_to(0.6)
    rise = mcu.pulses.rise_tick
    assert moved == [1, 1, 2]  # the slot each moves, as the firmware's ACK answers
    assert rise[1] == 200_000 + 10 + 100_020 - 5  # slot 1 moved by 10, slot 2 one new period later, then by -5
    assert rise[2] == rise[1] + 2 * 100_020


def test_mcu_refuses_out_of_envelope_and_past_requests():
    mcu = _mcu(max_width_ticks=10_000, max_duty=0.2)
    with pytest.raises(ScheduleRefused, match="envelope"):
        mcu.schedule(100_000, 100_000, 20_000, [True])
    with pytest.raises(ScheduleRefused, match="duty"):
        mcu.schedule(100_000, 40_000, 9_000, [True])
    with pytest.raises(ScheduleRefused, match="past"):
        mcu.schedule(10, 100_000, 5_000, [True, False])
    with pytest.raises(ScheduleRefused, match="no pulse train"):
        mcu.trim(1, 100_000)


def test_mcu_reset_restarts_the_counter_and_stops_the_laser():
    mcu = _mcu(gpio_connected=False)
    mcu.schedule(100_000, 100_000, 20_000, [True, False])  # 10 pulses/s, within the firmware's rate
    mcu.reset_at(0.5)
    mcu.advance_to(2.0)
    assert max(mcu.pulses.rise_s) < 0.5
    assert mcu.ping(1.0)[1] < 0.6 * 2e6  # ticks since the reset at 0.5 s


def test_gpio_edges_are_late_by_the_latency_model():
    mcu = _mcu(gpio_jitter_s=20e-6, gpio_latency_min_s=3e-6, gpio_outlier_prob=0.0)
    mcu.schedule(100_000, 100_000, 20_000, [True, False])  # 10 pulses/s, within the firmware's rate
    mcu.advance_to(60.0)
    ev = mcu.take_gpio_events(61.0)
    truth = np.sort(np.r_[mcu.pulses.rise_s, mcu.pulses.fall_s])
    late = np.array([e[0] for e in ev]) * 1e-9 - truth
    assert late.min() >= 3e-6 - 1e-9
    assert late.mean() == pytest.approx(23e-6, rel=0.1)


def test_simulated_camera_on_the_imx219_clock_lit_by_the_simulated_mcu():
    """The renderer driven by CameraClock and the MCU's pulses: a pulse covering exactly the
    exposure of rows 200-400 gives those rows the whole exposure of laser light, no row more."""
    from device.sim.camera import SimulatedCamera
    from device.config import load_preset
    from device.sim.render import FrameTiming, RenderOptions, row_overlap_s
    from device.sim.scene import wall_scene
    from device.sync.placement import roi_exposure_window

    cfg = load_preset("thesis-calibrated")
    timing = CameraTimingConfig(frame_duration_s=0.05, exposure_s=0.005, timestamp_jitter_s=10e-6, drop_probability=0.0)
    mcu = SimulatedMcu(McuConfig(drift_ppm=100.0, max_width_ticks=10**6), np.random.default_rng(1))
    cam = SimulatedCamera(cfg, wall_scene(1.5), mcu, options=RenderOptions(ray_samples=1024, background_step=8),
                          timing=timing)
    # place one pulse on frame 1's rows 200-400 using the truth of the clocks (what the controller
    # estimates): a copy of the camera's own clock, random state included, foretells its frames
    probe = copy.deepcopy(cam.clock)
    probe.next_frame()
    f1 = probe.next_frame()
    ws, we = roi_exposure_window(f1.true_start_s, f1.exposure_s, f1.line_time_s, 200, 400)
    t0 = math.ceil(mcu.tick_at(ws))
    width = math.floor(mcu.tick_at(we)) - t0
    mcu.now_s = 0.5
    mcu.schedule(t0, 10**9, width, [True])  # a single pulse (next slot far away)
    cam.start()
    frames = [cam.capture_with_truth() for _ in range(3)]
    assert [f.seq for f, _ in frames] == [0, 1, 2] and [f.lit for f, _ in frames] == [False, True, False]
    f, truth = frames[1]
    # metadata: the frame start, the ISP crop's 155 rows before image row 0, stamped late by the interrupt
    assert f.readout_offset_rows == 155
    assert f.row_exposure_ns(0)[1] > int(f1.true_start_s * 1e9)
    timing = FrameTiming(int(round(f1.true_start_s * 1e9)), f1.exposure_s * 1e6, f1.line_time_s * 1e9,
                         tuple(mcu.windows(0, 10**10)))
    overlap = row_overlap_s(timing, cfg.height)
    full = overlap >= f1.exposure_s - 1e-6  # within the tick rounding
    assert np.flatnonzero(full).tolist() == list(range(200, 401))


def test_simulated_mcu_refuses_trains_faster_than_the_firmware_min_period():
    mcu = SimulatedMcu(McuConfig(), np.random.default_rng(0))
    with pytest.raises(ScheduleRefused, match="envelope_rate"):
        mcu.schedule(10**6, 50_000, 2_000, [True])  # 25 ms between rises: 40 pulses/s
    with pytest.raises(ScheduleRefused, match="envelope_rate"):
        mcu.schedule(10**6, 80_000, 2_000, [True, False, True, False, False])  # lit slots 2 apart: 80 ms
    mcu.schedule(10**6, 100_000, 10_000, [True, False])  # 200 ms between lit rises: accepted
