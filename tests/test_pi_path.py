"""The Pi path of the device process, here without a Pi: the camera stack check, the GPIO edge
line from the command line or the configuration, and PING-only sync reported as degraded."""

import logging
import sys

import pytest

from device.config import ConfigError, config_from_dict, config_to_dict, load_preset
from device.service.assembly import AssemblyConfig, build_sensor
from device.sync.gpio_edges import parse_gpio_edge
from protocol import messages as m
from tests.fake_picamera2 import ManualClock, install_fake
from tests.test_picamera2_camera import TIMING, gradient


@pytest.fixture
def pi_camera(monkeypatch):
    install_fake(monkeypatch, clock=ManualClock(), render=gradient, timing=TIMING)


def test_gpio_edge_specs():
    assert parse_gpio_edge("gpiochip0:17") == ("/dev/gpiochip0", 17)
    assert parse_gpio_edge("/dev/gpiochip4:27") == ("/dev/gpiochip4", 27)
    for bad in ("gpiochip0", "gpiochip0:", ":17", "gpiochip0:x", "gpiochip0:-1"):
        with pytest.raises(ValueError, match="CHIP:LINE"):
            parse_gpio_edge(bad)


def test_the_configuration_carries_the_gpio_edge_line():
    cfg = load_preset("thesis-calibrated")
    assert cfg.gpio_edge is None and "pi" not in config_to_dict(cfg)
    doc = config_to_dict(cfg)
    doc["pi"] = {"gpio_edge": "gpiochip0:17"}
    wired = config_from_dict(doc, "wired.toml")
    assert wired.gpio_edge == "gpiochip0:17" and config_to_dict(wired)["pi"] == {"gpio_edge": "gpiochip0:17"}
    doc = config_to_dict(cfg)
    doc["pi"] = {"gpio_edge": "17"}
    with pytest.raises(ConfigError, match=r"\[pi\]: gpio_edge: .*CHIP:LINE"):
        config_from_dict(doc, "bad.toml")
    doc["pi"] = {"gpio_line": "gpiochip0:17"}
    with pytest.raises(ConfigError, match=r"\[pi\]"):
        config_from_dict(doc, "bad.toml")


def test_without_a_gpio_edge_line_sync_is_degraded_in_health_and_the_log(pi_camera, caplog):
    with caplog.at_level(logging.WARNING, logger="device.service.assembly"):
        built = build_sensor(AssemblyConfig(simulate=False, comcu="/dev/null-comcu"))
    assert m.ErrorCode.SYNC_DEGRADED in built.source.status().errors
    assert any("sync degraded" in r.getMessage() and "--gpio-edge" in r.getMessage() for r in caplog.records)
    assert built.source.laser.gpio_edges is None


def test_a_configured_gpio_edge_line_that_cannot_be_opened_stops_serve(pi_camera):
    with pytest.raises(RuntimeError, match="gpiod|gpiochip"):
        build_sensor(AssemblyConfig(simulate=False, gpio_edge="gpiochip99:17"))
    with pytest.raises(ValueError, match="CHIP:LINE"):
        build_sensor(AssemblyConfig(simulate=False, gpio_edge="seventeen"))


def test_the_simulated_sensor_syncs_by_gpio_edges_and_is_not_degraded():
    built = build_sensor(AssemblyConfig(simulate=True))
    try:
        assert m.ErrorCode.SYNC_DEGRADED not in built.source.status().errors
        assert built.source.laser.gpio_edges is not None
    finally:
        for close in built.closers:
            close()


def test_a_broken_camera_stack_stops_serve_with_what_to_install(monkeypatch):
    monkeypatch.setitem(sys.modules, "picamera2", None)
    with pytest.raises(RuntimeError, match="python3-picamera2.*--system-site-packages"):
        build_sensor(AssemblyConfig(simulate=False))
