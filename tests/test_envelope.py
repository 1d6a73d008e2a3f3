"""device.model.envelope: the firmware's compiled-in envelope against the Class 1 model.

The compiled-in defaults are read from firmware_pwm/Makefile (their one source of truth).
"""
import math
import random
import subprocess
import sys
from pathlib import Path

import pytest

from device.config import load_preset, save_config
from device.model import safety
from device.model.envelope import (EnvelopeError, FirmwareEnvelope, LineLaserOptics, compute_envelope,
                                   parse_makefile_envelope, period_candidates_s, shortest_class1_period_s,
                                   verify_envelope)

ROOT = Path(__file__).resolve().parents[1]
EYE_M = 0.010  # thesis 4.1.4: no eye closer than 1 cm


def _defaults():
    return parse_makefile_envelope((ROOT / "firmware_pwm" / "Makefile").read_text())


@pytest.fixture(scope="module")
def thesis():
    """The thesis laser (Table 4.4) from the preset: 808 nm, 120 deg fan, 4 mm line, 1 mm source."""
    laser = load_preset("thesis-design").laser
    optics = LineLaserOptics(laser.wavelength_m * 1e9, laser.fan_angle_rad, laser.line_height_m,
                             laser.source_diameter_m)
    assert (optics.wavelength_nm, math.degrees(optics.fan_rad), optics.line_height_m, optics.source_diameter_m) == \
        pytest.approx((808, 120, 4e-3, 1e-3))
    return optics


def _brute_force_worst(optics, power_w, env, samples, seed):
    """Largest NOHD over random trains inside the region (log-uniform widths and periods)."""
    rng = random.Random(seed)
    worst = 0.0
    lo_w, hi_w = math.log(100e-6), math.log(env.max_pulse_s)
    for _ in range(samples):
        w = math.exp(rng.uniform(lo_w, hi_w))
        p_min = max(env.min_period_s, w / env.max_duty)
        p = math.exp(rng.uniform(math.log(p_min), math.log(5.0)))
        worst = max(worst, safety.nohd_m(optics.train(w, p), power_w))
    return worst


def test_compiled_in_defaults_keep_the_thesis_laser_class1_over_the_whole_region(thesis):
    env = _defaults()
    assert (env.max_pulse_s, env.max_duty, env.min_period_s) == pytest.approx((17.4e-3, 0.2, 0.090))
    check = verify_envelope(thesis, 0.025, EYE_M, env)
    assert check.class1 and check.worst_nohd_m < EYE_M
    # the worst train is the pulse-train (C5) corner: 625 us pulses at the shortest period
    assert check.limiting_condition == "pulse_train"
    assert check.worst_pulse_s == pytest.approx(625e-6) and check.worst_period_s == pytest.approx(0.090)
    assert check.worst_nohd_m == pytest.approx(9.77e-3, abs=0.01e-3)
    assert check.points > 10_000
    # the worst train is exactly what safety.assess says of it
    train = thesis.train(check.worst_pulse_s, check.worst_period_s)
    assert safety.assess(train, EYE_M, 0.025).nohd_m == pytest.approx(check.worst_nohd_m, rel=1e-12)
    # and no random train inside the region is worse than the verified worst
    assert _brute_force_worst(thesis, 0.025, env, 3000, seed=1) <= check.worst_nohd_m * (1 + 1e-12)


def test_defaults_are_what_the_generator_computes_for_the_thesis_sensor(thesis):
    """10 Hz pulses (20 fps camera, every other frame) minus 10 ms of trim slack, 17.4 ms pulses."""
    env, check = compute_envelope(thesis, 0.025, EYE_M, 17.4e-3, 0.100 - 0.010)
    assert env == _defaults()
    assert check.class1


def test_a_two_number_envelope_or_a_short_min_period_is_caught(thesis):
    bad = FirmwareEnvelope(17_400, 200_000, 33_000)  # one pulse per 33 ms (every other frame at 60 fps)
    check = verify_envelope(thesis, 0.025, EYE_M, bad)
    assert not check.class1
    assert check.worst_nohd_m > 0.012 and check.limiting_condition == "pulse_train"
    assert 0.4e-3 < check.worst_pulse_s < 1.0e-3 and check.worst_period_s == pytest.approx(0.033)
    assert _brute_force_worst(thesis, 0.025, bad, 2000, seed=2) <= check.worst_nohd_m * (1 + 1e-12)
    # width and duty only (the rate limited by what the firmware can place): far outside
    no_rate = FirmwareEnvelope(17_400, 200_000, 300)
    assert verify_envelope(thesis, 0.025, EYE_M, no_rate, width_points=8).worst_nohd_m > 0.014
    # the generator's envelope for 33 ms (its duty cap follows: 17.4 / 33 = 53 %) is refused, naming
    # the worst train and the shortest Class 1 period for 17.4 ms pulses
    with pytest.raises(EnvelopeError, match=r"every 33 ms reach a NOHD of 15\.\d+ mm \(17\.400 ms every 33\.00 ms, "
                                            r"average_power\); the shortest Class 1 period for these pulses is 81\.87 ms"):
        compute_envelope(thesis, 0.025, EYE_M, 17.4e-3, 0.033)


def test_higher_power_gives_a_tighter_envelope(thesis):
    shortest = [shortest_class1_period_s(thesis, p, EYE_M, 17.4e-3) for p in (0.020, 0.025, 0.030)]
    assert shortest[0] < shortest[1] < 0.090 < shortest[2]
    for power, period in zip((0.020, 0.025, 0.030), shortest):
        env = FirmwareEnvelope(17_400, 990_000, round(period * 1e6))
        assert verify_envelope(thesis, power, EYE_M, env, width_points=60).class1
        tighter = FirmwareEnvelope(17_400, 990_000, round(period * 1e6) - 1)
        assert not verify_envelope(thesis, power, EYE_M, tighter, width_points=60).class1, "shortest, to the microsecond"
    with pytest.raises(EnvelopeError, match="shortest Class 1 period for these pulses is 1[0-9][0-9]"):
        compute_envelope(thesis, 0.030, EYE_M, 17.4e-3, 0.090)


def test_a_slower_train_can_be_worse_so_every_c5_step_is_checked(thesis):
    """C5 = N^-0.25 is 0.398 at N = 40 but 0.4 at N = 41: a 17.4 ms pulse train at N = 40 pulses
    in T2 (about 3.3 Hz) has a larger NOHD than at 10 Hz; the candidates include that step."""
    env = _defaults()
    periods = period_candidates_s(thesis, env, 17.4e-3)
    t2 = safety.t2_s(safety.angular_subtense_mrad(1e-3))
    assert any(p == pytest.approx(t2 / 40) for p in periods)
    slow = safety.nohd_m(thesis.train(17.4e-3, t2 / 40), 0.025)
    fast = safety.nohd_m(thesis.train(17.4e-3, 0.1), 0.025)
    assert slow > fast


def test_bad_inputs_are_named():
    with pytest.raises(EnvelopeError, match="min_period_us"):
        FirmwareEnvelope(17_400, 200_000, 10)
    with pytest.raises(EnvelopeError, match="max_pulse_us"):
        FirmwareEnvelope(35_000, 200_000, 90_000)
    with pytest.raises(EnvelopeError, match="max_duty_ppm"):
        FirmwareEnvelope(17_400, 1_000_000, 90_000)
    with pytest.raises(EnvelopeError, match="MIN_PERIOD_US"):
        parse_makefile_envelope("MAX_PULSE_US := 17400\nMAX_DUTY_PPM := 200000\n")
    with pytest.raises(EnvelopeError, match="power"):
        verify_envelope(LineLaserOptics(808, 2.0, 4e-3, 1e-3), float("nan"), EYE_M, _defaults())


def _generator(*args):
    return subprocess.run([sys.executable, "-m", "device.model.envelope", *args], cwd=ROOT,
                          capture_output=True, text=True, timeout=120)


def test_generator_prints_the_makefile_line(tmp_path):
    out = _generator("--preset", "thesis-design")
    assert out.returncode == 0, out.stderr
    env = _defaults()
    assert out.stdout.splitlines()[0] == (f"make -C firmware_pwm BUILD={env.build_dir} MAX_PULSE_US={env.max_pulse_us} "
                                          f"MAX_DUTY_PPM={env.max_duty_ppm} MIN_PERIOD_US={env.min_period_us}")
    assert "worst NOHD 9.77 mm" in out.stdout
    # another laser from a config file: 8 ms pulses at 15 Hz need a shorter minimum period
    cfg = load_preset("thesis-design")
    cfg = type(cfg)(**{**cfg.__dict__, "laser": type(cfg.laser)(**{**cfg.laser.__dict__, "pulse_s": 0.008,
                                                                   "rate_hz": 15.0, "power_w": 0.020})})
    save_config(cfg, tmp_path / "other.toml")
    out = _generator("--config", str(tmp_path / "other.toml"), "--slack-ms", "5")
    assert out.returncode == 0, out.stdout + out.stderr
    assert "MAX_PULSE_US=8000 MAX_DUTY_PPM=130000 MIN_PERIOD_US=61667" in out.stdout
    out = _generator("--preset", "thesis-design", "--power-mw", "30")
    assert out.returncode == 1 and "not Class 1 at 30 mW" in out.stdout


def test_the_envelope_a_firmware_announces_in_ticks_rounds_to_its_loose_side():
    # the production envelope at 16 MHz (2 MHz ticks) and at 8 MHz (1 MHz ticks): the same in microseconds
    assert FirmwareEnvelope.from_ticks(34_800, 200_000, 180_000, 2_000_000) == FirmwareEnvelope(17_400, 200_000, 90_000)
    assert FirmwareEnvelope.from_ticks(17_400, 200_000, 90_000, 1_000_000) == FirmwareEnvelope(17_400, 200_000, 90_000)
    # a tick's remainder: the pulse up, the period down (the firmware allows at least that much)
    assert FirmwareEnvelope.from_ticks(34_801, 200_000, 179_999, 2_000_000) == FirmwareEnvelope(17_401, 200_000, 89_999)
    with pytest.raises(EnvelopeError, match="ticks_per_second"):
        FirmwareEnvelope.from_ticks(34_800, 200_000, 180_000, 0)


def test_the_device_refuses_to_light_a_laser_its_co_mcus_envelope_does_not_keep_class_1():
    import dataclasses

    from device.config import load_preset, with_operating_point
    from device.design.report import sensor_at_rate
    from device.service.assembly import envelope_refusal, laser_pulse_s, roi_rows
    from device.vision.geometry import column_geometry
    from protocol import mcu

    cfg = load_preset("thesis-calibrated")  # the thesis laser, 25 mW, 10 scans/s
    pulse_s = 0.0174  # the pulse the device fires at most (laser_pulse_s)
    production = mcu.Info(2, 0x01, 50, 34_800, 200_000, 2_000_000, 180_000)  # firmware_pwm/Makefile at 16 MHz
    assert envelope_refusal(cfg, pulse_s)(production) is None  # Class 1 to 25.6 mW over every train it allows
    stronger = dataclasses.replace(cfg, laser=dataclasses.replace(cfg.laser, power_w=0.030))
    why = envelope_refusal(stronger, pulse_s)(production)
    assert why is not None and "up to 25.58 mW" in why and "30 mW" in why and "laserpi design" in why
    # a firmware built for that laser at 5 scans/s (12.6 ms pulses at least 190 ms apart) keeps it
    # Class 1, but lets through no train the sensor fires at 10 scans/s: every SCHEDULE would be
    # refused (the co-MCU starts nothing: a scan-less device with no reason given, before)
    at_5_hz = mcu.Info(2, 0x01, 50, 25_200, 70_000, 2_000_000, 380_000)  # 190 ms: 1 / rate less the sync's slack
    why = envelope_refusal(stronger, pulse_s)(at_5_hz)
    assert why is not None and "does not allow the sensor's train at 10 scans/s" in why and "17400 us pulses" in why
    slow = with_operating_point(stronger, scan_rate_hz=5.0)
    assert envelope_refusal(slow, 0.0126)(at_5_hz) is None
    # the 20 scans/s sensor (design's laser power, its own pulse) on the production firmware:
    # pulses 50 ms apart where it allows 90 ms; on the firmware design builds for 20/s it runs
    at_20_hz, at_20_hz_envelope = sensor_at_rate(cfg, 20.0)
    pulse_20 = laser_pulse_s(at_20_hz, *roi_rows(column_geometry(at_20_hz, at_20_hz.operating_point.min_m,
                                                                 at_20_hz.operating_point.max_m)))
    why = envelope_refusal(at_20_hz, pulse_20)(production)
    assert why is not None and f"at 20 scans/s: {pulse_20 * 1e6:.0f} us pulses 50000 us apart" in why
    def info(env):  # the INFO of a firmware with this envelope at 16 MHz (2 ticks a microsecond)
        return mcu.Info(2, 0x01, 50, 2 * env.max_pulse_us, env.max_duty_ppm, 2_000_000, 2 * env.min_period_us)

    assert envelope_refusal(at_20_hz, pulse_20)(info(at_20_hz_envelope)) is None
    # every rate design builds a firmware for passes on that firmware (its period rounded up to whole us)
    for rate in (10.0, 15.0, 20.0):
        sensor, env = sensor_at_rate(cfg, rate)
        assert envelope_refusal(sensor, 0.0174)(info(env)) is None, rate
    # one built without the sync's slack (MIN_PERIOD_US 50000 at 20/s) would refuse some of the
    # trimmed schedules: refused at start-up, the slack named
    tight = dataclasses.replace(at_20_hz_envelope, min_period_us=50_000, max_duty_ppm=348_000)
    why = envelope_refusal(at_20_hz, 0.0174)(info(tight))
    assert why is not None and "less the sync's 10000 us for its trims" in why
