"""20 scans/s (issue 18): the host link's budget, the scan-rate override of `laserpi serve`, and
the simulated sensor at 20 scans/s with the co-MCU firmware built for that rate."""

from __future__ import annotations

from pathlib import Path

import numpy as np

import pytest

import host_sdk
from device import cli
from device.config import PRESET_DIR, ConfigError, load_config, load_preset, with_operating_point
from device.design.report import rate_points
from device.service.child import start_serve, stop_serve
from device.sim.comcu_emulator import build_emulator
from protocol import messages as m
from protocol.mock_wall import default_settings
from protocol.server import DeviceConfig, settings_refusal

UART = 921_600


def config_at(tmp_path: Path, rate_hz: float, power_w: float) -> Path:
    """The thesis-calibrated preset with a laser for ``rate_hz`` pulses/s at ``power_w``."""
    text = (PRESET_DIR / "thesis-calibrated.toml").read_text()
    assert "rate_hz = 10.0" in text and "power_w = 0.025" in text
    path = tmp_path / f"at-{rate_hz:g}-hz.toml"
    path.write_text(text.replace("rate_hz = 10.0", f"rate_hz = {rate_hz}").replace("power_w = 0.025", f"power_w = {power_w}"))
    return path


# --- the link budget ----------------------------------------------------------------------------
def test_a_full_scan_at_20_hz_does_not_fit_921600_baud_and_the_reason_says_what_would():
    why = m.link_budget_refusal(1640, 20.0, UART)
    assert why is not None
    assert "1640 points at 20 scans/s need 996.0 kbit/s" in why and "921.6 kbit/s" in why and "USB" in why
    points = int(why.split("use at most ")[1].split(" points")[0])
    rate = float(why.split("at most ")[2].split(" scans/s")[0])
    budget = UART / (20 * m.UART_BITS_PER_BYTE)  # bytes per scan
    assert m.scan_wire_bytes(points) <= budget < m.scan_wire_bytes(points + 1)
    assert m.link_budget_refusal(points, 20.0, UART) is None and m.link_budget_refusal(points + 1, 20.0, UART)
    assert m.scan_wire_bytes(1640) * rate * m.UART_BITS_PER_BYTE <= UART
    assert m.link_budget_refusal(1640, rate, UART) is None


@pytest.mark.parametrize("points, rate, bps, fits", [
    (1640, 10.0, UART, True), (1640, 15.0, UART, True), (1640, 20.0, UART, False),
    (1640, 10.0, 460_800, False), (1640, 20.0, None, True), (1200, 20.0, UART, True),
])
def test_the_budget_is_bytes_per_scan_times_rate_at_10_bits_per_byte(points, rate, bps, fits):
    assert (m.link_budget_refusal(points, rate, bps) is None) == fits
    if bps is not None:
        assert fits == (m.scan_wire_bytes(points) * rate * 10 <= bps)


def test_set_config_and_power_on_settings_that_do_not_fit_are_refused():
    config = DeviceConfig(laser_limit_mw=5.0, settings=default_settings(1640), link_rate_bps=UART)
    faster = default_settings(1640).merged(m.ScanSettings(scan_rate_hz=20.0))
    code, why = settings_refusal(faster, config, 1640)
    assert code == m.NackCode.OUT_OF_RANGE and why == m.link_budget_refusal(1640, 20.0, UART)
    assert settings_refusal(faster.merged(m.ScanSettings(roi_count=1400)), config, 1640) is None
    with pytest.raises(ValueError, match="power-on settings do not fit the host link: 1640 points at 20 scans/s"):
        DeviceConfig(laser_limit_mw=5.0, settings=faster, link_rate_bps=UART)
    DeviceConfig(laser_limit_mw=5.0, settings=faster)  # a link that is not limited


def test_serve_refuses_a_start_up_setting_that_does_not_fit(capsys, tmp_path):
    assert cli.main(["serve", "--simulate", "--mock", "--points", "1640", "--baud", "460800",
                     "--link", str(tmp_path / "l")]) == 2
    assert "do not fit the host link: 1640 points at 10 scans/s" in capsys.readouterr().out
    assert not (tmp_path / "l").exists()


# --- the scan-rate override ---------------------------------------------------------------------
def test_the_override_is_checked_like_the_file(tmp_path):
    cfg = load_preset("thesis-calibrated")
    with pytest.raises(ConfigError, match=r"scan_rate_hz = 20 exceeds \[laser\] rate_hz = 10.*laserpi design"):
        with_operating_point(cfg, scan_rate_hz=20.0)
    at20 = with_operating_point(load_config(config_at(tmp_path, 20.0, 0.02)), scan_rate_hz=20.0)
    assert at20.operating_point.scan_rate_hz == 20.0
    too_fast = load_config(config_at(tmp_path, 25.0, 0.02))
    with pytest.raises(ConfigError, match="needs 44 frames/s; the 1640x1232 sensor mode runs at .* to 41.85 frames/s"):
        with_operating_point(too_fast, scan_rate_hz=22.0)


def test_serve_names_what_a_faster_rate_needs(capsys, tmp_path):
    assert cli.main(["serve", "--simulate", "--scan-rate-hz", "20", "--link", str(tmp_path / "l")]) == 2
    assert "exceeds [laser] rate_hz = 10" in capsys.readouterr().out
    assert cli.main(["serve", "--firmware", "x.elf", "--link", str(tmp_path / "l")]) == 2
    assert "--firmware needs --simulate" in capsys.readouterr().out
    assert cli.main(["serve", "--simulate", "--mock", "--scan-rate-hz", "20", "--link", str(tmp_path / "l")]) == 2


# --- the simulated sensor at 20 scans/s ---------------------------------------------------------
def test_bench_process_at_20_hz_runs_the_20_hz_sensor_and_firmware(tmp_path):
    from device.bench.process import LINK_BAUD, rate_arguments

    args = rate_arguments(20.0, tmp_path)
    cfg = load_config(args[args.index("--config") + 1])
    assert cfg.operating_point.scan_rate_hz == cfg.laser.rate_hz == 20.0
    (point,) = rate_points(load_preset("thesis-calibrated"), (20.0,))
    assert cfg.laser.power_w == point.envelope_power_w < 0.025
    elf = Path(args[args.index("--firmware") + 1])
    assert elf.exists() and str(elf.parent).endswith(point.envelope.build_dir)
    assert args[args.index("--baud") + 1] == str(LINK_BAUD)
    at10 = rate_arguments(10.0, tmp_path)  # the preset's rate: the production firmware, 921600 baud
    assert at10 == ["--config", str(tmp_path / "sensor.toml")]


@pytest.mark.slow
def test_serve_at_20_scans_per_second_locks_with_the_20_hz_firmware(tmp_path):
    cfg_path = config_at(tmp_path, 20.0, 0.02)
    (point,) = rate_points(load_config(cfg_path), (20.0,))
    assert point.envelope_power_w >= 0.02  # the laser is Class 1 with that envelope
    env = point.envelope
    _, elf = build_emulator("build/test-20hz", MAX_PULSE_US=env.max_pulse_us, MAX_DUTY_PPM=env.max_duty_ppm,
                            MIN_PERIOD_US=env.min_period_us)
    link, log = tmp_path / "laserpi", tmp_path / "serve.log"
    # 1640 points do not fit 921600 baud at 20 scans/s; 1200 fill 79 % of it (1500, 99 %, once
    # dropped 7 of 60 scans in CI: the simulated clock then raced to make up for a stall of this
    # machine, a burst of scans faster than the link carries; it no longer does)
    points = 1200
    proc = start_serve(link, ["--simulate", "--scene", "wall", "--distance-m", "2.0", "--config", str(cfg_path),
                              "--scan-rate-hz", "20", "--firmware", str(elf), "--points", str(points)],
                       log_path=log, timeout_s=90)
    try:
        with host_sdk.LaserPi(str(link), timeout_s=60.0) as sensor:
            assert sensor.info().scan_rate_hz == 20.0
            it = sensor.scans()
            first = next(it)
            assert first.ranges.size == points
            scans = [next(it) for _ in range(60)]
            health = sensor.health()
        assert health.sync_locked, log.read_text()[-3000:]
        # in the simulated clock (this machine may run the simulation slower than real time: the
        # renderer draws 40 frames per simulated second): every scan on the 50 ms grid of a train
        # locked at 20/s. A scan can be lost, and is then counted: a camera frame dropped while this
        # machine stalled the device (HEALTH frames_dropped), or a scan dropped whole by the link
        # when a stall let the queue overflow (scans_dropped, and a jump in the scan seq)
        seqs = np.array([s.seq for s in scans])
        steps = np.diff([s.device_time for s in scans]) / 0.05
        periods = np.rint(steps)
        assert np.all(np.abs(steps - periods) < 0.02) and np.all(periods >= 1), steps
        lost, link_lost = int(np.sum(periods - 1)), int(np.sum(np.diff(seqs) - 1))
        assert np.all(np.diff(seqs) >= 1) and link_lost <= health.scans_dropped
        assert lost <= 3 and lost <= health.frames_dropped + health.scans_dropped, (lost, health)
    finally:
        stop_serve(proc)
    assert "sync locked" in log.read_text()
