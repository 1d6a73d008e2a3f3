"""`laserpi design` at 10, 15 and 20 scans/s (issue 18): the Class 1 power and the range it allows,
monotonic in the scan rate and consistent with the eye-safety model and the firmware's envelope."""

import dataclasses
from pathlib import Path

import pytest

from device import cli
from device.config import load_preset
from device.design import report
from device.model import envelope, safety
from device.service.assembly import laser_pulse_s, roi_rows
from device.vision.geometry import column_geometry

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def cfg():
    return load_preset("thesis-calibrated")


@pytest.fixture(scope="module")
def points(cfg):
    return report.rate_points(cfg)


def test_the_pulse_is_the_one_the_device_fires_at_every_rate(cfg, points):
    op = cfg.operating_point
    pulse = laser_pulse_s(cfg, *roi_rows(column_geometry(cfg, op.min_m, op.max_m)))
    assert [p.scan_rate_hz for p in points] == [10.0, 15.0, 20.0]
    assert all(p.pulse_s == pulse for p in points)
    assert pulse == cfg.laser.pulse_s  # the ROI pulse (12 ms) is shorter than the 17.4 ms the guards may widen it to


def test_power_and_range_fall_as_the_rate_rises(points):
    for slow, fast in zip(points, points[1:]):
        assert fast.class1_power_w <= slow.class1_power_w
        assert fast.envelope_power_w < slow.envelope_power_w
        assert fast.power_w <= slow.power_w
        assert fast.background_range_m <= slow.background_range_m
        assert fast.background_range_indoor_m <= slow.background_range_indoor_m
    assert points[-1].class1_power_w < points[0].class1_power_w
    assert points[-1].background_range_m < points[0].background_range_m


def test_the_numbers_are_the_safety_models(cfg, points):
    for p in points:
        laser = safety.PulsedLineLaser(cfg.laser.wavelength_m * 1e9, p.pulse_s, p.scan_rate_hz, cfg.laser.fan_angle_rad,
                                       cfg.laser.line_height_m, cfg.laser.source_diameter_m)
        # the train's limit: its NOHD is the closest eye, exactly
        assert safety.nohd_m(laser, p.class1_power_w) == pytest.approx(report.CLOSEST_EYE_M, rel=1e-9)
        # the envelope allows that train and denser ones: its limit is at most the train's
        assert p.envelope_power_w <= p.class1_power_w
        assert p.envelope.max_pulse_s <= p.pulse_s and p.envelope.min_period_s < 1 / p.scan_rate_hz
        optics = envelope.LineLaserOptics(cfg.laser.wavelength_m * 1e9, cfg.laser.fan_angle_rad,
                                          cfg.laser.line_height_m, cfg.laser.source_diameter_m)
        below = envelope.verify_envelope(optics, p.envelope_power_w * (1 - 1e-6), report.CLOSEST_EYE_M, p.envelope)
        above = envelope.verify_envelope(optics, p.envelope_power_w * (1 + 1e-3), report.CLOSEST_EYE_M, p.envelope)
        assert below.class1 and not above.class1
        assert p.power_w == min(cfg.laser.power_w, p.envelope_power_w)
        assert p.frames_fit


def test_10_hz_is_the_shipped_firmware_and_20_hz_needs_less_power(cfg, points):
    shipped = envelope.parse_makefile_envelope((ROOT / "firmware_pwm" / "Makefile").read_text())
    assert points[0].envelope == shipped
    assert points[0].envelope_power_w >= cfg.laser.power_w  # the thesis laser is Class 1 with it
    assert points[-1].envelope.min_period_us == 40_000  # 50 ms less the 10 ms slack
    assert points[-1].envelope_power_w < cfg.laser.power_w  # ... but not at 20 scans/s


def test_a_rate_the_sensor_mode_cannot_run_is_marked(cfg):
    fast = cfg.window.mode.max_frame_rate_hz / 2 + 0.5
    (p,) = report.rate_points(cfg, (fast,))
    assert not p.frames_fit


def test_the_readable_report_shows_the_rates(capsys):
    assert cli.main(["design", "--preset", "thesis-calibrated"]) == 0
    out = capsys.readouterr().out
    assert "the sensor mode allows at most 20.93 scans/s" in out
    assert "MIN_PERIOD_US=40000" in out
    rows = [line.split() for line in out.splitlines() if line.strip().split(" ")[0] in ("10", "15", "20")
            and " mW " in line]
    assert [r[0] for r in rows] == ["10", "15", "20"]


def test_the_report_prints_limits_a_user_can_copy(capsys, cfg, points):
    """A printed power limit is rounded down (a laser set to it stays within it: 20.0769 mW was
    printed 20.08, which the device then refused), and each rate's make line builds into a
    directory of its own (run verbatim, it replaced the production ELF that serve runs)."""
    assert cli.main(["design", "--preset", "thesis-calibrated"]) == 0
    out = capsys.readouterr().out
    for p in points:
        row = next(line.split() for line in out.splitlines() if line.split()[:1] == [f"{p.scan_rate_hz:g}"]
                   and " mW " in line)
        class1_mw, envelope_mw, power_mw = float(row[1]), float(row[3]), float(row[5])
        assert class1_mw <= p.class1_power_w * 1e3 < class1_mw + 0.01
        assert envelope_mw <= p.envelope_power_w * 1e3 < envelope_mw + 0.01
        assert power_mw <= p.power_w * 1e3 < power_mw + 0.01
        assert f"BUILD={p.envelope.build_dir} " in out and p.envelope.build_dir != "build"
    assert safety.mw_down(0.0200769) == 20.07 and safety.mw_down(0.02008) == 20.08 and safety.mw_down(0.30 * 1e-3) == 0.30


def test_a_config_at_20_hz_changes_nothing_but_the_operating_point(cfg):
    # the table does not depend on the operating point's own rate
    at20 = dataclasses.replace(cfg, operating_point=dataclasses.replace(cfg.operating_point, scan_rate_hz=20.0))
    assert report.rate_points(at20, (20.0,))[0] == report.rate_points(cfg, (20.0,))[0]
